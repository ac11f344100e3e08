// The map's named places: read from fleet/map, found by a click, and what the job form's pickup and
// dropoff fields take (a place's name or a square X,Y).
import assert from "node:assert/strict";
import { test } from "node:test";
import { FleetView } from "../static/js/model.js";
import { parseWhere, pickedFor, PlaceIndex, readPlaces, resolveWhere, whereText } from "../static/js/places.js";
import { LIMITS } from "../static/js/protocol_table.js";

const A3 = { name: "A3", square: [3, 4], kinds: ["pickup"] };
const A4 = { name: "A4", square: [4, 4], kinds: ["pickup", "dropoff"] };
const P2 = { name: "P2", square: [9, 1], kinds: ["dropoff"] };
const PARK = { name: "park-1", square: [0, 0], kinds: ["parking"] };
const index = () => new PlaceIndex([A3, A4, P2, PARK]);

test("the map's places are kept; a malformed one is left out and counted", () => {
  assert.deepEqual(readPlaces(undefined), { places: [], dropped: 0 }, "a map without places: none");
  const bad = [
    { name: "bad name", square: [1, 1], kinds: ["pickup"] },
    { name: "B1", square: [1], kinds: ["pickup"] },
    { name: "B2", square: [1, 1], kinds: [] },
    { name: "B3", square: [1, 1], kinds: ["shelf"] },
    { name: "B4", square: [1, 1], kinds: ["pickup", "dropoff", "charger", "parking", "pickup"] },
    { name: "B5", square: [1.5, 1], kinds: ["pickup"] },
    { name: "B6", square: [LIMITS.max_coord + 1, 1], kinds: ["pickup"] },
    null, "A9",
  ];
  const { places, dropped } = readPlaces([A3, ...bad, { ...P2, kinds: ["dropoff", "dropoff"] }]);
  assert.deepEqual(places, [A3, P2], "repeated kinds are one");
  assert.equal(dropped, bad.length);
  assert.deepEqual(readPlaces({ A3 }), { places: [], dropped: 1 }, "not a list: none");
  const many = Array.from({ length: LIMITS.max_places + 1 }, (_, i) => ({ name: `p${i}`, square: [i % 100, 0], kinds: ["pickup"] }));
  assert.deepEqual(readPlaces(many), { places: [], dropped: many.length }, "more than the schema allows: none");
  assert.equal(readPlaces(many.slice(1)).places.length, LIMITS.max_places);
});

test("a click finds the place on its square; the form's lists offer each kind's names, sorted", () => {
  const i = index();
  assert.equal(i.at([3, 4]), A3);
  assert.equal(i.at([3, 5]), null);
  assert.equal(i.at(null), null);
  assert.deepEqual(i.namesOf("pickup"), ["A3", "A4"]);
  assert.deepEqual(i.namesOf("dropoff"), ["A4", "P2"]);
  assert.deepEqual(i.namesOf("charger"), []);
  // A click in a field: the place's name when it is of that field's kind, else the square.
  assert.deepEqual(pickedFor(i, [3, 4], "pickup"), { text: "A3", name: "A3" });
  assert.deepEqual(pickedFor(i, [3, 4], "dropoff"), { text: "3,4", name: null }, "A3 is no dropoff");
  assert.deepEqual(pickedFor(i, [4, 4], "dropoff"), { text: "A4", name: "A4" });
  assert.deepEqual(pickedFor(i, [0, 0], "pickup"), { text: "0,0", name: null }, "a parking place is no pickup");
  assert.deepEqual(pickedFor(i, [7, 7], "pickup"), { text: "7,7", name: null });
});

test("a field takes a place's name or a square X,Y, in words when it is neither", () => {
  for (const text of ["3,4", " 3, 4 ", "3 4", "[3, 4]", "[3,4]"]) assert.deepEqual(parseWhere(text), { square: [3, 4] }, text);
  assert.deepEqual(parseWhere("-1,4"), { square: [-1, 4] }, "off the map: the map check says so");
  assert.deepEqual(parseWhere("A3"), { name: "A3" });
  assert.deepEqual(parseWhere(" shelf-3.b "), { name: "shelf-3.b" });
  assert.deepEqual(parseWhere("34"), { name: "34" }, "one number is a name (as the CLI reads it)");
  assert.deepEqual(parseWhere(""), { error: "give a place's name or a square X,Y" });
  assert.deepEqual(parseWhere(null), { error: "give a place's name or a square X,Y" });
  assert.deepEqual(parseWhere("3,4,5"), { error: '"3,4,5" is neither a place\'s name nor a square X,Y' });
  assert.deepEqual(parseWhere("1.5,2"), { error: '"1.5,2" is neither a place\'s name nor a square X,Y' });
  assert.match(parseWhere("x".repeat(65)).error, /is neither/, "longer than an id");
});

test("a name is resolved against the places, for its role", () => {
  const i = index();
  assert.deepEqual(resolveWhere(i, parseWhere("A3"), "pickup"), { value: "A3", square: [3, 4], place: A3 });
  assert.deepEqual(resolveWhere(i, parseWhere("2,2"), "pickup"), { value: [2, 2], square: [2, 2], place: null });
  assert.equal(resolveWhere(i, parseWhere("A3"), "dropoff").error,
    "dropoff: place A3 is not a dropoff (it is: pickup); the dropoffs are A4, P2");
  assert.equal(resolveWhere(new PlaceIndex([PARK]), parseWhere("park-1"), "pickup").error,
    "pickup: place park-1 is not a pickup (it is: parking)", "no pickups to offer instead");
  assert.equal(resolveWhere(i, parseWhere(""), "pickup").error, "pickup: give a place's name or a square X,Y");
  // At most 20 names, and how many more.
  const many = new PlaceIndex(Array.from({ length: 25 }, (_, n) => ({ name: `s${String(n).padStart(2, "0")}`, square: [n, 0], kinds: ["pickup"] })));
  const said = resolveWhere(many, parseWhere("Q9"), "pickup").error;
  assert.match(said, /^pickup: no place is named 'Q9': the places are s00, s01, .*, s19 \(and 5 more\) \(or give a square X,Y\)$/);
});

test("squares read the same with a place's name and without", () => {
  assert.equal(whereText([3, 4], "A3"), "A3 [3, 4]");
  assert.equal(whereText([3, 4]), "[3, 4]");
});

test("the fleet view keeps the map's places and says how many it left out", () => {
  const v = new FleetView();
  const map = { name: "m", width: 10, height: 10, rows: Array(10).fill(".".repeat(10)), obstacles: [] };
  assert.equal(v.apply("map", null, JSON.stringify({ ...map, places: [A3, P2] }), 0), null);
  assert.equal(v.places.at([9, 1]).name, "P2");
  assert.deepEqual(v.map.places, [A3, P2]);
  assert.equal(v.apply("map", null, JSON.stringify({ ...map, places: [A3, { name: "x y" }, 7] }), 1), "ignored 2 malformed places on the map");
  assert.deepEqual(v.map.places, [A3], "the map and its good places stay");
  assert.equal(v.places.at([9, 1]), null, "P2 is no longer a place");
  const both = v.apply("map", null, JSON.stringify({ ...map, chargers: [{ name: "C1" }], places: [{}] }), 2);
  assert.equal(both, "ignored 1 malformed charger and 1 malformed place on the map");
  assert.equal(new FleetView(map).places.places.length, 0, "the dashboard's starting map: no places");
});
