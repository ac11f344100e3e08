// Showing the fleet: the map, the units and jobs tables, the coordinator's and the broker's state,
// the message log. What each cell says comes from pure functions (testable under node); `PageView`
// puts it on the page.

import { drawChart, drawFleet } from "./draw.js";
import { whereText } from "./places.js";
import { TIMING } from "./protocol_table.js";
import { syncRows } from "./rows.js";
import { CHART_MINUTES, durationText, eventLines, latestFinished, tookSeconds, unitJob } from "./story.js";
import { phaseText, shownUnits, unitState, visibleSlice } from "./units.js";

const $ = (sel) => document.querySelector(sel);
// px of a jobs row and of a units row (two lines: style.css): the tables show only the rows in view
const ROW_H = 25;
const UNIT_ROW_H = 46;
const FINAL_COUNTED = ["done", "cancelled", "rejected", "failed"];

// ---- what the page says (pure) ----

export function mapTitle(map) {
  return map ? `${map.name} ${map.width} x ${map.height}` : "no map yet";
}

const CONTROL_WORDS = { paused: "paused", out_of_service: "out of service" };

const PLAN_WORDS = { to_charger: "to charger", queued: "waiting for charger", charging: "charging at" };

/**
 * What the energy policy does with a unit, in words: the plan and its charger ("to charger C1",
 * "waiting for charger C2", "stranded"), then the coordinator's reason, when it gives one (alone
 * when it names them already: "charging: 62 % of 80 %").
 */
export function planText(plan) {
  if (!plan) return null;
  let head;
  if (plan.plan === "stranded") head = "stranded";
  else {
    const words = PLAN_WORDS[plan.plan] ?? plan.plan;
    head = plan.charger ? `${words} ${plan.charger}` : (plan.plan === "queued" ? "waiting for a charger" : words);
  }
  if (!plan.reason) return plan.plan === "stranded" ? "stranded: it cannot reach a charger" : head;
  // A reason that names the charger or the plan already says it all.
  const says = (plan.charger && plan.reason.includes(plan.charger)) || plan.reason.startsWith(head.split(" ")[0]);
  return says ? plan.reason : `${head}: ${plan.reason}`;
}

/** "62 %", with " ⚡" while it charges, " empty" at 0 % (it cannot move); null without energy. */
export function batteryText(pct, charging) {
  if (typeof pct !== "number" || !Number.isFinite(pct)) return null;
  return `${Math.round(pct)} %${charging ? " ⚡" : (pct <= 0 ? " empty" : "")}`;
}

// The coordinator's default thresholds (gridfleet/energy.py ChargingSpec), for a page that has not
// heard its energy view (fleet/energy) yet.
export const DEFAULT_THRESHOLDS = { critical_pct: 20, good_pct: 50 };

/**
 * How low a battery at `pct` is against the coordinator's thresholds (the energy view's, else the
 * defaults): {level, words}; level "ok", "low" (at or below good_pct), "critical" (at or below
 * critical_pct) or "empty" (0 %); words say so for its title (null when ok). Null without energy.
 */
export function batteryLevel(pct, thresholds = null) {
  if (typeof pct !== "number" || !Number.isFinite(pct)) return null;
  const t = thresholds ?? DEFAULT_THRESHOLDS;
  if (pct <= 0) return { level: "empty", words: "empty: it cannot move" };
  if (pct <= t.critical_pct) return { level: "critical", words: `critical (at or below ${t.critical_pct} %)` };
  if (pct <= t.good_pct) return { level: "low", words: `low (at or below ${t.good_pct} %)` };
  return { level: "ok", words: null };
}

/** The link cell's title: "battery 62 %, charging · online", "battery 19 %, critical (…) · online". */
export function linkTitle(said, battery, level) {
  if (!battery) return said;
  const rest = said.replace(/^\S+ %( ⚡| empty)?/, "").replace(/^ · /, "");
  const how = battery.charging ? "charging" : level?.words;
  return `battery ${Math.round(battery.pct)} %${how ? `, ${how}` : ""}${rest ? ` · ${rest}` : ""}`;
}

/**
 * The units table's cells for unit `u` (a FleetView unit): [text, className] each. `job`: the job
 * it works on (its own, or the queue's before pickup); `control`: an operator's control of it (paused, out of service);
 * `jobWait`: why that job waits, in the coordinator's words (a unit between orders says "idle"
 * while its job is stuck: the job's words say what holds it); `plan`: what the energy policy
 * does with it (fleet/energy), or null; `note`: why the coordinator moves or holds it (its
 * route's note, e.g. "leaving zone aisle-4 (closed: cleaning)"), or null.
 */
export function unitCells(u, job = u.state?.job_id ?? null, control = null, jobWait = null, phase = null, plan = null, note = null) {
  const s = u.state;
  const cap = u.factsheet ? `/${u.factsheet.capacity_kg}` : "";
  let status = s ? s.status + (s.wait_reason ? `: ${s.wait_reason}` : "") : "—";
  const quiet = s && !s.wait_reason && (s.status === "idle" || s.status === "holding");
  // Where its job takes it ("to pickup P3"), and why that job waits when the unit says nothing.
  if (phase && s && (quiet || s.status === "moving")) status = `${s.status} · ${phase}`;
  if (jobWait && quiet) status = `${s.status} · ${jobWait}`;
  if (control) status = `${CONTROL_WORDS[control] ?? control} · ${status}`;
  if (note && !status.includes(note)) status += ` · ${note}`;
  // A job whose item is on board is marked (the load says how heavy).
  const carrying = s && s.load_kg > 0 ? "job carrying" : "job";
  // A VDA 5050 vehicle (gridfleet vda5050 carries it) says so beside its link, with its battery;
  // its own errors (a FATAL one makes its unit broken) follow the status.
  const vda = /^vda5050-(.+)$/.exec(u.factsheet?.model ?? "");
  const own = u.vehicle;
  let link = (u.connection ?? "?") + (vda ? ` · VDA 5050 ${vda[1]}` : "");
  // Its battery from its state (protocol.md §4.3), else a VDA 5050 vehicle's own condition.
  const battery = s?.battery_pct != null ? batteryText(s.battery_pct, s.charging)
    : batteryText(own?.battery_pct, own?.charging);
  if (battery) link = `${battery} · ${link}`; // first: the column is narrow, the colour says the link
  const energy = planText(plan);
  if (energy && !status.includes(energy)) status += ` · ${energy}`; // once, if the unit says it too
  if (own?.errors?.length) status += ` · vehicle: ${own.errors.join("; ")}`;
  return [
    [u.id, "id"], [link, vda || own ? "link vda" : "link"],
    [s ? `[${s.position[0]}, ${s.position[1]}]` : "—", "pos"], [status, "status"],
    [job ?? "—", carrying], [s ? `${s.load_kg}${cap} kg` : (cap ? `0${cap} kg` : "—"), "load"],
  ];
}

/**
 * The unit row's control buttons for `control` (null, paused, out_of_service): [label, command];
 * `energy`: the unit reports energy, so it can be sent to charge.
 */
export function controlButtons(control, energy = false) {
  if (control === "out_of_service") return [["in service", "in_service", "bring back into service"]];
  const out = ["out", "out_of_service", "take out of service"];
  const charge = energy ? [["charge", "charge", "send to charge (to full, then back to work)"]] : [];
  if (control === "paused") return [["resume", "resume", "resume"], out, ...charge];
  return [["pause", "pause", "pause"], out, ...charge];
}

/**
 * The chargers in words, one line each: "C1 [0, 2]: u03 on it or on its way · queue u04, u05"
 * (`chargers` from FleetView.chargers; `battery(id)` says whether its unit is charging there).
 */
export function chargerLines(chargers, battery = () => null) {
  return chargers.map((c) => {
    const [x, y] = c.square;
    let who = "free";
    if (c.unit) who = battery(c.unit)?.charging ? `${c.unit} charging` : `${c.unit} on its way`;
    const queue = c.queue.length ? ` · queue ${c.queue.join(", ")}` : "";
    return `${c.name} [${x}, ${y}]: ${who}${queue}`;
  });
}

/** When unit `u` was last heard of, at `now` (ms). */
export function seenText(u, now) {
  return u.lastSeen == null ? "never" : `${Math.max(0, Math.round((now - u.lastSeen) / 1000))} s ago`;
}

/** "A3 [3, 4] → [8, 8]": a job's pickup and dropoff, each with the place it was named by. */
export function routeText(j) {
  const named = (name) => (typeof name === "string" && name ? name : null);
  return `${whereText(j.pickup, named(j.pickup_place))} → ${whereText(j.dropoff, named(j.dropoff_place))}`;
}

/** A job of the queue: `n` its number on the map (P n, D n), and why it waits, if it does. */
export function jobCells(j, n) {
  return [[String(n), "no"], [j.id, "id"], [j.state, "state"], [j.wait_reason ?? "", "waits"],
    [j.unit ?? "—", "unit"], [routeText(j), "route"], [String(j.mass_kg), "mass"]];
}

/** A finished job; `periodS` the coordinator's step period, for how long it took. */
export function finishedCells(j, periodS) {
  return [[j.id, "id"], [j.state, "state"], [j.unit ?? "—", "unit"], [routeText(j), "route"],
    [durationText(tookSeconds(j, periodS)), "took"], [j.reason ?? "", "reason"]];
}

/**
 * "done 3 · cancelled 1": the finished jobs by state, always in that order. The coordinator's
 * counts (of every job ever) win over the latest finished jobs the view lists.
 */
export function finishedCounts(finished, counts) {
  const shown = {};
  for (const j of finished) shown[j.state] = (shown[j.state] ?? 0) + 1;
  const states = [...FINAL_COUNTED, ...Object.keys(shown).filter((k) => !FINAL_COUNTED.includes(k))];
  return states
    .map((k) => [k, counts[k] ?? shown[k] ?? 0])
    .filter(([, n]) => n > 0)
    .map(([k, n]) => `${k} ${n}`)
    .join(" · ");
}

/** The coordinator's badge: {state, text}, from its status and its latest step. */
export function coordinatorBadge(c, step) {
  if (!c) return { state: "unknown", text: "coordinator: not seen" };
  return { state: c.state, text: `coordinator: ${c.state}, step ${step}${stepPace(c)}` };
}

/** " · 7.9 ms a step (set 5 ms)": the step time it achieves, once it has measured one. */
export function stepPace(c) {
  if (typeof c?.achieved_step_s !== "number") return "";
  const time = (s) => (s < 1 ? `${+(s * 1000).toFixed(1)} ms` : `${+s.toFixed(2)} s`);
  return ` · ${time(c.achieved_step_s)} a step (set ${time(stepPeriodS(c))})`;
}

/** The coordinator's step period in seconds: its status's, or the schema's default when absent. */
export function stepPeriodS(c) {
  return typeof c?.step_period_s === "number" ? c.step_period_s : TIMING.default_step_s;
}

// ---- on the page ----

export class PageView {
  /** Shows FleetView `view`. */
  constructor(view) {
    this.view = view;
    this.mapBox = null; // the map's box, {width, height}, from a ResizeObserver
    this.revealing = null; // a unit whose row the next fill scrolls to
    for (const id of ["#unit-search", "#unit-filter", "#unit-sort"]) {
      $(id)?.addEventListener("input", () => { $("#units-box").scrollTop = 0; this.onChange?.(); });
    }
    for (const id of ["#units-box", "#jobs-box"]) $(id)?.addEventListener("scroll", () => this.onChange?.(), { passive: true });
  }

  /** Draw the map; returns its layout. */
  renderMap(now, ui) {
    const layout = drawFleet($("#map"), this.view, now, ui, this.mapBox);
    const legend = $("#state-legend");
    const byState = $("#map").dataset.colors === "state";
    if (legend.hidden === byState) legend.hidden = !byState;
    return layout;
  }

  /** Fill in the tables, the badges, the events and the chart. */
  renderPanel(now, ui) {
    const name = $("#map-name");
    name.textContent = name.title = mapTitle(this.view.map);
    this.units(now, ui);
    this.chargers();
    this.jobs(ui);
    this.coordinator();
    this.events();
    this.chart();
  }

  /** Every unit id, in order (for the goal form's list). */
  unitIds() {
    return [...this.view.units.keys()].sort();
  }

  /** The card of unit `id` beside the pointer at (x, y) on the map; null hides it. */
  hoverCard(id, x = 0, y = 0) {
    const card = $("#unit-card");
    const row = id && this.view.units.has(id) ? this.unitRow(id) : null;
    if (!row) { card.hidden = true; return; }
    const [, link, square, status, job, load] = row.cells.map(([t]) => t);
    card.textContent = `${id} · ${link} · ${square}\n${status}\njob ${job} · ${load}`;
    card.style.left = `${x + 14}px`;
    card.style.top = `${y + 14}px`;
    card.hidden = false;
  }

  /** Scroll the units table to unit `id`'s row at the next fill (clearing a search that hides it). */
  revealUnit(id) {
    this.revealing = id;
  }

  /** The coordinator's recent history, newest first: it survives a reload (fleet/events). */
  events() {
    const ul = $("#events");
    const newest = this.view.events[this.view.events.length - 1];
    const key = `${this.view.events.length}|${newest?.at ?? ""}|${newest?.text ?? ""}`;
    if (ul.dataset.key === key) return; // rebuilt only when the history changed
    ul.dataset.key = key;
    const lines = eventLines(this.view.events);
    ul.replaceChildren(...lines.map((line) => {
      const li = document.createElement("li");
      li.className = `event-${line.kind}`;
      const time = document.createElement("time");
      time.textContent = line.time;
      li.append(time, ` ${line.text}`);
      return li;
    }));
  }

  /** Jobs done per minute and how busy the units are. */
  chart() {
    // The coordinator counts jobs done per minute (the view lists only the latest finished).
    const counts = this.view.donePerMinute.slice(-CHART_MINUTES);
    const perMinute = [...new Array(CHART_MINUTES - counts.length).fill(0), ...counts];
    drawChart($("#chart"), perMinute, this.view.utilisation.latest());
  }

  /** Each unit's row content, with its state for the filter. */
  unitRows() {
    const now = Date.now();
    return this.unitIds().map((id) => this.unitRow(id, now));
  }

  /** Unit `id`'s row content: its cells, its state, and what the search and sort read. */
  unitRow(id, now = Date.now()) {
    const u = this.view.units.get(id);
    const job = unitJob(this.view, id);
    const queued = this.view.jobById.get(job);
    const control = this.view.routes[id]?.control ?? null;
    const phase = phaseText(queued, queued ? this.view.jobNumbers.of(queued.id) : null);
    const cells = unitCells(u, job, control, queued?.wait_reason ?? null, phase, this.view.energyPlan(id), this.view.routeNote(id));
    const state = unitState(u, control, !!job, this.view.isSilent(u, now));
    return { id, cells, state, status: cells[3][0], job, load: u.state?.load_kg ?? 0 };
  }

  /** The chargers under the units table: who is on each and who waits (hidden without any). */
  chargers() {
    const el = $("#chargers");
    if (!el) return;
    const lines = chargerLines(this.view.chargers(), (id) => this.view.battery(id));
    const key = lines.join("\n");
    if (el.dataset.key === key) return;
    el.dataset.key = key;
    el.hidden = !lines.length;
    $("#chargers-list").replaceChildren(...lines.map((line) => {
      const li = document.createElement("li");
      li.textContent = line;
      return li;
    }));
  }

  units(now, ui) {
    const rows = this.unitRows();
    const pick = () => shownUnits(rows, $("#unit-search").value, $("#unit-filter").value, $("#unit-sort").value);
    let shown = pick();
    const box = $("#units-box");
    let scrollTop = box.scrollTop;
    if (this.revealing) {
      let at = shown.findIndex((r) => r.id === this.revealing);
      if (at < 0 && rows.some((r) => r.id === this.revealing)) {
        $("#unit-search").value = "";
        $("#unit-filter").value = "all";
        shown = pick();
        at = shown.findIndex((r) => r.id === this.revealing);
      }
      if (at >= 0) scrollTop = Math.max(0, at * UNIT_ROW_H - (box.clientHeight || 400) / 2);
      this.revealing = null;
    }
    const slice = visibleSlice(shown.length, UNIT_ROW_H, scrollTop, box.clientHeight || 400);
    syncRows($("#units tbody"), shown.slice(slice.first, slice.last), {
      keyName: "unit",
      key: (r) => r.id,
      cells: (r) => r.cells,
      extra: (tr, r, fresh) => {
        const id = r.id;
        const u = this.view.units.get(id);
        if (fresh) {
          const seen = document.createElement("td");
          seen.className = "seen";
          const control = document.createElement("td");
          control.className = "control";
          tr.append(seen, control);
        }
        this.controls(tr.querySelector("td.control"), id, r.state === "away");
        tr.dataset.link = u.connection ?? "unknown";
        // Its battery as a bar behind the link cell, coloured by the coordinator's thresholds
        // (style.css: amber low, red critical or empty), and its charge for tests.
        const battery = this.view.battery(id);
        const level = battery ? batteryLevel(battery.pct, this.view.energy?.thresholds) : null;
        const link = tr.children[1];
        const pct = battery ? String(Math.round(battery.pct)) : "";
        if ((link.dataset.battery ?? "") !== pct) {
          if (battery) link.dataset.battery = pct; else delete link.dataset.battery;
          link.style.setProperty("--battery", battery ? `${battery.pct}%` : "");
        }
        if (level) link.dataset.level = level.level; else delete link.dataset.level;
        link.classList.toggle("charging", !!battery?.charging);
        tr.dataset.state = r.state; // moving, idle, … away: what the filter and the map's colours say
        tr.classList.toggle("selected", id === ui.selectedUnit);
        tr.style.setProperty("--unit-color", this.view.colorOf(id)); // its stripe (style.css)
        // The whole cell in words: "battery 62 %, charging · online".
        link.title = linkTitle(link.textContent, battery, level);
        tr.children[3].title = tr.children[3].textContent; // the whole of a long status
        tr.children[4].title = tr.children[4].textContent;
      },
    }, slice);
    if (box.scrollTop !== scrollTop) box.scrollTop = scrollTop; // the rows are there to scroll to now
    $("#units-count").textContent = shown.length === rows.length ? `(${rows.length})` : `(${shown.length} of ${rows.length})`;
    this.seen(now);
  }

  /**
   * A unit's pause / out-of-service (and, with energy, charge) buttons, and "remove" for a lost
   * one (`away`): rebuilt only when its control, its energy or whether it is lost changes.
   */
  controls(td, id, away = false) {
    const control = this.view.routes[id]?.control ?? "";
    const energy = this.view.hasEnergy(id);
    const key = `${control}${away ? "|away" : ""}${energy ? "|energy" : ""}`;
    if (td.dataset.control === key && td.children.length) return;
    td.dataset.control = key;
    const buttons = controlButtons(control || null, energy).map(([label, command, what]) => {
      const b = document.createElement("button");
      b.type = "button";
      b.dataset.unit = id;
      b.dataset.command = command;
      b.textContent = label;
      b.title = `${what}: ${id}`;
      return b;
    });
    if (away) {
      const b = document.createElement("button");
      b.type = "button";
      b.dataset.remove = id;
      b.textContent = "remove";
      b.title = `remove ${id} for good: only once it is physically off the floor`;
      buttons.push(b);
    }
    td.replaceChildren(...buttons);
  }

  /** The "seen" column and the silent mark: they change with the clock alone. */
  seen(now) {
    for (const tr of document.querySelectorAll("#units tbody tr[data-unit]")) {
      const u = this.view.units.get(tr.dataset.unit);
      const td = tr.querySelector(".seen");
      if (!u || !td) continue;
      const text = seenText(u, now);
      if (td.textContent !== text) td.textContent = text;
      tr.classList.toggle("silent", this.view.isSilent(u, now));
    }
  }

  jobs(ui) {
    const active = this.view.activeJobs();
    const box = $("#jobs-box");
    const slice = visibleSlice(active.length, ROW_H, box.scrollTop, box.clientHeight || 300);
    syncRows($("#jobs tbody"), active.slice(slice.first, slice.last), {
      keyName: "job",
      key: (j) => j.id,
      cells: (j) => jobCells(j, this.view.jobNumbers.of(j.id)),
      extra: (tr, j, fresh) => {
        tr.className = `job-${j.state}`;
        tr.classList.toggle("selected", j.id === ui.selectedJob);
        tr.children[3].title = j.wait_reason ?? ""; // the whole reason, when the cell cuts it
        tr.children[5].title = tr.children[5].textContent; // the whole route, places named
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
    }, slice);
    $("#queue-count").textContent = `(${active.length})`;
    const finished = this.view.finishedJobs();
    const period = this.view.coordinator ? stepPeriodS(this.view.coordinator) : undefined;
    syncRows($("#finished tbody"), latestFinished(finished), {
      keyName: "job",
      key: (j) => j.id,
      cells: (j) => finishedCells(j, period),
      extra: (tr, j) => { tr.className = `job-${j.state}`; },
    });
    $("#finished-counts").textContent = finishedCounts(finished, this.view.counts);
  }

  coordinator() {
    const badge = coordinatorBadge(this.view.coordinator, this.view.coordinatorStep());
    const el = $("#coord");
    el.dataset.state = badge.state;
    el.textContent = badge.text;
  }
}

/** The broker connection's badge. */
export function showConnection(state, text) {
  const conn = $("#conn");
  conn.dataset.state = state;
  conn.textContent = text;
}

/** The page cannot work (no settings, no MQTT.js): say why, in place of the broker's badge. */
export function showFatal(text) {
  const el = $("#fatal");
  el.textContent = text;
  el.hidden = false;
  showConnection("failed", "no MQTT client");
}

/** A line at the top of the message log (the latest 50 are kept). */
export function log(text) {
  const li = document.createElement("li");
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  const ul = $("#log");
  ul.prepend(li);
  while (ul.children.length > 50) ul.lastChild.remove();
}
