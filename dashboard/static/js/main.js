// The page: connects to the broker, keeps a FleetView, renders it, and sends operator requests.

import { BrokerConnection } from "./connection.js";
import { initialClicks, mapClick, selectUnit, setMode } from "./clicks.js";
import { drawFleet, squareAt } from "./draw.js";
import { Forms } from "./forms.js";
import { FleetView } from "./model.js";
import { Requests, sentFeedback } from "./requests.js";
import { syncRows } from "./rows.js";
import {
  encodeEstop, ID_RE, makeClientId, parseTopic, Stamper, subscriptions, topicsFor,
} from "./protocol.js";

const $ = (sel) => document.querySelector(sel);
const HOLD_MS = 1500; // release needs a deliberate press-and-hold
const ESTOP_BY = "dashboard";

function fatal(text) {
  const el = $("#fatal");
  el.textContent = text;
  el.hidden = false;
  $("#conn").dataset.state = "failed";
  $("#conn").textContent = "no MQTT client";
}

async function start() {
  let settings;
  try {
    const res = await fetch("/api/settings");
    settings = await res.json();
  } catch (e) {
    fatal(`cannot load /api/settings from the dashboard server: ${e}`);
    return;
  }
  if (!settings.mqtt_js.available) {
    fatal(settings.mqtt_js.hint);
    return;
  }
  let mqtt;
  try {
    mqtt = (await import("/vendor/mqtt.esm.js")).default;
  } catch (e) {
    fatal(`cannot load MQTT.js (${e.message}). ${settings.mqtt_js.hint ?? ""}`);
    return;
  }
  const params = new URLSearchParams(location.search);
  const wanted = params.get("client");
  const clientId = wanted && ID_RE.test(wanted) ? wanted : makeClientId(settings.client_prefix);
  new Dashboard(mqtt, settings, clientId).run();
}

class Dashboard {
  constructor(mqtt, settings, clientId) {
    this.mqttLib = mqtt;
    this.settings = settings;
    this.clientId = clientId;
    this.topics = topicsFor(settings.root);
    this.view = new FleetView(settings.map, settings.colors ?? {});
    this.stamper = new Stamper(clientId);
    this.requests = new Requests(clientId, this.stamper);
    this.ui = initialClicks(); // the map's click mode and what it has picked so far
    this.layout = null;
    this.dirty = true;
    this.localStop = false; // the operator pressed STOP and the broker has not echoed it yet
    this.forms = new Forms(this.view, {
      send: (kind, form, what, body) => this.request(kind, form, what, body),
      onUnitChosen: (id) => { this.ui = selectUnit(this.ui, id); this.dirty = true; },
    });
    document.body.dataset.clientId = clientId;
  }

  run() {
    this.connect();
    this.bindControls();
    // The map's box changes with the window and with the page around it (e.g. the stop banner).
    new ResizeObserver(() => { this.dirty = true; }).observe($("#canvas-wrap"));
    const frame = () => {
      const now = Date.now();
      // Redraw on change, and while a fresh obstacle flashes.
      if (this.dirty || this.view.knownObstacles(now).some((o) => o.fresh)) {
        this.render(now);
        this.dirty = false;
      }
      requestAnimationFrame(frame);
    };
    requestAnimationFrame(frame);
    setInterval(() => this.renderSeen(Date.now()), 500);
  }

  // ---- MQTT ----
  connect() {
    const subs = subscriptions(this.topics, this.clientId);
    const conn = $("#conn");
    this.client = new BrokerConnection(this.mqttLib, this.settings.broker_ws, this.clientId, subs, {
      onStatus: (state, text) => { conn.dataset.state = state; conn.textContent = text; this.renderEstop(); },
      onMessage: (topic, payload) => this.onMessage(topic, payload),
      onLog: (text) => this.log(text),
    }).start();
  }

  onMessage(topic, payload) {
    const parsed = parseTopic(this.topics.prefix, topic);
    if (!parsed) return;
    const text = new TextDecoder().decode(payload);
    if (parsed.kind === "reply") {
      if (parsed.id === this.clientId) this.show(this.requests.reply(text));
      return;
    }
    const problem = this.view.apply(parsed.kind, parsed.id, text, Date.now());
    if (problem) this.log(problem);
    if (parsed.kind === "errors" && !problem) this.show(this.requests.error(this.view.lastError));
    if (parsed.kind === "estop") this.localStop = false;
    this.dirty = true;
  }

  /** Feedback and a log line from the request bookkeeping, either may be null. */
  show({ feedback, log }) {
    if (feedback) this.forms.feedback(feedback.form, feedback.kind, feedback.text);
    if (log) this.log(log);
  }

  request(kind, form, what, body) {
    const { request_id, message } = this.requests.create(kind, form, what, body);
    this.client.publish(this.topics.request(kind), JSON.stringify(message), { qos: 1, retain: false });
    this.show({ feedback: sentFeedback(form, what, this.client.connected), log: null });
    return request_id;
  }

  publishEstop(engaged, reason) {
    const payload = encodeEstop(engaged, ESTOP_BY, reason);
    this.client.publish(this.topics.estop, payload, { qos: 1, retain: true });
  }

  // ---- controls ----
  bindControls() {
    $("#stop").addEventListener("click", () => {
      this.localStop = true;
      this.publishEstop(true, `operator pressed STOP on ${this.clientId}`);
      this.log("STOP pressed: emergency stop sent");
      this.renderEstop();
    });
    this.bindRelease($("#release"));
    for (const r of document.querySelectorAll("input[name=clickmode]")) {
      r.addEventListener("change", () => {
        this.ui = setMode(this.ui, r.value);
        this.dirty = true;
      });
    }
    const canvas = $("#map");
    canvas.addEventListener("click", (ev) => this.onMapClick(ev));
    canvas.addEventListener("mousemove", (ev) => {
      const sq = this.layout && squareAt(this.layout, ev.offsetX, ev.offsetY);
      $("#hover").textContent = sq ? `[${sq[0]}, ${sq[1]}]` : "";
    });
    this.forms.bind();
    $("#jobs tbody").addEventListener("click", (ev) => {
      const btn = ev.target.closest("button[data-cancel]");
      if (btn) this.forms.cancelJob(btn.dataset.cancel);
    });
    $("#units tbody").addEventListener("click", (ev) => {
      const row = ev.target.closest("tr[data-unit]");
      if (row) this.selectUnit(row.dataset.unit);
    });
  }

  bindRelease(btn) {
    let timer = null, startedAt = 0, raf = null;
    const fill = btn.querySelector(".fill");
    const cancel = () => {
      clearTimeout(timer); timer = null;
      cancelAnimationFrame(raf);
      fill.style.width = "0%";
      btn.classList.remove("holding");
    };
    const grow = () => {
      fill.style.width = `${Math.min(100, ((Date.now() - startedAt) / HOLD_MS) * 100)}%`;
      if (timer) raf = requestAnimationFrame(grow);
    };
    const begin = (ev) => {
      ev.preventDefault();
      if (timer) return;
      startedAt = Date.now();
      btn.classList.add("holding");
      timer = setTimeout(() => {
        timer = null;
        cancel();
        this.localStop = false;
        this.publishEstop(false, `released by operator on ${this.clientId}`);
        this.log("emergency stop released by operator");
      }, HOLD_MS);
      raf = requestAnimationFrame(grow);
    };
    btn.addEventListener("pointerdown", begin);
    btn.addEventListener("keydown", (ev) => { if ((ev.key === " " || ev.key === "Enter") && !ev.repeat) begin(ev); });
    for (const e of ["pointerup", "pointerleave", "pointercancel", "keyup", "blur"]) btn.addEventListener(e, cancel);
  }

  selectUnit(id) {
    this.ui = selectUnit(this.ui, id);
    this.forms.showUnit(id);
    this.dirty = true;
  }

  onMapClick(ev) {
    if (!this.layout) return;
    const sq = squareAt(this.layout, ev.offsetX, ev.offsetY);
    if (!sq) return;
    const { state, effect } = mapClick(this.ui, sq, this.view.unitAt(sq[0], sq[1])?.id ?? null);
    this.ui = state;
    if (!effect) return;
    if (effect.type === "select") this.forms.showUnit(effect.unit);
    else if (effect.type === "goal") this.forms.goalAt(effect.square);
    else if (effect.type === "pickup") this.forms.pickupAt(effect.square);
    else if (effect.type === "dropoff") this.forms.dropoffAt(effect.square);
    this.dirty = true;
  }

  log(text) {
    const li = document.createElement("li");
    li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
    const ul = $("#log");
    ul.prepend(li);
    while (ul.children.length > 50) ul.lastChild.remove();
  }

  // ---- rendering ----
  render(now) {
    this.layout = drawFleet($("#map"), this.view, now, this.ui);
    const m = this.view.map;
    $("#map-name").textContent = m ? `${m.name} ${m.width} x ${m.height}` : "no map yet";
    this.renderUnits(now);
    this.renderJobs();
    this.renderEstop();
    this.renderCoordinator();
  }

  renderUnits(now) {
    const tbody = $("#units tbody");
    const ids = [...this.view.units.keys()].sort();
    syncRows(tbody, ids, {
      keyName: "unit",
      key: (id) => id,
      cells: (id) => {
        const u = this.view.units.get(id);
        const s = u.state;
        const cap = u.factsheet ? `/${u.factsheet.capacity_kg}` : "";
        const status = s ? s.status + (s.wait_reason ? `: ${s.wait_reason}` : "") : "—";
        return [
          [id, "id"], [u.connection ?? "?", "link"],
          [s ? `[${s.position[0]}, ${s.position[1]}]` : "—", "pos"], [status, "status"],
          [s?.job_id ?? "—", "job"], [s ? `${s.load_kg}${cap} kg` : (cap ? `0${cap} kg` : "—"), "load"],
        ];
      },
      extra: (tr, id, fresh) => {
        const u = this.view.units.get(id);
        if (fresh) {
          const seen = document.createElement("td");
          seen.className = "seen";
          tr.append(seen);
        }
        tr.dataset.link = u.connection ?? "unknown";
        tr.classList.toggle("selected", id === this.ui.selectedUnit);
        tr.children[0].style.borderLeft = `6px solid ${this.view.colorOf(id)}`;
        tr.children[3].title = u.state?.wait_reason ?? "";
      },
    });
    this.renderSeen(now);
    this.forms.syncUnits(ids, this.ui.selectedUnit);
  }

  renderSeen(now) {
    for (const tr of document.querySelectorAll("#units tbody tr")) {
      const u = this.view.units.get(tr.dataset.unit);
      const td = tr.querySelector(".seen");
      if (!u || !td) continue;
      td.textContent = u.lastSeen == null ? "never" : `${Math.max(0, Math.round((now - u.lastSeen) / 1000))} s ago`;
      tr.classList.toggle("silent", this.view.isSilent(u, now));
    }
  }

  renderJobs() {
    const active = this.view.activeJobs();
    syncRows($("#jobs tbody"), active, {
      keyName: "job",
      key: (j) => j.id,
      cells: (j) => [[j.id, "id"], [j.state, "state"], [j.unit ?? "—", "unit"],
        [`[${j.pickup}] → [${j.dropoff}]`, "route"], [String(j.mass_kg), "mass"]],
      extra: (tr, j, fresh) => {
        tr.className = `job-${j.state}`;
        if (!fresh) return;
        const td = document.createElement("td");
        const b = document.createElement("button");
        b.type = "button";
        b.dataset.cancel = j.id;
        b.textContent = "delete";
        b.title = `delete job ${j.id}`;
        td.append(b);
        tr.append(td);
      },
    });
    $("#queue-count").textContent = `(${active.length})`;
    const finished = this.view.finishedJobs();
    syncRows($("#finished tbody"), finished, {
      keyName: "job",
      key: (j) => j.id,
      cells: (j) => [[j.id, "id"], [j.state, "state"], [j.unit ?? "—", "unit"], [j.reason ?? "", "reason"]],
      extra: (tr, j) => { tr.className = `job-${j.state}`; },
    });
    const counts = {};
    for (const j of finished) counts[j.state] = (counts[j.state] ?? 0) + 1;
    for (const [k, v] of Object.entries(this.view.counts)) if (k in counts || ["done", "cancelled", "rejected", "failed"].includes(k)) counts[k] = v;
    $("#finished-counts").textContent = Object.entries(counts).map(([k, v]) => `${k} ${v}`).join(" · ");
  }

  renderEstop() {
    const e = this.view.estop;
    const stopped = this.view.stopped || this.localStop;
    document.body.dataset.estop = stopped ? "engaged" : (e ? "released" : "unknown");
    const banner = $("#estop-banner");
    banner.hidden = !stopped;
    if (stopped) {
      banner.textContent = e?.engaged
        ? `EMERGENCY STOP — engaged by ${e.by}${e.reason ? ": " + e.reason : ""}`
        : "EMERGENCY STOP — sending…";
    }
    $("#stop").textContent = stopped ? "STOPPED" : "STOP";
    $("#release").hidden = !this.view.stopped;
  }

  renderCoordinator() {
    const c = this.view.coordinator;
    const el = $("#coord");
    el.dataset.state = c?.state ?? "unknown";
    el.textContent = c ? `coordinator: ${c.state}, step ${this.view.coordinatorStep()}` : "coordinator: not seen";
  }
}

start();
