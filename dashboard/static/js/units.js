// The units at fleet scale: what each is doing in words, finding and sorting them, and a colour per
// state for a map with too many units for a colour each. Pure: no DOM.

export const MANY_UNITS = 24; // from this many units on, the map colours units by state
const PHASES = { assigned: "to pickup", to_pickup: "to pickup", loaded: "to dropoff", to_dropoff: "to dropoff" };

/** "to pickup P3" / "to dropoff D3": where a unit's job takes it next; null without one. */
export function phaseText(job, n) {
  const phase = job && PHASES[job.state];
  if (!phase) return null;
  return `${phase} ${phase === "to pickup" ? "P" : "D"}${n ?? ""}`;
}

/** The state a unit is in, for its colour and the filter: one of STATE_COLORS' keys. */
export function unitState(u, control, hasJob, silent = false) {
  const s = u.state;
  if (u.connection === "offline" || u.connection === "broken" || silent || !s) return "away";
  if (control) return "held";
  if (s.estop || s.status === "stopped" || s.status === "holding") return "stopped";
  if (s.status === "moving") return "moving";
  if (s.status === "waiting") return "waiting";
  return hasJob ? "job" : "idle";
}

export const STATE_COLORS = {
  moving: "#2e7d32", waiting: "#f9a825", idle: "#90a4ae", job: "#1565c0",
  stopped: "#c62828", held: "#6a1b9a", away: "#cfd8dc",
};

const FILTERS = {
  all: () => true,
  moving: (st) => st === "moving",
  waiting: (st) => st === "waiting",
  idle: (st) => st === "idle",
  working: (st, row) => !!row.job,
  carrying: (st, row) => row.load > 0,
  stopped: (st) => st === "stopped",
  held: (st) => st === "held",
  away: (st) => st === "away",
};

/**
 * The unit rows to show: `rows` ({id, state, status, job, load}) whose id, status or job contains
 * `query` (any case) and whose state passes `filter`, sorted by `sort` (id, status, job, load).
 */
export function shownUnits(rows, query = "", filter = "all", sort = "id") {
  const q = query.trim().toLowerCase();
  const pass = FILTERS[filter] ?? FILTERS.all;
  const found = rows.filter((r) => pass(r.state, r) && (!q || [r.id, r.status, r.job ?? ""].some((t) => t.toLowerCase().includes(q))));
  const byId = (a, b) => (a.id < b.id ? -1 : a.id > b.id ? 1 : 0);
  const keys = {
    id: byId,
    status: (a, b) => a.status.localeCompare(b.status) || byId(a, b),
    job: (a, b) => (a.job ?? "\uffff").localeCompare(b.job ?? "\uffff") || byId(a, b),
    load: (a, b) => b.load - a.load || byId(a, b),
  };
  return found.sort(keys[sort] ?? byId);
}

/** Which rows of `count` (each `rowH` px) a box scrolled to `scrollTop`, `viewH` high, shows. */
export function visibleSlice(count, rowH, scrollTop, viewH, overscan = 6) {
  const first = Math.max(0, Math.min(count, Math.floor(scrollTop / rowH) - overscan));
  const last = Math.max(first, Math.min(count, Math.ceil((scrollTop + viewH) / rowH) + overscan));
  return { first, last, top: first * rowH, bottom: (count - last) * rowH };
}
