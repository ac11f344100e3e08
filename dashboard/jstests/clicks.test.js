// The map's click modes: look, click sets goal, click picks job squares.
import assert from "node:assert/strict";
import { test } from "node:test";
import { initialClicks, mapClick, MODES, selectUnit, setMode } from "../static/js/clicks.js";

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
    mode: "none", selectedUnit: null, pending: null, selectedJob: null, zoom: { scale: 1, pan: [0, 0] },
  });
  assert.deepEqual(MODES, ["none", "goal", "job"]);
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
