// The forms' checks before sending, the requests they make and their words.
import assert from "node:assert/strict";
import { test } from "node:test";
import {
  cancelRequest, goalRequest, jobRequest, pickedDropoff, pickedPickup, readJobForm, removeQuestion, removeRequest,
  zoneAsk,
} from "../static/js/forms.js";
import { FleetView } from "../static/js/model.js";

const MAP = { name: "m", width: 10, height: 10, rows: Array(10).fill(".".repeat(10)), obstacles: [] };
const PLACES = [
  { name: "A3", square: [3, 4], kinds: ["pickup"] },
  { name: "A4", square: [4, 4], kinds: ["pickup", "dropoff"] },
  { name: "P2", square: [9, 1], kinds: ["dropoff"] },
  { name: "C1", square: [0, 9], kinds: ["charger"] },
];
const withMap = () => new FleetView(MAP);
const withPlaces = () => {
  const v = new FleetView();
  v.apply("map", null, JSON.stringify({ ...MAP, places: PLACES }), 0);
  return v;
};
const job = (fields = {}) => ({ pickup: "1,1", dropoff: "8,8", mass: 1.5, priority: 0, jobId: null, ...fields });
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
    what: "job [1, 1] → [8, 8], 1.5 kg",
    body: { pickup: [1, 1], dropoff: [8, 8], mass_kg: 1.5, priority: 7, job_id: "heavy-2" },
  });
  assert.equal(jobRequest(withMap(), job()).body.job_id, null, "no id: the coordinator names it");
});

test("a job the coordinator would refuse for its form is refused here, in words", () => {
  const refused = (fields, view = withMap()) => jobRequest(view, job(fields)).error;
  assert.equal(refused({}, new FleetView()), "no map yet: waiting for the coordinator's fleet/map");
  assert.equal(refused({ pickup: "12,1" }), "pickup [12,1] is not a square of the map");
  assert.equal(refused({ dropoff: "8,-1" }), "dropoff [8,-1] is not a square of the map");
  assert.equal(refused({ pickup: "" }), "pickup: give a place's name or a square X,Y");
  assert.equal(refused({ dropoff: "8;8" }), 'dropoff: "8;8" is neither a place\'s name nor a square X,Y');
  for (const mass of [0, -1, NaN, Infinity]) assert.equal(refused({ mass }), "mass must be more than 0 kg", String(mass));
  for (const priority of [-1, 101, 2.5, NaN]) assert.equal(refused({ priority }), "priority must be a whole number 0–100", String(priority));
  assert.equal(refused({ priority: 100 }), undefined);
  assert.equal(refused({ jobId: "no spaces" }), "job id: letters, digits, _ . - only (max 64)");
  assert.equal(refused({ jobId: "x".repeat(65) }), "job id: letters, digits, _ . - only (max 64)");
});

test("a job by place names goes as the names; squares and names mix", () => {
  assert.deepEqual(jobRequest(withPlaces(), job({ pickup: " A3 ", dropoff: "P2" })), {
    what: "job A3 [3, 4] → P2 [9, 1], 1.5 kg",
    body: { pickup: "A3", dropoff: "P2", mass_kg: 1.5, priority: 0, job_id: null },
  });
  const mixed = jobRequest(withPlaces(), job({ pickup: "[5, 5]", dropoff: "A4" }));
  assert.deepEqual(mixed.body, { pickup: [5, 5], dropoff: "A4", mass_kg: 1.5, priority: 0, job_id: null });
  assert.equal(mixed.what, "job [5, 5] → A4 [4, 4], 1.5 kg");
  // A square that is a place's stays a square: the coordinator takes squares as they are.
  assert.deepEqual(jobRequest(withPlaces(), job({ pickup: "9,1" })).body.pickup, [9, 1]);
});

test("a place name the map does not have, or of the other kind, is refused here with the names", () => {
  const refused = (fields) => jobRequest(withPlaces(), job(fields)).error;
  assert.equal(refused({ pickup: "Q9" }), "pickup: no place is named 'Q9': the places are A3, A4, C1, P2 (or give a square X,Y)");
  assert.equal(refused({ pickup: "P2" }), "pickup: place P2 is not a pickup (it is: dropoff); the pickups are A3, A4");
  assert.equal(refused({ dropoff: "C1" }), "dropoff: place C1 is not a dropoff (it is: charger); the dropoffs are A4, P2");
  assert.equal(refused({ pickup: "a3" }), "pickup: no place is named 'a3': the places are A3, A4, C1, P2 (or give a square X,Y)",
    "names are as the map spells them");
  assert.equal(jobRequest(withMap(), job({ dropoff: "P2" })).error, "dropoff: no place is named 'P2': the map names no places (or give a square X,Y)");
});

test("the job form's fields are read as typed and as numbers; empty priority is 0, empty id none", () => {
  const values = readJobForm(form({ pickup: "0,5", dropoff: "P2", mass: "50", priority: "", job_id: "  " }));
  assert.deepEqual(values, { pickup: "0,5", dropoff: "P2", mass: 50, priority: 0, jobId: null });
  assert.equal(readJobForm(form({ pickup: "A3", dropoff: "9,5", mass: "1", priority: "3", job_id: " j-1 " })).jobId, "j-1");
});

test("delete, and the words for squares and places picked on the map", () => {
  assert.deepEqual(cancelRequest("job-4"), { what: "delete job job-4", body: { job_id: "job-4" } });
  assert.equal(pickedPickup([5, 0]), "pickup [5, 0]: now click the dropoff square");
  assert.equal(pickedPickup([3, 4], "A3"), "pickup A3 [3, 4]: now click the dropoff square");
  assert.equal(pickedDropoff([5, 9]), "dropoff [5, 9]: set the mass and press “queue job”");
  assert.equal(pickedDropoff([9, 1], "P2"), "dropoff P2 [9, 1]: set the mass and press “queue job”");
  assert.equal(zoneAsk({ first: [3, 0], last: [4, 9] }), "close [3, 0] to [4, 9] (2 x 10 squares):");
});

test("a lost unit's removal is the protocol's remove_unit, asked for in words first", () => {
  assert.deepEqual(removeRequest("hv1"), { what: "remove hv1", body: { unit: "hv1", reason: null } });
  assert.match(removeQuestion("hv1"), /^Remove hv1 for good\?/);
  assert.match(removeQuestion("hv1"), /physically off the floor/);
});
