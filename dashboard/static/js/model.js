// The fleet as the page knows it, built only from MQTT messages. Pure: no DOM, no network, no clock
// (callers pass `now` in milliseconds).

import { PlaceIndex, readPlaces } from "./places.js";
import { decodeEstop, decodePress, FINAL_JOB_STATES, ID_RE } from "./protocol.js";
import { LIMITS } from "./protocol_table.js";
import { JobNumbers, Utilisation } from "./story.js";
import { readZones } from "./zones.js";

// What the page keeps of a unit, each from its retained topic; a unit with none of them is gone.
const UNIT_PARTS = ["state", "connection", "factsheet", "vehicle"];

export const HIGHLIGHT_MS = 4000; // how long a newly discovered obstacle stays highlighted
const key = (sq) => `${sq[0]},${sq[1]}`;
// A square as the protocol writes one, [x, y] of whole numbers 0 to max_coord; and a list of
// them (absent: none).
const isCoord = (v) => Number.isInteger(v) && v >= 0 && v <= LIMITS.max_coord;
const isSquare = (sq) => Array.isArray(sq) && sq.length === 2 && sq.every(isCoord);
const areSquares = (list) => list === undefined || (Array.isArray(list) && list.every(isSquare));
const isObject = (v) => typeof v === "object" && v !== null && !Array.isArray(v);
const isId = (v) => typeof v === "string" && ID_RE.test(v);
const isPct = (v) => typeof v === "number" && Number.isFinite(v) && v >= 0 && v <= 100;
export const ENERGY_PLANS = new Set(["to_charger", "queued", "charging", "stranded"]);
const isCharger = (c) => isObject(c) && isId(c.name) && isSquare(c.square);

/** A unit state's battery: {battery_pct, charging}, each null/false unless well formed. */
function batteryOf(msg) {
  const ok = (msg.battery_pct == null || isPct(msg.battery_pct)) && (msg.charging == null || typeof msg.charging === "boolean");
  return { ok, battery_pct: isPct(msg.battery_pct) ? msg.battery_pct : null, charging: msg.charging === true };
}

/**
 * The energy view (fleet/energy) as the page keeps it: its thresholds when well formed, its
 * chargers and its units' plans, each entry that is not left out. `dropped`: how many were.
 */
export function readEnergy(msg) {
  let dropped = 0;
  const t = msg.thresholds;
  const thresholds = isObject(t) && ["critical_pct", "good_pct", "sufficient_pct", "full_pct"].every((k) => isPct(t[k]))
    ? { critical_pct: t.critical_pct, good_pct: t.good_pct, sufficient_pct: t.sufficient_pct, full_pct: t.full_pct }
    : null;
  if (!thresholds) dropped += 1;
  const chargers = [];
  for (const c of Array.isArray(msg.chargers) ? msg.chargers : []) {
    const queue = c?.queue ?? [];
    if (isCharger(c) && (c.unit == null || isId(c.unit)) && Array.isArray(queue) && queue.every(isId)) {
      chargers.push({ name: c.name, square: c.square, unit: c.unit ?? null, queue });
    } else dropped += 1;
  }
  const units = new Map();
  for (const [id, e] of Object.entries(isObject(msg.units) ? msg.units : {})) {
    if (isId(id) && isObject(e) && ENERGY_PLANS.has(e.plan) && (e.charger == null || isId(e.charger))
      && (e.reason == null || typeof e.reason === "string")) {
      units.set(id, { plan: e.plan, charger: e.charger ?? null, reason: e.reason ?? null });
    } else dropped += 1;
  }
  if (msg.chargers !== undefined && !Array.isArray(msg.chargers)) dropped += 1;
  if (msg.units !== undefined && !isObject(msg.units)) dropped += 1;
  return { energy: { thresholds, chargers, units }, dropped };
}

/** Whether every job of a queue view can be listed and drawn: an id, a state, its two squares. */
const jobsDrawable = (msg) => [msg.jobs, msg.finished ?? []].every((list) => Array.isArray(list)
  && list.every((j) => isObject(j) && typeof j.id === "string" && typeof j.state === "string"
    && isSquare(j.pickup) && isSquare(j.dropoff)));
/** Whether every route of a routes view is drawable: its squares squares, its target one or null. */
const routesDrawable = (routes) => isObject(routes) && Object.values(routes).every((r) => isObject(r)
  && areSquares(r.released) && areSquares(r.planned) && (r.target == null || isSquare(r.target)));

export class FleetView {
  constructor(initialMap = null, colors = {}) {
    this.map = initialMap; // {name, width, height, rows, obstacles, chargers, places}
    this.places = new PlaceIndex(initialMap?.places ?? []); // the map's named places
    this.zones = []; // the closed zones (fleet/zones), in the order they were closed
    this.colors = colors; // fallback unit colours, e.g. from the scenario
    this.units = new Map(); // id -> {id, connection, factsheet, state, vehicle, lastSeen}
    this.jobs = []; // JobView objects of the jobs not finished (fleet/jobs `jobs`)
    this.finished = []; // the latest finished jobs, newest first (fleet/jobs `finished`)
    this.jobById = new Map(); // id -> a job not finished
    this.jobOfUnit = new Map(); // unit id -> the id of the job the queue gives it
    this.counts = {}; // every job the coordinator has known, by state
    this.donePerMinute = []; // jobs done in each of the last minutes, the current one last
    this.routes = {}; // unit -> {released, planned, target}
    this.routesStep = null; // the coordinator's step, from its routes (published every step)
    this.coordinator = null;
    this.latch = null; // fleet/estop: {engaged, by, reason} or null when nobody has said
    this.presses = new Map(); // "kind/id" -> the held stop press of a unit or device
    this.obstacles = new Map(); // "x,y" -> first seen (ms); -Infinity: known before the page was
    this.lastError = null;
    this.events = []; // the coordinator's recent history (fleet/events), oldest first
    // The energy policy's view (fleet/energy): thresholds, chargers with who is on them and who
    // waits, and the units it moves; null before it is heard (a fleet without energy).
    this.energy = null;
    this.jobNumbers = new JobNumbers(); // P3 on the map goes with D3 and row 3
    this.utilisation = new Utilisation(); // sampled by the page (utilisation.sample)
    this.heardAt = null; // when the page last heard anything at all (ms), null before it has
  }

  /** Something arrived (any message): the page's own link worked at `now`. */
  heard(now) {
    this.heardAt = this.heardAt == null ? now : Math.max(this.heardAt, now);
  }

  unit(id) {
    let u = this.units.get(id);
    if (!u) {
      u = { id, connection: null, factsheet: null, state: null, vehicle: null, lastSeen: null };
      this.units.set(id, u);
    }
    return u;
  }

  /**
   * Apply one message; returns a string describing a problem, or null. `retained`: replayed by
   * the broker on subscribing, so what it says was known before the page loaded.
   */
  apply(kind, id, text, now, retained = false) {
    this.heard(now);
    const seen = retained ? -Infinity : now; // an obstacle is "new" only if found since the load
    if (kind === "estop") {
      if (text === "") { this.latch = null; return null; }
      const signal = decodeEstop(text);
      if (!signal) return `ignored an invalid emergency-stop payload: ${text.slice(0, 60)}`;
      this.latch = signal;
      return null;
    }
    if (kind === "stop" || kind === "device_stop") {
      let press;
      try { press = decodePress(text, id); } catch { return `ignored an invalid stop press of ${id}`; }
      if (press) this.presses.set(`${kind}/${id}`, press); else this.presses.delete(`${kind}/${id}`);
      return null;
    }
    if (text === "" && kind === "zones") { this.zones = []; return null; } // cleared: none closed
    if (text === "") { // a cleared retained message
      if (id && UNIT_PARTS.includes(kind)) {
        const u = this.units.get(id);
        if (u) { u[kind] = null; if (UNIT_PARTS.every((part) => !u[part])) this.units.delete(id); }
      }
      return null;
    }
    let msg;
    try {
      msg = JSON.parse(text);
    } catch {
      return `ignored malformed JSON on ${kind}${id ? " of " + id : ""}`;
    }
    if (typeof msg !== "object" || msg === null) return `ignored a non-object on ${kind}`;
    switch (kind) {
      case "connection": this.unit(id).connection = msg.state; break;
      case "factsheet": this.unit(id).factsheet = msg; break;
      // A VDA 5050 vehicle's battery and own errors (protocol.md §4.7).
      case "vehicle": this.unit(id).vehicle = msg; break;
      case "state": {
        if (!isSquare(msg.position)) return `ignored a state of ${id} without a position`;
        if (!areSquares(msg.obstacles)) return `ignored a state of ${id} with malformed obstacles`;
        const u = this.unit(id);
        const battery = batteryOf(msg);
        // A bad battery is left out (the unit shows none), the rest of its state kept.
        u.state = battery.ok ? msg : { ...msg, battery_pct: battery.battery_pct, charging: battery.charging };
        u.lastSeen = now;
        for (const sq of msg.obstacles ?? []) this.noteObstacle(sq, seen);
        if (!battery.ok) return `ignored a malformed battery in a state of ${id}`;
        break;
      }
      case "map": {
        if (!Array.isArray(msg.rows)) return "ignored a map without rows";
        // A size of whole squares, at least one (the schema's): no map of no squares to draw.
        const size = (v) => Number.isInteger(v) && v >= 1 && v <= LIMITS.max_coord + 1;
        if (!size(msg.width) || !size(msg.height) || !areSquares(msg.obstacles)) {
          return "ignored a map without its size or with malformed obstacles";
        }
        // Chargers and places that cannot be drawn are left out; the map stays.
        const listed = Array.isArray(msg.chargers) ? msg.chargers : [];
        const chargers = listed.filter(isCharger);
        const { places, dropped } = readPlaces(msg.places);
        this.map = { ...msg, chargers, places };
        this.places = new PlaceIndex(places);
        for (const sq of msg.obstacles ?? []) this.noteObstacle(sq, seen);
        const bad = listed.length - chargers.length + (msg.chargers !== undefined && !Array.isArray(msg.chargers) ? 1 : 0);
        const problems = [];
        if (bad) problems.push(`${bad} malformed charger${bad === 1 ? "" : "s"}`);
        if (dropped) problems.push(`${dropped} malformed place${dropped === 1 ? "" : "s"}`);
        if (problems.length) return `ignored ${problems.join(" and ")} on the map`;
        break;
      }
      case "jobs":
        if (!jobsDrawable(msg)) return "ignored a malformed queue view";
        this.takeJobs(msg);
        break;
      case "routes":
        if (!routesDrawable(msg.routes)) return "ignored routes with a malformed route";
        this.routes = msg.routes;
        if (Number.isInteger(msg.step)) this.routesStep = msg.step;
        break;
      case "zones": {
        // A view that breaks its schema changes nothing: the zones shown stay those last heard.
        const read = readZones(msg);
        if (read.error) return read.error;
        this.zones = read.zones;
        break;
      }
      case "coordinator": this.coordinator = msg; break;
      case "errors":
        if (typeof msg.topic !== "string" || typeof msg.reason !== "string") return "ignored a malformed error report";
        this.lastError = msg;
        break;
      case "events": this.events = Array.isArray(msg.events) ? msg.events : []; break;
      case "energy": {
        if (Array.isArray(msg)) return "ignored a malformed energy view";
        const { energy, dropped } = readEnergy(msg);
        this.energy = energy;
        if (dropped) return `ignored ${dropped} malformed part${dropped === 1 ? "" : "s"} of the energy view`;
        break;
      }
      default: break;
    }
    return null;
  }

  /** The queue view: the jobs under way indexed once here, not looked up per unit and frame. */
  takeJobs(msg) {
    const listed = Array.isArray(msg.jobs) ? msg.jobs : [];
    const finished = Array.isArray(msg.finished) ? msg.finished : [];
    this.jobs = listed.filter((j) => !FINAL_JOB_STATES.has(j.state));
    this.finished = [...finished, ...listed.filter((j) => FINAL_JOB_STATES.has(j.state))];
    this.jobById = new Map(this.jobs.map((j) => [j.id, j]));
    this.jobOfUnit = new Map();
    for (const j of this.jobs) if (j.unit && !this.jobOfUnit.has(j.unit)) this.jobOfUnit.set(j.unit, j.id);
    this.jobNumbers.claim([...this.jobs, ...this.finished].map((j) => j.id)); // numbered ids first: theirs to keep
    this.counts = msg.counts ?? {};
    this.donePerMinute = Array.isArray(msg.done_per_minute) ? msg.done_per_minute : [];
  }

  noteObstacle(sq, now) {
    const k = key(sq);
    if (!this.obstacles.has(k)) this.obstacles.set(k, now);
  }

  /** Obstacles known from the map or from units' reports, each with whether it is new. */
  knownObstacles(now) {
    return Array.from(this.obstacles, ([k, t]) => {
      const [x, y] = k.split(",").map(Number);
      return { x, y, fresh: now - t < HIGHLIGHT_MS };
    });
  }

  /**
   * A unit whose state has been silent for 5 step periods (≥ 0.5 s), as protocol.md §8 says,
   * counted up to when the page last heard anything: a silence the page shares with every unit
   * is its own link's (hearing.js), and says nothing of the unit's.
   */
  isSilent(u, now) {
    if (u.lastSeen == null) return false;
    const period = u.factsheet?.step_period_s ?? 1;
    const heard = this.heardAt == null ? now : Math.min(now, this.heardAt);
    return heard - u.lastSeen > Math.max(500, 5 * period * 1000);
  }

  /** The coordinator's latest step: its status says it only on changes, its routes every step. */
  coordinatorStep() {
    const steps = [this.coordinator?.step, this.routesStep].filter(Number.isInteger);
    return steps.length ? Math.max(...steps) : null;
  }

  /**
   * Where unit `id` is heading: its reported direction, or, between a step and its next order
   * (when a unit reports "-"), the first square of its planned route; "-" when neither says.
   */
  heading(id) {
    const s = this.units.get(id)?.state;
    if (!s) return "-";
    if (s.direction && s.direction !== "-") return s.direction;
    const r = this.routes[id];
    // The routes may date from before the unit's last move: skip the square it now stands on.
    const path = [...(r?.released ?? []), ...(r?.planned ?? [])];
    const at = path.findIndex((sq) => sq[0] === s.position[0] && sq[1] === s.position[1]);
    const next = path[at + 1];
    if (!next) return "-";
    const [dx, dy] = [next[0] - s.position[0], next[1] - s.position[1]];
    return { "0,-1": "N", "1,0": "E", "0,1": "S", "-1,0": "W" }[`${dx},${dy}`] ?? "-";
  }

  /** The unit standing on (x, y) by its last state, or null. */
  unitAt(x, y) {
    for (const u of this.units.values()) {
      if (u.state && u.state.position[0] === x && u.state.position[1] === y) return u;
    }
    return null;
  }

  /** Unit `id`'s battery from its state: {pct, charging}, or null when it reports no energy. */
  battery(id) {
    const s = this.units.get(id)?.state;
    return isPct(s?.battery_pct) ? { pct: s.battery_pct, charging: s.charging === true } : null;
  }

  /** Whether unit `id` reports energy (its factsheet's model, or a battery in its state). */
  hasEnergy(id) {
    const u = this.units.get(id);
    return isObject(u?.factsheet?.energy) || this.battery(id) != null;
  }

  /** What the energy policy does with unit `id` ({plan, charger, reason}), or null. */
  energyPlan(id) {
    return this.energy?.units.get(id) ?? null;
  }

  /**
   * The chargers to draw: the map's, each with who is on it (or on the way) and who waits,
   * from the energy view; the view's own when the map lists none.
   */
  chargers() {
    const live = new Map((this.energy?.chargers ?? []).map((c) => [c.name, c]));
    const mapped = this.map?.chargers ?? [];
    const base = mapped.length ? mapped : [...live.values()];
    return base.map((c) => ({
      name: c.name, square: c.square, unit: live.get(c.name)?.unit ?? null, queue: live.get(c.name)?.queue ?? [],
    }));
  }

  /** Why the coordinator moves or holds unit `id` (its route's `note`), or null. */
  routeNote(id) {
    const note = this.routes[id]?.note;
    return typeof note === "string" && note ? note : null;
  }

  activeJobs() { return this.jobs; }
  finishedJobs() { return this.finished; }

  colorOf(id) {
    return this.units.get(id)?.factsheet?.color ?? this.colors[id] ?? "#607d8b";
  }

  /** True when (x, y) lies on the map and is not a wall. */
  isFree(x, y) {
    const m = this.map;
    if (!m || x < 0 || y < 0 || x >= m.width || y >= m.height) return false;
    // A square the rows leave out (the schema does not tie them to width and height) is a wall.
    return m.rows[y]?.[x] === "." && !this.obstacles.has(`${x},${y}`);
  }

  onMap(x, y) {
    const m = this.map;
    return !!m && Number.isInteger(x) && Number.isInteger(y) && x >= 0 && y >= 0 && x < m.width && y < m.height;
  }

  /**
   * The stop as protocol.md 5.1 reads it: the latch when engaged, else a held press (marked
   * `press: true`: the coordinator has not copied it into the latch yet), else the latch.
   */
  get estop() {
    if (this.latch?.engaged) return this.latch;
    const press = this.presses.values().next().value;
    return press ? { ...press, press: true } : this.latch;
  }

  get stopped() { return !!this.estop?.engaged; }
}
