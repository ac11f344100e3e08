// Whether the page hears anything at all: its bound, the broker badge's words, and units judged
// against what the page last heard, not against a silence it shares with them.
import assert from "node:assert/strict";
import { test } from "node:test";
import { CLIENT_OPTIONS, KEEP_ALIVE_S } from "../static/js/connection.js";
import { brokerBadge, deafAfterMs, newsPeriodS, stepPeriodS } from "../static/js/hearing.js";
import { FleetView } from "../static/js/model.js";

const state = (position) => JSON.stringify({ position, status: "moving", load_kg: 0 });

test("the page's keep-alive is every gridfleet client's, 10 s", () => {
  assert.equal(KEEP_ALIVE_S, 10);
  assert.equal(CLIENT_OPTIONS.keepalive, KEEP_ALIVE_S);
});

test("deaf after 10 of the coordinator's steps, and never sooner than 3 s", () => {
  assert.equal(deafAfterMs(0.1), 3000);
  assert.equal(deafAfterMs(1), 10000);
  assert.equal(deafAfterMs(0.5), 5000);
});

test("the step the page expects: the longer of the coordinator's aim and achievement, else 1 s", () => {
  assert.equal(stepPeriodS(null), 1);
  assert.equal(stepPeriodS({ step_period_s: 0.1, achieved_step_s: null }), 0.1);
  assert.equal(stepPeriodS({ step_period_s: 0.1, achieved_step_s: 0.4 }), 0.4);
  assert.equal(stepPeriodS({ step_period_s: "fast" }), 1, "nonsense is not a period");
});

test("a connected page that hears nothing says so, in words, and is connected again when it hears", () => {
  const at = (since, now) => brokerBadge("connected", "broker: connected", since, now, 0.1);
  assert.deepEqual(at(1000, 4000), { state: "connected", text: "broker: connected" });
  assert.deepEqual(at(1000, 13_500), {
    state: "deaf", text: "broker: nothing heard for 12 s — this page's link may be down",
  });
  assert.deepEqual(at(13_400, 13_500), { state: "connected", text: "broker: connected" });
  // A coordinator at 1 s steps: silence is allowed for 10 s.
  assert.equal(brokerBadge("connected", "broker: connected", 0, 9000, 1).state, "connected");
  assert.equal(brokerBadge("connected", "broker: connected", 0, 10_500, 1).state, "deaf");
});

test("the connection's own words win while it is not connected", () => {
  const lost = brokerBadge("reconnecting", "broker: connection lost, reconnecting…", 0, 60_000, 0.1);
  assert.deepEqual(lost, { state: "reconnecting", text: "broker: connection lost, reconnecting…" });
  assert.equal(brokerBadge("failed", "subscribe failed: no", 0, 60_000, 0.1).state, "failed");
  assert.equal(brokerBadge("connected", "broker: connected", null, 60_000, 0.1).state, "connected");
});

test("units are not away for a silence the page shares with them", () => {
  const v = new FleetView();
  v.apply("factsheet", "u1", JSON.stringify({ capacity_kg: 1, step_period_s: 0.1 }), 0);
  v.apply("state", "u1", state([0, 0]), 1000);
  v.apply("state", "u2", state([5, 5]), 1000);
  const [u1, u2] = [v.units.get("u1"), v.units.get("u2")];
  // Nothing at all heard since 1000: the page's link, not theirs.
  assert.equal(v.isSilent(u1, 20_000), false);
  assert.equal(v.isSilent(u2, 20_000), false);
  // Hearing again, and only u2: u1 is silent, counted up to what the page heard.
  v.apply("state", "u2", state([5, 6]), 20_000);
  v.apply("routes", null, JSON.stringify({ step: 9, routes: {} }), 20_000);
  assert.equal(v.isSilent(u1, 20_000), true);
  assert.equal(v.isSilent(u2, 20_000), false);
  v.apply("state", "u1", state([0, 1]), 20_100);
  assert.equal(v.isSilent(u1, 20_100), false);
});

test("any message counts as hearing, and the page's clock never runs backwards", () => {
  const v = new FleetView();
  assert.equal(v.heardAt, null);
  v.apply("errors", null, "not json", 500); // refused, but heard
  assert.equal(v.heardAt, 500);
  v.heard(400);
  assert.equal(v.heardAt, 500);
});

test("no news is due from a coordinator that is not online: a quiet link is not a deaf page", () => {
  assert.equal(newsPeriodS({ state: "online", step_period_s: 0.1, achieved_step_s: 0.2 }), 0.2);
  for (const coordinator of [null, { state: "offline", step_period_s: 0.1 }, { state: "broken", step_period_s: 0.1 }]) {
    assert.equal(newsPeriodS(coordinator), null);
    assert.equal(brokerBadge("connected", "broker: connected", 0, 600_000, newsPeriodS(coordinator)).state, "connected");
  }
});
