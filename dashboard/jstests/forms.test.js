// The forms' checks before sending, the requests they make and their words.
import assert from "node:assert/strict";
import { test } from "node:test";
import {
  cancelRequest, goalRequest, jobRequest, pickedDropoff, pickedPickup, readJobForm, removeQuestion, removeRequest,
} from "../static/js/forms.js";
import { FleetView } from "../static/js/model.js";

const MAP = { name: "m", width: 10, height: 10, rows: Array(10).fill(".".repeat(10)), obstacles: [] };
const withMap = () => new FleetView(MAP);
const job = (fields = {}) => ({ pickup: [1, 1], dropoff: [8, 8], mass: 1.5, priority: 0, jobId: null, ...fields });
const form = (values) => Object.fromEntries(Object.entries(values).map(([k, v]) => [k, { value: v }]));

test("a goal needs a unit, a map and a square on it", () => {
  assert.deepEqual(goalRequest(withMap(), "", [1, 1]), { error: "choose a unit first (list or map)" });
  assert.deepEqual(goalRequest(new FleetView(), "u1", [1, 1]), { error: "no map yet: waiting for the coordinator's fleet/map" });
  assert.deepEqual(goalRequest(withMap(), "u1", [10, 2]), { error: "[10,2] is not a square of the map" });
  assert.deepEqual(goalRequest(withMap(), "u1", [1.5, 2]), { error: "[1.5,2] is not a square of the map" });
  assert.deepEqual(goalRequest(withMap(), "unit2", [9, 3]), { what: "goal [9, 3] for unit2", body: { unit: "unit2", target: [9, 3] } });
});

test("clearing a goal needs only a unit (not even a map)", () => {
  assert.deepEqual(goalRequest(new FleetView(), "u1", null), { what: "clear the goal of u1", body: { unit: "u1", target: null } });
  assert.deepEqual(goalRequest(new FleetView(), "", null), { error: "choose a unit first (list or map)" });
});

test("a job is described and sent as the protocol's submit_job", () => {
  assert.deepEqual(jobRequest(withMap(), job({ priority: 7, jobId: "heavy-2" })), {
    what: "job [1,1] → [8,8], 1.5 kg",
    body: { pickup: [1, 1], dropoff: [8, 8], mass_kg: 1.5, priority: 7, job_id: "heavy-2" },
  });
  assert.equal(jobRequest(withMap(), job()).body.job_id, null, "no id: the coordinator names it");
});

test("a job the coordinator would refuse for its form is refused here, in words", () => {
  const refused = (fields, view = withMap()) => jobRequest(view, job(fields)).error;
  assert.equal(refused({}, new FleetView()), "no map yet: waiting for the coordinator's fleet/map");
  assert.equal(refused({ pickup: [12, 1] }), "pickup [12,1] is not a square of the map");
  assert.equal(refused({ dropoff: [8, -1] }), "dropoff [8,-1] is not a square of the map");
  for (const mass of [0, -1, NaN, Infinity]) assert.equal(refused({ mass }), "mass must be more than 0 kg", String(mass));
  for (const priority of [-1, 101, 2.5, NaN]) assert.equal(refused({ priority }), "priority must be a whole number 0–100", String(priority));
  assert.equal(refused({ priority: 100 }), undefined);
  assert.equal(refused({ jobId: "no spaces" }), "job id: letters, digits, _ . - only (max 64)");
  assert.equal(refused({ jobId: "x".repeat(65) }), "job id: letters, digits, _ . - only (max 64)");
});

test("the job form's fields are read as numbers; empty priority is 0, empty id none", () => {
  const values = readJobForm(form({ px: "0", py: "5", dx: "9", dy: "5", mass: "50", priority: "", job_id: "  " }));
  assert.deepEqual(values, { pickup: [0, 5], dropoff: [9, 5], mass: 50, priority: 0, jobId: null });
  assert.equal(readJobForm(form({ px: "0", py: "5", dx: "9", dy: "5", mass: "1", priority: "3", job_id: " j-1 " })).jobId, "j-1");
});

test("delete, and the words for squares picked on the map", () => {
  assert.deepEqual(cancelRequest("job-4"), { what: "delete job job-4", body: { job_id: "job-4" } });
  assert.equal(pickedPickup([5, 0]), "pickup [5, 0]: now click the dropoff square");
  assert.equal(pickedDropoff([5, 9]), "dropoff [5, 9]: set the mass and press “queue job”");
});

test("a lost unit's removal is the protocol's remove_unit, asked for in words first", () => {
  assert.deepEqual(removeRequest("hv1"), { what: "remove hv1", body: { unit: "hv1", reason: null } });
  assert.match(removeQuestion("hv1"), /^Remove hv1 for good\?/);
  assert.match(removeQuestion("hv1"), /physically off the floor/);
});
