// Alerts on the page (protocol.md §5.8): a notification for every alert nobody has acknowledged,
// which stays until somebody does (here, at `gridfleet alerts --ack`, or on another page), and the
// Alerts tab listing those in force and the latest cleared. Redrawn only when the alerts view
// changes (a raise, a clear, an acknowledgement), never for the fleet's other messages.

import {
  ackRequest, alertCells, alertsKey, alertsOf, alertWhen, moreText, TOASTS_SHOWN, unacknowledged,
} from "./alerts.js";
import { shortStamp } from "./history.js";
import { clockText } from "./story.js";

const $ = (sel) => document.querySelector(sel);

export class AlertsView {
  /** `send(kind, form, what, body)` publishes a request (the acknowledgement). */
  constructor({ send }) {
    this.send = send;
    this.alerts = { active: [], cleared: [] };
    this.key = null;
    this.heard = false; // a view has come (the alerts process runs, or ran)
    this.acking = new Set(); // alerts whose acknowledgement is on its way
    for (const sel of ["#toast-list", "#alerts-active", "#alerts-cleared"]) {
      $(sel).addEventListener("click", (ev) => {
        const b = ev.target.closest("button[data-ack]");
        if (b) this.acknowledge(b.dataset.ack);
      });
    }
  }

  /** The retained `fleet/alerts` (its text): shown when it changed. */
  take(text) {
    let msg = null;
    try { msg = text ? JSON.parse(text) : { active: [], cleared: [] }; } catch { /* told below */ }
    if (typeof msg !== "object" || msg === null) return "ignored a malformed fleet/alerts";
    this.alerts = alertsOf(msg);
    this.heard = true;
    const key = alertsKey(this.alerts);
    if (key === this.key) return null;
    this.key = key;
    this.render();
    return null;
  }

  acknowledge(id) {
    const alert = [...this.alerts.active, ...this.alerts.cleared].find((a) => a.id === id);
    if (!alert || this.acking.has(id)) return;
    const req = ackRequest(alert);
    this.acking.add(id);
    this.send("ack_alert", "alerts", req.what, req.body);
    this.render();
  }

  /** An acknowledgement was refused (or given up): its button may be pressed again. */
  answered() {
    if (!this.acking.size) return;
    this.acking.clear();
    this.render();
  }

  render() {
    const waiting = unacknowledged(this.alerts);
    const count = $("#alerts-count");
    count.textContent = waiting.length ? String(waiting.length) : "";
    $("#toast-list").replaceChildren(...waiting.slice(0, TOASTS_SHOWN).map((a) => this.toast(a)));
    $("#toast-more").textContent = moreText(waiting.length);
    $("#alerts-none").hidden = this.heard;
    this.table("#alerts-active tbody", this.alerts.active);
    this.table("#alerts-cleared tbody", this.alerts.cleared);
  }

  toast(a) {
    const div = document.createElement("div");
    div.className = "toast";
    div.dataset.alert = a.id;
    div.dataset.severity = a.severity ?? "";
    div.setAttribute("role", "alert");
    const text = document.createElement("div");
    text.className = "text";
    text.textContent = a.text;
    const when = document.createElement("div");
    when.className = "when";
    when.textContent = `${a.severity ?? ""} · ${alertWhen(a, clockText)}`;
    div.append(text, this.ackButton(a), when);
    return div;
  }

  ackButton(a) {
    const b = document.createElement("button");
    b.type = "button";
    b.dataset.ack = a.id;
    b.disabled = this.acking.has(a.id);
    b.textContent = b.disabled ? "acknowledging…" : "Acknowledge";
    b.title = `acknowledge alert ${a.id}: you have seen it and take it on`;
    return b;
  }

  table(sel, alerts) {
    const clock = (iso) => shortStamp(iso, Date.now());
    if (!alerts.length) {
      const tr = document.createElement("tr");
      const td = document.createElement("td");
      td.colSpan = 6;
      td.className = "none";
      td.textContent = "none";
      tr.append(td);
      $(sel).replaceChildren(tr);
      return;
    }
    $(sel).replaceChildren(...alerts.map((a) => {
      const tr = document.createElement("tr");
      tr.dataset.alert = a.id;
      tr.className = `alert-${a.severity}`;
      for (const [text, className] of alertCells(a, clock)) {
        const td = document.createElement("td");
        td.className = className;
        td.textContent = text;
        tr.append(td);
      }
      const td = document.createElement("td");
      if (!a.acked_by) td.append(this.ackButton(a));
      tr.append(td);
      return tr;
    }));
  }
}
