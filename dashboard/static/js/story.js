// What the page tells about the fleet's work: each unit's job, numbered pickup/dropoff pairs,
// finished jobs newest first with how long they took, the coordinator's event log, and the
// figures of the throughput chart. Pure: no DOM, no clock (callers pass `now` in ms).

export const FINISHED_SHOWN = 20; // the finished table's rows: the latest, newest first
export const CHART_MINUTES = 10; // the chart's span
export const SAMPLE_MS = 5000; // how often the page samples how busy the units are

/** The job unit `id` works on: its own state's, else the one the queue assigns it (not final). */
export function unitJob(view, id) {
  const own = view.units.get(id)?.state?.job_id;
  if (own) return own;
  return view.jobOfUnit.get(id) ?? null;
}

/**
 * Stable numbers for jobs, so a pickup "P3" is matched with its dropoff "D3" and its row. A job
 * id ending in a number keeps it ("job-258" is 258: every page, and every reload, says the same);
 * others, or one whose number is taken, get the next number nobody has.
 */
export class JobNumbers {
  constructor() {
    this.numbers = new Map();
    this.taken = new Set();
    this.next = 1;
  }

  /** The number of job `id`, given the first time it is asked for. */
  of(id) {
    if (!this.numbers.has(id) && !this.own(id)) {
      while (this.taken.has(this.next)) this.next += 1;
      this.give(id, this.next);
    }
    return this.numbers.get(id);
  }

  /** Give each of `ids` that ends in a free number that number, before any is counted out. */
  claim(ids) {
    for (const id of ids) if (!this.numbers.has(id)) this.own(id);
  }

  own(id) {
    const m = /(\d{1,6})$/.exec(id);
    const n = m ? Number(m[1]) : null;
    if (n === null || this.taken.has(n)) return false;
    this.give(id, n);
    return true;
  }

  give(id, n) {
    this.taken.add(n);
    this.numbers.set(id, n);
  }
}

/** Seconds job `j` took from submission to its end, from the coordinator's steps; null if unknown. */
export function tookSeconds(j, periodS) {
  const created = j.created_step ?? 0; // the schema's default: left out, it is step 0
  if (!Number.isInteger(j.done_step) || !Number.isInteger(created) || !(periodS > 0)) return null;
  return Math.max(0, j.done_step - created) * periodS;
}

/** "8.5 s", "2 min 05 s", "1 h 02 min". */
export function durationText(seconds) {
  if (seconds == null) return "—";
  if (seconds < 60) return `${+seconds.toFixed(1)} s`;
  const s = Math.round(seconds);
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(s / 3600)} h ${String(Math.floor((s % 3600) / 60)).padStart(2, "0")} min`;
}

/** The finished jobs newest first (by the step they ended), at most `most`. */
export function latestFinished(finished, most = FINISHED_SHOWN) {
  const step = (j) => (Number.isInteger(j.done_step) ? j.done_step : -1);
  return [...finished].sort((a, b) => step(b) - step(a) || (a.id < b.id ? 1 : -1)).slice(0, most);
}

/** "10:04:31", local time, of an ISO timestamp; "" when it does not parse. */
export function clockText(iso) {
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return "";
  return [d.getHours(), d.getMinutes(), d.getSeconds()].map((n) => String(n).padStart(2, "0")).join(":");
}

/** The coordinator's event history (oldest first, as published) as log lines, newest first. */
export function eventLines(events) {
  if (!Array.isArray(events)) return [];
  return events
    .filter((e) => e && typeof e.text === "string")
    .map((e) => ({ time: clockText(e.at), text: e.text, kind: e.kind ?? "", job: e.job ?? null, unit: e.unit ?? null }))
    .reverse();
}

/** Units online and, of those, units with work (a job, a goal or moving), at one moment. */
export function busyUnits(view) {
  let online = 0, busy = 0;
  for (const u of view.units.values()) {
    if (u.connection !== "online" || !u.state) continue;
    online += 1;
    if (unitJob(view, u.id) || u.state.status !== "idle") busy += 1;
  }
  return { online, busy };
}

/** Samples of how busy the units were: the share of online units with work, kept `minutes`. */
export class Utilisation {
  constructor(minutes = CHART_MINUTES) {
    this.keepMs = minutes * 60000;
    this.samples = []; // {t, share}
  }

  /** Take a sample at `now` (ms) unless the last one is less than SAMPLE_MS old. */
  sample(view, now) {
    const last = this.samples[this.samples.length - 1];
    if (last && now - last.t < SAMPLE_MS) return;
    const { online, busy } = busyUnits(view);
    if (online === 0) return;
    this.samples.push({ t: now, share: busy / online });
    while (this.samples.length && now - this.samples[0].t > this.keepMs) this.samples.shift();
  }

  /** The latest share, 0..1, or null before the first sample. */
  latest() {
    return this.samples.length ? this.samples[this.samples.length - 1].share : null;
  }
}

/**
 * Places one label per item where it overlaps no other label, no unit and stays in `bounds`:
 * below, above, right or left of its unit; an item with no free place gets none (the units table
 * names every unit). Items are {id, cx, cy, r, w, h}; returns [{id, x, y, w, h}] (x, y: centre).
 */
export function placeLabels(items, bounds) {
  const boxes = (x, y, w, h) => ({ x0: x - w / 2, y0: y - h / 2, x1: x + w / 2, y1: y + h / 2 });
  const overlaps = (a, b) => a.x0 < b.x1 && b.x0 < a.x1 && a.y0 < b.y1 && b.y0 < a.y1;
  const inside = (a) => a.x0 >= bounds.x0 && a.y0 >= bounds.y0 && a.x1 <= bounds.x1 && a.y1 <= bounds.y1;
  // Boxes in buckets of a grid, so each spot is checked against its neighbours only: with 500
  // units, checking every box against every other took most of a frame.
  const size = Math.max(16, ...items.map((it) => Math.max(it.w, it.h, 2 * it.r)));
  const buckets = new Map();
  const cells = (b, visit) => {
    for (let gx = Math.floor(b.x0 / size); gx <= Math.floor(b.x1 / size); gx++) {
      for (let gy = Math.floor(b.y0 / size); gy <= Math.floor(b.y1 / size); gy++) visit(`${gx},${gy}`);
    }
  };
  const add = (box) => cells(box, (k) => { if (!buckets.has(k)) buckets.set(k, []); buckets.get(k).push(box); });
  const clashes = (box, id) => {
    let hit = false;
    cells(box, (k) => { hit ||= (buckets.get(k) ?? []).some((t) => t.id !== id && overlaps(box, t)); });
    return hit;
  };
  for (const it of items) add({ id: it.id, ...boxes(it.cx, it.cy, 2 * it.r, 2 * it.r) });
  const placed = [];
  for (const it of items) {
    const gap = it.r + it.h / 2 + 1;
    const side = it.r + it.w / 2 + 2;
    const spots = [[it.cx, it.cy + gap], [it.cx, it.cy - gap], [it.cx + side, it.cy], [it.cx - side, it.cy]];
    for (const [x, y] of spots) {
      const box = boxes(x, y, it.w, it.h);
      if (!inside(box) || clashes(box, it.id)) continue;
      add({ id: null, ...box }); // a placed label: in the way of every other
      placed.push({ id: it.id, x, y, w: it.w, h: it.h });
      break;
    }
  }
  return placed;
}
