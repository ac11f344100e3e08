// What the page's tables and badges say, from the fleet model.
import assert from "node:assert/strict";
import { test } from "node:test";
import { FleetView } from "../static/js/model.js";
import {
  controlButtons, coordinatorBadge, finishedCells, finishedCounts, jobCells, mapTitle, routeText, seenText, unitCells,
} from "../static/js/view.js";

const text = (cells) => cells.map(([t]) => t);

test("the map's title", () => {
  assert.equal(mapTitle(null), "no map yet");
  assert.equal(mapTitle({ name: "playfield", width: 10, height: 10 }), "playfield 10 x 10");
});

test("a VDA 5050 vehicle's row says so beside its link", () => {
  const v = new FleetView();
  v.apply("connection", "agv1", JSON.stringify({ state: "online" }), 0);
  v.apply("factsheet", "agv1", JSON.stringify({ capacity_kg: 3, step_period_s: 0.5, model: "vda5050-2.0.0" }), 0);
  assert.deepEqual(unitCells(v.units.get("agv1"))[1], ["online · VDA 5050 2.0.0", "link vda"]);
  v.apply("factsheet", "unit1", JSON.stringify({ capacity_kg: 3, step_period_s: 0.5, model: "gridfleet-sim" }), 0);
  assert.deepEqual(unitCells(v.units.get("unit1"))[1], ["?", "link"]);
});

test("a VDA 5050 vehicle's row shows its battery and its own errors", () => {
  const v = new FleetView();
  v.apply("connection", "agv1", JSON.stringify({ state: "broken" }), 0);
  v.apply("factsheet", "agv1", JSON.stringify({ capacity_kg: 3, step_period_s: 0.5, model: "vda5050-2.1.0" }), 0);
  const condition = { battery_pct: 41.6, charging: true, errors: ["FATAL motorFault: left wheel", "WARNING lowBattery"] };
  v.apply("vehicle", "agv1", JSON.stringify(condition), 0);
  const [, link, , status] = unitCells(v.units.get("agv1"));
  assert.deepEqual(link, ["42 % ⚡ · broken · VDA 5050 2.1.0", "link vda"]);
  assert.equal(status[0], "— · vehicle: FATAL motorFault: left wheel; WARNING lowBattery");
  v.apply("vehicle", "agv1", JSON.stringify({ battery_pct: null, charging: false, errors: [] }), 0);
  assert.deepEqual(text(unitCells(v.units.get("agv1"))).slice(1, 4), ["broken · VDA 5050 2.1.0", "—", "—"]);
  // Cleared with the rest of the unit's retained topics: the row goes once all are.
  for (const kind of ["connection", "factsheet", "vehicle"]) v.apply(kind, "agv1", "", 0);
  assert.equal(v.units.has("agv1"), false);
});

test("a unit's row: link, square, status with its reason, job and load of capacity", () => {
  const v = new FleetView();
  v.apply("connection", "unit1", JSON.stringify({ state: "online" }), 0);
  assert.deepEqual(unitCells(v.units.get("unit1")), [
    ["unit1", "id"], ["online", "link"], ["—", "pos"], ["—", "status"], ["—", "job"], ["—", "load"],
  ]);
  v.apply("factsheet", "unit1", JSON.stringify({ capacity_kg: 2, step_period_s: 0.1 }), 0);
  assert.equal(unitCells(v.units.get("unit1"))[5][0], "0/2 kg", "an empty load before its first state");
  v.apply("state", "unit1", JSON.stringify({ position: [1, 0], status: "moving", job_id: "job-1", load_kg: 1.5 }), 0);
  assert.deepEqual(text(unitCells(v.units.get("unit1"))), ["unit1", "online", "[1, 0]", "moving", "job-1", "1.5/2 kg"]);
  assert.equal(unitCells(v.units.get("unit1"))[4][1], "job carrying", "its item is on board");
  v.apply("state", "unit2", JSON.stringify({ position: [4, 4], status: "waiting", wait_reason: "released square [4, 5] is blocked", load_kg: 0 }), 0);
  assert.deepEqual(text(unitCells(v.units.get("unit2"))),
    ["unit2", "?", "[4, 4]", "waiting: released square [4, 5] is blocked", "—", "0 kg"]);
  // Before pickup the queue names the unit's job; an operator's control comes first in its status.
  const [, , , status, job] = text(unitCells(v.units.get("unit2"), "job-7", "out_of_service"));
  assert.deepEqual([status, job], ["out of service · waiting: released square [4, 5] is blocked", "job-7"]);
  // A unit between orders says "idle" while its job is stuck: the job's words say what holds it.
  const stuck = "its unit unit1 has not moved for over 5 min at [1, 0]; unit2 stands where it must go";
  v.apply("state", "unit1", JSON.stringify({ position: [1, 0], status: "idle", job_id: "job-1", load_kg: 1.5 }), 0);
  assert.equal(text(unitCells(v.units.get("unit1"), "job-1", null, stuck))[3], `idle · ${stuck}`);
  assert.equal(text(unitCells(v.units.get("unit1"), "job-1", null, null))[3], "idle");
  v.apply("state", "unit1", JSON.stringify({ position: [1, 0], status: "moving", job_id: "job-1", load_kg: 1.5 }), 0);
  assert.equal(text(unitCells(v.units.get("unit1"), "job-1", null, stuck))[3], "moving", "under way: nothing to add");
});

test("a unit's status says why the coordinator moves or holds it (its route's note)", () => {
  const v = new FleetView();
  v.apply("state", "u1", JSON.stringify({ position: [3, 2], status: "moving", load_kg: 0 }), 0);
  const leaving = "leaving zone aisle-4 (closed: cleaning)";
  assert.equal(text(unitCells(v.units.get("u1"), null, null, null, null, null, leaving))[3], `moving · ${leaving}`);
  v.apply("state", "u1", JSON.stringify({ position: [3, 2], status: "holding", load_kg: 0 }), 0);
  const boxed = "holding: inside closed zone aisle-4 and no way out";
  assert.equal(text(unitCells(v.units.get("u1"), null, "paused", null, null, null, boxed))[3], `paused · holding · ${boxed}`);
  assert.equal(text(unitCells(v.units.get("u1")))[3], "holding", "no note: nothing added");
  // From the routes view: only a note that is text.
  v.apply("routes", null, JSON.stringify({ step: 1, routes: { u1: { released: [], planned: [], note: boxed }, u2: { note: 5 } } }), 0);
  assert.equal(v.routeNote("u1"), boxed);
  assert.equal(v.routeNote("u2"), null);
  assert.equal(v.routeNote("nobody"), null);
});

test("a unit row's buttons follow its control", () => {
  const commands = (control) => controlButtons(control).map(([, c]) => c);
  assert.deepEqual(commands(null), ["pause", "out_of_service"]);
  assert.deepEqual(commands("paused"), ["resume", "out_of_service"]);
  assert.deepEqual(commands("out_of_service"), ["in_service"]);
});

test("when a unit was last heard of", () => {
  assert.equal(seenText({ lastSeen: null }, 5000), "never");
  assert.equal(seenText({ lastSeen: 1000 }, 3400), "2 s ago");
  assert.equal(seenText({ lastSeen: 1000 }, 900), "0 s ago", "never in the future");
});

test("job rows", () => {
  const j = { id: "job-2", state: "to_pickup", unit: "unit2", pickup: [8, 8], dropoff: [1, 8], mass_kg: 4 };
  assert.deepEqual(text(jobCells(j, 3)), ["3", "job-2", "to_pickup", "", "unit2", "[8, 8] → [1, 8]", "4"]);
  // A square named by a place says the place's name first.
  const named = { ...j, pickup_place: "A3", dropoff: [3, 4], dropoff_place: "P-2" };
  assert.equal(jobCells(named, 3)[5][0], "A3 [8, 8] → P-2 [3, 4]");
  assert.equal(routeText({ ...j, pickup_place: null, dropoff_place: "P2" }), "[8, 8] → P2 [1, 8]");
  assert.equal(routeText({ ...j, pickup_place: 7 }), "[8, 8] → [1, 8]", "a name that is not text is left out");
  assert.deepEqual(jobCells({ ...j, unit: null }, 3)[4], ["—", "unit"]);
  const waiting = { ...j, state: "queued", unit: null, wait: "no_unit_free", wait_reason: "every unit that can carry 4 kg is busy (unit1)" };
  assert.deepEqual(text(jobCells(waiting, 4)).slice(2, 4), ["queued", "every unit that can carry 4 kg is busy (unit1)"]);
  const squares = { pickup: [1, 1], dropoff: [8, 8] };
  assert.deepEqual(text(finishedCells({ id: "job-9", state: "rejected", unit: null, reason: "too heavy", ...squares }, 0.1)),
    ["job-9", "rejected", "—", "[1, 1] → [8, 8]", "—", "too heavy"]);
  const done = { id: "job-0", state: "done", unit: "unit4", created_step: 10, done_step: 135, ...squares, dropoff_place: "P2" };
  assert.deepEqual(text(finishedCells(done, 0.1)), ["job-0", "done", "unit4", "[1, 1] → P2 [8, 8]", "12.5 s", ""]);
});

test("finished counts: the coordinator's counts for every final state, ours for the rest", () => {
  const done = (id) => ({ id, state: "done" });
  assert.equal(finishedCounts([], {}), "");
  assert.equal(finishedCounts([done("a"), { id: "b", state: "rejected" }], { done: 1, rejected: 1 }), "done 1 · rejected 1");
  assert.equal(finishedCounts([done("a")], { done: 12, failed: 2, queued: 3 }), "done 12 · failed 2",
    "the view keeps only the latest finished jobs; states still in play are not counted here");
  assert.equal(finishedCounts([done("a"), done("b")], {}), "done 2");
});

test("the coordinator's badge", () => {
  assert.deepEqual(coordinatorBadge(null, null), { state: "unknown", text: "coordinator: not seen" });
  assert.deepEqual(coordinatorBadge({ state: "online" }, 42), { state: "online", text: "coordinator: online, step 42" });
});

test("the badge shows the step time the coordinator achieves against the one set", () => {
  const status = { state: "online", step_period_s: 0.005, achieved_step_s: 0.0079 };
  assert.equal(coordinatorBadge(status, 9).text, "coordinator: online, step 9 · 7.9 ms a step (set 5 ms)");
  const slow = { state: "online", step_period_s: 1, achieved_step_s: 1.25 };
  assert.equal(coordinatorBadge(slow, 3).text, "coordinator: online, step 3 · 1.25 s a step (set 1 s)");
  const unmeasured = { state: "online", step_period_s: 1, achieved_step_s: null };
  assert.equal(coordinatorBadge(unmeasured, 3).text, "coordinator: online, step 3");
});
