// What a click on the map means: the click mode, the chosen unit and a half-picked job. Pure: no DOM;
// each step takes a state and returns a new one (the old one is never changed) and at most one
// effect for the page to carry out.
//
// State: {mode, selectedUnit, pending, selectedJob, zoom}
//   mode          "none" (look), "goal" (click sets goal) or "job" (click picks job squares)
//   selectedUnit  the unit chosen in the list, on the map or in the goal form; null for none
//   pending       the job's pickup square once picked, until its dropoff is clicked (drawn ringed)
//   selectedJob   the job chosen in the queue: its pickup and dropoff stand out, joined
//   zoom          {scale, pan}: 1 and [0, 0] show the whole map (draw.js zoomAt, panBy)
//
// Effects: {type: "select", unit}, {type: "goal", square}, {type: "pickup", square},
//          {type: "dropoff", square}

export const MODES = ["none", "goal", "job"];

export function initialClicks() {
  return { mode: "none", selectedUnit: null, pending: null, selectedJob: null, zoom: { scale: 1, pan: [0, 0] } };
}

/** The operator chose another click mode: a half-picked job is forgotten. */
export function setMode(state, mode) {
  return { ...state, mode, pending: null };
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
      // Pickup first, then dropoff; a third click starts a new job.
      if (state.pending === null) return { state: { ...state, pending: square }, effect: { type: "pickup", square } };
      return { state: { ...state, pending: null }, effect: { type: "dropoff", square } };
    default:
      return unitHere ? choose(state, unitHere) : { state, effect: null };
  }
}

function choose(state, unit) {
  return { state: selectUnit(state, unit), effect: { type: "select", unit } };
}
