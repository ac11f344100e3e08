// FleetView: the page's pure model of the fleet, fed with message text.
import assert from "node:assert/strict";
import { test } from "node:test";
import { FleetView, HIGHLIGHT_MS } from "../static/js/model.js";

const state = (pos, extra = {}) => JSON.stringify({ header: {}, step: 1, position: pos, direction: "-", status: "idle", ...extra });
const MAP = { name: "m", width: 3, height: 2, rows: ["..@", "..."], obstacles: [] };

test("units come from connection, factsheet and state", () => {
  const v = new FleetView();
  assert.equal(v.apply("connection", "u1", JSON.stringify({ state: "online" }), 0), null);
  v.apply("factsheet", "u1", JSON.stringify({ capacity_kg: 5, step_period_s: 0.1, color: "#112233" }), 0);
  v.apply("state", "u1", state([1, 0]), 100);
  const u = v.units.get("u1");
  assert.equal(u.connection, "online");
  assert.deepEqual(u.state.position, [1, 0]);
  assert.equal(u.lastSeen, 100);
  assert.equal(v.colorOf("u1"), "#112233");
  assert.equal(v.colorOf("nobody"), "#607d8b");
});

test("bad input is reported and changes nothing", () => {
  const v = new FleetView();
  v.apply("state", "u1", state([1, 0]), 0);
  assert.match(v.apply("state", "u1", "{oops", 1), /malformed JSON/);
  assert.match(v.apply("state", "u1", JSON.stringify({ step: 2 }), 1), /without a position/);
  assert.match(v.apply("map", null, JSON.stringify({ width: 3 }), 1), /without rows/);
  for (const [width, height] of [[0, 2], [-1, 2], [3, -4], [3, 4096 + 1], [2.5, 2]]) {
    assert.match(v.apply("map", null, JSON.stringify({ ...MAP, width, height }), 1), /without its size/, `${width} x ${height}`);
  }
  assert.equal(v.map, null, "no map of no squares (nor fewer)");
  assert.deepEqual(v.units.get("u1").state.position, [1, 0]);
  v.apply("estop", null, "engaged|device1|x", 2);
  assert.match(v.apply("estop", null, "nonsense", 3), /invalid emergency-stop/);
  assert.equal(v.stopped, true, "an invalid payload never releases");
});

test("a held press stops the fleet on the page until it is cleared; the latch wins", () => {
  const v = new FleetView();
  v.apply("estop", null, "released|dashboard|ok", 0);
  v.apply("device_stop", "dev1", "engaged|dev1|button", 1);
  assert.equal(v.stopped, true);
  assert.deepEqual(v.estop, { engaged: true, by: "dev1", reason: "button", press: true });
  assert.match(v.apply("device_stop", "dev1", "released|dev1|button", 2), /invalid stop press of dev1/);
  assert.equal(v.stopped, true, "a press cannot release");
  v.apply("estop", null, "engaged|dev1|button", 3); // the coordinator's copy
  assert.deepEqual(v.estop, { engaged: true, by: "dev1", reason: "button" });
  v.apply("estop", null, "released|operator|checked", 4);
  assert.equal(v.stopped, true, "released, but the press is not cleared yet");
  v.apply("device_stop", "dev1", "", 5); // cleared by the coordinator after the release
  assert.equal(v.stopped, false);
});

test("a cleared retained message removes the unit", () => {
  const v = new FleetView();
  v.apply("state", "u1", state([0, 0]), 0);
  v.apply("state", "u1", "", 1);
  assert.equal(v.units.has("u1"), false);
});

test("obstacles are highlighted while new, then plain", () => {
  const v = new FleetView(MAP);
  v.apply("state", "u1", state([0, 0], { obstacles: [[1, 1]] }), 1000);
  v.apply("map", null, JSON.stringify({ ...MAP, obstacles: [[1, 1], [0, 1]] }), 2000);
  assert.deepEqual(v.knownObstacles(2000), [{ x: 1, y: 1, fresh: true }, { x: 0, y: 1, fresh: true }]);
  assert.deepEqual(v.knownObstacles(1000 + HIGHLIGHT_MS).map((o) => o.fresh), [false, true]);
  assert.equal(v.isFree(1, 1), false);
  assert.equal(v.isFree(2, 0), false);
  assert.equal(v.isFree(1, 0), true);
  assert.equal(v.onMap(2, 1), true);
  assert.equal(v.onMap(3, 0), false);
});

test("the queue view: jobs under way indexed by unit, the latest finished, the chart's counts; silent units", () => {
  const v = new FleetView();
  const squares = { pickup: [0, 0], dropoff: [1, 1] }; // a job without them is refused whole
  v.apply("jobs", null, JSON.stringify({
    jobs: [{ id: "a", state: "queued", ...squares }, { id: "k", state: "to_pickup", unit: "u1", ...squares }],
    finished: [{ id: "b", state: "done", ...squares }, { id: "c", state: "failed", ...squares }],
    counts: { done: 7 }, done_per_minute: [0, 2, 5],
  }), 0);
  assert.deepEqual(v.activeJobs().map((j) => j.id), ["a", "k"]);
  assert.deepEqual(v.finishedJobs().map((j) => j.id), ["b", "c"]);
  assert.equal(v.jobOfUnit.get("u1"), "k");
  assert.equal(v.jobById.get("k").state, "to_pickup");
  assert.deepEqual(v.donePerMinute, [0, 2, 5]);
  // A finished job listed among the jobs (a view from elsewhere) still counts as finished.
  v.apply("jobs", null, JSON.stringify({ jobs: [{ id: "a", state: "queued", ...squares }, { id: "d", state: "done", ...squares }] }), 0);
  assert.deepEqual([v.activeJobs().map((j) => j.id), v.finishedJobs().map((j) => j.id)], [["a"], ["d"]]);
  assert.deepEqual([v.jobOfUnit.size, v.donePerMinute], [0, []]);
  v.apply("factsheet", "u1", JSON.stringify({ capacity_kg: 1, step_period_s: 0.2 }), 0);
  v.apply("state", "u1", state([0, 0]), 0);
  const u = v.units.get("u1");
  assert.equal(v.isSilent(u, 900), false);
  v.apply("routes", null, JSON.stringify({ step: 11, routes: {} }), 1100); // the page still hears
  assert.equal(v.isSilent(u, 1100), true);
});

test("the coordinator's step comes from its routes too (its status is sent only on changes)", () => {
  const v = new FleetView();
  assert.equal(v.coordinatorStep(), null);
  v.apply("coordinator", null, JSON.stringify({ state: "online", step: 0, step_period_s: 1 }), 0);
  assert.equal(v.coordinatorStep(), 0);
  v.apply("routes", null, JSON.stringify({ step: 42, routes: {} }), 1);
  assert.equal(v.coordinatorStep(), 42);
  v.apply("coordinator", null, JSON.stringify({ state: "online", step: 43, step_period_s: 1 }), 2);
  assert.equal(v.coordinatorStep(), 43);
});

test("a unit's heading: its direction, else the first square of its route", () => {
  const v = new FleetView();
  assert.equal(v.heading("u1"), "-");
  v.apply("state", "u1", state([2, 2], { direction: "W" }), 0);
  assert.equal(v.heading("u1"), "W");
  v.apply("state", "u1", state([2, 2]), 1);
  assert.equal(v.heading("u1"), "-");
  v.apply("routes", null, JSON.stringify({ step: 3, routes: { u1: { released: [], planned: [[2, 3], [2, 4]] } } }), 2);
  assert.equal(v.heading("u1"), "S");
  v.apply("routes", null, JSON.stringify({ step: 4, routes: { u1: { released: [[3, 2]], planned: [] } } }), 3);
  assert.equal(v.heading("u1"), "E");
  v.apply("routes", null, JSON.stringify({ step: 5, routes: { u1: { released: [[5, 5]], planned: [] } } }), 4);
  assert.equal(v.heading("u1"), "-", "a route that does not start next to the unit says nothing");
});

test("a heading from routes sent before the unit's last move starts after its square", () => {
  const v = new FleetView();
  v.apply("routes", null, JSON.stringify({ step: 3, routes: { u1: { released: [[1, 0]], planned: [[1, 1], [1, 2]] } } }), 0);
  v.apply("state", "u1", state([0, 0]), 1);
  assert.equal(v.heading("u1"), "E");
  v.apply("state", "u1", state([1, 0]), 2); // moved into its released square; no new order yet
  assert.equal(v.heading("u1"), "S");
});

test("the unit on a square is found by its last state", () => {
  const v = new FleetView();
  v.apply("connection", "u0", JSON.stringify({ state: "online" }), 0); // no state yet: on no square
  v.apply("state", "u1", state([1, 0]), 0);
  v.apply("state", "u2", state([2, 1]), 0);
  assert.equal(v.unitAt(1, 0).id, "u1");
  assert.equal(v.unitAt(2, 1).id, "u2");
  assert.equal(v.unitAt(0, 0), null);
  v.apply("state", "u1", state([0, 0]), 1);
  assert.equal(v.unitAt(1, 0), null);
  assert.equal(v.unitAt(0, 0).id, "u1");
});

test("a view the page cannot draw is refused whole, in words, and the last good one stays", () => {
  const v = new FleetView();
  v.apply("map", null, JSON.stringify(MAP), 0);
  v.apply("state", "u1", state([1, 0]), 0);
  const good = { step: 2, routes: { u1: { released: [[1, 1]], planned: [], target: [1, 1] } } };
  assert.equal(v.apply("routes", null, JSON.stringify(good), 0), null);
  for (const routes of [{ u1: null }, { u1: { released: 5 } }, { u1: { target: ["a", 1] } }, []]) {
    assert.match(v.apply("routes", null, JSON.stringify({ step: 3, routes }), 0), /malformed route/);
  }
  assert.deepEqual(v.routes, good.routes);
  for (const position of [[1e20, 0], [-1, 0], [1.5, 0], null]) {
    assert.match(v.apply("state", "u1", state(position), 0), /without a position/);
  }
  assert.deepEqual(v.units.get("u1").state.position, [1, 0]);
  const job = { id: "j", state: "queued", pickup: [0, 0], dropoff: [2, 1] };
  assert.equal(v.apply("jobs", null, JSON.stringify({ jobs: [job] }), 0), null);
  assert.match(v.apply("jobs", null, JSON.stringify({ jobs: [{ ...job, pickup: null }] }), 0), /malformed queue/);
  assert.deepEqual(v.activeJobs().map((j) => j.id), ["j"]);
  assert.match(v.apply("errors", null, JSON.stringify({ topic: 5, reason: "x" }), 0), /malformed error/);
  // A square its rows leave out is a wall (the schema ties the rows to neither width nor height).
  v.apply("map", null, JSON.stringify({ ...MAP, height: 3 }), 0);
  assert.equal(v.isFree(0, 2), false);
});
