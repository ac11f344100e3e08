// The page's protocol helpers: topic parsing, estop text, headers, client ids.
import assert from "node:assert/strict";
import { test } from "node:test";
import {
  decodeEstop, encodeEstop, ID_RE, makeClientId, parseTopic, Stamper, subscriptions, topicsFor,
} from "../static/js/protocol.js";

const T = topicsFor("lab/a");

test("topics follow protocol.md", () => {
  assert.equal(T.estop, "lab/a/v1/fleet/estop");
  assert.equal(T.request("submit_job"), "lab/a/v1/requests/submit_job");
  assert.equal(T.reply("dash-1"), "lab/a/v1/replies/dash-1");
  const subs = subscriptions(T, "dash-1");
  assert.equal(subs["lab/a/v1/units/+/state"].qos, 0);
  assert.equal(subs["lab/a/v1/fleet/routes"].qos, 0);
  assert.equal(subs["lab/a/v1/fleet/estop"].qos, 1);
  assert.ok("lab/a/v1/replies/dash-1" in subs);
});

test("parseTopic routes ours and refuses the rest", () => {
  assert.deepEqual(parseTopic(T.prefix, "lab/a/v1/units/unit1/state"), { kind: "state", id: "unit1" });
  assert.deepEqual(parseTopic(T.prefix, "lab/a/v1/fleet/jobs"), { kind: "jobs", id: null });
  assert.deepEqual(parseTopic(T.prefix, "lab/a/v1/replies/d"), { kind: "reply", id: "d" });
  assert.equal(parseTopic(T.prefix, "lab/b/v1/fleet/jobs"), null);
  assert.equal(parseTopic(T.prefix, "lab/a/v1/units/unit1/bogus"), null);
  assert.equal(parseTopic(T.prefix, "lab/a/v1/units/$bad/state"), null);
  assert.equal(parseTopic(T.prefix, "lab/a/v1/fleet/map/extra"), null);
});

test("estop text round trip; invalid payloads are not releases", () => {
  assert.equal(encodeEstop(true, "dashboard", "a\nb"), "engaged|dashboard|a b");
  assert.equal(encodeEstop(false, "dashboard", "x".repeat(300)).length, "released|dashboard|".length + 200);
  assert.deepEqual(decodeEstop("engaged|device1|button|pressed"), { engaged: true, by: "device1", reason: "button|pressed" });
  assert.deepEqual(decodeEstop("released|op"), { engaged: false, by: "op", reason: "" });
  for (const bad of ["", "released", "maybe|x|y", "released|bad id|x", "RELEASED|a|b"]) {
    assert.equal(decodeEstop(bad), null, bad);
  }
});

test("headers count per kind; client ids are valid ids", () => {
  const s = new Stamper("dash-1");
  assert.equal(s.header("submit_job").seq, 0);
  assert.equal(s.header("submit_job").seq, 1);
  const h = s.header("set_goal");
  assert.equal(h.seq, 0);
  assert.equal(h.version, "1.0");
  assert.equal(h.sender, "dash-1");
  assert.match(h.timestamp, /^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$/);
  const id = makeClientId("dashboard");
  assert.match(id, ID_RE);
  assert.notEqual(id, makeClientId("dashboard"));
});
