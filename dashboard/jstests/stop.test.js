// The emergency stop as the page sends and shows it.
import assert from "node:assert/strict";
import { test } from "node:test";
import { decodeEstop } from "../static/js/protocol.js";
import { estopLook, estopPayload, HOLD_MS } from "../static/js/stop.js";

test("STOP and the release are sent by 'dashboard', naming the page", () => {
  // The page's own client id: the one id its account is sure to own (protocol.md §10).
  assert.equal(estopPayload(true, "ann-page-3fa2c1"), "engaged|ann-page-3fa2c1|STOP pressed on the page");
  assert.equal(estopPayload(false, "ann-page-3fa2c1"), "released|ann-page-3fa2c1|released on the page");
  assert.deepEqual(decodeEstop(estopPayload(true, "dash-1")), { engaged: true, by: "dash-1", reason: "STOP pressed on the page" });
  assert.equal(HOLD_MS, 1500);
});

test("nobody has said: unknown, STOP ready, nothing to release", () => {
  assert.deepEqual(estopLook(null, false), { state: "unknown", banner: null, stopLabel: "STOP", canRelease: false });
});

test("pressed here: shown at once, before the broker has it, and not yet releasable", () => {
  assert.deepEqual(estopLook(null, true), { state: "engaged", banner: "EMERGENCY STOP — sending…", stopLabel: "STOPPED", canRelease: false });
  const released = { engaged: false, by: "operator", reason: "checked" };
  assert.equal(estopLook(released, true).banner, "EMERGENCY STOP — sending…");
});

test("a press not latched yet: shown, but nothing to release", () => {
  const look = estopLook({ engaged: true, by: "dev1", reason: "button", press: true }, false);
  assert.equal(look.state, "engaged");
  assert.match(look.banner, /pressed on dev1: button \(not latched yet/);
  assert.equal(look.canRelease, false);
});

test("engaged on the broker: who stopped and why, and the release", () => {
  const byDevice = { engaged: true, by: "device1", reason: "button pressed" };
  assert.deepEqual(estopLook(byDevice, false), {
    state: "engaged", banner: "EMERGENCY STOP — engaged by device1: button pressed", stopLabel: "STOPPED", canRelease: true,
  });
  assert.equal(estopLook({ engaged: true, by: "device1", reason: "" }, false).banner, "EMERGENCY STOP — engaged by device1");
});

test("released on the broker", () => {
  assert.deepEqual(estopLook({ engaged: false, by: "operator", reason: "checked" }, false),
    { state: "released", banner: null, stopLabel: "STOP", canRelease: false });
});
