// Closed zones: the view read as its schema has it, the rectangle a drag makes, the requests the
// zone form and the "Open" buttons send (exactly as their schemas want), and the list's words.
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { test } from "node:test";
import { FleetView } from "../static/js/model.js";
import { Stamper } from "../static/js/protocol.js";
import { LIMITS } from "../static/js/protocol_table.js";
import { Requests } from "../static/js/requests.js";
import {
  closeZoneRequest, dragRect, inZone, isDateTime, mayChange, normaliseRect, openZoneRequest, readZones, rectText,
  zoneCells, zoneLabel,
} from "../static/js/zones.js";

const schema = (name) => JSON.parse(readFileSync(new URL(`../../protocol/schemas/${name}.json`, import.meta.url), "utf8"));
const MAP = { name: "m", width: 10, height: 8, rows: Array(8).fill(".".repeat(10)), obstacles: [] };
const AISLE = {
  name: "aisle-4", first: [3, 0], last: [4, 7], reason: "cleaning", closed_by: "op", closed_at: "2026-11-21T10:00:43.100Z",
};
const view = (zones) => JSON.stringify({ header: { version: "1.6", seq: 0, timestamp: "2026-11-21T10:00:43Z", sender: "coordinator" }, zones });

test("a zones view as its schema has it is kept, its corners least and greatest", () => {
  const { zones } = readZones(JSON.parse(view([AISLE, { ...AISLE, name: "dock", first: [9, 7], last: [8, 6], closed_by: null }])));
  assert.deepEqual(zones[0], AISLE);
  assert.deepEqual([zones[1].first, zones[1].last, zones[1].closed_by], [[8, 6], [9, 7], null]);
  const unsigned = Object.fromEntries(Object.entries(AISLE).filter(([k]) => k !== "closed_by"));
  assert.deepEqual(readZones({ zones: [unsigned] }).zones[0].closed_by, null, "closed_by may be left out");
  assert.deepEqual(readZones({ header: {} }), { zones: [] }, "no zones: none closed");
  assert.deepEqual(readZones({ zones: [{ ...AISLE, reason: "" }] }).zones[0].reason, "", "a reason may be empty in the view");
  assert.equal(readZones({ zones: [{ ...AISLE, reason: "🧹".repeat(LIMITS.max_text) }] }).error, undefined,
    "500 characters (each two UTF-16 units) are 500 characters");
});

test("a zones view that breaks its schema is refused, saying where", () => {
  const refused = (msg) => readZones(msg).error;
  const zone = (fields) => ({ zones: [{ ...AISLE, ...fields }] });
  const without = (key) => ({ zones: [Object.fromEntries(Object.entries(AISLE).filter(([k]) => k !== key))] });
  assert.equal(refused([]), "ignored a zones view that is not an object");
  assert.equal(refused({ zones: null }), "ignored a zones view whose zones are not a list");
  assert.equal(refused({ zones: [], extra: 1 }), "ignored a zones view with unknown fields (extra)");
  const many = Array.from({ length: LIMITS.max_zones + 1 }, (_, i) => ({ ...AISLE, name: `z${i}` }));
  assert.equal(refused({ zones: many }), `ignored a zones view of ${many.length} zones (at most ${LIMITS.max_zones})`);
  assert.equal(refused({ zones: many.slice(1) }), undefined);
  assert.equal(refused({ zones: [AISLE, 7] }), "ignored a malformed zones view: zone 2 is not an object");
  assert.equal(refused(zone({ colour: "red" })), "ignored a malformed zones view: zone 1 aisle-4 has unknown fields (colour)");
  for (const key of ["name", "first", "last", "reason", "closed_at"]) assert.match(refused(without(key)), new RegExp(`has no ${key}$`), key);
  assert.match(refused(zone({ name: "aisle 4" })), /zone 1 aisle 4 has a name that is not an id$/);
  for (const first of [[3], [3, -1], [3, 0.5], [3, LIMITS.max_coord + 1], "3,0", null]) {
    assert.match(refused(zone({ first })), /has a corner that is not a square$/, JSON.stringify(first));
  }
  assert.match(refused(zone({ reason: null })), /has a reason that is not text of at most 500 characters$/);
  assert.match(refused(zone({ reason: "x".repeat(LIMITS.max_text + 1) })), /has a reason that is not text/);
  assert.match(refused(zone({ closed_by: "bad id" })), /has a closed_by that is not an id$/);
  assert.match(refused(zone({ closed_at: "yesterday" })), /has a closed_at that is not a date and time \(RFC 3339\)$/);
});

test("date-times as RFC 3339 has them: real days, seconds and an offset", () => {
  for (const ok of ["2026-11-21T10:00:43Z", "2026-11-21t10:00:43.123456+01:00", "2024-02-29T23:59:60Z", "0001-01-01T00:00:00-23:59"]) {
    assert.ok(isDateTime(ok), ok);
  }
  for (const bad of ["2026-11-21T10:00Z", "2026-11-21T10:00:43", "2026-11-21 10:00:43Z", "2025-02-29T00:00:00Z",
    "2026-13-01T00:00:00Z", "2026-04-31T00:00:00Z", "2026-11-21T24:00:00Z", "2026-11-21T10:60:00Z",
    "2026-11-21T10:00:61Z", "2026-11-21T10:00:00+24:00", "0000-01-01T00:00:00Z", "2026-11-21T10:00:43Z\n", 20261121, null]) {
    assert.equal(isDateTime(bad), false, String(bad));
  }
});

test("the fleet view keeps the last good zones: a bad view changes nothing, a cleared one clears", () => {
  const v = new FleetView(MAP);
  assert.equal(v.apply("zones", null, view([AISLE]), 0), null);
  assert.deepEqual(v.zones.map((z) => z.name), ["aisle-4"]);
  assert.match(v.apply("zones", null, view([{ ...AISLE, first: "x" }]), 1), /corner that is not a square/);
  assert.match(v.apply("zones", null, "{oops", 1), /malformed JSON on zones/);
  assert.deepEqual(v.zones.map((z) => z.name), ["aisle-4"], "still the zones last heard");
  assert.equal(v.apply("zones", null, view([]), 2), null);
  assert.deepEqual(v.zones, []);
  v.apply("zones", null, view([AISLE]), 3);
  assert.equal(v.apply("zones", null, "", 4), null, "a cleared retained view");
  assert.deepEqual(v.zones, []);
});

test("a drag's rectangle: any two corners, the far one held on the map", () => {
  assert.deepEqual(normaliseRect([5, 1], [2, 6]), { first: [2, 1], last: [5, 6] });
  assert.deepEqual(normaliseRect([2, 2], [2, 2]), { first: [2, 2], last: [2, 2] });
  assert.deepEqual(dragRect([5, 1], [2.9, 6.1], 10, 8), { first: [2, 1], last: [5, 6] });
  assert.deepEqual(dragRect([5, 1], [-4, 99], 10, 8), { first: [0, 1], last: [5, 7] });
  assert.deepEqual(dragRect([5, 1], [12.5, -0.5], 10, 8), { first: [5, 0], last: [9, 1] });
  assert.ok(inZone(AISLE, [3, 0]) && inZone(AISLE, [4, 7]) && !inZone(AISLE, [5, 0]) && !inZone(AISLE, [2, 3]));
});

test("the zone form's request: exactly CloseZone's fields, or why not in words", () => {
  const v = new FleetView(MAP);
  assert.deepEqual(closeZoneRequest(v, { first: [4, 7], last: [3, 0], name: " aisle-4 ", reason: "  cleaning " }), {
    what: "close zone aisle-4 [3, 0] to [4, 7] (2 x 8 squares)",
    body: { name: "aisle-4", first: [3, 0], last: [4, 7], reason: "cleaning" },
  });
  const refused = (fields, on = v) => closeZoneRequest(on, { first: [1, 1], last: [2, 2], name: "z", reason: "r", ...fields }).error;
  assert.equal(refused({}), undefined);
  assert.equal(refused({}, new FleetView()), "no map yet: waiting for the coordinator's fleet/map");
  assert.equal(refused({ first: null }), "drag over the map first: the zone's rectangle");
  assert.equal(refused({ last: [10, 2] }), "[10,2] is not a square of the map");
  for (const name of ["", "aisle 4", "-x", "x".repeat(65)]) {
    assert.equal(refused({ name }), "zone name: letters, digits, _ . - only (max 64), e.g. aisle-4", name);
  }
  for (const reason of ["", "   ", null]) {
    assert.equal(refused({ reason }), "give a reason (it is shown to every operator and kept in the audit)", String(reason));
  }
  assert.equal(refused({ reason: "x".repeat(501) }), "the reason is 501 characters long: at most 500");
  assert.equal(refused({ reason: "x".repeat(500) }), undefined);
});

test("the requests as published carry exactly what CloseZone and OpenZone want", () => {
  const requests = new Requests("dash-1", new Stamper("dash-1"), { session: "abc123" });
  const close = closeZoneRequest(new FleetView(MAP), { first: [4, 7], last: [3, 0], name: "aisle-4", reason: "cleaning" });
  const open = openZoneRequest({ name: "aisle-4", first: [3, 0], last: [4, 7], reason: "cleaning" });
  assert.deepEqual(open, { what: "open zone aisle-4", body: { name: "aisle-4" } });
  for (const [kind, model, req] of [["close_zone", "CloseZone", close], ["open_zone", "OpenZone", open]]) {
    const { message } = requests.create(kind, "zone", req.what, req.body);
    const s = schema(model);
    assert.deepEqual(Object.keys(message).sort(), Object.keys(s.properties).sort(), `${model}: every field, none other`);
    for (const key of s.required) assert.ok(key in message, `${model}: ${key}`);
    assert.match(message.name, new RegExp(s.properties.name.pattern));
    assert.equal(message.reply_to, "dash-1");
    assert.match(message.request_id, /^dash-1-abc123-\d+$/);
    const header = s.$defs.Header;
    assert.deepEqual(Object.keys(message.header).sort(), Object.keys(header.properties).sort());
    assert.equal(message.header.version, header.properties.version.const);
  }
  const { message } = requests.create("close_zone", "zone", close.what, close.body);
  const props = schema("CloseZone").properties;
  for (const corner of ["first", "last"]) {
    assert.equal(message[corner].length, props[corner].prefixItems.length);
    message[corner].forEach((v, i) => {
      const item = props[corner].prefixItems[i];
      assert.ok(Number.isInteger(v) && v >= item.minimum && v <= item.maximum, `${corner}[${i}] = ${v}`);
    });
  }
  assert.ok(message.reason.length >= props.reason.minLength && message.reason.length <= props.reason.maxLength);
});

test("the zones list and the map say each zone in words", () => {
  const clock = (iso) => `at ${iso.slice(11, 19)}`;
  assert.deepEqual(zoneCells(AISLE, clock), [
    ["aisle-4", "name"], ["[3, 0] to [4, 7] (2 x 8 squares)", "rect"], ["cleaning", "reason"], ["op", "by"], ["at 10:00:43", "at"],
  ]);
  assert.equal(zoneCells({ ...AISLE, closed_by: null }, clock)[3][0], "?", "nobody named");
  assert.equal(rectText({ first: [2, 2], last: [2, 2] }), "[2, 2] (1 square)");
  assert.equal(zoneLabel(AISLE), "aisle-4 · cleaning");
});

test("who may close and open zones: people's accounts, not viewers (the settings say)", () => {
  assert.equal(mayChange({ may_change: true }), true);
  assert.equal(mayChange({ may_change: false }), false);
  assert.equal(mayChange({}), true, "settings that do not say: the coordinator still refuses");
  assert.equal(mayChange(null), true);
});
