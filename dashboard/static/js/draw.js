// Draws the fleet on a canvas that fills its container. Returns the layout so clicks map to squares.

import { placeLabels, unitJob } from "./story.js";
import { MANY_UNITS, STATE_COLORS, unitState } from "./units.js";
import { rectText, zoneLabel } from "./zones.js";

const ARROW = { N: [0, -1], E: [1, 0], S: [0, 1], W: [-1, 0] };
export const MAX_ZOOM = 40;

// A size that is a positive number, or 1: a box not laid out yet (0 x 0), a map that says it has
// no squares or fewer, would make every size drawn from it zero or negative (a unit's circle of
// negative radius throws, and stops the page drawing).
const positive = (v) => (Number.isFinite(v) && v > 0 ? v : 1);

/** The map fitted to the box (zoom 1), or `zoom.scale` times that, shifted by `zoom.pan` px. */
export function fitLayout(width, height, columns, lines, zoom = { scale: 1, pan: [0, 0] }) {
  const [w, h, cols, rows] = [width, height, columns, lines].map(positive);
  const fit = Math.min(w / cols, h / rows);
  // Whole pixels once a square is big enough to show its grid lines; fractions below, so a map
  // of 500 x 140 squares still fits the box.
  const raw = fit * positive(zoom.scale);
  const cell = raw >= 6 ? Math.floor(raw) : raw;
  const pan = (i) => (Number.isFinite(zoom.pan?.[i]) ? zoom.pan[i] : 0);
  const ox = Math.floor((w - cell * cols) / 2 + pan(0));
  const oy = Math.floor((h - cell * rows) / 2 + pan(1));
  return { w, h, cell, ox, oy, cols, rows };
}

/** The layout in the canvas's box: `box` ({width, height}) when known, else measured now. */
export function layoutFor(canvas, map, zoom, box = null) {
  const rect = box ?? canvas.parentElement.getBoundingClientRect();
  const w = Math.max(50, rect.width), h = Math.max(50, rect.height);
  return fitLayout(w, h, map ? map.width : 10, map ? map.height : 10, zoom);
}

/**
 * Zoom by `factor` about the point (px, py) of the canvas, the square under it staying put;
 * the scale stays within 1 (the whole map) and MAX_ZOOM.
 */
export function zoomAt(zoom, layout, px, py, factor) {
  const scale = Math.min(MAX_ZOOM, Math.max(1, zoom.scale * factor));
  if (scale === 1) return { scale: 1, pan: [0, 0] };
  const centred = fitLayout(layout.w, layout.h, layout.cols, layout.rows, { scale, pan: [0, 0] });
  // The map's point under the pointer stays there: the origin moves towards or away from it.
  const k = centred.cell / layout.cell;
  const ox = px - (px - layout.ox) * k, oy = py - (py - layout.oy) * k;
  return clampPan({ scale, pan: [ox - centred.ox, oy - centred.oy] }, layout);
}

/** Pan by (dx, dy) px, keeping part of the map in view. */
export function panBy(zoom, layout, dx, dy) {
  return clampPan({ scale: zoom.scale, pan: [zoom.pan[0] + dx, zoom.pan[1] + dy] }, layout);
}

function clampPan(zoom, layout) {
  const next = fitLayout(layout.w, layout.h, layout.cols, layout.rows, { scale: zoom.scale, pan: [0, 0] });
  // At most half the map's size beyond centred: some of it always shows.
  const mx = Math.max(0, (next.cell * layout.cols) / 2), my = Math.max(0, (next.cell * layout.rows) / 2);
  return { scale: zoom.scale, pan: [Math.max(-mx, Math.min(mx, zoom.pan[0])), Math.max(-my, Math.min(my, zoom.pan[1]))] };
}

/** Which square a point (relative to the canvas) is on, or null. */
export function squareAt(layout, px, py) {
  const [x, y] = squaresAt(layout, px, py).map(Math.floor);
  return x >= 0 && y >= 0 && x < layout.cols && y < layout.rows ? [x, y] : null;
}

/** Where a point (relative to the canvas) is in squares, fractions kept, on the map or off it. */
export function squaresAt(layout, px, py) {
  return [(px - layout.ox) / layout.cell, (py - layout.oy) / layout.cell];
}

export function drawFleet(canvas, view, now, ui, box = null) {
  const map = view.map;
  const L = layoutFor(canvas, map, ui.zoom, box);
  // Many units: a colour per state (moving, waiting, ...) says more than 150 colours that repeat.
  const byState = view.units.size >= MANY_UNITS;
  const colorOf = (id) => {
    if (!byState) return view.colorOf(id);
    const u = view.units.get(id);
    return u ? STATE_COLORS[unitState(u, view.routes[id]?.control, !!unitJob(view, id), view.isSilent(u, now))] : "#607d8b";
  };
  canvas.dataset.colors = byState ? "state" : "unit";
  const dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(L.w * dpr) || canvas.height !== Math.round(L.h * dpr)) {
    canvas.width = Math.round(L.w * dpr);
    canvas.height = Math.round(L.h * dpr);
    canvas.style.width = `${L.w}px`;
    canvas.style.height = `${L.h}px`;
  }
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, L.w, L.h);
  const c = L.cell;
  const at = (x, y) => [L.ox + x * c, L.oy + y * c];
  const mid = (x, y) => [L.ox + (x + 0.5) * c, L.oy + (y + 0.5) * c];
  if (!map) {
    g.fillStyle = "#888";
    g.font = "16px sans-serif";
    g.fillText("waiting for the map (fleet/map)…", 20, 30);
    return L;
  }
  // Floor, walls and grid lines change only with the map or the window: drawn once, then copied.
  g.drawImage(baseLayer(map, L, dpr), 0, 0, L.w, L.h);
  // Discovered obstacles; new ones flash.
  const obstacles = view.knownObstacles(now);
  canvas.dataset.obstacles = obstacles.map((o) => `${o.x},${o.y}${o.fresh ? "*" : ""}`).sort().join(" ");
  for (const o of obstacles) {
    const [sx, sy] = at(o.x, o.y);
    g.fillStyle = o.fresh && Math.floor(now / 300) % 2 === 0 ? "#ff8f00" : "#6d4c41";
    g.fillRect(sx, sy, c, c);
    if (o.fresh) {
      g.strokeStyle = "#e65100";
      g.lineWidth = Math.max(2, c * 0.12);
      g.strokeRect(sx + 2, sy + 2, c - 4, c - 4);
    }
  }
  drawZones(g, canvas, view.zones, L);
  tintPlaces(g, view.places.places, L);
  const chargers = view.chargers();
  drawChargers(g, canvas, chargers, L);
  // Pickup and dropoff markers of jobs still in play: redrawn only when the queue, the view or
  // the chosen job changed (hundreds of jobs, drawn on every frame, were most of a frame).
  const layer = markerLayer(view, L, dpr, ui.selectedJob, byState);
  g.drawImage(layer.canvas, 0, 0, L.w, L.h);
  if (canvas.dataset.markers !== layer.text) canvas.dataset.markers = layer.text;
  // Routes: released squares solid, planned rest dashed, target ringed.
  for (const [id, r] of Object.entries(view.routes)) {
    const u = view.units.get(id);
    const color = colorOf(id);
    const start = u?.state?.position;
    const path = [...(r.released ?? []), ...(r.planned ?? [])];
    const nRel = (r.released ?? []).length;
    // Two strokes a unit: the released squares wide, the planned rest thin and faint. Not
    // dashed: dashes cost more than the rest of the map together in a browser without a GPU.
    g.lineCap = "round";
    g.strokeStyle = color;
    for (const released of [true, false]) {
      const part = released ? path.slice(0, nRel) : path.slice(nRel);
      const from = released ? start : (path[nRel - 1] ?? start);
      if (!from || !part.length) continue;
      g.globalAlpha = released ? 0.9 : 0.4;
      g.lineWidth = released ? Math.max(3, c * 0.14) : Math.max(1.5, c * 0.06);
      g.beginPath();
      g.moveTo(...mid(from[0], from[1]));
      for (const sq of part) g.lineTo(...mid(sq[0], sq[1]));
      g.stroke();
    }
    g.globalAlpha = 1;
    if (r.target) drawTarget(g, mid(r.target[0], r.target[1]), c, color);
  }
  // Goals set in standalone mode.
  for (const u of view.units.values()) {
    const goal = u.state?.goal;
    if (goal && !view.routes[u.id]?.target) drawTarget(g, mid(goal[0], goal[1]), c, colorOf(u.id));
  }
  // Units on top.
  const drawn = [];
  const headings = [];
  const carrying = [];
  const labelled = [];
  for (const u of view.units.values()) {
    if (!u.state) continue;
    const [x, y] = u.state.position;
    const [cx, cy] = mid(x, y);
    const color = colorOf(u.id);
    const alive = u.connection !== "offline" && u.connection !== "broken";
    g.globalAlpha = alive ? 1 : 0.35;
    g.fillStyle = color;
    g.beginPath();
    g.arc(cx, cy, c * 0.38, 0, 2 * Math.PI);
    g.fill();
    g.lineWidth = ui.selectedUnit === u.id ? 4 : 1.5;
    g.strokeStyle = ui.selectedUnit === u.id ? "#000" : "#fff";
    g.stroke();
    const heading = view.heading(u.id);
    headings.push(`${u.id}:${heading}`);
    const d = ARROW[heading];
    if (d) {
      g.fillStyle = "#fff";
      g.beginPath();
      const tip = [cx + d[0] * c * 0.32, cy + d[1] * c * 0.32];
      const back = [cx - d[0] * c * 0.05, cy - d[1] * c * 0.05];
      const side = [-d[1] * c * 0.17, d[0] * c * 0.17];
      g.moveTo(...tip);
      g.lineTo(back[0] + side[0], back[1] + side[1]);
      g.lineTo(back[0] - side[0], back[1] - side[1]);
      g.closePath();
      g.fill();
    }
    if (u.state.load_kg > 0) {
      // What it carries: a parcel on its back, with the job's number.
      const job = unitJob(view, u.id);
      const b = c * 0.3;
      g.fillStyle = "#ffb300";
      g.strokeStyle = "#5d4037";
      g.lineWidth = 1.5;
      g.fillRect(cx + c * 0.12, cy - c * 0.48, b, b);
      g.strokeRect(cx + c * 0.12, cy - c * 0.48, b, b);
      carrying.push(`${u.id}:${job ?? "?"}`);
    }
    if (u.state.status === "stopped" || u.state.estop) {
      g.strokeStyle = "#d50000";
      g.lineWidth = 3;
      g.strokeRect(cx - c * 0.45, cy - c * 0.45, c * 0.9, c * 0.9);
    }
    g.globalAlpha = 1;
    labelled.push({ id: u.id, cx, cy, r: c * 0.4 });
    drawn.push(`${u.id}@${x},${y}`);
  }
  labelChargers(g, chargers, L);
  // The places' marks and names, over the units (a unit on a place does not hide its name).
  const places = placesLayer(view.places.places, chargers, L, dpr);
  g.drawImage(places.canvas, 0, 0, L.w, L.h);
  if (canvas.dataset.places !== places.text) canvas.dataset.places = places.text;
  if (canvas.dataset.placeNames !== places.named) canvas.dataset.placeNames = places.named;
  labelZones(g, view.zones, L);
  // Names last, where they overlap no other name and no unit (placeLabels).
  const size = Math.max(10, Math.min(14, Math.floor(c * 0.35)));
  g.font = `${size}px sans-serif`;
  const items = labelled.map((it) => ({ ...it, w: g.measureText(it.id).width + 4, h: size + 2 }));
  const labels = placeLabels(items, { x0: 0, y0: 0, x1: L.w, y1: L.h });
  for (const label of labels) {
    // A white halo keeps the name readable over routes and markers.
    g.strokeStyle = "rgba(255, 255, 255, 0.9)";
    g.lineWidth = 3;
    g.lineJoin = "round";
    g.strokeText(label.id, label.x, label.y);
    g.fillStyle = "#000";
    g.fillText(label.id, label.x, label.y);
  }
  canvas.dataset.labels = JSON.stringify(labels.map((l) => [l.id, Math.round(l.x - l.w / 2), Math.round(l.y - l.h / 2), Math.round(l.w), Math.round(l.h)]));
  canvas.dataset.carrying = carrying.sort().join(" ");
  if (ui.pending) {
    const [sx, sy] = at(ui.pending[0], ui.pending[1]);
    g.strokeStyle = "#00838f";
    g.lineWidth = 3;
    g.strokeRect(sx + 1.5, sy + 1.5, c - 3, c - 3);
  }
  drawZoneDraft(g, canvas, ui.zone, L);
  // What was drawn, for people using assistive tools and for tests.
  canvas.dataset.units = drawn.sort().join(" ");
  canvas.dataset.headings = headings.sort().join(" ");
  canvas.dataset.cell = String(+c.toFixed(2));
  canvas.dataset.ox = String(L.ox);
  canvas.dataset.oy = String(L.oy);
  return L;
}

/**
 * The chargers: a square mark each (amber frame, lightning bolt), its name above it when the
 * squares are big enough, and "+2" for the units queued for it; a charger given to a unit (on it
 * or on its way) has a solid frame. `data-chargers` says it all in words, for tests and tools.
 */
function drawChargers(g, canvas, chargers, L) {
  const c = L.cell;
  const said = [];
  for (const ch of chargers) {
    const [x, y] = ch.square;
    if (x >= L.cols || y >= L.rows) continue; // off this map: nothing to draw it on
    const sx = L.ox + x * c, sy = L.oy + y * c;
    g.fillStyle = "#fff8e1";
    g.fillRect(sx + 1, sy + 1, c - 2, c - 2);
    g.strokeStyle = "#f57f17";
    g.lineWidth = Math.max(2, c * 0.1);
    g.setLineDash(ch.unit ? [] : [Math.max(2, c * 0.15), Math.max(2, c * 0.1)]);
    g.strokeRect(sx + c * 0.06, sy + c * 0.06, c * 0.88, c * 0.88);
    g.setLineDash([]);
    if (c >= 10) {
      // A lightning bolt in the square's corner: the unit on it covers its middle.
      g.fillStyle = "#f57f17";
      g.beginPath();
      g.moveTo(sx + c * 0.3, sy + c * 0.1);
      g.lineTo(sx + c * 0.14, sy + c * 0.32);
      g.lineTo(sx + c * 0.24, sy + c * 0.32);
      g.lineTo(sx + c * 0.16, sy + c * 0.5);
      g.lineTo(sx + c * 0.34, sy + c * 0.26);
      g.lineTo(sx + c * 0.24, sy + c * 0.26);
      g.closePath();
      g.fill();
    }
    said.push(`${ch.name}@${x},${y}:${ch.unit ?? "-"}${ch.queue.length ? `+${ch.queue.join(",")}` : ""}`);
  }
  const text = said.sort().join(" ");
  if (canvas.dataset.chargers !== text) canvas.dataset.chargers = text;
}

/**
 * The chargers' names (top right inside the square) and how many units wait for each ("+2",
 * bottom right): drawn over the units, so the unit charging there does not hide them.
 */
function labelChargers(g, chargers, L) {
  const c = L.cell;
  if (c < 14) return;
  g.font = `bold ${Math.max(9, Math.floor(c * 0.24))}px sans-serif`;
  g.textAlign = "right";
  g.lineWidth = 3;
  g.lineJoin = "round";
  for (const ch of chargers) {
    const [x, y] = ch.square;
    if (x >= L.cols || y >= L.rows) continue;
    const sx = L.ox + x * c, sy = L.oy + y * c;
    const words = [[ch.name, "top", sy + c * 0.08]];
    if (ch.queue.length) words.push([`+${ch.queue.length}`, "bottom", sy + c * 0.94]);
    for (const [word, baseline, at] of words) {
      g.textBaseline = baseline;
      g.strokeStyle = "rgba(255, 255, 255, 0.9)";
      g.strokeText(word, sx + c * 0.94, at, c * 0.8);
      g.fillStyle = "#e65100";
      g.fillText(word, sx + c * 0.94, at, c * 0.8);
    }
  }
  g.textAlign = "left";
  g.textBaseline = "alphabetic";
}

/** A rectangle of squares ({first, last}) in px of the canvas: [x, y, width, height]. */
function rectPx(z, L) {
  const c = L.cell;
  return [L.ox + z.first[0] * c, L.oy + z.first[1] * c, (z.last[0] - z.first[0] + 1) * c, (z.last[1] - z.first[1] + 1) * c];
}

/**
 * The closed zones: a red tint, hatched, with a red frame (their names and reasons come with
 * the labels, over the units). `data-zones` lists them: "aisle-4@3,0-4,9".
 */
function drawZones(g, canvas, zones, L) {
  const said = [];
  for (const z of zones) {
    const [x, y, w, h] = rectPx(z, L);
    said.push(`${z.name}@${z.first[0]},${z.first[1]}-${z.last[0]},${z.last[1]}`);
    if (x > L.w || y > L.h || x + w < 0 || y + h < 0) continue; // out of view
    g.save();
    g.fillStyle = "rgba(198, 40, 40, 0.13)";
    g.fillRect(x, y, w, h);
    g.beginPath();
    g.rect(x, y, w, h);
    g.clip();
    // Hatched every 8 px, the lines fixed to the map (they pan with it); only the part in
    // view is drawn, however large the zone.
    const x0 = Math.max(x, 0), x1 = Math.min(x + w, L.w), y0 = Math.max(y, 0), y1 = Math.min(y + h, L.h);
    const step = 8, rise = y1 - y0, base = L.ox + L.oy;
    g.strokeStyle = "rgba(198, 40, 40, 0.4)";
    g.lineWidth = 1;
    g.beginPath();
    for (let d = Math.floor((x0 - rise + y1 - base) / step) * step + base - y1; d <= x1; d += step) {
      g.moveTo(d, y1);
      g.lineTo(d + rise, y0);
    }
    g.stroke();
    g.restore();
    g.strokeStyle = "#c62828";
    g.lineWidth = 2;
    g.strokeRect(x + 1, y + 1, w - 2, h - 2);
  }
  const text = said.join(" ");
  if (canvas.dataset.zones !== text) canvas.dataset.zones = text;
}

/** Each closed zone's name and reason ("aisle-4 · cleaning") at its top left, over the units. */
function labelZones(g, zones, L) {
  if (!zones.length) return;
  g.font = "bold 12px sans-serif";
  g.textAlign = "left";
  g.textBaseline = "top";
  g.lineWidth = 3;
  g.lineJoin = "round";
  for (const z of zones) {
    const [x, y, w, h] = rectPx(z, L);
    if (x > L.w || y > L.h || x + w < 0 || y + h < 0) continue;
    const text = zoneLabel(z);
    // Inside its top left corner, or of the part in view when zoomed in on it; a narrow zone's
    // words run on beyond it rather than being squeezed.
    const lx = Math.max(x, 0) + 3, ly = Math.max(y, 0) + 3;
    const room = Math.max(x + w - lx - 3, 140);
    g.strokeStyle = "rgba(255, 255, 255, 0.9)";
    g.strokeText(text, lx, ly, room);
    g.fillStyle = "#b71c1c";
    g.fillText(text, lx, ly, room);
  }
  g.textBaseline = "alphabetic";
}

/** The zone being drawn (clicks.js `zone`): a dashed teal frame and its squares in words. */
function drawZoneDraft(g, canvas, zone, L) {
  const text = zone ? `${zone.first[0]},${zone.first[1]}-${zone.last[0]},${zone.last[1]}` : "";
  if ((canvas.dataset.draft ?? "") !== text) canvas.dataset.draft = text;
  if (!zone) return;
  const [x, y, w, h] = rectPx(zone, L);
  g.fillStyle = "rgba(0, 131, 143, 0.15)";
  g.fillRect(x, y, w, h);
  g.strokeStyle = "#00838f";
  g.lineWidth = 2;
  g.setLineDash([6, 4]);
  g.strokeRect(x + 1, y + 1, w - 2, h - 2);
  g.setLineDash([]);
  g.font = "bold 12px sans-serif";
  g.textAlign = "left";
  g.textBaseline = "bottom";
  const words = rectText(zone);
  const ty = y > 16 ? y - 2 : y + h + 14; // above it, or below when it touches the top
  g.lineWidth = 3;
  g.strokeStyle = "rgba(255, 255, 255, 0.9)";
  g.strokeText(words, x, ty);
  g.fillStyle = "#006064";
  g.fillText(words, x, ty);
  g.textBaseline = "alphabetic";
}

// A place's kinds as small marks in its square's lower left corner (a charger is drawn as one).
const PLACE_MARKS = { pickup: "#00897b", dropoff: "#8e24aa", parking: "#1e88e5" };

/** Each place's square tinted by its first kind, under the units: strong when too small for marks. */
function tintPlaces(g, places, L) {
  const c = L.cell;
  g.globalAlpha = c < 8 ? 0.55 : 0.12;
  for (const p of places) {
    const kind = p.kinds.find((k) => PLACE_MARKS[k]);
    const sx = L.ox + p.square[0] * c, sy = L.oy + p.square[1] * c;
    if (!kind || p.square[0] >= L.cols || p.square[1] >= L.rows || sx > L.w || sy > L.h || sx + c < 0 || sy + c < 0) continue;
    g.fillStyle = PLACE_MARKS[kind];
    g.fillRect(sx, sy, c, c);
  }
  g.globalAlpha = 1;
}

const NAMED_FROM = 16; // px a square needs for its place's name to be written in it

const placesCache = { places: null, key: "", canvas: null, text: "", named: "" };

/**
 * The places: a mark per kind (pickup ▲, dropoff ▼, parking ▬) in the square's lower left
 * corner, a tint of the square when squares are too small for marks, and the name in the
 * square's upper left once a square is NAMED_FROM px (a charger's place: its name is the
 * charger's, written already). Drawn once per map and view, then copied. Its `text` lists
 * every place ("A3@3,4:pickup"), `named` the names written.
 */
function placesLayer(places, chargers, L, dpr) {
  const key = `${L.w}x${L.h}@${dpr}:${L.cell}:${L.ox},${L.oy}:${chargers.map((ch) => ch.name).join(",")}`;
  if (placesCache.places === places && placesCache.key === key) return placesCache;
  const [canvas, g] = layerCanvas(placesCache.canvas, L, dpr);
  const c = L.cell;
  const chargerAt = new Set(chargers.map((ch) => `${ch.name}@${ch.square[0]},${ch.square[1]}`));
  // What the places are changes with the map alone, not with every zoom and pan.
  const text = placesCache.places === places ? null : places.map((p) => `${p.name}@${p.square[0]},${p.square[1]}:${p.kinds.join("+")}`);
  const named = [];
  const font = Math.max(9, Math.min(13, Math.floor(c * 0.26)));
  g.font = `bold ${font}px sans-serif`;
  g.textAlign = "left";
  g.textBaseline = "top";
  g.lineJoin = "round";
  for (const p of places) {
    const [x, y] = p.square;
    if (x >= L.cols || y >= L.rows) continue; // off this map
    const sx = L.ox + x * c, sy = L.oy + y * c;
    if (sx > L.w || sy > L.h || sx + c < 0 || sy + c < 0) continue; // out of view
    const marks = p.kinds.filter((k) => PLACE_MARKS[k]);
    if (c < 8) continue; // too small for marks: the tint under the units says it (tintPlaces)
    const m = Math.max(4, c * 0.18);
    marks.forEach((kind, i) => {
      const mx = sx + c * 0.06 + i * (m + 2), my = sy + c * 0.94;
      g.fillStyle = PLACE_MARKS[kind];
      g.beginPath();
      if (kind === "pickup") { g.moveTo(mx, my); g.lineTo(mx + m, my); g.lineTo(mx + m / 2, my - m); }
      else if (kind === "dropoff") { g.moveTo(mx, my - m); g.lineTo(mx + m, my - m); g.lineTo(mx + m / 2, my); }
      else g.rect(mx, my - m * 0.55, m, m * 0.55);
      g.closePath();
      g.fill();
    });
    if (c < NAMED_FROM || chargerAt.has(`${p.name}@${x},${y}`)) continue;
    const room = c * 0.88;
    g.lineWidth = 3;
    g.strokeStyle = "rgba(255, 255, 255, 0.9)";
    g.strokeText(p.name, sx + c * 0.06, sy + c * 0.05, room);
    g.fillStyle = "#263238";
    g.fillText(p.name, sx + c * 0.06, sy + c * 0.05, room);
    named.push(p.name);
  }
  return Object.assign(placesCache, {
    places, key, canvas, text: text ? text.sort().join(" ") : placesCache.text, named: named.sort().join(" "),
  });
}

/** An off-screen canvas the size of the view (`canvas` again, or a new one), cleared. */
function layerCanvas(canvas, L, dpr) {
  const layer = canvas ?? document.createElement("canvas");
  layer.width = Math.round(L.w * dpr);
  layer.height = Math.round(L.h * dpr);
  const g = layer.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, L.w, L.h);
  return [layer, g];
}

const markerCache = { jobs: null, key: "", canvas: null, text: "" };

function markerLayer(view, L, dpr, selectedJob, byState) {
  const key = `${L.w}x${L.h}@${dpr}:${L.cell}:${L.ox},${L.oy}:${selectedJob}:${byState}`;
  if (markerCache.jobs === view.jobs && markerCache.key === key) return markerCache;
  const [canvas, g] = layerCanvas(markerCache.canvas, L, dpr);
  const c = L.cell;
  const at = (x, y) => [L.ox + x * c, L.oy + y * c];
  const mid = (x, y) => [L.ox + (x + 0.5) * c, L.oy + (y + 0.5) * c];
  const ui = { selectedJob };
  g.font = `bold ${Math.max(8, Math.floor(c * 0.32))}px sans-serif`;
  g.textAlign = "center";
  g.textBaseline = "middle";
  const markers = [];
  const crowded = view.activeJobs().length > MANY_UNITS; // then queued jobs are shown faintly
  for (const j of view.activeJobs()) {
    const color = j.unit ? (byState ? "#455a64" : view.colorOf(j.unit)) : "#455a64";
    const n = view.jobNumbers.of(j.id);
    const chosen = j.id === ui.selectedJob;
    const carried = j.state === "loaded" || j.state === "to_dropoff";
    g.globalAlpha = crowded && !j.unit && !chosen ? 0.35 : 1;
    if (chosen && !carried) {
      // The selected job's pair, joined: where the item is and where it goes.
      g.strokeStyle = color;
      g.lineWidth = 2;
      g.setLineDash([6, 4]);
      g.beginPath();
      g.moveTo(...mid(j.pickup[0], j.pickup[1]));
      g.lineTo(...mid(j.dropoff[0], j.dropoff[1]));
      g.stroke();
      g.setLineDash([]);
    }
    for (const [sq, letter] of [[j.pickup, "P"], [j.dropoff, "D"]]) {
      if (letter === "P" && carried) continue;
      const [sx, sy] = at(sq[0], sq[1]);
      g.strokeStyle = color;
      g.lineWidth = chosen ? 4 : 2;
      g.strokeRect(sx + c * 0.12, sy + c * 0.12, c * 0.76, c * 0.76);
      if (letter === "D" && c >= 8) {
        // A dropoff is a box in a box (not dashed: see the routes).
        g.lineWidth = 1;
        g.strokeRect(sx + c * 0.22, sy + c * 0.22, c * 0.56, c * 0.56);
      }
      g.fillStyle = color;
      // Squeezed into its box when long (P258): never cut off by the rings around it.
      if (c >= 14) g.fillText(`${letter}${n}`, sx + c * 0.5, sy + c * 0.5, c * 0.68);
      markers.push(`${letter}${n}@${sq[0]},${sq[1]}`);
    }
  }
  g.globalAlpha = 1;
  return Object.assign(markerCache, { jobs: view.jobs, key, canvas, text: markers.sort().join(" ") });
}

const baseCache = { map: null, key: "", canvas: null };

function baseLayer(map, L, dpr) {
  const key = `${L.w}x${L.h}@${dpr}:${L.cell}:${L.ox},${L.oy}`;
  if (baseCache.map === map && baseCache.key === key) return baseCache.canvas;
  const [canvas, g] = layerCanvas(baseCache.canvas, L, dpr);
  const c = L.cell;
  g.fillStyle = "#fafafa";
  g.fillRect(L.ox, L.oy, map.width * c, map.height * c);
  g.fillStyle = "#37474f";
  // Only the squares in view: zoomed in on a big map, most are not.
  const x0 = Math.max(0, Math.floor(-L.ox / c)), x1 = Math.min(map.width, Math.ceil((L.w - L.ox) / c));
  const y0 = Math.max(0, Math.floor(-L.oy / c)), y1 = Math.min(map.height, Math.ceil((L.h - L.oy) / c));
  for (let y = y0; y < y1; y++) {
    const row = map.rows[y] ?? ""; // a row the map leaves out (or cuts short) is walls
    for (let x = x0; x < x1; x++) {
      if (row[x] !== ".") g.fillRect(L.ox + x * c, L.oy + y * c, c, c);
    }
  }
  if (c >= 6) {
    g.strokeStyle = "#d0d4d8";
    g.lineWidth = 1;
    g.beginPath();
    for (let x = x0; x <= x1; x++) { g.moveTo(L.ox + x * c + 0.5, L.oy + y0 * c); g.lineTo(L.ox + x * c + 0.5, L.oy + y1 * c); }
    for (let y = y0; y <= y1; y++) { g.moveTo(L.ox + x0 * c, L.oy + y * c + 0.5); g.lineTo(L.ox + x1 * c, L.oy + y * c + 0.5); }
    g.stroke();
  }
  Object.assign(baseCache, { map, key, canvas });
  return canvas;
}

/**
 * The throughput chart: a bar per minute of jobs done (oldest left, the current minute right),
 * and how busy the units are now as a line across, labelled with its share. Its figures and
 * labels go in data attributes too, for tests and assistive tools.
 */
export function drawChart(canvas, perMinute, share) {
  drawBars(canvas, perMinute, share, {
    attr: "perMinute", oldest: `${perMinute.length} min ago`, newest: "this minute",
    none: `no job done in the last ${perMinute.length} min`,
  });
}

/** The day's chart: a bar per clock hour of jobs done, the last 24 (from the job history). */
export function drawDayChart(canvas, perHour, share) {
  drawBars(canvas, perHour, share, {
    attr: "perHour", oldest: `${perHour.length} h ago`, newest: "this hour",
    none: `no job done in the last ${perHour.length} h`,
  });
}

/** Bars of `counts` (oldest left) and the share of units busy; `words` label them. */
function drawBars(canvas, counts, share, words) {
  const key = `${counts.join(" ")}|${share}`;
  if (canvas.dataset.key === key) return;
  canvas.dataset.key = key;
  canvas.dataset[words.attr] = counts.join(" ");
  canvas.dataset.utilisation = share == null ? "" : share.toFixed(2);
  const busy = share == null ? "" : `${Math.round(share * 100)} % of units busy`;
  const none = counts.every((n) => n === 0);
  canvas.dataset.busy = busy;
  canvas.dataset.note = none ? words.none : "";
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth || 300, h = canvas.clientHeight || 96;
  canvas.width = Math.round(w * dpr);
  canvas.height = Math.round(h * dpr);
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  const axis = 12; // the time axis under the bars
  const plot = h - axis - 14; // room above the tallest bar for its count
  const base = h - axis;
  const top = Math.max(1, ...counts);
  const bw = w / counts.length;
  g.font = "10px sans-serif";
  g.textBaseline = "bottom";
  g.textAlign = "center";
  counts.forEach((n, i) => {
    const bh = (plot * n) / top;
    g.fillStyle = "#4caf50";
    g.fillRect(i * bw + 2, base - bh, bw - 4, bh);
    if (n) { g.fillStyle = "#1b5e20"; g.fillText(String(n), i * bw + bw / 2, base - bh); }
  });
  g.strokeStyle = "#90a4ae";
  g.lineWidth = 1;
  g.beginPath();
  g.moveTo(0, base + 0.5);
  g.lineTo(w, base + 0.5);
  g.stroke();
  g.fillStyle = "#607d8b";
  g.textBaseline = "top";
  g.textAlign = "left";
  g.fillText(words.oldest, 2, base + 1);
  g.textAlign = "right";
  g.fillText(words.newest, w - 2, base + 1);
  if (none) {
    g.textAlign = "center";
    g.textBaseline = "middle";
    g.fillText(canvas.dataset.note, w / 2, base / 2);
  }
  if (share != null) {
    const y = base - plot * share;
    g.strokeStyle = "#1565c0";
    g.lineWidth = 2;
    g.setLineDash([5, 3]);
    g.beginPath();
    g.moveTo(0, y);
    g.lineTo(w, y);
    g.stroke();
    g.setLineDash([]);
    g.fillStyle = "#1565c0";
    g.textAlign = "left";
    g.textBaseline = y > 14 ? "bottom" : "top";
    g.fillText(busy, 4, y - 1);
  }
}

function drawTarget(g, [cx, cy], c, color) {
  g.strokeStyle = color;
  g.lineWidth = Math.max(2, c * 0.08);
  // Two rings: a target, leaving room for a pickup/dropoff letter inside.
  g.beginPath();
  g.arc(cx, cy, c * 0.44, 0, 2 * Math.PI);
  g.stroke();
  g.beginPath();
  g.arc(cx, cy, c * 0.3, 0, 2 * Math.PI);
  g.stroke();
}
