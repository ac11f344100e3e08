// Named places of the map (fleet/map `places`, protocol.md §5.10): reading them, finding the
// place on a square, and what the job form's pickup and dropoff fields take: a place's name or a
// square "X,Y". Pure: no DOM, no network.

import { ID_RE } from "./protocol.js";
import { LIMITS } from "./protocol_table.js";

export const PLACE_KINDS = ["pickup", "dropoff", "charger", "parking"];
const NAMES_SAID = 20; // place names an error lists at most

const isCoord = (v) => Number.isInteger(v) && v >= 0 && v <= LIMITS.max_coord;
const isSquare = (sq) => Array.isArray(sq) && sq.length === 2 && sq.every(isCoord);
const isPlace = (p) => typeof p === "object" && p !== null && typeof p.name === "string" && ID_RE.test(p.name)
  && isSquare(p.square) && Array.isArray(p.kinds) && p.kinds.length >= 1 && p.kinds.length <= 4
  && p.kinds.every((k) => PLACE_KINDS.includes(k));
const key = (sq) => `${sq[0]},${sq[1]}`;

/**
 * The map's `places` as the page keeps them: {places, dropped}, each well-formed place, its
 * kinds without repeats; `dropped` counts those left out (all of them when the list is not a
 * list of at most LIMITS.max_places). Absent: none.
 */
export function readPlaces(listed) {
  if (listed === undefined) return { places: [], dropped: 0 };
  if (!Array.isArray(listed) || listed.length > LIMITS.max_places) {
    return { places: [], dropped: Array.isArray(listed) ? listed.length : 1 };
  }
  const places = listed.filter(isPlace).map((p) => ({ name: p.name, square: p.square, kinds: [...new Set(p.kinds)] }));
  return { places, dropped: listed.length - places.length };
}

/** The places by name and by square ("x,y"), looked up once per map, not per click or frame. */
export class PlaceIndex {
  constructor(places = []) {
    this.places = places;
    this.byName = new Map(places.map((p) => [p.name, p]));
    this.bySquare = new Map(places.map((p) => [key(p.square), p]));
  }

  /** The place on square `sq` ([x, y]), or null. */
  at(sq) {
    return sq ? this.bySquare.get(key(sq)) ?? null : null;
  }

  /** The names of the places of `kind`, sorted: what a pickup or dropoff field offers. */
  namesOf(kind) {
    return this.places.filter((p) => p.kinds.includes(kind)).map((p) => p.name).sort();
  }
}

/**
 * A pickup or dropoff field's text: {square: [x, y]} for "X,Y" (also "X Y", "[X, Y]"), {name}
 * for a place's name, or {error} in words. Squares are whole numbers; anything else that is
 * not an id is neither.
 */
export function parseWhere(text) {
  const t = String(text ?? "").trim();
  if (!t) return { error: "give a place's name or a square X,Y" };
  const sq = /^\[?\s*(-?\d+)\s*(?:,\s*|\s+)(-?\d+)\s*\]?$/.exec(t);
  if (sq) return { square: [Number(sq[1]), Number(sq[2])] };
  if (ID_RE.test(t)) return { name: t };
  return { error: `"${t.slice(0, 40)}" is neither a place's name nor a square X,Y` };
}

/** "A3 [3, 4]" for a square named by a place, "[3, 4]" for one given as a square. */
export function whereText(square, name = null) {
  const at = `[${square[0]}, ${square[1]}]`;
  return name ? `${name} ${at}` : at;
}

/** "A3, A4, P2 (and 3 more)": at most NAMES_SAID names, sorted. */
function namesText(names) {
  const sorted = [...names].sort();
  const more = sorted.length > NAMES_SAID ? ` (and ${sorted.length - NAMES_SAID} more)` : "";
  return `${sorted.slice(0, NAMES_SAID).join(", ")}${more}`;
}

/**
 * A field's parsed text (`parseWhere`) checked against the map's places for `role` ("pickup" or
 * "dropoff"): {value, square, place}, `value` what submit_job carries (the name, or [x, y]); or
 * {error}. A name must be a place of that kind; squares are checked against the map elsewhere.
 */
export function resolveWhere(index, parsed, role) {
  if (parsed.error) return { error: `${role}: ${parsed.error}` };
  if (parsed.square) return { value: parsed.square, square: parsed.square, place: null };
  const place = index.byName.get(parsed.name);
  if (!place) {
    const known = index.places.length ? `the places are ${namesText(index.byName.keys())}` : "the map names no places";
    return { error: `${role}: no place is named '${parsed.name}': ${known} (or give a square X,Y)` };
  }
  if (!place.kinds.includes(role)) {
    const offered = index.namesOf(role);
    const instead = offered.length ? `; the ${role}s are ${namesText(offered)}` : "";
    return { error: `${role}: place ${place.name} is not a ${role} (it is: ${place.kinds.join(", ")})${instead}` };
  }
  return { value: place.name, square: place.square, place };
}

/**
 * What a click on square `sq` puts into the `role` field: {text, name}, the name of the place
 * there when it is a place of that kind (`name` the same), else the square as "X,Y" (`name`
 * null).
 */
export function pickedFor(index, sq, role) {
  const place = index.at(sq);
  if (place && place.kinds.includes(role)) return { text: place.name, name: place.name };
  return { text: `${sq[0]},${sq[1]}`, name: null };
}
