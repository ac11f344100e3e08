// The units at fleet scale: words for what each does, search, filter, sort, the rows in view.
import assert from "node:assert/strict";
import { test } from "node:test";
import { phaseText, shownUnits, STATE_COLORS, unitState, visibleSlice } from "../static/js/units.js";

test("where a unit's job takes it next", () => {
  assert.equal(phaseText({ state: "assigned" }, 3), "to pickup P3");
  assert.equal(phaseText({ state: "to_pickup" }, 3), "to pickup P3");
  assert.equal(phaseText({ state: "to_dropoff" }, 12), "to dropoff D12");
  assert.equal(phaseText({ state: "queued" }, 3), null, "not the unit's yet");
  assert.equal(phaseText(undefined, null), null);
});

test("a unit's state, for its colour and the filter", () => {
  const unit = (status, extra = {}) => ({ connection: "online", state: { status, ...extra } });
  assert.equal(unitState(unit("moving"), null, true), "moving");
  assert.equal(unitState(unit("waiting"), null, true), "waiting");
  assert.equal(unitState(unit("idle"), null, false), "idle");
  assert.equal(unitState(unit("idle"), null, true), "job", "idle while it holds a job is not idle");
  assert.equal(unitState(unit("moving", { estop: true }), null, true), "stopped");
  assert.equal(unitState(unit("holding"), null, true), "stopped");
  assert.equal(unitState(unit("moving"), "paused", true), "held");
  assert.equal(unitState({ connection: "broken", state: { status: "moving" } }, null, true), "away");
  assert.equal(unitState(unit("moving"), null, true, true), "away", "silent");
  for (const s of ["moving", "waiting", "idle", "job", "stopped", "held", "away"]) assert.ok(STATE_COLORS[s]);
});

test("find, filter and sort the units", () => {
  const rows = [
    { id: "u003", state: "moving", status: "moving · to pickup P7", job: "job-7", load: 0 },
    { id: "u001", state: "idle", status: "idle", job: null, load: 0 },
    { id: "u042", state: "waiting", status: "waiting: square [3, 4] held by u007", job: "job-2", load: 4 },
    { id: "u010", state: "held", status: "paused · idle", job: null, load: 1 },
  ];
  const ids = (r) => r.map((x) => x.id);
  assert.deepEqual(ids(shownUnits(rows)), ["u001", "u003", "u010", "u042"]);
  assert.deepEqual(ids(shownUnits(rows, "U04")), ["u042"], "any case");
  assert.deepEqual(ids(shownUnits(rows, "u007")), ["u042"], "the status's words are searched");
  assert.deepEqual(ids(shownUnits(rows, "job-7")), ["u003"]);
  assert.deepEqual(ids(shownUnits(rows, "", "working")), ["u003", "u042"]);
  assert.deepEqual(ids(shownUnits(rows, "", "carrying")), ["u010", "u042"]);
  assert.deepEqual(ids(shownUnits(rows, "", "held")), ["u010"]);
  assert.deepEqual(ids(shownUnits(rows, "", "all", "load")), ["u042", "u010", "u001", "u003"]);
  assert.deepEqual(ids(shownUnits(rows, "", "all", "job")), ["u042", "u003", "u001", "u010"], "no job last");
  assert.deepEqual(ids(shownUnits(rows, "", "all", "status")), ["u001", "u003", "u010", "u042"]);
  assert.deepEqual(ids(shownUnits(rows, "nobody")), []);
});

test("only the rows in view, and room for the rest", () => {
  // 150 rows of 25 px in a 300 px box scrolled to 1000 px: rows 40..52 show, 6 more each side.
  assert.deepEqual(visibleSlice(150, 25, 1000, 300, 6), { first: 34, last: 58, top: 850, bottom: 2300 });
  assert.deepEqual(visibleSlice(4, 25, 0, 300, 6), { first: 0, last: 4, top: 0, bottom: 0 });
  assert.deepEqual(visibleSlice(0, 25, 0, 300), { first: 0, last: 0, top: 0, bottom: 0 });
  const end = visibleSlice(150, 25, 99999, 300, 6);
  assert.equal(end.last, 150);
  assert.ok(end.first <= end.last);
});
