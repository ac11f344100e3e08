// The History view's words and figures: the query its filters make, the table's cells, each job's
// duration, the charges' starts and ends, and the CSV a person downloads. Pure: no DOM, no
// network, no clock (callers pass `now` in ms). protocol.md §6.10 says what the coordinator answers.

import { FINAL_JOB_STATES, ID_RE } from "./protocol.js";
import { JOB_STATES } from "./protocol_table.js";
import { durationText } from "./story.js";

// The columns of `gridfleet job history --csv` (console/job.py HISTORY_COLUMNS), in its order: a
// file from the page and one from the command read the same.
export const HISTORY_COLUMNS = [
  "at", "job", "state", "unit", "wait", "reason", "since_submitted_s", "pickup_x",
  "pickup_y", "dropoff_x", "dropoff_y", "mass_kg", "priority", "submitted_by",
];
// The columns of `gridfleet job history --charges --csv` (console/job.py CHARGE_COLUMNS).
export const CHARGE_COLUMNS = ["at", "unit", "charger", "event", "battery_pct", "reason"];
export const HISTORY_KINDS = ["jobs", "charges"]; // what a query asks for (its `kind`)
export const CHARGE_EVENTS = ["started", "ended"];
export const TABLE_PAGE = 200; // entries a page of the table asks for (the coordinator's default)
export const EXPORT_PAGE = 1000; // entries a page of a download asks for (the most it gives)
export const DAY_MS = 24 * 3600 * 1000;

/**
 * A time typed in a filter: a `datetime-local` value (the person's local time, as the browser
 * shows it) or an ISO time with its zone. Returns a Date, null for an empty field, or throws in
 * words naming `what`.
 */
export function readTime(text, what) {
  const t = (text ?? "").trim();
  if (!t) return null;
  // A date and time without a zone is the person's own clock, as the inputs show it.
  const local = /^\d{4}-\d\d-\d\dT\d\d:\d\d(:\d\d(\.\d+)?)?$/.test(t);
  const zoned = /^\d{4}-\d\d-\d\dT\d\d:\d\d(:\d\d(\.\d+)?)?(Z|[+-]\d\d:\d\d)$/.test(t);
  const d = local || zoned ? new Date(t) : new Date(NaN);
  if (Number.isNaN(d.getTime())) throw new Error(`${what} "${t}" is not a time: use the picker, e.g. 2026-11-26T14:00`);
  return d;
}

/** A `datetime-local` input's value for the time `ms` on the person's own clock (minutes). */
export function localInputValue(ms) {
  const d = new Date(ms);
  const two = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())}T${two(d.getHours())}:${two(d.getMinutes())}`;
}

/**
 * The job_history request the filters make ({kind, since, until, unit, job, state}: the fields'
 * text), checked here first so a mistake is told at once: {body} or {error} in words. An empty
 * `since` is a day before `now` (ms); an empty `kind` is the jobs'. The charges' query takes the
 * range and the unit only: the job and state filters are the jobs', and left out of it.
 */
export function historyQuery(fields, now, limit = TABLE_PAGE) {
  let since, until;
  try {
    since = readTime(fields.since, "since");
    until = readTime(fields.until, "until");
  } catch (e) {
    return { error: e.message };
  }
  since ??= new Date(now - DAY_MS);
  if (until && since >= until) return { error: `since ${fields.since} is not before until ${fields.until}` };
  const kind = (fields.kind ?? "").trim() || "jobs";
  if (!HISTORY_KINDS.includes(kind)) return { error: `"${kind}" is neither jobs nor charges` };
  const charges = kind === "charges";
  const unit = (fields.unit ?? "").trim() || null;
  const job = charges ? null : (fields.job ?? "").trim() || null;
  const state = charges ? null : (fields.state ?? "").trim() || null;
  if (unit && !ID_RE.test(unit)) return { error: `unit "${unit}": letters, digits, _ . - only (max 64)` };
  if (job && !ID_RE.test(job)) return { error: `job "${job}": letters, digits, _ . - only (max 64)` };
  if (state && !JOB_STATES.includes(state)) return { error: `state "${state}" is not one of ${JOB_STATES.join(", ")}` };
  return {
    body: {
      kind, since: since.toISOString(), until: until ? until.toISOString() : null,
      unit, job_id: job, state, limit, cursor: null,
    },
  };
}

/**
 * A timestamp as the command writes it: UTC, milliseconds (cut, not rounded, as Python's
 * `isoformat(timespec="milliseconds")`), `Z`. The coordinator's own have microseconds.
 */
export function utcStamp(iso) {
  const m = /^(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d)(?:\.(\d+))?(?:Z|\+00:00)$/.exec(iso ?? "");
  if (m) return `${m[1]}.${(m[2] ?? "").padEnd(3, "0").slice(0, 3)}Z`;
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? String(iso ?? "") : d.toISOString();
}

/** One entry as the CSV's cells, in HISTORY_COLUMNS' order (empty for null, as the command). */
export function historyRow(e) {
  const cells = [
    utcStamp(e.at), e.job, e.state, e.unit, e.wait, e.reason, e.since_submitted_s,
    e.pickup?.[0], e.pickup?.[1], e.dropoff?.[0], e.dropoff?.[1], e.mass_kg, e.priority ?? 0, e.submitted_by,
  ];
  return cells.map((c) => (c == null ? "" : String(c)));
}

/** One charge entry as the CSV's cells, in CHARGE_COLUMNS' order (empty for null, as the command). */
export function chargeRow(e) {
  const cells = [utcStamp(e.at), e.unit, e.charger, e.event, e.battery_pct, e.reason];
  return cells.map((c) => (c == null ? "" : String(c)));
}

/** A cell quoted as Python's csv module does (QUOTE_MINIMAL): only when it must be. */
export function csvCell(text) {
  return /[",\r\n]/.test(text) ? `"${text.replace(/"/g, '""')}"` : text;
}

/**
 * The whole CSV of `entries` of a query of `kind` ("jobs", or "charges": the command's columns of
 * each): a header line, then one line per entry, each ending in \n.
 */
export function historyCsv(entries, kind = "jobs") {
  const [columns, row] = kind === "charges" ? [CHARGE_COLUMNS, chargeRow] : [HISTORY_COLUMNS, historyRow];
  const lines = [columns, ...entries.map(row)];
  return lines.map((cells) => cells.map(csvCell).join(",") + "\n").join("");
}

/** The file name of a download: the range it covers, in UTC (`gridfleet-history-…Z.csv`, `gridfleet-charges-…`). */
export function csvName(body, now) {
  const stamp = (iso) => iso.replace(/\.\d+Z$/, "Z").replace(/:/g, "");
  const until = body.until ?? new Date(now).toISOString();
  const what = body.kind === "charges" ? "charges" : "history";
  return `gridfleet-${what}-${stamp(body.since)}-${stamp(until)}.csv`;
}

const isTime = (v) => typeof v === "string" && !Number.isNaN(Date.parse(v));
const isId = (v) => typeof v === "string" && ID_RE.test(v);
const isWords = (v) => v == null || typeof v === "string";
const isObject = (v) => typeof v === "object" && v !== null && !Array.isArray(v);

/** True for a job entry the table and the CSV can show (§6.10): its time, job and state at least. */
export function isJobEntry(e) {
  return isObject(e) && isTime(e.at) && isId(e.job) && JOB_STATES.includes(e.state)
    && (e.unit == null || isId(e.unit)) && isWords(e.reason)
    && (e.since_submitted_s == null || Number.isFinite(e.since_submitted_s));
}

/** True for a charge entry as §6.10 has it: time, unit, charger, event, battery 0–100, words or null. */
export function isChargeEntry(e) {
  return isObject(e) && isTime(e.at) && isId(e.unit) && isId(e.charger) && CHARGE_EVENTS.includes(e.event)
    && Number.isFinite(e.battery_pct) && e.battery_pct >= 0 && e.battery_pct <= 100 && isWords(e.reason);
}

/** The list a page of the query `body` carries: `charges` for the charges' query, else `entries`. */
export function historyEntriesOf(page, body) {
  return body?.kind === "charges" ? page.charges : page.entries;
}

/** Whether an entry of a page of the query `body` may be shown (the check of its kind). */
export function isHistoryEntry(e, body) {
  return body?.kind === "charges" ? isChargeEntry(e) : isJobEntry(e);
}

/** The table's cells of one charge entry: [text, className] each (its battery as the command: "35.0 %"). */
export function chargeCells(e, clock) {
  return [
    [clock(e.at), "at"], [e.unit, "unit"], [e.charger, "charger"], [e.event, "event"],
    [`${e.battery_pct.toFixed(1)} %`, "battery"], [e.reason ?? "", "reason"],
  ];
}

/** What the loaded charge entries say in one line: how many, how many started and ended, of how many units. */
export function chargeSummary(entries, more) {
  if (!entries.length) return "no charge started or ended in this range";
  const count = (event) => entries.filter((e) => e.event === event).length;
  const units = new Set(entries.map((e) => e.unit)).size;
  return `${entries.length} charge ${entries.length === 1 ? "entry" : "entries"}${more ? " (more to load)" : ""} — `
    + `started ${count("started")} · ended ${count("ended")} — ${units} unit${units === 1 ? "" : "s"}`;
}

/** The table's cells of one entry: [text, className] each; a final entry shows the job's duration. */
export function historyCells(e, clock) {
  const final = FINAL_JOB_STATES.has(e.state);
  const took = typeof e.since_submitted_s === "number" ? durationText(e.since_submitted_s) : "—";
  return [
    [clock(e.at), "at"], [e.job, "job"], [e.state, "state"], [e.unit ?? "—", "unit"],
    [final ? took : `+${took}`, final ? "took final" : "took"], [e.reason ?? "", "reason"],
  ];
}

/**
 * What the loaded entries say in one line: how many jobs ended, by state, and how long the done
 * ones took (median and longest: the `since_submitted_s` of their `done` entry).
 */
export function historySummary(entries, more) {
  if (!entries.length) return "no change in this range";
  const ended = new Map(); // job -> its final entry
  for (const e of entries) if (FINAL_JOB_STATES.has(e.state)) ended.set(e.job, e);
  const byState = {};
  for (const e of ended.values()) byState[e.state] = (byState[e.state] ?? 0) + 1;
  const took = [...ended.values()].filter((e) => e.state === "done").map((e) => e.since_submitted_s).sort((a, b) => a - b);
  const parts = [`${entries.length} changes${more ? " (more to load)" : ""}`];
  const states = Object.entries(byState).map(([s, n]) => `${s} ${n}`).join(" · ");
  if (states) parts.push(`jobs ended: ${states}`);
  if (took.length) {
    const median = took[Math.floor((took.length - 1) / 2)];
    parts.push(`done took ${durationText(median)} (median), ${durationText(took[took.length - 1])} at most`);
  }
  return parts.join(" — ");
}

/** "14:02:03" for a time of the day `now` (ms) lies in, else "11-26 14:02": the person's clock. */
export function shortStamp(iso, now) {
  const d = new Date(iso);
  if (iso == null || Number.isNaN(d.getTime())) return "";
  const two = (n) => String(n).padStart(2, "0");
  const today = new Date(now);
  if (d.toDateString() === today.toDateString()) return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
  return `${two(d.getMonth() + 1)}-${two(d.getDate())} ${two(d.getHours())}:${two(d.getMinutes())}`;
}

/** "2026-11-27 14:02:03", the person's local time, of an ISO timestamp; "" when it does not parse. */
export function stampText(iso) {
  const d = new Date(iso);
  if (iso == null || Number.isNaN(d.getTime())) return "";
  const two = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} `
    + `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}
