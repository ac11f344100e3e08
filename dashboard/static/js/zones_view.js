// The closed zones' list beside the map (protocol.md §5.11): every zone the coordinator says is
// closed, with an "Open" button each for the accounts that may change the fleet (none for a
// viewer). Rebuilt only when the zones, the clock's day or an opening under way change.

import { shortStamp } from "./history.js";
import { openZoneRequest, zoneCells } from "./zones.js";

const $ = (sel) => document.querySelector(sel);
const COLUMNS = 6;

export class ZonesView {
  /** `send(kind, form, what, body)` publishes a request; `mayChange`: "Open" buttons, or none. */
  constructor({ send, mayChange }) {
    this.send = send;
    this.mayChange = mayChange;
    this.zones = [];
    this.key = null;
    this.opening = new Set(); // zones whose open_zone is on its way
    $("#zones tbody").addEventListener("click", (ev) => {
      const b = ev.target.closest("button[data-open]");
      if (b) this.open(b.dataset.open);
    });
    if (!mayChange) $("#zones-hint").textContent = "no unit is sent into a closed zone (fleet/zones); your account may not open or close them";
  }

  /** The zones as the fleet view holds them (FleetView.zones), at `now` (ms). */
  show(zones, now) {
    const names = new Set(zones.map((z) => z.name));
    for (const name of this.opening) if (!names.has(name)) this.opening.delete(name); // opened
    const key = JSON.stringify([zones, [...this.opening], new Date(now).toDateString()]);
    if (key === this.key) return;
    this.key = key;
    this.zones = zones;
    this.render(now);
  }

  open(name) {
    const zone = this.zones.find((z) => z.name === name);
    if (!zone || this.opening.has(name) || !this.mayChange) return;
    const req = openZoneRequest(zone);
    this.opening.add(name);
    this.send("open_zone", "zones", req.what, req.body);
    this.key = null;
    this.render(Date.now());
  }

  /** An open_zone was refused (or given up): its button may be pressed again. */
  answered() {
    if (!this.opening.size) return;
    this.opening.clear();
    this.key = null;
    this.render(Date.now());
  }

  render(now) {
    $("#zones-count").textContent = `(${this.zones.length})`;
    const tbody = $("#zones tbody");
    if (!this.zones.length) {
      const tr = document.createElement("tr");
      const td = document.createElement("td");
      td.colSpan = COLUMNS;
      td.className = "none";
      td.textContent = this.mayChange ? "none closed: to close one, choose “drag closes a zone” and drag over the map" : "none closed";
      tr.append(td);
      tbody.replaceChildren(tr);
      return;
    }
    const clock = (iso) => shortStamp(iso, now);
    tbody.replaceChildren(...this.zones.map((z) => {
      const tr = document.createElement("tr");
      tr.dataset.zone = z.name;
      for (const [text, className] of zoneCells(z, clock)) {
        const td = document.createElement("td");
        td.className = className;
        td.textContent = text;
        td.title = text;
        tr.append(td);
      }
      const td = document.createElement("td");
      if (this.mayChange) {
        const b = document.createElement("button");
        b.type = "button";
        b.dataset.open = z.name;
        b.disabled = this.opening.has(z.name);
        b.textContent = b.disabled ? "opening…" : "Open";
        b.title = `open zone ${z.name}: units may be sent into it again`;
        td.append(b);
      }
      tr.append(td);
      return tr;
    }));
  }
}
