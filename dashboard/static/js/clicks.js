// What a click (or a drag) on the map means: the click mode, the chosen unit, a half-picked job
// and a zone being drawn. Pure: no DOM; each step takes a state and returns a new one (the old one
// is never changed) and at most one effect for the page to carry out.
//
// State: {mode, selectedUnit, pending, pickField, selectedJob, zoom, zone}
//   mode          "none" (look), "goal" (click sets goal), "job" (click picks job squares) or
//                 "zone" (a drag draws a zone to close)
//   selectedUnit  the unit chosen in the list, on the map or in the goal form; null for none
//   pending       the job's pickup square once picked, until its dropoff is clicked (drawn ringed)
//   pickField     the job form's field the next click fills: "pickup", or "dropoff" after a
//                 pickup was picked or once the operator focused the dropoff field
//   selectedJob   the job chosen in the queue: its pickup and dropoff stand out, joined
//   zoom          {scale, pan}: 1 and [0, 0] show the whole map (draw.js zoomAt, panBy)
//   zone          the rectangle being drawn, {from, first, last, dragging}, kept once drawn until
//                 the zone form sends it or is cancelled; null for none
//
// Effects: {type: "select", unit}, {type: "goal", square}, {type: "pickup", square},
//          {type: "dropoff", square}, {type: "zone", first, last} (a rectangle drawn)

import { dragRect, normaliseRect } from "./zones.js";

export const MODES = ["none", "goal", "job", "zone"];
export const PICK_FIELDS = ["pickup", "dropoff"];

export function initialClicks() {
  return {
    mode: "none", selectedUnit: null, pending: null, pickField: "pickup", selectedJob: null,
    zoom: { scale: 1, pan: [0, 0] }, zone: null,
  };
}

/** The operator chose another click mode: a half-picked job and a zone being drawn are forgotten. */
export function setMode(state, mode) {
  return { ...state, mode, pending: null, pickField: "pickup", zone: null };
}

/** The operator focused the job form's pickup or dropoff field: the next click fills it. */
export function pickInto(state, field) {
  return PICK_FIELDS.includes(field) ? { ...state, pickField: field } : state;
}

/** In the zone mode, the pointer went down on `square`: a rectangle of that one square begins. */
export function zoneStart(state, square) {
  if (state.mode !== "zone" || !square) return state;
  return { ...state, zone: { from: square, ...normaliseRect(square, square), dragging: true } };
}

/**
 * The pointer moved to `at` ([x, y] in squares, maybe fractional or off the map of `cols` x
 * `rows`) while drawing: the rectangle from where it began to the square there, held on the map.
 */
export function zoneMove(state, at, cols, rows) {
  if (!state.zone?.dragging) return state;
  return { ...state, zone: { ...state.zone, ...dragRect(state.zone.from, at, cols, rows) } };
}

/** The pointer went up: the rectangle is drawn, and the page asks for its name and reason. */
export function zoneEnd(state) {
  if (!state.zone?.dragging) return { state, effect: null };
  const { first, last } = state.zone;
  return { state: { ...state, zone: { ...state.zone, dragging: false } }, effect: { type: "zone", first, last } };
}

/** The zone drawn was sent, or the operator cancelled it: nothing is drawn any more. */
export function zoneDone(state) {
  return state.zone ? { ...state, zone: null } : state;
}

/** The operator chose `unit` (null: none). */
export function selectUnit(state, unit) {
  return { ...state, selectedUnit: unit };
}

/**
 * A click on `square`, with `unitHere` the id of the unit standing there (or null).
 * Returns {state, effect}; effect is null when the click means nothing.
 */
export function mapClick(state, square, unitHere = null) {
  switch (state.mode) {
    case "goal":
      // Clicking a unit chooses it; clicking anything else (or the chosen unit) sends the goal.
      if (unitHere && unitHere !== state.selectedUnit) return choose(state, unitHere);
      return { state, effect: { type: "goal", square } };
    case "job":
      // Into the field the operator focused last; else pickup first, then dropoff, and a third
      // click starts a new job.
      if (state.pickField !== "dropoff") {
        return { state: { ...state, pending: square, pickField: "dropoff" }, effect: { type: "pickup", square } };
      }
      return { state: { ...state, pending: null, pickField: "pickup" }, effect: { type: "dropoff", square } };
    case "zone":
      return { state, effect: null }; // a drag draws the zone (zoneStart, zoneMove, zoneEnd)
    default:
      return unitHere ? choose(state, unitHere) : { state, effect: null };
  }
}

function choose(state, unit) {
  return { state: selectUnit(state, unit), effect: { type: "select", unit } };
}
