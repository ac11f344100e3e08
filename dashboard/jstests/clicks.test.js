// The map's click modes: look, click sets goal, click picks job squares.
import assert from "node:assert/strict";
import { test } from "node:test";
import {
  initialClicks, mapClick, MODES, pickInto, selectUnit, setMode, zoneDone, zoneEnd, zoneMove, zoneStart,
} from "../static/js/clicks.js";

/** Click the squares in turn (each `[square, unitHere]`); the effects, and the last state. */
function clicks(state, ...steps) {
  const effects = [];
  for (const [square, unitHere] of steps) {
    const out = mapClick(state, square, unitHere);
    effects.push(out.effect);
    state = out.state;
  }
  return { state, effects };
}

test("the page starts looking, with nothing chosen", () => {
  assert.deepEqual(initialClicks(), {
    mode: "none", selectedUnit: null, pending: null, pickField: "pickup", selectedJob: null,
    zoom: { scale: 1, pan: [0, 0] }, zone: null,
  });
  assert.deepEqual(MODES, ["none", "goal", "job", "zone"]);
});

test("look: a click on a unit chooses it, elsewhere nothing", () => {
  const { state, effects } = clicks(initialClicks(), [[0, 0], "u1"], [[3, 3], null], [[9, 0], "u2"]);
  assert.deepEqual(effects, [{ type: "select", unit: "u1" }, null, { type: "select", unit: "u2" }]);
  assert.equal(state.selectedUnit, "u2");
  assert.equal(state.pending, null);
});

test("click sets goal: a unit is chosen first, then a square is its goal", () => {
  const goal = setMode(initialClicks(), "goal");
  const { state, effects } = clicks(goal, [[9, 0], "u2"], [[9, 3], null], [[0, 0], "u1"], [[0, 0], "u1"]);
  assert.deepEqual(effects, [
    { type: "select", unit: "u2" },
    { type: "goal", square: [9, 3] },
    { type: "select", unit: "u1" },
    { type: "goal", square: [0, 0] }, // the chosen unit's own square: a goal like any other
  ]);
  assert.equal(state.selectedUnit, "u1");
});

test("click sets goal with nobody chosen sends the goal (the form says which unit)", () => {
  const { effects } = clicks(setMode(initialClicks(), "goal"), [[4, 4], null]);
  assert.deepEqual(effects, [{ type: "goal", square: [4, 4] }]);
});

test("click picks job squares: pickup, then dropoff, then a new pickup; units are squares too", () => {
  const job = setMode(selectUnit(initialClicks(), "u1"), "job");
  let out = mapClick(job, [5, 0], "u3");
  assert.deepEqual(out.effect, { type: "pickup", square: [5, 0] });
  assert.deepEqual(out.state.pending, [5, 0], "the pickup is ringed until the dropoff");
  out = mapClick(out.state, [5, 9], null);
  assert.deepEqual(out.effect, { type: "dropoff", square: [5, 9] });
  assert.equal(out.state.pending, null);
  out = mapClick(out.state, [1, 1], null);
  assert.deepEqual(out.effect, { type: "pickup", square: [1, 1] });
  assert.equal(out.state.selectedUnit, "u1", "picking job squares leaves the chosen unit alone");
});

test("a click fills the job field focused last: the dropoff first, then the pickup", () => {
  const job = pickInto(setMode(initialClicks(), "job"), "dropoff");
  let out = mapClick(job, [5, 9], null);
  assert.deepEqual(out.effect, { type: "dropoff", square: [5, 9] });
  assert.equal(out.state.pending, null, "no pickup is ringed");
  out = mapClick(out.state, [5, 0], null);
  assert.deepEqual(out.effect, { type: "pickup", square: [5, 0] });
  // Focusing the pickup again after a pickup was picked: the next click replaces it.
  out = mapClick(pickInto(out.state, "pickup"), [6, 0], null);
  assert.deepEqual(out.effect, { type: "pickup", square: [6, 0] });
  assert.deepEqual(out.state.pending, [6, 0]);
  assert.equal(pickInto(out.state, "mass"), out.state, "no other field takes squares");
  assert.equal(setMode(pickInto(job, "dropoff"), "job").pickField, "pickup", "a new mode starts at the pickup");
});

test("zone mode: a drag draws a rectangle, its corners least and greatest, held on the map", () => {
  const zone = setMode(initialClicks(), "zone");
  assert.deepEqual(mapClick(zone, [2, 2], "u1"), { state: zone, effect: null }, "a click alone chooses nothing");
  let state = zoneStart(zone, [6, 5]);
  assert.deepEqual(state.zone, { from: [6, 5], first: [6, 5], last: [6, 5], dragging: true });
  state = zoneMove(state, [2.7, 8.2], 10, 10); // up and to the left of where it began
  assert.deepEqual([state.zone.first, state.zone.last], [[2, 5], [6, 8]]);
  state = zoneMove(state, [-3, 14.5], 10, 10); // off the map: held at its edge
  assert.deepEqual([state.zone.first, state.zone.last], [[0, 5], [6, 9]]);
  const out = zoneEnd(state);
  assert.deepEqual(out.effect, { type: "zone", first: [0, 5], last: [6, 9] });
  assert.equal(out.state.zone.dragging, false, "still drawn while its form asks");
  assert.equal(zoneMove(out.state, [9, 9], 10, 10), out.state, "the drag has ended: no more moves");
  assert.deepEqual(zoneEnd(out.state), { state: out.state, effect: null });
  assert.equal(zoneDone(out.state).zone, null);
  assert.equal(setMode(out.state, "look").zone, null, "another mode forgets it");
  // A click without a move is a zone of one square; outside zone mode a drag draws nothing.
  assert.deepEqual(zoneEnd(zoneStart(zone, [3, 3])).effect, { type: "zone", first: [3, 3], last: [3, 3] });
  const looking = initialClicks();
  assert.equal(zoneStart(looking, [3, 3]), looking);
  assert.equal(zoneStart(zone, null), zone, "down off the map: nothing");
});

test("changing the mode forgets a half-picked job but not the chosen unit", () => {
  const picked = mapClick(setMode(selectUnit(initialClicks(), "u2"), "job"), [2, 2], null).state;
  const again = setMode(picked, "job");
  assert.equal(again.pending, null);
  assert.equal(again.selectedUnit, "u2");
  assert.deepEqual(mapClick(again, [3, 3], null).effect, { type: "pickup", square: [3, 3] });
  assert.equal(setMode(picked, "goal").pending, null);
});

test("steps never change the state they are given", () => {
  const before = setMode(initialClicks(), "job");
  const frozen = Object.freeze({ ...before });
  const out = mapClick(frozen, [1, 2], null);
  assert.notEqual(out.state, frozen);
  assert.deepEqual(frozen, before);
  assert.equal(selectUnit(frozen, "u1").selectedUnit, "u1");
  assert.equal(frozen.selectedUnit, null);
});
