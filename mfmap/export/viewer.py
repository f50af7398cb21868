"""The 3D view of report.html: the building's points, trajectory and connectors, explorable offline.

A small hand-written renderer on a 2D canvas (points with a depth buffer, lines on top), not
WebGL: it needs no GPU and no library, so the page opens on any machine and in a headless
browser. The clouds are thinned to a point budget and stored as 16-bit integers in the page,
so a long log's page stays a few MB.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mfmap.export.cabin import Cabin
from mfmap.export.foxglove import CABIN_HEIGHT_M, floor_colour
from mfmap.export.nav2 import level_name

POINT_BUDGET = 200_000  # points in the page over all floors (6 bytes each, before base64)
TRAJECTORY_BUDGET = 5_000


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode()


def thin(points: np.ndarray, keep: int) -> np.ndarray:
    """Every k-th point so that about `keep` remain (the clouds are voxelised: even density)."""
    if points.shape[0] <= keep:
        return points
    step = math.ceil(points.shape[0] / keep)
    return points[::step]


def view_data(clouds: dict[int, np.ndarray], elevation_m: dict[int, float], traj_xyz: np.ndarray,
              floors_doc: dict[str, Any], cabins: Sequence[Cabin],
              point_budget: int = POINT_BUDGET) -> dict[str, Any]:
    """What the page's script draws, as JSON-able values (arrays base64 little-endian)."""
    total = sum(c.shape[0] for c in clouds.values())
    thinned = {f: thin(c, max(1, round(point_budget * c.shape[0] / max(total, 1)))) for f, c in clouds.items()}
    allpts = [c for c in thinned.values() if c.shape[0]] + ([traj_xyz] if traj_xyz.shape[0] else [])
    stacked = np.concatenate(allpts) if allpts else np.zeros((1, 3))
    lo = stacked.min(axis=0).astype(np.float64)
    hi = stacked.max(axis=0).astype(np.float64)
    span = np.maximum(hi - lo, 1e-3)
    floors = []
    for f in sorted(thinned):
        q = np.round((thinned[f].astype(np.float64) - lo) / span * 65535).astype("<u2")
        floors.append({"id": f, "name": level_name(f), "elevation": round(elevation_m.get(f, 0.0), 3),
                       "colour": list(floor_colour(f)), "count": int(q.shape[0]), "points": _b64(q)})
    connectors = []
    for conn in floors_doc["connectors"]:
        cabin = next((c for c in cabins if conn["kind"] == "elevator"
                      and math.hypot(c.x_m - conn["x"], c.y_m - conn["y"]) < 2.5), None)
        x, y, yaw, w, d = ((cabin.x_m, cabin.y_m, cabin.yaw_rad, cabin.inner_width_m, cabin.inner_depth_m)
                           if cabin is not None else (conn["x"], conn["y"], 0.0, 2.0, 2.0))
        connectors.append({"kind": conn["kind"], "id": conn["id"], "x": x, "y": y, "yaw": yaw, "w": w, "d": d,
                           "h": CABIN_HEIGHT_M,
                           "floors": [f for f in conn["floors"] if f in elevation_m],
                           "z": [round(elevation_m[f], 3) for f in conn["floors"] if f in elevation_m]})
    traj = thin(traj_xyz, TRAJECTORY_BUDGET).astype("<f4")
    return {"lo": lo.round(4).tolist(), "span": span.round(4).tolist(), "floors": floors,
            "trajectory": _b64(traj), "connectors": connectors}


_SCRIPT = r"""
(function () {
  "use strict";
  const data = JSON.parse(document.getElementById("mfmap-3d-data").textContent);
  const canvas = document.getElementById("mfmap-3d");
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height;
  const BG = [250, 250, 250];
  function bytes(b64) {
    const s = atob(b64), out = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out.buffer;
  }
  const lo = data.lo, span = data.span;
  const floors = data.floors.map(f => ({...f, q: new Uint16Array(bytes(f.points)), visible: true}));
  const traj = new Float32Array(bytes(data.trajectory));
  const show = {trajectory: true, connectors: true};
  // Points this high above their floor are its ceiling: hidden by default, to see into the rooms.
  const CUT_M = 2.0;
  let ceiling = CUT_M;
  const centre = [lo[0] + span[0] / 2, lo[1] + span[1] / 2, lo[2] + span[2] / 2];
  const cam = {az: -0.9, el: 0.55, dist: 1.15 * Math.max(span[0], span[1], span[2]), target: centre.slice()};
  const img = ctx.createImageData(W, H);
  const pix = new Uint32Array(img.data.buffer);
  const depth = new Float32Array(W * H);
  const bg = (255 << 24) | (BG[2] << 16) | (BG[1] << 8) | BG[0];
  let view = null;
  function basis() {
    const ce = Math.cos(cam.el), se = Math.sin(cam.el), ca = Math.cos(cam.az), sa = Math.sin(cam.az);
    const back = [ce * ca, ce * sa, se];  // from the target to the eye
    const right = [-sa, ca, 0];
    const up = [-se * ca, -se * sa, ce];
    const eye = [cam.target[0] + back[0] * cam.dist, cam.target[1] + back[1] * cam.dist,
                 cam.target[2] + back[2] * cam.dist];
    return {eye, right, up, back, f: 0.5 * H / Math.tan(0.4)};
  }
  function project(v, x, y, z) {
    const dx = x - v.eye[0], dy = y - v.eye[1], dz = z - v.eye[2];
    const zc = -(dx * v.back[0] + dy * v.back[1] + dz * v.back[2]);
    if (zc < 0.1) return null;
    return [W / 2 + v.f * (dx * v.right[0] + dy * v.right[1] + dz * v.right[2]) / zc,
            H / 2 - v.f * (dx * v.up[0] + dy * v.up[1] + dz * v.up[2]) / zc, zc];
  }
  function drawPoints(v, f) {
    const q = f.q, n = q.length / 3, c = f.colour;
    const sx = span[0] / 65535, sy = span[1] / 65535, sz = span[2] / 65535;
    const r = v.right, u = v.up, b = v.back, e = v.eye, fl = v.f;
    for (let i = 0; i < n; i++) {
      const x = lo[0] + q[3 * i] * sx - e[0], y = lo[1] + q[3 * i + 1] * sy - e[1];
      const zw = lo[2] + q[3 * i + 2] * sz;
      const z = zw - e[2];
      const zc = -(x * b[0] + y * b[1] + z * b[2]);
      if (zc < 0.1) continue;
      const px = (W / 2 + fl * (x * r[0] + y * r[1] + z * r[2]) / zc) | 0;
      const py = (H / 2 - fl * (x * u[0] + y * u[1] + z * u[2]) / zc) | 0;
      if (px < 0 || py < 0 || px >= W - 1 || py >= H - 1) continue;
      const k = py * W + px;
      if (depth[k] <= zc || zw - f.elevation > ceiling) continue;
      const s = 0.55 + 0.45 * Math.min(Math.max((zw - f.elevation) / 3, 0), 1);
      const col = (255 << 24) | (((c[2] * s) | 0) << 16) | (((c[1] * s) | 0) << 8) | ((c[0] * s) | 0);
      depth[k] = zc; pix[k] = col;
      depth[k + 1] = zc; pix[k + 1] = col; depth[k + W] = zc; pix[k + W] = col;
    }
  }
  function line(v, pts, colour, width) {
    ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.beginPath();
    let pen = false;
    for (const p of pts) {
      const s = project(v, p[0], p[1], p[2]);
      if (!s) { pen = false; continue; }
      if (pen) ctx.lineTo(s[0], s[1]); else ctx.moveTo(s[0], s[1]);
      pen = true;
    }
    ctx.stroke();
  }
  function box(v, c, z, colour) {
    const cy = Math.cos(c.yaw), sy = Math.sin(c.yaw), corners = [];
    for (const [a, b] of [[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) {
      const lx = a * c.w / 2, ly = b * c.d / 2;
      corners.push([c.x + cy * lx - sy * ly, c.y + sy * lx + cy * ly]);
    }
    line(v, corners.map(p => [p[0], p[1], z]), colour, 2);
    line(v, corners.map(p => [p[0], p[1], z + c.h]), colour, 2);
    for (const p of corners.slice(0, 4)) line(v, [[p[0], p[1], z], [p[0], p[1], z + c.h]], colour, 2);
  }
  function render() {
    view = basis();
    pix.fill(bg); depth.fill(Infinity);
    for (const f of floors) if (f.visible) drawPoints(view, f);
    ctx.putImageData(img, 0, 0);
    const shown = new Set(floors.filter(f => f.visible).map(f => f.id));
    if (show.trajectory) {
      const pts = [];
      for (let i = 0; i < traj.length; i += 3) pts.push([traj[i], traj[i + 1], traj[i + 2]]);
      line(view, pts, "rgba(214,39,40,0.9)", 1.5);
    }
    if (show.connectors) {
      for (const c of data.connectors) {
        const colour = c.kind === "elevator" ? "#e6b428" : "#3cc8c8";
        c.floors.forEach((f, i) => { if (shown.has(f)) box(view, c, c.z[i], colour); });
        if (c.z.length > 1) line(view, [[c.x, c.y, Math.min(...c.z)], [c.x, c.y, Math.max(...c.z) + c.h]], colour, 3);
      }
    }
    // Each floor's name at the corner of the building that is leftmost on the screen.
    ctx.font = "bold 14px sans-serif"; ctx.textAlign = "right";
    for (const f of floors) {
      if (!f.visible) continue;
      let best = null;
      for (const x of [lo[0], lo[0] + span[0]]) for (const y of [lo[1], lo[1] + span[1]]) {
        const s = project(view, x, y, f.elevation);
        if (s && (!best || s[0] < best[0])) best = s;
      }
      if (best) { ctx.fillStyle = `rgb(${f.colour.join(",")})`; ctx.fillText(`${f.name} ${f.elevation.toFixed(2)} m`, best[0] - 6, best[1]); }
    }
    ctx.textAlign = "left";
  }
  // The canvas tells when it has drawn what was asked (data-frames counts the frames drawn,
  // data-busy is 1 while one is due), so a test or script can wait for the view to settle.
  let pending = false, frames = 0;
  function drawn() { canvas.dataset.frames = String(++frames); canvas.dataset.busy = pending ? "1" : "0"; }
  function redraw() {
    if (pending) return;
    pending = true; canvas.dataset.busy = "1";
    requestAnimationFrame(() => { pending = false; render(); drawn(); });
  }
  const controls = document.getElementById("mfmap-3d-controls");
  function toggle(label, checked, onchange, colour) {
    const l = document.createElement("label");
    const box = document.createElement("input");
    box.type = "checkbox"; box.checked = checked; box.dataset.toggle = label;
    box.addEventListener("change", () => { onchange(box.checked); redraw(); });
    l.appendChild(box);
    const span = document.createElement("span");
    span.textContent = " " + label; if (colour) span.style.color = colour;
    l.appendChild(span); controls.appendChild(l);
  }
  for (const f of floors) toggle(f.name, true, on => { f.visible = on; }, `rgb(${f.colour.join(",")})`);
  toggle("trajectory", true, on => { show.trajectory = on; });
  toggle("connectors", true, on => { show.connectors = on; });
  toggle("ceilings", false, on => { ceiling = on ? Infinity : CUT_M; });
  let drag = null;
  canvas.addEventListener("mousedown", e => { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2}; e.preventDefault(); });
  canvas.addEventListener("contextmenu", e => e.preventDefault());
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", e => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const v = basis(), k = cam.dist / v.f;
      for (let i = 0; i < 3; i++) cam.target[i] += k * (-dx * v.right[i] + dy * v.up[i]);
    } else {
      cam.az -= dx * 0.008;
      cam.el = Math.min(Math.max(cam.el + dy * 0.008, -1.5), 1.5);
    }
    redraw();
  });
  canvas.addEventListener("wheel", e => { cam.dist *= Math.exp(e.deltaY * 0.001); e.preventDefault(); redraw(); }, {passive: false});
  render();
  drawn();
  canvas.dataset.ready = "1";
})();
"""


def view_html(data: dict[str, Any], width: int = 1000, height: int = 620) -> str:
    """The 3D view's section of the page: canvas, toggles, the data and the script."""
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    return "\n".join([
        "<h2>Building in 3D</h2>",
        "<p>Drag to rotate, shift-drag (or right-drag) to pan, wheel to zoom; the boxes toggle "
        "floors, the trajectory, the connectors and the ceilings (hidden at first, to see into the rooms).</p>",
        "<div id='mfmap-3d-controls' style='display:flex;gap:1.2em;margin:.4em 0'></div>",
        f"<canvas id='mfmap-3d' width='{width}' height='{height}' "
        "style='border:1px solid #bbb;max-width:100%;cursor:grab'></canvas>",
        f"<script type='application/json' id='mfmap-3d-data'>{payload}</script>",
        f"<script>{_SCRIPT}</script>",
    ])
