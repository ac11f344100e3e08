// Draws the fleet on a canvas that fills its container. Returns the layout so clicks map to squares.

const ARROW = { N: [0, -1], E: [1, 0], S: [0, 1], W: [-1, 0] };

export function layoutFor(canvas, map) {
  const rect = canvas.parentElement.getBoundingClientRect();
  const w = Math.max(50, rect.width), h = Math.max(50, rect.height);
  const cols = map ? map.width : 10, rows = map ? map.height : 10;
  const cell = Math.max(2, Math.floor(Math.min(w / cols, h / rows)));
  const ox = Math.floor((w - cell * cols) / 2), oy = Math.floor((h - cell * rows) / 2);
  return { w, h, cell, ox, oy, cols, rows };
}

/** Which square a point (relative to the canvas) is on, or null. */
export function squareAt(layout, px, py) {
  const x = Math.floor((px - layout.ox) / layout.cell), y = Math.floor((py - layout.oy) / layout.cell);
  return x >= 0 && y >= 0 && x < layout.cols && y < layout.rows ? [x, y] : null;
}

export function drawFleet(canvas, view, now, ui) {
  const map = view.map;
  const L = layoutFor(canvas, map);
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
  // Pickup and dropoff markers of jobs still in play.
  g.font = `bold ${Math.max(8, Math.floor(c * 0.32))}px sans-serif`;
  g.textAlign = "center";
  g.textBaseline = "middle";
  for (const j of view.activeJobs()) {
    const color = j.unit ? view.colorOf(j.unit) : "#455a64";
    for (const [sq, letter] of [[j.pickup, "P"], [j.dropoff, "D"]]) {
      if (letter === "P" && (j.state === "loaded" || j.state === "to_dropoff")) continue;
      const [sx, sy] = at(sq[0], sq[1]);
      g.strokeStyle = color;
      g.lineWidth = 2;
      g.setLineDash(letter === "P" ? [] : [4, 3]);
      g.strokeRect(sx + c * 0.12, sy + c * 0.12, c * 0.76, c * 0.76);
      g.setLineDash([]);
      g.fillStyle = color;
      g.fillText(letter, sx + c * 0.5, sy + c * 0.5);
    }
  }
  // Routes: released squares solid, planned rest dashed, target ringed.
  for (const [id, r] of Object.entries(view.routes)) {
    const u = view.units.get(id);
    const color = view.colorOf(id);
    const start = u?.state?.position;
    const path = [...(r.released ?? []), ...(r.planned ?? [])];
    const nRel = (r.released ?? []).length;
    let prev = start;
    g.lineCap = "round";
    path.forEach((sq, i) => {
      if (prev) {
        g.strokeStyle = color;
        g.globalAlpha = i < nRel ? 0.9 : 0.45;
        g.lineWidth = i < nRel ? Math.max(3, c * 0.14) : Math.max(2, c * 0.07);
        g.setLineDash(i < nRel ? [] : [c * 0.15, c * 0.12]);
        g.beginPath();
        g.moveTo(...mid(prev[0], prev[1]));
        g.lineTo(...mid(sq[0], sq[1]));
        g.stroke();
      }
      prev = sq;
    });
    g.setLineDash([]);
    g.globalAlpha = 1;
    if (r.target) drawTarget(g, mid(r.target[0], r.target[1]), c, color);
  }
  // Goals set in standalone mode.
  for (const u of view.units.values()) {
    const goal = u.state?.goal;
    if (goal && !view.routes[u.id]?.target) drawTarget(g, mid(goal[0], goal[1]), c, view.colorOf(u.id));
  }
  // Units on top.
  const drawn = [];
  const headings = [];
  for (const u of view.units.values()) {
    if (!u.state) continue;
    const [x, y] = u.state.position;
    const [cx, cy] = mid(x, y);
    const color = view.colorOf(u.id);
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
    if (u.state.status === "stopped" || u.state.estop) {
      g.strokeStyle = "#d50000";
      g.lineWidth = 3;
      g.strokeRect(cx - c * 0.45, cy - c * 0.45, c * 0.9, c * 0.9);
    }
    g.globalAlpha = 1;
    if (c >= 18) {
      g.font = `${Math.max(8, Math.floor(c * 0.22))}px sans-serif`;
      const ly = cy + c * 0.58 > L.oy + map.height * c ? cy - c * 0.55 : cy + c * 0.55;
      // A white halo keeps the name readable over routes and markers in the next square.
      g.strokeStyle = "rgba(255, 255, 255, 0.9)";
      g.lineWidth = 3;
      g.lineJoin = "round";
      g.strokeText(u.id, cx, ly);
      g.fillStyle = "#000";
      g.fillText(u.id, cx, ly);
    }
    drawn.push(`${u.id}@${x},${y}`);
  }
  if (ui.pending) {
    const [sx, sy] = at(ui.pending[0], ui.pending[1]);
    g.strokeStyle = "#00838f";
    g.lineWidth = 3;
    g.strokeRect(sx + 1.5, sy + 1.5, c - 3, c - 3);
  }
  // What was drawn, for people using assistive tools and for tests.
  canvas.dataset.units = drawn.sort().join(" ");
  canvas.dataset.headings = headings.sort().join(" ");
  canvas.dataset.cell = String(c);
  canvas.dataset.ox = String(L.ox);
  canvas.dataset.oy = String(L.oy);
  return L;
}

const baseCache = { map: null, key: "", canvas: null };

function baseLayer(map, L, dpr) {
  const key = `${L.w}x${L.h}@${dpr}`;
  if (baseCache.map === map && baseCache.key === key) return baseCache.canvas;
  const canvas = baseCache.canvas ?? document.createElement("canvas");
  canvas.width = Math.round(L.w * dpr);
  canvas.height = Math.round(L.h * dpr);
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, L.w, L.h);
  const c = L.cell;
  g.fillStyle = "#fafafa";
  g.fillRect(L.ox, L.oy, map.width * c, map.height * c);
  g.fillStyle = "#37474f";
  for (let y = 0; y < map.height; y++) {
    const row = map.rows[y];
    for (let x = 0; x < map.width; x++) {
      if (row[x] !== ".") g.fillRect(L.ox + x * c, L.oy + y * c, c, c);
    }
  }
  if (c >= 6) {
    g.strokeStyle = "#d0d4d8";
    g.lineWidth = 1;
    g.beginPath();
    for (let x = 0; x <= map.width; x++) { g.moveTo(L.ox + x * c + 0.5, L.oy); g.lineTo(L.ox + x * c + 0.5, L.oy + map.height * c); }
    for (let y = 0; y <= map.height; y++) { g.moveTo(L.ox, L.oy + y * c + 0.5); g.lineTo(L.ox + map.width * c, L.oy + y * c + 0.5); }
    g.stroke();
  }
  Object.assign(baseCache, { map, key, canvas });
  return canvas;
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
