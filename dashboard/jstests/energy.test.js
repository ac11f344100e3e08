// Energy on the page: a unit's battery and plan, the chargers and who is on them, the charge
// button; every value read from the wire checked, a bad one left out without breaking the rest.
import assert from "node:assert/strict";
import { test } from "node:test";
import { controlRequest } from "../static/js/forms.js";
import { FleetView, readEnergy } from "../static/js/model.js";
import {
  DEFAULT_THRESHOLDS, batteryLevel, batteryText, chargerLines, controlButtons, linkTitle, planText, unitCells,
} from "../static/js/view.js";

const state = (extra = {}) => JSON.stringify({ position: [1, 0], status: "idle", load_kg: 0, ...extra });
const MAP = { name: "m", width: 4, height: 2, rows: ["....", "...."], obstacles: [] };
const THRESHOLDS = { critical_pct: 20, good_pct: 50, sufficient_pct: 80, full_pct: 95, available_from: "sufficient" };
const text = (cells) => cells.map(([t]) => t);

test("a unit's battery and charging come from its state; a unit without energy shows nothing new", () => {
  const v = new FleetView();
  v.apply("connection", "u1", JSON.stringify({ state: "online" }), 0);
  assert.equal(v.apply("state", "u1", state({ battery_pct: 61.6, charging: true }), 0), null);
  assert.deepEqual(v.battery("u1"), { pct: 61.6, charging: true });
  assert.equal(text(unitCells(v.units.get("u1")))[1], "62 % ⚡ · online");
  v.apply("state", "u1", state({ battery_pct: 38, charging: false }), 1);
  assert.equal(text(unitCells(v.units.get("u1")))[1], "38 % · online");
  assert.equal(v.hasEnergy("u1"), true);
  v.apply("connection", "u2", JSON.stringify({ state: "online" }), 0);
  v.apply("state", "u2", state({ battery_pct: null, charging: false }), 0);
  assert.deepEqual(text(unitCells(v.units.get("u2"))).slice(1, 4), ["online", "[1, 0]", "idle"]);
  assert.equal(v.battery("u2"), null);
  assert.equal(v.hasEnergy("u2"), false);
  // Its factsheet's model says it has energy before its first battery reading.
  v.apply("factsheet", "u3", JSON.stringify({ capacity_kg: 1, step_period_s: 0.1, energy: { move_pct: 1, idle_pct_per_s: 0, charge_pct_per_s: 1 } }), 0);
  assert.equal(v.hasEnergy("u3"), true);
});

test("a bad battery is left out, the rest of the state kept", () => {
  for (const bad of [{ battery_pct: "62" }, { battery_pct: 140 }, { battery_pct: -1 }, { battery_pct: [50] }, { charging: "yes" }]) {
    const v = new FleetView();
    assert.match(v.apply("state", "u1", state({ position: [2, 1], ...bad }), 0), /malformed battery in a state of u1/);
    const u = v.units.get("u1");
    assert.deepEqual(u.state.position, [2, 1], JSON.stringify(bad));
    assert.equal(v.battery("u1"), null);
    assert.equal(text(unitCells(u))[1], "?", "no battery shown");
  }
  assert.equal(batteryText(Number.NaN, true), null);
  assert.equal(batteryText(undefined), null);
});

test("the map's chargers: malformed ones left out, the map kept", () => {
  const v = new FleetView();
  const chargers = [{ name: "C1", square: [0, 1] }, { name: "bad name!", square: [1, 1] }, { name: "C3", square: [1] }, "C4", null];
  assert.match(v.apply("map", null, JSON.stringify({ ...MAP, chargers }), 0), /ignored 4 malformed chargers on the map/);
  assert.equal(v.map.width, 4);
  assert.deepEqual(v.chargers(), [{ name: "C1", square: [0, 1], unit: null, queue: [] }]);
  assert.match(v.apply("map", null, JSON.stringify({ ...MAP, chargers: "C1" }), 1), /1 malformed charger on/);
  assert.deepEqual(v.chargers(), []);
  assert.equal(v.apply("map", null, JSON.stringify(MAP), 2), null, "a map of 1.4: no chargers");
});

test("the energy view says who is on each charger, who waits, and each unit's plan", () => {
  const v = new FleetView();
  v.apply("map", null, JSON.stringify({ ...MAP, chargers: [{ name: "C1", square: [0, 1] }, { name: "C2", square: [3, 1] }] }), 0);
  const view = {
    thresholds: THRESHOLDS,
    chargers: [{ name: "C1", square: [0, 1], unit: "u1", queue: ["u2", "u3"] }, { name: "C2", square: [3, 1], unit: "u4", queue: [] }],
    units: {
      u1: { plan: "charging", charger: "C1", reason: "charging: 62 % of 80 %" },
      u2: { plan: "queued", charger: "C1", reason: null },
      u4: { plan: "to_charger", charger: "C2" },
      u5: { plan: "stranded", charger: null, reason: null },
    },
  };
  assert.equal(v.apply("energy", null, JSON.stringify(view), 0), null);
  assert.deepEqual(v.chargers(), [
    { name: "C1", square: [0, 1], unit: "u1", queue: ["u2", "u3"] },
    { name: "C2", square: [3, 1], unit: "u4", queue: [] },
  ]);
  assert.deepEqual(v.energy.thresholds, { critical_pct: 20, good_pct: 50, sufficient_pct: 80, full_pct: 95 });
  v.apply("state", "u1", state({ position: [0, 1], battery_pct: 62, charging: true }), 0);
  assert.deepEqual(chargerLines(v.chargers(), (id) => v.battery(id)),
    ["C1 [0, 1]: u1 charging · queue u2, u3", "C2 [3, 1]: u4 on its way"]);
  assert.equal(planText(v.energyPlan("u1")), "charging: 62 % of 80 %");
  assert.equal(planText(v.energyPlan("u2")), "waiting for charger C1");
  assert.equal(planText(v.energyPlan("u4")), "to charger C2");
  assert.equal(planText(v.energyPlan("u5")), "stranded: it cannot reach a charger");
  assert.equal(
    planText({ plan: "to_charger", charger: "C1", reason: "below good 50 %; charges up to 80 %" }),
    "to charger C1: below good 50 %; charges up to 80 %",
  );
  assert.equal(planText({ plan: "stranded", reason: "no charger can be reached from [3, 3]" }), "stranded: no charger can be reached from [3, 3]");
  assert.equal(planText(v.energyPlan("u9")), null);
  assert.equal(text(unitCells(v.units.get("u1"), null, null, null, null, v.energyPlan("u1")))[3],
    "idle · charging: 62 % of 80 %");
  // The plan goes with the energy view's next word: a unit it no longer lists has none.
  v.apply("energy", null, JSON.stringify({ thresholds: THRESHOLDS, chargers: [], units: {} }), 1);
  assert.equal(v.energyPlan("u1"), null);
  assert.deepEqual(v.chargers()[0], { name: "C1", square: [0, 1], unit: null, queue: [] });
});

test("a malformed energy view: its bad parts left out, the good ones kept, the page told", () => {
  const v = new FleetView();
  const view = {
    thresholds: { critical_pct: "low" },
    chargers: [{ name: "C1", square: [0, 1], unit: "u1", queue: ["u2"] }, { name: "C2", square: [0, 1], unit: 7 },
      { name: "C3", square: [1, 1], queue: "u2" }],
    units: { u1: { plan: "charging", charger: "C1" }, u2: { plan: "napping" }, u3: { plan: "queued", reason: 5 }, u4: "x" },
  };
  assert.match(v.apply("energy", null, JSON.stringify(view), 0), /ignored 6 malformed parts of the energy view/);
  assert.equal(v.energy.thresholds, null);
  assert.deepEqual(v.energy.chargers.map((c) => c.name), ["C1"]);
  assert.deepEqual([...v.energy.units.keys()], ["u1"]);
  assert.deepEqual(readEnergy({ thresholds: THRESHOLDS, chargers: {}, units: [] }).dropped, 2);
  assert.match(v.apply("energy", null, "[1, 2]", 1), /ignored/);
  assert.match(v.apply("energy", null, "{oops", 1), /malformed JSON on energy/);
  assert.deepEqual(v.energy.chargers.map((c) => c.name), ["C1"], "what was known stays");
  // The map's chargers are drawn from the view when the map lists none.
  assert.deepEqual(v.chargers(), [{ name: "C1", square: [0, 1], unit: "u1", queue: ["u2"] }]);
});

test("the charge button: for units with energy, beside pause and out of service", () => {
  const commands = (control, energy) => controlButtons(control, energy).map(([, c]) => c);
  assert.deepEqual(commands(null, true), ["pause", "out_of_service", "charge"]);
  assert.deepEqual(controlButtons(null, true)[2], ["charge", "charge", "send to charge (to full, then back to work)"],
    "a word, as on its neighbours");
  assert.deepEqual(commands("paused", true), ["resume", "out_of_service", "charge"]);
  assert.deepEqual(commands("out_of_service", true), ["in_service"]);
  assert.deepEqual(commands(null, false), ["pause", "out_of_service"]);
  assert.deepEqual(controlRequest("u3", "charge"), { what: "send to charge u3", body: { unit: "u3", command: "charge" } });
});

test("a battery's level by the coordinator's thresholds: amber at or below good, red at or below critical", () => {
  const t = { critical_pct: 25, good_pct: 60, sufficient_pct: 80, full_pct: 95 };
  const level = (pct, thresholds = t) => batteryLevel(pct, thresholds)?.level ?? null;
  assert.deepEqual([61, 60.4, 60, 25.1, 25, 0.4, 0].map((p) => level(p)), ["ok", "ok", "low", "low", "critical", "critical", "empty"]);
  assert.equal(batteryLevel(60, t).words, "low (at or below 60 %)");
  assert.equal(batteryLevel(25, t).words, "critical (at or below 25 %)");
  assert.equal(batteryLevel(0, t).words, "empty: it cannot move");
  assert.equal(batteryLevel(61, t).words, null);
  // Without the energy view: the coordinator's defaults (20 % and 50 %).
  assert.deepEqual(DEFAULT_THRESHOLDS, { critical_pct: 20, good_pct: 50 });
  assert.deepEqual([51, 50, 21, 20, 0].map((p) => level(p, null)), ["ok", "low", "low", "critical", "empty"]);
  assert.equal(batteryLevel(null, t), null);
  assert.equal(batteryLevel(Number.NaN), null);
});

test("an empty battery says so in words; charging keeps its own mark", () => {
  assert.equal(batteryText(0, false), "0 % empty");
  assert.equal(batteryText(0, true), "0 % ⚡");
  assert.equal(batteryText(0.4, false), "0 %", "nearly, not yet: it can still move");
  const v = new FleetView();
  v.apply("connection", "u1", JSON.stringify({ state: "online" }), 0);
  v.apply("state", "u1", state({ battery_pct: 0, charging: false, status: "waiting", wait_reason: "battery empty: cannot move" }), 0);
  const [, [link]] = unitCells(v.units.get("u1"));
  assert.equal(link, "0 % empty · online");
  assert.equal(linkTitle(link, v.battery("u1"), batteryLevel(0)), "battery 0 %, empty: it cannot move · online");
  assert.equal(linkTitle("62 % ⚡ · VDA 5050 x", { pct: 61.6, charging: true }, batteryLevel(61.6)),
    "battery 62 %, charging · VDA 5050 x");
  assert.equal(linkTitle("19 % · online", { pct: 19, charging: false }, batteryLevel(19, THRESHOLDS)),
    "battery 19 %, critical (at or below 20 %) · online");
  assert.equal(linkTitle("80 % · online", { pct: 80, charging: false }, batteryLevel(80)), "battery 80 % · online");
  assert.equal(linkTitle("online", null, null), "online");
});
