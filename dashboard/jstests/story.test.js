import { test } from "node:test";
import assert from "node:assert/strict";

import { fitLayout, MAX_ZOOM, panBy, squareAt, zoomAt } from "../static/js/draw.js";
import { FleetView } from "../static/js/model.js";
import {
  busyUnits, durationText, eventLines, JobNumbers, latestFinished, placeLabels,
  tookSeconds, unitJob, Utilisation,
} from "../static/js/story.js";

const MAP = { name: "m", width: 10, height: 10, rows: Array(10).fill("..........") };

function fleet() {
  const v = new FleetView(MAP);
  v.apply("connection", "u1", JSON.stringify({ state: "online" }), 0);
  v.apply("state", "u1", JSON.stringify({ position: [1, 1], status: "idle", load_kg: 0, job_id: null }), 0);
  v.apply("connection", "u2", JSON.stringify({ state: "online" }), 0);
  v.apply("state", "u2", JSON.stringify({ position: [5, 5], status: "moving", load_kg: 2, job_id: "carried" }), 0);
  v.apply("jobs", null, JSON.stringify({ jobs: [
    { id: "fetch", state: "to_pickup", unit: "u1", pickup: [2, 2], dropoff: [3, 3], mass_kg: 1 },
    { id: "carried", state: "to_dropoff", unit: "u2", pickup: [4, 4], dropoff: [6, 6], mass_kg: 2 },
  ] }), 0);
  return v;
}

test("a unit's job: its own once picked up, the queue's before", () => {
  const v = fleet();
  assert.equal(unitJob(v, "u1"), "fetch");
  assert.equal(unitJob(v, "u2"), "carried");
  assert.equal(unitJob(v, "nobody"), null);
  assert.deepEqual(busyUnits(v), { online: 2, busy: 2 });
});

test("job numbers are given once and kept", () => {
  const n = new JobNumbers();
  assert.deepEqual([n.of("a"), n.of("b"), n.of("a"), n.of("c")], [1, 2, 1, 3]);
});

test("a job id ending in a number keeps it, on every page and after a reload", () => {
  const n = new JobNumbers();
  assert.deepEqual([n.of("job-258"), n.of("job-3"), n.of("crate"), n.of("job-258")], [258, 3, 1, 258]);
  assert.equal(n.of("other-3"), 2, "a number taken already: the next free one");
  assert.equal(new JobNumbers().of("job-258"), 258, "a new page says the same");
  const view = new JobNumbers();
  view.claim(["too-heavy", "job-1", "job-2"]); // a queue view: numbered ids keep theirs first
  assert.deepEqual([view.of("too-heavy"), view.of("job-1"), view.of("job-2")], [3, 1, 2]);
});

test("how long a job took, in words", () => {
  assert.equal(tookSeconds({ created_step: 10, done_step: 135 }, 0.1), 12.5);
  assert.equal(tookSeconds({ created_step: 10, done_step: null }, 0.1), null);
  assert.equal(tookSeconds({ created_step: 10, done_step: 20 }, undefined), null, "no step period yet");
  assert.deepEqual([8.5, 125, 3720].map(durationText), ["8.5 s", "2 min 05 s", "1 h 02 min"]);
  assert.equal(durationText(null), "—");
});

test("finished jobs newest first, bounded", () => {
  const jobs = Array.from({ length: 30 }, (_, i) => ({ id: `j${i}`, state: "done", done_step: i }));
  const shown = latestFinished(jobs, 20);
  assert.equal(shown.length, 20);
  assert.deepEqual(shown.slice(0, 2).map((j) => j.id), ["j29", "j28"]);
});

test("the coordinator's events, newest first, with a local time; junk skipped", () => {
  const at = new Date(2026, 10, 24, 9, 5, 7).toISOString();
  const lines = eventLines([
    { at, kind: "job", text: "job a queued", job: "a" },
    { at, kind: "stop", text: "emergency stop ENGAGED by operator: drill" },
    null,
    { at: "not a time", kind: "unit", text: "u1 online", unit: "u1" },
  ]);
  assert.deepEqual(lines.map((l) => [l.time, l.text]), [
    ["", "u1 online"], ["09:05:07", "emergency stop ENGAGED by operator: drill"], ["09:05:07", "job a queued"],
  ]);
  assert.deepEqual(eventLines("junk"), []);
});

test("utilisation is sampled at most every few seconds and kept for the chart's span", () => {
  const v = fleet();
  const u = new Utilisation(1);
  assert.equal(u.latest(), null);
  u.sample(v, 0);
  u.sample(v, 1000); // too soon: not taken
  assert.equal(u.samples.length, 1);
  v.apply("jobs", null, JSON.stringify({ jobs: [] }), 0);
  v.apply("state", "u2", JSON.stringify({ position: [5, 5], status: "idle", load_kg: 0, job_id: null }), 0);
  u.sample(v, 6000);
  assert.equal(u.latest(), 0);
  u.sample(v, 70000);
  assert.deepEqual(u.samples.map((s) => s.t), [70000], "older than the span: dropped");
});

const overlap = (a, b) => a.x - a.w / 2 < b.x + b.w / 2 && b.x - b.w / 2 < a.x + a.w / 2
  && a.y - a.h / 2 < b.y + b.h / 2 && b.y - b.h / 2 < a.y + a.h / 2;

test("labels never overlap each other or another unit, and stay in bounds", () => {
  // Units packed in a row, a square (20 px) apart: the warehouse's parking row.
  const items = Array.from({ length: 12 }, (_, i) => ({ id: `u${i}`, cx: 10 + 20 * i, cy: 100, r: 8, w: 26, h: 12 }));
  const labels = placeLabels(items, { x0: 0, y0: 0, x1: 250, y1: 200 });
  assert.ok(labels.length >= 6, `most get a label (${labels.length})`);
  for (const [i, a] of labels.entries()) {
    assert.ok(a.x - a.w / 2 >= 0 && a.x + a.w / 2 <= 250, `${a.id} in bounds`);
    for (const b of labels.slice(i + 1)) assert.ok(!overlap(a, b), `${a.id} and ${b.id} overlap`);
    for (const it of items) {
      if (it.id === a.id) continue;
      assert.ok(!overlap(a, { x: it.cx, y: it.cy, w: 2 * it.r, h: 2 * it.r }), `${a.id} covers ${it.id}`);
    }
  }
  // A lone unit's label goes below it; at the bottom edge, above it.
  assert.deepEqual(placeLabels([{ id: "a", cx: 50, cy: 50, r: 8, w: 20, h: 10 }], { x0: 0, y0: 0, x1: 100, y1: 100 })[0].y, 64);
  assert.deepEqual(placeLabels([{ id: "a", cx: 50, cy: 95, r: 8, w: 20, h: 10 }], { x0: 0, y0: 0, x1: 100, y1: 100 })[0].y, 81);
});

test("a big map fits whole at zoom 1; the wheel zooms about the pointer; panning stops at the edge", () => {
  const fit = fitLayout(700, 400, 500, 140);
  assert.ok(fit.cell * 500 <= 700 && fit.cell * 140 <= 400, "500 x 140 squares fit 700 x 400 px");
  assert.deepEqual(squareAt(fit, fit.ox + 0.5, fit.oy + 0.5), [0, 0]);
  const zoom = { scale: 1, pan: [0, 0] };
  const under = squareAt(fit, 300, 200);
  const zoomed = zoomAt(zoom, fit, 300, 200, 5); // past 6 px a square: whole pixels
  const after = fitLayout(700, 400, 500, 140, zoomed);
  assert.ok(after.cell > 3 * fit.cell);
  assert.deepEqual(squareAt(after, 300, 200), under, "the square under the pointer stays there");
  assert.equal(zoomAt(zoomed, after, 300, 200, 0.01).scale, 1, "never smaller than the whole map");
  assert.equal(zoomAt(zoom, fit, 0, 0, 1e6).scale, MAX_ZOOM);
  const far = panBy(zoomed, after, 1e6, -1e6);
  const edge = fitLayout(700, 400, 500, 140, far);
  assert.ok(edge.ox < 700 && edge.oy + edge.cell * 140 > 0, "part of the map stays in view");
});

test("a box or a map of no size, or less, lays out squares of a positive size (never a negative radius)", () => {
  const sizes = [[0, 0, 10, 10], [-5, 300, 10, 10], [300, 300, 0, 10], [300, 300, -3, -1], [NaN, 300, 10, Infinity]];
  for (const [w, h, cols, rows] of sizes) {
    for (const zoom of [{ scale: 1, pan: [0, 0] }, { scale: 0, pan: [NaN, 1] }, { scale: -2, pan: [] }]) {
      const L = fitLayout(w, h, cols, rows, zoom);
      const said = JSON.stringify([w, h, cols, rows, zoom]);
      assert.ok(L.cell > 0 && Number.isFinite(L.cell), `cell ${L.cell} for ${said}`);
      assert.ok([L.w, L.h, L.cols, L.rows, L.ox, L.oy].every(Number.isFinite), said);
      assert.ok(L.w > 0 && L.h > 0 && L.cols >= 1 && L.rows >= 1, said);
    }
  }
  assert.deepEqual(fitLayout(300, 200, 3, 2), fitLayout(300, 200, 3, 2, { scale: 1, pan: [0, 0] }), "sizes that are fine stay as they are");
  assert.equal(fitLayout(300, 200, 3, 2).cell, 100);
});

test("obstacles replayed on load are not new; ones found since are", () => {
  const v = new FleetView(MAP);
  v.apply("map", null, JSON.stringify({ ...MAP, obstacles: [[1, 1]] }), 1000, true);
  v.apply("state", "u1", JSON.stringify({ position: [0, 0], obstacles: [[2, 2]] }), 1000, true);
  v.apply("state", "u1", JSON.stringify({ position: [0, 0], obstacles: [[2, 2], [3, 3]] }), 2000, false);
  const fresh = v.knownObstacles(2500).filter((o) => o.fresh).map((o) => [o.x, o.y]);
  assert.deepEqual(fresh, [[3, 3]]);
  v.apply("events", null, JSON.stringify({ events: [{ at: "2026-11-24T09:00:00Z", kind: "job", text: "x" }] }), 0);
  assert.equal(v.events.length, 1);
});
