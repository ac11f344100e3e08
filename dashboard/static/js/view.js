// Showing the fleet: the map, the units and jobs tables, the coordinator's and the broker's state,
// the message log. What each cell says comes from pure functions (testable under node); `PageView`
// puts it on the page.

import { drawChart, drawFleet } from "./draw.js";
import { syncRows } from "./rows.js";
import { donePerMinute, durationText, eventLines, latestFinished, tookSeconds, unitJob } from "./story.js";

const $ = (sel) => document.querySelector(sel);
const FINAL_COUNTED = ["done", "cancelled", "rejected", "failed"];

// ---- what the page says (pure) ----

export function mapTitle(map) {
  return map ? `${map.name} ${map.width} x ${map.height}` : "no map yet";
}

const CONTROL_WORDS = { paused: "paused", out_of_service: "out of service" };

/**
 * The units table's cells for unit `u` (a FleetView unit): [text, className] each. `job`: the job
 * it works on (its own, or the queue's before pickup); `control`: an operator's hold on it;
 * `jobWait`: why that job waits, in the coordinator's words (a unit between orders says "idle"
 * while its job is stuck: the job's words say what holds it).
 */
export function unitCells(u, job = u.state?.job_id ?? null, control = null, jobWait = null) {
  const s = u.state;
  const cap = u.factsheet ? `/${u.factsheet.capacity_kg}` : "";
  let status = s ? s.status + (s.wait_reason ? `: ${s.wait_reason}` : "") : "—";
  const quiet = s && !s.wait_reason && (s.status === "idle" || s.status === "holding");
  if (jobWait && quiet) status = `${s.status} · ${jobWait}`;
  if (control) status = `${CONTROL_WORDS[control] ?? control} · ${status}`;
  // A job whose item is on board is marked (the load says how heavy).
  const carrying = s && s.load_kg > 0 ? "job carrying" : "job";
  return [
    [u.id, "id"], [u.connection ?? "?", "link"],
    [s ? `[${s.position[0]}, ${s.position[1]}]` : "—", "pos"], [status, "status"],
    [job ?? "—", carrying], [s ? `${s.load_kg}${cap} kg` : (cap ? `0${cap} kg` : "—"), "load"],
  ];
}

/** The unit row's control buttons for `control` (null, paused, out_of_service): [label, command]. */
export function controlButtons(control) {
  if (control === "out_of_service") return [["in service", "in_service"]];
  if (control === "paused") return [["resume", "resume"], ["out of service", "out_of_service"]];
  return [["pause", "pause"], ["out of service", "out_of_service"]];
}

/** When unit `u` was last heard of, at `now` (ms). */
export function seenText(u, now) {
  return u.lastSeen == null ? "never" : `${Math.max(0, Math.round((now - u.lastSeen) / 1000))} s ago`;
}

/** A job of the queue: `n` its number on the map (P n, D n), and why it waits, if it does. */
export function jobCells(j, n) {
  return [[String(n), "no"], [j.id, "id"], [j.state, "state"], [j.wait_reason ?? "", "waits"],
    [j.unit ?? "—", "unit"], [`[${j.pickup}] → [${j.dropoff}]`, "route"], [String(j.mass_kg), "mass"]];
}

/** A finished job; `periodS` the coordinator's step period, for how long it took. */
export function finishedCells(j, periodS) {
  return [[j.id, "id"], [j.state, "state"], [j.unit ?? "—", "unit"],
    [durationText(tookSeconds(j, periodS)), "took"], [j.reason ?? "", "reason"]];
}

/**
 * "done 3 · failed 1": the finished jobs by state. The coordinator's own counts win (it keeps
 * only the latest finished jobs in the view) for the states shown and for every final state.
 */
export function finishedCounts(finished, counts) {
  const shown = {};
  for (const j of finished) shown[j.state] = (shown[j.state] ?? 0) + 1;
  for (const [k, v] of Object.entries(counts)) if (k in shown || FINAL_COUNTED.includes(k)) shown[k] = v;
  return Object.entries(shown).map(([k, v]) => `${k} ${v}`).join(" · ");
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
  return ` · ${time(c.achieved_step_s)} a step (set ${time(c.step_period_s)})`;
}

// ---- on the page ----

export class PageView {
  /** Shows FleetView `view`. */
  constructor(view) {
    this.view = view;
  }

  /** Draw and fill in everything; `ui` is the map's click state. Returns the map's layout. */
  render(now, ui) {
    const layout = drawFleet($("#map"), this.view, now, ui);
    $("#map-name").textContent = mapTitle(this.view.map);
    this.units(now, ui);
    this.jobs(ui);
    this.coordinator();
    this.events();
    this.chart();
    return layout;
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
    const c = this.view.coordinator;
    const perMinute = donePerMinute(this.view.finishedJobs(), this.view.coordinatorStep(), c?.step_period_s);
    drawChart($("#chart"), perMinute, this.view.utilisation.latest());
  }

  units(now, ui) {
    const ids = [...this.view.units.keys()].sort();
    syncRows($("#units tbody"), ids, {
      keyName: "unit",
      key: (id) => id,
      cells: (id) => {
        const job = unitJob(this.view, id);
        const wait = this.view.activeJobs().find((j) => j.id === job)?.wait_reason ?? null;
        return unitCells(this.view.units.get(id), job, this.view.routes[id]?.control, wait);
      },
      extra: (tr, id, fresh) => {
        const u = this.view.units.get(id);
        if (fresh) {
          const seen = document.createElement("td");
          seen.className = "seen";
          const control = document.createElement("td");
          control.className = "control";
          tr.append(seen, control);
        }
        this.controls(tr.querySelector("td.control"), id);
        tr.dataset.link = u.connection ?? "unknown";
        tr.classList.toggle("selected", id === ui.selectedUnit);
        tr.children[0].style.borderLeft = `6px solid ${this.view.colorOf(id)}`;
        tr.children[3].title = tr.children[3].textContent;  // the whole of a long status
      },
    });
    this.seen(now);
  }

  /** A unit's pause / out-of-service buttons, rebuilt only when its hold changes. */
  controls(td, id) {
    const control = this.view.routes[id]?.control ?? "";
    if (td.dataset.control === control && td.children.length) return;
    td.dataset.control = control;
    td.replaceChildren(...controlButtons(control || null).map(([label, command]) => {
      const b = document.createElement("button");
      b.type = "button";
      b.dataset.unit = id;
      b.dataset.command = command;
      b.textContent = label;
      b.title = `${label}: ${id}`;
      return b;
    }));
  }

  /** The "seen" column and the silent mark: they change with the clock alone. */
  seen(now) {
    for (const tr of document.querySelectorAll("#units tbody tr")) {
      const u = this.view.units.get(tr.dataset.unit);
      const td = tr.querySelector(".seen");
      if (!u || !td) continue;
      td.textContent = seenText(u, now);
      tr.classList.toggle("silent", this.view.isSilent(u, now));
    }
  }

  jobs(ui) {
    const active = this.view.activeJobs();
    syncRows($("#jobs tbody"), active, {
      keyName: "job",
      key: (j) => j.id,
      cells: (j) => jobCells(j, this.view.jobNumbers.of(j.id)),
      extra: (tr, j, fresh) => {
        tr.className = `job-${j.state}`;
        tr.classList.toggle("selected", j.id === ui.selectedJob);
        tr.children[3].title = j.wait_reason ?? ""; // the whole reason, when the cell cuts it
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
    const period = this.view.coordinator?.step_period_s;
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
