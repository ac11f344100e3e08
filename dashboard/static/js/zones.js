// Closed zones on the page (fleet/zones, requests/close_zone and open_zone: protocol.md §5.11,
// §6.12, §6.13): reading the view as its schema has it, the rectangle a drag over the map makes,
// the requests the zone form and the "Open" buttons send, and the zones list's words. Pure: no
// DOM, no network, no clock.

import { ID_RE } from "./protocol.js";
import { LIMITS } from "./protocol_table.js";

const ZONE_FIELDS = new Set(["name", "first", "last", "reason", "closed_by", "closed_at"]);
const REQUIRED = ["name", "first", "last", "reason", "closed_at"];
// A date-time as the schema's format has it (RFC 3339, section 5.6: seconds and an offset, or Z).
const DATE_TIME = /^(\d{4})-(\d\d)-(\d\d)T(\d\d):(\d\d):(\d\d)(\.\d+)?(Z|[+-](\d\d):(\d\d))$/i;

const isCoord = (v) => Number.isInteger(v) && v >= 0 && v <= LIMITS.max_coord;
const isSquare = (sq) => Array.isArray(sq) && sq.length === 2 && sq.every(isCoord);
// Text as the schema counts it: in characters (code points), not UTF-16 units.
const isText = (v) => typeof v === "string" && [...v].length <= LIMITS.max_text;

/** Whether `v` is an RFC 3339 date-time: a real day of its month, a leap second's :60 too. */
export function isDateTime(v) {
  const m = typeof v === "string" ? DATE_TIME.exec(v) : null;
  if (!m) return false;
  const [year, month, day, hour, minute, second] = m.slice(1, 7).map(Number);
  const leap = year % 4 === 0 && (year % 100 !== 0 || year % 400 === 0);
  const days = [31, leap ? 29 : 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31][month - 1];
  const offsetOk = m[9] === undefined || (Number(m[9]) < 24 && Number(m[10]) < 60);
  // Year 1 at the earliest, as the coordinator's clock (Python's datetime) can write.
  return year >= 1 && days !== undefined && day >= 1 && day <= days && hour < 24 && minute < 60 && second <= 60 && offsetOk;
}

/**
 * A people's account may change the fleet from the page (an operator or dashboard one, or anybody
 * without accounts): the settings' `may_change`. Settings that do not say are read as allowed,
 * as the Audit tab's are (the coordinator and the broker still refuse a viewer).
 */
export function mayChange(settings) {
  return settings?.may_change !== false;
}

/** Where a zone breaks the schema (models' Zone), in words; null when it does not. */
function zoneProblem(z) {
  if (typeof z !== "object" || z === null || Array.isArray(z)) return "is not an object";
  const extra = Object.keys(z).filter((k) => !ZONE_FIELDS.has(k));
  if (extra.length) return `has unknown fields (${extra.join(", ").slice(0, 60)})`;
  const missing = REQUIRED.filter((k) => !(k in z));
  if (missing.length) return `has no ${missing.join(", ")}`;
  if (typeof z.name !== "string" || !ID_RE.test(z.name)) return "has a name that is not an id";
  if (!isSquare(z.first) || !isSquare(z.last)) return "has a corner that is not a square";
  if (!isText(z.reason)) return `has a reason that is not text of at most ${LIMITS.max_text} characters`;
  if (z.closed_by != null && (typeof z.closed_by !== "string" || !ID_RE.test(z.closed_by))) return "has a closed_by that is not an id";
  if (!isDateTime(z.closed_at)) return "has a closed_at that is not a date and time (RFC 3339)";
  return null;
}

/**
 * The zones view (`fleet/zones`, parsed) as the page keeps it: {zones} (each with its corners
 * least and greatest), or {error} in words when it breaks its schema: then the page keeps the
 * zones it had, as it keeps its queue when a queue view is malformed.
 */
export function readZones(msg) {
  if (typeof msg !== "object" || msg === null || Array.isArray(msg)) return { error: "ignored a zones view that is not an object" };
  const extra = Object.keys(msg).filter((k) => k !== "header" && k !== "zones");
  if (extra.length) return { error: `ignored a zones view with unknown fields (${extra.join(", ").slice(0, 60)})` };
  const listed = msg.zones === undefined ? [] : msg.zones;
  if (!Array.isArray(listed)) return { error: "ignored a zones view whose zones are not a list" };
  if (listed.length > LIMITS.max_zones) return { error: `ignored a zones view of ${listed.length} zones (at most ${LIMITS.max_zones})` };
  const zones = [];
  for (const [i, z] of listed.entries()) {
    const problem = zoneProblem(z);
    if (problem) {
      const which = typeof z?.name === "string" ? ` ${z.name.slice(0, 64)}` : "";
      return { error: `ignored a malformed zones view: zone ${i + 1}${which} ${problem}` };
    }
    zones.push({ ...normaliseRect(z.first, z.last), name: z.name, reason: z.reason, closed_by: z.closed_by ?? null, closed_at: z.closed_at });
  }
  return { zones };
}

/** The rectangle between two corner squares, any two: {first (least x, y), last (greatest)}. */
export function normaliseRect(a, b) {
  return {
    first: [Math.min(a[0], b[0]), Math.min(a[1], b[1])],
    last: [Math.max(a[0], b[0]), Math.max(a[1], b[1])],
  };
}

/**
 * The rectangle a drag from square `from` to the point under the pointer makes: its corners, the
 * far one held on the map (`cols` x `rows`) when the pointer has left it. `to` may be any
 * [x, y] of squares, fractional or off the map.
 */
export function dragRect(from, to, cols, rows) {
  const hold = (v, n) => Math.max(0, Math.min(n - 1, Math.floor(v)));
  return normaliseRect(from, [hold(to[0], cols), hold(to[1], rows)]);
}

/** Whether square `sq` lies in zone (or rectangle) `z`. */
export function inZone(z, sq) {
  return sq[0] >= z.first[0] && sq[0] <= z.last[0] && sq[1] >= z.first[1] && sq[1] <= z.last[1];
}

/** "[3, 0] to [4, 9]" (one square: "[3, 0]"), and how many squares: "2 x 10 squares". */
export function rectText(z) {
  const [a, b] = [z.first, z.last];
  const corners = a[0] === b[0] && a[1] === b[1] ? `[${a[0]}, ${a[1]}]` : `[${a[0]}, ${a[1]}] to [${b[0]}, ${b[1]}]`;
  const w = b[0] - a[0] + 1, h = b[1] - a[1] + 1;
  return `${corners} (${w * h === 1 ? "1 square" : `${w} x ${h} squares`})`;
}

/**
 * The close_zone request of the zone form: a rectangle ({first, last}, from a drag), a name and
 * a reason as typed; {what, body} exactly as CloseZone wants them, or {error} in words. `view`:
 * the FleetView (its map holds the corners).
 */
export function closeZoneRequest(view, { first, last, name, reason }) {
  if (!view.map) return { error: "no map yet: waiting for the coordinator's fleet/map" };
  if (!first || !last) return { error: "drag over the map first: the zone's rectangle" };
  for (const sq of [first, last]) {
    if (!view.onMap(sq[0], sq[1])) return { error: `[${sq}] is not a square of the map` };
  }
  const zoneName = String(name ?? "").trim();
  if (!ID_RE.test(zoneName)) return { error: "zone name: letters, digits, _ . - only (max 64), e.g. aisle-4" };
  const why = String(reason ?? "").trim();
  if (!why) return { error: "give a reason (it is shown to every operator and kept in the audit)" };
  if (why.length > LIMITS.max_text) return { error: `the reason is ${why.length} characters long: at most ${LIMITS.max_text}` };
  const rect = normaliseRect(first, last);
  return {
    what: `close zone ${zoneName} ${rectText(rect)}`,
    body: { name: zoneName, first: rect.first, last: rect.last, reason: why },
  };
}

/** The open_zone request of a zone's "Open" button. */
export function openZoneRequest(zone) {
  return { what: `open zone ${zone.name}`, body: { name: zone.name } };
}

/** The zones list's row of zone `z`: [text, className] each; `clock(iso)` says when. */
export function zoneCells(z, clock) {
  return [
    [z.name, "name"], [rectText(z), "rect"], [z.reason, "reason"],
    [z.closed_by ?? "?", "by"], [clock(z.closed_at), "at"],
  ];
}

/** What the map writes on a closed zone: "aisle-4 · cleaning". */
export function zoneLabel(z) {
  return `${z.name} · ${z.reason}`;
}
