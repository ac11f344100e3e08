// The page's wiring: loads its settings and MQTT.js, then ties the broker connection, the fleet
// model, the request bookkeeping, the forms, the map's click modes and the view together.
//
//   login.js       the settings from the dashboard server, logging in and out
//   connection.js  the MQTT.js client, its status, subscribing on every connect
//   hearing.js     whether the page hears anything at all, and the broker badge's words
//   model.js       FleetView: the fleet as the page knows it, from messages alone
//   requests.js    request ids, the requests waiting (sent again until answered), the words
//   forms.js       the goal, job and zone forms: checks, requests, messages
//   clicks.js      what a click (or, closing a zone, a drag) on the map means in each click mode
//   places.js, zones.js   the map's named places; the closed zones and their requests
//   zones_view.js  the closed zones' list, with its "Open" buttons
//   stop.js        STOP, hold to release, and how the stop shows
//   view.js        the map, the tables, the badges and the message log (draw.js, rows.js)
//   tabs.js        the tabs beside the map: the fleet now, History, Audit, Alerts
//   history_view.js, audit_view.js   the records the coordinator keeps, page by page (paged_view.js)
//   alerts_view.js the alerts' notifications, until acknowledged, and their list
//   throughput.js  jobs done an hour over the last day, from the job history

import { mayReadAudit } from "./audit.js";
import { AlertsView } from "./alerts_view.js";
import { AuditView } from "./audit_view.js";
import {
  initialClicks, mapClick, pickInto, selectUnit, setMode, zoneDone, zoneEnd, zoneMove, zoneStart,
} from "./clicks.js";
import { BrokerConnection } from "./connection.js";
import { drawDayChart, layoutFor, panBy, squareAt, squaresAt, zoomAt } from "./draw.js";
import { Forms, removeQuestion } from "./forms.js";
import { brokerBadge, newsPeriodS } from "./hearing.js";
import { HistoryView } from "./history_view.js";
import { loadSettings, logIn, logOut, mqttLogin } from "./login.js";
import { FleetView } from "./model.js";
import { PagedQuery } from "./paging.js";
import { ID_RE, makeClientId, parseTopic, Stamper, subscriptions, topicsFor } from "./protocol.js";
import { Requests, sentFeedback } from "./requests.js";
import { bindStopControls, estopLook, estopPayload, showEstop } from "./stop.js";
import { Tabs } from "./tabs.js";
import { DayThroughput, dayDue } from "./throughput.js";
import { log, PageView, showConnection, showFatal } from "./view.js";
import { inZone, mayChange } from "./zones.js";
import { ZonesView } from "./zones_view.js";

const $ = (sel) => document.querySelector(sel);
const PANEL_MS = 250; // the tables, chart and badges are filled in at most 4 times a second
const MAP_MS = 100; // the map is redrawn for the fleet's news at most 10 times a second
const PANEL_ONLY = new Set(["coordinator", "errors", "events", "reply"]); // nothing on the map
// Answers of their own, each to one view: nothing of the fleet's map or tables changes with them.
const RECORD_KINDS = new Set(["alerts", "history_reply", "audit_reply"]);
const RECORD_FORMS = new Set(["history", "audit", "day", "alerts"]); // their words' places

async function start() {
  const loaded = await loadSettings(fetch);
  if (loaded.kind === "login") {
    showLogin(loaded.message); // no settings, no broker credentials, no MQTT connection
    return;
  }
  if (loaded.kind === "error") {
    showFatal(loaded.message);
    return;
  }
  const settings = loaded.settings;
  document.body.dataset.auth = settings.login?.required ? "in" : "none";
  if (settings.login?.user) showUser(settings.login.user);
  if (!settings.mqtt_js.available) {
    showFatal(settings.mqtt_js.hint);
    return;
  }
  let mqtt;
  try {
    mqtt = (await import("/vendor/mqtt.esm.js")).default;
  } catch (e) {
    showFatal(`cannot load MQTT.js (${e.message}). ${settings.mqtt_js.hint ?? ""}`);
    return;
  }
  const params = new URLSearchParams(location.search);
  const wanted = params.get("client");
  // With accounts the broker lets a login use only client ids its account owns (its name, then '-').
  const own = settings.mqtt?.username;
  const owned = (id) => (!own || id === own || id.startsWith(`${own}-`) ? id : `${own}-${id}`.slice(0, 64));
  const clientId = owned(wanted && ID_RE.test(wanted) ? wanted : makeClientId(settings.client_prefix));
  dashboard = new Dashboard(mqtt, settings, clientId);
  dashboard.run();
}

let dashboard = null; // the running page, once logged in (or without accounts)

// ---- login ----
function showLogin(message) {
  document.body.dataset.auth = "login";
  $("#login").hidden = false;
  $("#login-message").textContent = message;
  $("#login-form input[name=username]").focus();
}

function bindLogin() {
  const form = $("#login-form");
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const button = form.querySelector("button[type=submit]");
    button.disabled = true; // one attempt at a time
    $("#login-message").textContent = "logging in…";
    const result = await logIn(fetch, form.username.value, form.password.value);
    button.disabled = false;
    form.password.value = "";
    if (!result.ok) {
      $("#login-message").textContent = result.message;
      return;
    }
    $("#login").hidden = true;
    $("#login-message").textContent = "";
    start();
  });
}

function showUser(user) {
  $("#user").textContent = user;
  $("#user").hidden = false;
  const button = $("#logout");
  button.hidden = false;
  button.addEventListener("click", async () => {
    button.disabled = true;
    await logOut(fetch);
    // Closed before the reload, so the broker sees the person leave at once.
    await Promise.race([dashboard?.client.stop(), new Promise((done) => setTimeout(done, 1000))]);
    location.reload(); // the login form again, and nothing the page heard
  });
}

class Dashboard {
  constructor(mqtt, settings, clientId) {
    this.clientId = clientId;
    this.topics = topicsFor(settings.root);
    this.view = new FleetView(settings.map, settings.colors ?? {});
    this.page = new PageView(this.view);
    this.page.onChange = () => { this.panelDirty = this.panelUrgent = true; }; // a search, a scroll
    this.requests = new Requests(clientId, new Stamper(clientId));
    this.ui = initialClicks(); // the map's click mode, what it picked, the chosen job, the zoom
    this.layout = null;
    this.dirty = true; // the map needs drawing
    this.mapUrgent = true; // ... on the next frame (the operator zoomed, panned, chose)
    this.mapAt = 0; // when the map was last drawn
    this.panelDirty = true; // the tables, the chart and the badges need filling in
    this.panelUrgent = true; // ... at once (the operator did something), not at the next tick
    this.panelAt = 0; // when the panel was last filled in
    this.localStop = false; // the operator pressed STOP and the broker has not echoed it yet
    this.mayAudit = mayReadAudit(settings); // the Audit tab, for accounts that may read it
    this.mayChange = mayChange(settings); // closing and opening zones: not for a viewer
    this.day = new DayThroughput(); // jobs done an hour, from the job history
    this.dayQuery = new PagedQuery(); // the day chart's question to the history, page by page
    this.dayAsked = null; // {at, done}: when the history was last asked, and the jobs done then
    this.conn = { state: "connecting", text: "connecting…" }; // the connection's own status
    this.connectedAt = null; // when it last connected (ms): a silence counts from then at most
    this.badge = null; // what the broker badge shows
    this.forms = new Forms(this.view, {
      send: (kind, form, what, body) => this.request(kind, form, what, body),
      onUnitChosen: (id) => { this.ui = selectUnit(this.ui, id); this.touched(); },
      onPickField: (field) => { this.ui = pickInto(this.ui, field); },
      onZoneDone: () => { this.ui = zoneDone(this.ui); this.touched(); },
    });
    this.zones = new ZonesView({
      send: (kind, form, what, body) => this.request(kind, form, what, body),
      mayChange: this.mayChange,
    });
    $("#zone-mode").hidden = !this.mayChange;
    const subs = subscriptions(this.topics, clientId, { audit: this.mayAudit });
    this.client = new BrokerConnection(mqtt, settings.broker_ws, clientId, subs, {
      onStatus: (state, text) => {
        // Presses are read afresh from the retained ones: one cleared meanwhile is not replayed.
        if (state === "connected") {
          this.view.presses.clear();
          this.connectedAt = Date.now();
          if (!this.dayAsked) this.askDay(Date.now()); // the day's chart, once subscribed
        }
        this.conn = { state, text };
        this.showBroker(Date.now());
        this.renderEstop();
      },
      onMessage: (topic, payload, retained) => this.onMessage(topic, payload, retained),
      onLog: log,
    }, mqttLogin(settings));
    document.body.dataset.clientId = clientId;
  }

  run() {
    this.client.start();
    this.bindControls();
    this.bindRecords();
    // The map's box changes with the window and with the page around it (e.g. the stop banner);
    // kept here, so drawing never asks the browser for a layout.
    new ResizeObserver(([entry]) => {
      this.page.mapBox = { width: entry.contentRect.width, height: entry.contentRect.height };
      this.touched();
    }).observe($("#canvas-wrap"));
    const frame = () => {
      // The next frame first: a drawing that throws (reported as the page's error) must not
      // stop every later one, or the page would show the fleet of that moment for good.
      requestAnimationFrame(frame);
      const now = Date.now();
      // The map when something changed (and while a fresh obstacle flashes), at most every
      // MAP_MS unless the operator is at it; the tables at most every PANEL_MS: a fleet sends
      // hundreds of messages a second, and redrawing for each frame's worth of them kept the
      // page busy and the fleet waiting.
      const flashing = this.view.knownObstacles(now).some((o) => o.fresh);
      if ((this.dirty || flashing) && (this.mapUrgent || now - this.mapAt >= MAP_MS)) {
        this.layout = this.page.renderMap(now, this.ui);
        this.dirty = this.mapUrgent = false;
        this.mapAt = now;
      }
      if (this.panelDirty && (this.panelUrgent || now - this.panelAt >= PANEL_MS)) {
        this.renderPanel(now);
        this.panelDirty = this.panelUrgent = false;
        this.panelAt = now;
      }
    };
    requestAnimationFrame(frame);
    setInterval(() => {
      const now = Date.now();
      this.page.seen(now);
      this.showBroker(now); // a page gone deaf hears no message to tell it so: the clock does
    }, 500);
    setInterval(() => {
      const now = Date.now();
      this.view.utilisation.sample(this.view, now);
      this.panelDirty = true;
      // The day's chart: what is new in the history, once a minute or sooner after jobs were done.
      if (this.dayAsked && dayDue(this.dayAsked, this.view.counts.done, now)) this.askDay(now);
    }, 1000);
    setInterval(() => this.retry(Date.now()), 500);
  }

  // ---- the records: History, Audit, Alerts, the day's chart ----
  bindRecords() {
    const records = {
      send: (kind, form, what, body) => this.request(kind, form, what, body, { quiet: true }),
      feedback: (form, kind, text) => this.forms.feedback(form, kind, text),
    };
    this.history = new HistoryView(records);
    this.audit = new AuditView(records);
    this.alerts = new AlertsView({ send: (kind, form, what, body) => this.request(kind, form, what, body) });
    this.tabs = new Tabs({
      onOpen: (name) => {
        if (name === "history") this.history.open();
        if (name === "audit") this.audit.open();
      },
    });
    this.tabs.offer("audit", this.mayAudit);
  }

  /** Ask the history for the day's done jobs not counted yet, unless a question is on its way. */
  askDay(now) {
    if (this.dayQuery.busy) return;
    this.dayAsked = { at: now, done: this.view.counts.done };
    this.drawDay(now); // a new hour's bar, even before the answer
    const body = this.dayQuery.begin(this.day.query(now));
    this.dayQuery.sent(this.request("job_history", "day", "the day's throughput", body, { quiet: true }));
  }

  /** A page for the day's chart: counted, the next asked for, the chart drawn. */
  dayPage(page) {
    if (this.dayQuery.error) {
      this.forms.feedback("day", "refused", `the day's throughput: ${this.dayQuery.error}`);
      return;
    }
    this.day.add(page.entries ?? []);
    const body = this.dayQuery.more();
    if (body) this.dayQuery.sent(this.request("job_history", "day", "the day's throughput", body, { quiet: true }));
    else this.drawDay(Date.now());
  }

  drawDay(now) {
    if (!this.dayQuery.body) return; // nothing asked yet: no bars rather than a false "none"
    drawDayChart($("#day-chart"), this.day.perHour(now), null);
  }

  /** A message for the records (alerts, a page of the history or the audit): to its view. */
  onRecord(kind, id, text) {
    if (kind === "alerts") {
      const problem = this.alerts.take(text);
      if (problem) log(problem);
      return;
    }
    if (id !== this.clientId) return; // another page's answer
    let page;
    try { page = JSON.parse(text); } catch { log(`ignored a malformed ${kind}`); return; }
    if (typeof page !== "object" || page === null) return;
    this.requests.settle(page.request_id); // answered: sent no more
    if (kind === "audit_reply") { this.audit.onPage(page); return; }
    if (this.dayQuery.take(page)) { this.dayPage(page); return; }
    this.history.onPage(page);
  }

  // ---- messages in, requests out ----
  onMessage(topic, payload, retained = false) {
    const now = Date.now();
    this.view.heard(now);
    if (this.badge?.state === "deaf") this.showBroker(now); // hearing again: at once
    const parsed = parseTopic(this.topics.prefix, topic);
    if (!parsed) return;
    const text = new TextDecoder().decode(payload);
    if (RECORD_KINDS.has(parsed.kind)) { this.onRecord(parsed.kind, parsed.id, text); return; }
    if (parsed.kind === "reply") {
      if (parsed.id === this.clientId) this.show(this.requests.reply(text));
      return;
    }
    const problem = this.view.apply(parsed.kind, parsed.id, text, now, retained);
    if (problem) log(problem);
    if (parsed.kind === "errors" && !problem) {
      // A refused request of anybody's is in the coordinator's events, in words: only ours is
      // shown here, under its form; other reports (a unit refusing an order) go in the log.
      const { feedback, log: line } = this.requests.error(this.view.lastError);
      const request = (this.view.lastError?.topic ?? "").includes("/requests/");
      this.show({ feedback, log: request ? null : line });
    }
    if (parsed.kind === "estop") this.localStop = false;
    if (!PANEL_ONLY.has(parsed.kind)) this.dirty = true;
    if (parsed.kind === "map") this.mapUrgent = true; // rare, and the map's layout hangs on it
    this.panelDirty = true;
  }

  /** The operator changed something on the page: map and panel show it on the next frame. */
  touched() {
    this.dirty = this.mapUrgent = this.panelDirty = this.panelUrgent = true;
  }

  /** Feedback and a log line from the request bookkeeping, either may be null. */
  show({ feedback, log: line }) {
    if (feedback) {
      this.forms.feedback(feedback.form, feedback.kind, feedback.text);
      if (RECORD_FORMS.has(feedback.form)) this.recordAnswered(feedback);
      if (feedback.form === "zones" && feedback.kind === "refused") this.zones.answered();
    }
    if (line) log(line);
  }

  /** A record's request was answered on the reply topic, or given up: its view hears it. */
  recordAnswered({ form, kind, text }) {
    // Accepted: the view says so (an acknowledged alert's notification goes with the next view).
    if (kind !== "refused") return;
    if (form === "alerts") this.alerts.answered();
    if (form === "history") this.history.gaveUp(text);
    if (form === "audit") this.audit.gaveUp(text);
    if (form === "day") this.dayQuery.gaveUp(text);
  }

  /** Publish a request; returns its id. `quiet`: no "sent, waiting" words (its view says). */
  request(kind, form, what, body, { quiet = false } = {}) {
    const { request_id, message } = this.requests.create(kind, form, what, body);
    this.client.publish(this.topics.request(kind), JSON.stringify(message), { qos: 1, retain: false });
    if (!quiet) this.show({ feedback: sentFeedback(form, what, this.client.connected), log: null });
    return request_id;
  }

  /** Requests still without a reply go out again; those waited for too long are given up. */
  retry(now) {
    const { resend, feedback } = this.requests.due(now);
    for (const { kind, message } of resend) {
      this.client.publish(this.topics.request(kind), JSON.stringify(message), { qos: 1, retain: false });
    }
    for (const f of feedback) this.show({ feedback: f, log: f.text });
  }

  publishEstop(engaged) {
    this.client.publish(this.topics.estop, estopPayload(engaged, this.clientId), { qos: 1, retain: true });
  }

  // ---- controls ----
  bindControls() {
    bindStopControls({
      onStop: () => {
        this.localStop = true;
        this.publishEstop(true);
        log("STOP pressed: emergency stop sent");
        this.renderEstop();
      },
      onRelease: () => {
        this.localStop = false;
        this.publishEstop(false);
        log("emergency stop released by operator");
      },
    });
    for (const r of document.querySelectorAll("input[name=clickmode]")) {
      r.addEventListener("change", () => {
        if (this.ui.zone && r.value !== "zone") this.forms.endZone(); // its form goes with it
        this.ui = setMode(this.ui, r.value);
        this.touched();
      });
    }
    const canvas = $("#map");
    canvas.addEventListener("click", (ev) => {
      if (this.dragged) { this.dragged = false; return; } // the end of a pan, not a click
      this.onMapClick(ev);
    });
    this.bindZoom(canvas);
    canvas.addEventListener("mousemove", (ev) => {
      const sq = this.layout && squareAt(this.layout, ev.offsetX, ev.offsetY);
      $("#hover").textContent = sq ? this.squareWords(sq) : "";
      this.page.hoverCard(sq ? this.view.unitAt(sq[0], sq[1])?.id ?? null : null, ev.offsetX, ev.offsetY);
    });
    canvas.addEventListener("mouseleave", () => this.page.hoverCard(null));
    this.forms.bind();
    $("#jobs tbody").addEventListener("click", (ev) => {
      const btn = ev.target.closest("button[data-cancel]");
      if (btn) { this.forms.cancelJob(btn.dataset.cancel); return; }
      const row = ev.target.closest("tr[data-job]");
      if (row) this.selectJob(row.dataset.job);
    });
    $("#units tbody").addEventListener("click", (ev) => {
      const btn = ev.target.closest("button[data-command]");
      if (btn) { this.forms.controlUnit(btn.dataset.unit, btn.dataset.command); return; }
      const gone = ev.target.closest("button[data-remove]");
      if (gone) { // for good: the operator confirms it is off the floor first (protocol.md §6.11)
        if (window.confirm(removeQuestion(gone.dataset.remove))) this.forms.removeUnit(gone.dataset.remove);
        return;
      }
      const row = ev.target.closest("tr[data-unit]");
      if (row) this.selectUnit(row.dataset.unit);
    });
  }

  /** The wheel zooms about the pointer, a drag pans, "fit map" shows it whole again. */
  bindZoom(canvas) {
    const layout = () => this.layout ?? layoutFor(canvas, this.view.map, this.ui.zoom);
    canvas.addEventListener("wheel", (ev) => {
      ev.preventDefault(); // the page itself does not scroll under the map
      const factor = ev.deltaY < 0 ? 1.25 : 0.8;
      this.ui = { ...this.ui, zoom: zoomAt(this.ui.zoom, layout(), ev.offsetX, ev.offsetY, factor) };
      this.touched();
    }, { passive: false });
    let from = null;
    canvas.addEventListener("pointerdown", (ev) => {
      this.dragged = false;
      if (this.ui.mode === "zone") { this.zoneDown(canvas, ev); return; } // a drag draws, not pans
      from = [ev.clientX, ev.clientY];
    });
    canvas.addEventListener("pointermove", (ev) => {
      if (this.ui.zone?.dragging) { this.zoneDrag(ev); return; }
      if (!from || ev.buttons === 0) { from = null; return; }
      const [dx, dy] = [ev.clientX - from[0], ev.clientY - from[1]];
      if (!this.dragged && Math.hypot(dx, dy) < 5) return; // a click that wobbled
      this.dragged = true;
      canvas.classList.add("panning");
      from = [ev.clientX, ev.clientY];
      this.ui = { ...this.ui, zoom: panBy(this.ui.zoom, layout(), dx, dy) };
      this.touched();
    });
    const end = () => { from = null; canvas.classList.remove("panning"); };
    canvas.addEventListener("pointerup", (ev) => { end(); if (this.ui.zone?.dragging) this.zoneUp(ev); });
    canvas.addEventListener("pointerleave", end);
    canvas.addEventListener("pointercancel", () => { if (this.ui.zone?.dragging) this.forms.endZone(); });
    $("#fit").addEventListener("click", () => {
      this.ui = { ...this.ui, zoom: { scale: 1, pan: [0, 0] } };
      this.touched();
    });
  }

  // ---- closing a zone: a drag over the map, then its name and reason ----
  zoneDown(canvas, ev) {
    const sq = this.layout && squareAt(this.layout, ev.offsetX, ev.offsetY);
    if (!sq) return;
    canvas.setPointerCapture?.(ev.pointerId); // the drag goes on beyond the map's edge
    this.ui = zoneStart(this.ui, sq);
    this.touched();
  }

  zoneDrag(ev) {
    if (!this.layout) return;
    const at = squaresAt(this.layout, ev.offsetX, ev.offsetY);
    this.ui = zoneMove(this.ui, at, this.layout.cols, this.layout.rows);
    this.touched();
  }

  zoneUp(ev) {
    this.zoneDrag(ev);
    const { state, effect } = zoneEnd(this.ui);
    this.ui = state;
    this.touched();
    if (!effect) return;
    // The form over the map's edge farther from the rectangle, so it hides none of it.
    const L = this.layout;
    const middle = L.oy + ((effect.first[1] + effect.last[1] + 1) / 2) * L.cell;
    this.forms.askZone({ first: effect.first, last: effect.last }, middle < L.h / 2 ? "bottom" : "top");
  }

  /** The line under the map for the square under the pointer: its place and closed zones. */
  squareWords(sq) {
    const place = this.view.places.at(sq);
    const zones = this.view.zones.filter((z) => inZone(z, sq)).map((z) => z.name);
    return [`[${sq[0]}, ${sq[1]}]`, place ? `${place.name} (${place.kinds.join(", ")})` : null,
      zones.length ? `in closed zone ${zones.join(", ")}` : null].filter(Boolean).join(" · ");
  }

  /** A job row chosen: its P and D stand out on the map, joined; chosen again, unchosen. */
  selectJob(id) {
    this.ui = { ...this.ui, selectedJob: this.ui.selectedJob === id ? null : id };
    this.touched();
  }

  /** A unit chosen in its row or on the map: marked on both; `reveal` scrolls its row into view. */
  selectUnit(id, reveal = false) {
    this.ui = selectUnit(this.ui, id);
    this.forms.showUnit(id);
    if (reveal) this.page.revealUnit(id);
    this.touched();
  }

  onMapClick(ev) {
    if (!this.layout) return;
    const sq = squareAt(this.layout, ev.offsetX, ev.offsetY);
    if (!sq) return;
    const { state, effect } = mapClick(this.ui, sq, this.view.unitAt(sq[0], sq[1])?.id ?? null);
    this.ui = state;
    this.touched();
    if (!effect) return;
    if (effect.type === "select") {
      this.forms.showUnit(effect.unit);
      this.page.revealUnit(effect.unit); // its row, however far down the table
    }
    else if (effect.type === "goal") this.forms.goalAt(effect.square);
    else if (effect.type === "pickup") this.forms.pickupAt(effect.square);
    else if (effect.type === "dropoff") this.forms.dropoffAt(effect.square);
  }

  // ---- rendering ----
  /** The broker badge: the connection's status, or that the page has heard nothing for a while. */
  showBroker(now) {
    const since = this.connectedAt == null ? null : Math.max(this.connectedAt, this.view.heardAt ?? -Infinity);
    const badge = brokerBadge(this.conn.state, this.conn.text, since, now, newsPeriodS(this.view.coordinator));
    if (badge.state === this.badge?.state && badge.text === this.badge?.text) return;
    this.badge = badge;
    showConnection(badge.state, badge.text);
  }

  renderPanel(now) {
    this.page.renderPanel(now, this.ui);
    this.forms.syncUnits(this.page.unitIds(), this.ui.selectedUnit);
    this.forms.syncPlaces(this.view.places);
    this.zones.show(this.view.zones, now);
    this.renderEstop();
  }

  renderEstop() {
    showEstop(estopLook(this.view.estop, this.localStop));
  }
}

bindLogin();
start();
