// sinew viewer: draws one task's frames on a 2D canvas with an orthographic camera,
// with a timeline, playback, charts linked to the timeline and the task's metrics.
//
// The data is the JSON object in the element #sinew-data, written by sinew-viz: bulk
// numbers are little-endian f32 arrays in base64, indices are plain JSON arrays. Nothing
// is fetched, so the page works when opened from disk.
//
// A 2D canvas with our own projection is used rather than WebGL so the page draws the
// same with or without a GPU. The camera is orthographic: the silhouettes of spheres
// and capsules are then exact (a disc, and a segment thickened by the radius), and depth
// ordering is by each primitive's centre (painter's algorithm).
'use strict';
(function () {
  const data = JSON.parse(document.getElementById('sinew-data').textContent);

  // Decodes base64 little-endian f32 values; DataView reads little-endian on any host.
  function decodeF32(b64) {
    const bin = atob(b64);
    const view = new DataView(new ArrayBuffer(bin.length));
    for (let i = 0; i < bin.length; i++) view.setUint8(i, bin.charCodeAt(i));
    const out = new Float32Array(bin.length / 4);
    for (let i = 0; i < out.length; i++) out[i] = view.getFloat32(4 * i, true);
    return out;
  }

  const shown = data.frames;            // original index of each shown frame
  const nShown = shown.length;
  const total = data.totalFrames;
  const nPoints = data.pointCount;
  const nGoals = data.goalCount;
  const points = decodeF32(data.points);
  const goals = decodeF32(data.goals);
  const times = decodeF32(data.times);
  const path = decodeF32(data.targetPath);
  const rest = decodeF32(data.restLengths);
  const triRest = decodeF32(data.triangleRest);
  const segs = data.segments;
  const tris = data.triangles;
  const isCloth = data.kind === 'cloth';
  if (points.length !== nShown * nPoints * 3 || goals.length !== nShown * nGoals * 3) {
    throw new Error('sinew viewer: position data does not match the frame count');
  }
  // Segments that are edges of a triangle are drawn with the surface, not again.
  const segOnSurface = new Uint8Array(segs.length / 2);
  if (tris.length > 0) {
    const edges = new Set();
    const key = (i, j) => (i < j ? i * nPoints + j : j * nPoints + i);
    for (let t = 0; t < tris.length; t += 3) {
      for (let e = 0; e < 3; e++) edges.add(key(tris[t + e], tris[t + (e + 1) % 3]));
    }
    for (let s = 0; s < segOnSurface.length; s++) {
      segOnSurface[s] = edges.has(key(segs[2 * s], segs[2 * s + 1])) ? 1 : 0;
    }
  }
  const strainScale = data.strainScale || 1;
  const hasStrain = rest.length > 0 || triRest.length > 0;

  // ---- Scene bounds, over every shown frame, so the camera does not jump. ----
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  function grow(x, y, z, r) {
    lo[0] = Math.min(lo[0], x - r); lo[1] = Math.min(lo[1], y - r); lo[2] = Math.min(lo[2], z - r);
    hi[0] = Math.max(hi[0], x + r); hi[1] = Math.max(hi[1], y + r); hi[2] = Math.max(hi[2], z + r);
  }
  for (const arr of [points, goals, path]) {
    for (let i = 0; i + 2 < arr.length; i += 3) grow(arr[i], arr[i + 1], arr[i + 2], 0);
  }
  for (const list of data.colliders) {
    for (const c of list) {
      // A half-space is unbounded: only its point counts, so the view is not lost.
      if (c.k === 'plane') grow(c.p[0], c.p[1], c.p[2], 0);
      if (c.k === 'sphere') grow(c.c[0], c.c[1], c.c[2], c.r);
      if (c.k === 'capsule') { grow(c.a[0], c.a[1], c.a[2], c.r); grow(c.b[0], c.b[1], c.b[2], c.r); }
    }
  }
  if (!(lo[0] <= hi[0])) { lo.fill(-1); hi.fill(1); }
  const centre = [0, 1, 2].map((k) => 0.5 * (lo[k] + hi[k]));
  const radius = Math.max(1e-3, 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]));

  // ---- Camera: azimuth about +y from +z towards +x, elevation above the xz plane. ----
  const home = { yaw: 0.6, pitch: 0.35, zoom: 1, panX: 0, panY: 0 };
  const cam = Object.assign({}, home);
  let right, up, toward, scale, width, height;
  function setBasis() {
    const cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw);
    const cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
    right = [cy, 0, -sy];
    toward = [cp * sy, sp, cp * cy];
    up = [-sp * sy, cp, -sp * cy];   // toward x right
    scale = cam.zoom * 0.45 * Math.min(width, height) / radius;
  }
  // Screen position and depth (larger is nearer) of a world point, written into out.
  function project(x, y, z, out) {
    const dx = x - centre[0], dy = y - centre[1], dz = z - centre[2];
    out[0] = 0.5 * width + cam.panX + scale * (dx * right[0] + dy * right[1] + dz * right[2]);
    out[1] = 0.5 * height + cam.panY - scale * (dx * up[0] + dy * up[1] + dz * up[2]);
    out[2] = dx * toward[0] + dy * toward[1] + dz * toward[2];
    return out;
  }

  // Blue (compressed) through grey (at rest) to red (stretched), scaled by strainScale.
  function strainRgb(strain) {
    const t = Math.max(-1, Math.min(1, strain / strainScale));
    const grey = [150, 150, 150];
    const end = t < 0 ? [49, 54, 149] : [215, 48, 39];
    const a = Math.abs(t);
    return [0, 1, 2].map((k) => grey[k] + a * (end[k] - grey[k]));
  }
  // Strain colours quantized to 129 steps and shading to 33, each string built once:
  // setting a canvas colour from a string parses it, and most neighbours share one.
  const palette = new Map();
  function paletteColour(strain, lit) {
    const t = Math.round(64 * Math.max(-1, Math.min(1, strain / strainScale)));
    const l = Math.round(32 * Math.max(0, Math.min(1, lit)));
    const key = t * 64 + l;
    let c = palette.get(key);
    if (c === undefined) {
      c = rgb(strainRgb((t / 64) * strainScale), 0.55 + 0.45 * (l / 32));
      palette.set(key, c);
    }
    return c;
  }
  function rgb(c, shade) {
    const f = shade === undefined ? 1 : shade;
    return 'rgb(' + Math.round(c[0] * f) + ',' + Math.round(c[1] * f) + ',' + Math.round(c[2] * f) + ')';
  }

  // ---- DOM ----
  const canvas = document.getElementById('view');
  const ctx = canvas.getContext('2d');
  const slider = document.getElementById('timeline');
  const playButton = document.getElementById('play');
  const speedSelect = document.getElementById('speed');
  const caption = document.getElementById('caption');
  const frameLabel = document.getElementById('frame-label');
  const legend = document.getElementById('legend');
  const BACKGROUND = '#fbfbf8';
  let current = 0;

  function resize() {
    const cssWidth = Math.max(300, canvas.clientWidth || 800);
    const cssHeight = Math.round(Math.min(cssWidth * 0.72, Math.max(320, window.innerHeight - 220)));
    const dpr = window.devicePixelRatio || 1;
    canvas.width = Math.round(cssWidth * dpr);
    canvas.height = Math.round(cssHeight * dpr);
    canvas.style.height = cssHeight + 'px';
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    width = cssWidth;
    height = cssHeight;
  }

  // Two unit vectors spanning the plane with normal n.
  function planeAxes(n) {
    const len = Math.hypot(n[0], n[1], n[2]);
    const u0 = [n[0] / len, n[1] / len, n[2] / len];
    const helper = Math.abs(u0[1]) < 0.9 ? [0, 1, 0] : [1, 0, 0];
    let a = [u0[1] * helper[2] - u0[2] * helper[1], u0[2] * helper[0] - u0[0] * helper[2], u0[0] * helper[1] - u0[1] * helper[0]];
    const al = Math.hypot(a[0], a[1], a[2]);
    a = [a[0] / al, a[1] / al, a[2] / al];
    const b = [u0[1] * a[2] - u0[2] * a[1], u0[2] * a[0] - u0[0] * a[2], u0[0] * a[1] - u0[1] * a[0]];
    return [u0, a, b];
  }

  // A half-space as a grid on its plane, centred at the scene centre's foot point.
  function drawPlane(c) {
    const [n, a, b] = planeAxes(c.n);
    const d = (centre[0] - c.p[0]) * n[0] + (centre[1] - c.p[1]) * n[1] + (centre[2] - c.p[2]) * n[2];
    const foot = [centre[0] - d * n[0], centre[1] - d * n[1], centre[2] - d * n[2]];
    const half = 1.3 * radius;
    const lines = 10;
    const s = [0, 0, 0], e = [0, 0, 0];
    const at = (u, v, out) => project(foot[0] + u * a[0] + v * b[0], foot[1] + u * a[1] + v * b[1], foot[2] + u * a[2] + v * b[2], out);
    ctx.fillStyle = 'rgba(120, 140, 110, 0.12)';
    ctx.beginPath();
    for (const [u, v] of [[-1, -1], [1, -1], [1, 1], [-1, 1]]) {
      at(u * half, v * half, s);
      ctx.lineTo(s[0], s[1]);
    }
    ctx.closePath();
    ctx.fill();
    ctx.strokeStyle = 'rgba(90, 110, 80, 0.45)';
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let k = 0; k <= lines; k++) {
      const t = -half + (2 * half * k) / lines;
      at(t, -half, s); at(t, half, e);
      ctx.moveTo(s[0], s[1]); ctx.lineTo(e[0], e[1]);
      at(-half, t, s); at(half, t, e);
      ctx.moveTo(s[0], s[1]); ctx.lineTo(e[0], e[1]);
    }
    ctx.stroke();
  }

  function drawSphere(c) {
    const p = project(c.c[0], c.c[1], c.c[2], [0, 0, 0]);
    const r = scale * c.r;
    const g = ctx.createRadialGradient(p[0] - 0.35 * r, p[1] - 0.35 * r, 0.1 * r, p[0], p[1], r);
    g.addColorStop(0, 'rgba(225, 230, 240, 0.95)');
    g.addColorStop(1, 'rgba(120, 130, 155, 0.95)');
    ctx.fillStyle = g;
    ctx.strokeStyle = 'rgb(80, 88, 110)';
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.arc(p[0], p[1], Math.max(r, 0.5), 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  }

  function drawCapsule(c) {
    const a = project(c.a[0], c.a[1], c.a[2], [0, 0, 0]);
    const b = project(c.b[0], c.b[1], c.b[2], [0, 0, 0]);
    const w = 2 * scale * c.r;
    ctx.lineCap = 'round';
    ctx.strokeStyle = 'rgb(80, 88, 110)';
    ctx.lineWidth = w + 2;
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
    ctx.strokeStyle = 'rgba(170, 178, 200, 1)';
    ctx.lineWidth = w;
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
    ctx.lineCap = 'butt';
  }

  function drawGoal(x, y, r) {
    ctx.strokeStyle = 'rgb(200, 30, 30)';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.moveTo(x - 1.6 * r, y); ctx.lineTo(x + 1.6 * r, y);
    ctx.moveTo(x, y - 1.6 * r); ctx.lineTo(x, y + 1.6 * r);
    ctx.stroke();
  }

  function drawAxes() {
    const o = [46, height - 40];
    const names = ['x', 'y', 'z'];
    const colours = ['rgb(200,40,40)', 'rgb(40,150,40)', 'rgb(40,70,200)'];
    ctx.font = '11px sans-serif';
    for (let k = 0; k < 3; k++) {
      const dx = 26 * right[k], dy = -26 * up[k];
      ctx.strokeStyle = colours[k];
      ctx.fillStyle = colours[k];
      ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(o[0] + dx, o[1] + dy); ctx.stroke();
      ctx.fillText(names[k], o[0] + 1.2 * dx - 3, o[1] + 1.2 * dy + 4);
    }
  }

  // A path corner at (x, y), pushed half a pixel away from (cx, cy).
  function growTo(x, y, cx, cy) {
    const dx = x - cx, dy = y - cy;
    const grow = 0.5 / (Math.sqrt(dx * dx + dy * dy) || 1);
    ctx.lineTo(x + dx * grow, y + dy * grow);
  }

  // Draws shown frame f. Returns the strain range drawn, for the caption.
  function draw(f) {
    setBasis();
    ctx.fillStyle = BACKGROUND;
    ctx.fillRect(0, 0, width, height);
    const base = f * nPoints * 3;
    // Every point projected once.
    const sx = new Float32Array(nPoints), sy = new Float32Array(nPoints), sz = new Float32Array(nPoints);
    const tmp = [0, 0, 0];
    for (let i = 0; i < nPoints; i++) {
      project(points[base + 3 * i], points[base + 3 * i + 1], points[base + 3 * i + 2], tmp);
      sx[i] = tmp[0]; sy[i] = tmp[1]; sz[i] = tmp[2];
    }
    // Math.hypot is several times slower than the square root in V8, and these run for
    // every triangle edge and spring of every frame drawn.
    function dist(i, j) {
      const a = base + 3 * i, b = base + 3 * j;
      const dx = points[a] - points[b], dy = points[a + 1] - points[b + 1], dz = points[a + 2] - points[b + 2];
      return Math.sqrt(dx * dx + dy * dy + dz * dz);
    }
    const colliders = data.colliders.length === 1 ? data.colliders[0] : data.colliders[f];

    // Half-spaces lie behind everything else.
    for (const c of colliders) if (c.k === 'plane') drawPlane(c);

    // Target path: a thin line under the moving parts.
    if (path.length >= 6) {
      ctx.strokeStyle = 'rgba(40, 90, 200, 0.55)';
      ctx.lineWidth = 1.2;
      ctx.beginPath();
      for (let i = 0; i < path.length; i += 3) {
        project(path[i], path[i + 1], path[i + 2], tmp);
        if (i === 0) ctx.moveTo(tmp[0], tmp[1]); else ctx.lineTo(tmp[0], tmp[1]);
      }
      ctx.stroke();
    }

    // Each effector's trail over the last 60 shown frames, so tracking can be seen.
    ctx.strokeStyle = 'rgba(240, 140, 20, 0.7)';
    ctx.lineWidth = 1.5;
    for (const e of data.effectors) {
      ctx.beginPath();
      for (let g = Math.max(0, f - 60); g <= f; g++) {
        const o = (g * nPoints + e) * 3;
        project(points[o], points[o + 1], points[o + 2], tmp);
        if (g === Math.max(0, f - 60)) ctx.moveTo(tmp[0], tmp[1]); else ctx.lineTo(tmp[0], tmp[1]);
      }
      ctx.stroke();
    }

    // Everything with depth, sorted far to near. Items live in flat arrays (kind, index,
    // depth, colour) rather than objects: a 101 x 101 cloth has 20 000 triangles a frame.
    const nTris = tris.length / 3, nSegs = segs.length / 2;
    const count = nTris + nSegs + colliders.length;
    const kind = new Uint8Array(count), index = new Uint32Array(count);
    const depth = new Float64Array(count), colour = new Array(count);
    let n = 0;
    let strainLo = Infinity, strainHi = -Infinity;
    for (let q = 0; q < nTris; q++) {
      const t = 3 * q, i = tris[t], j = tris[t + 1], k = tris[t + 2];
      let strain = 0;
      for (let e = 0; e < 3; e++) {
        const a = tris[t + e], b = tris[t + (e + 1) % 3];
        strain += dist(a, b) / triRest[t + e] - 1;
      }
      strain /= 3;
      strainLo = Math.min(strainLo, strain); strainHi = Math.max(strainHi, strain);
      // Two-sided Lambert shading with the light at the camera.
      const pi = base + 3 * i, pj = base + 3 * j, pk = base + 3 * k;
      const ux = points[pj] - points[pi], uy = points[pj + 1] - points[pi + 1], uz = points[pj + 2] - points[pi + 2];
      const vx = points[pk] - points[pi], vy = points[pk + 1] - points[pi + 1], vz = points[pk + 2] - points[pi + 2];
      const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
      const nl = Math.sqrt(nx * nx + ny * ny + nz * nz) || 1;
      const lit = Math.abs(nx * toward[0] + ny * toward[1] + nz * toward[2]) / nl;
      kind[n] = 0; index[n] = t; depth[n] = (sz[i] + sz[j] + sz[k]) / 3;
      colour[n] = paletteColour(strain, lit);
      n++;
    }
    for (let s = 0; s < nSegs; s++) {
      const i = segs[2 * s], j = segs[2 * s + 1];
      let c = isCloth ? 'rgb(120,120,120)' : 'rgb(50,50,60)';
      if (rest.length > 0) {
        const strain = dist(i, j) / rest[s] - 1;
        strainLo = Math.min(strainLo, strain); strainHi = Math.max(strainHi, strain);
        c = paletteColour(strain, 1);
      }
      // With a surface, springs are seen through its colours; drawing them as well
      // would only hide it (and cost as much again).
      if (segOnSurface[s] || nTris > 0) continue;
      kind[n] = 1; index[n] = s; depth[n] = 0.5 * (sz[i] + sz[j]); colour[n] = c;
      n++;
    }
    for (let c = 0; c < colliders.length; c++) {
      const col = colliders[c];
      if (col.k === 'sphere') {
        kind[n] = 2; index[n] = c; depth[n] = project(col.c[0], col.c[1], col.c[2], tmp)[2]; n++;
      } else if (col.k === 'capsule') {
        const za = project(col.a[0], col.a[1], col.a[2], tmp)[2];
        const zb = project(col.b[0], col.b[1], col.b[2], tmp)[2];
        kind[n] = 3; index[n] = c; depth[n] = 0.5 * (za + zb); n++;
      }
    }
    const order = new Uint32Array(n);
    for (let m = 0; m < n; m++) order[m] = m;
    order.sort((p, q) => depth[p] - depth[q]);
    const boneWidth = isCloth ? 1 : 4;
    let lastFill = '';
    for (let m = 0; m < n; m++) {
      const it = order[m];
      if (kind[it] === 0) {
        // One fill a triangle, its corners pushed half a pixel away from its centroid:
        // it closes the hairline seams antialiasing leaves between neighbours at half
        // the cost of stroking each edge.
        const t = index[it], i = tris[t], j = tris[t + 1], k = tris[t + 2];
        const cx = (sx[i] + sx[j] + sx[k]) / 3, cy = (sy[i] + sy[j] + sy[k]) / 3;
        if (colour[it] !== lastFill) { ctx.fillStyle = colour[it]; lastFill = colour[it]; }
        ctx.beginPath();
        growTo(sx[i], sy[i], cx, cy);
        growTo(sx[j], sy[j], cx, cy);
        growTo(sx[k], sy[k], cx, cy);
        ctx.fill();
      } else if (kind[it] === 1) {
        const s = index[it];
        ctx.strokeStyle = colour[it];
        ctx.lineWidth = boneWidth;
        ctx.lineCap = 'round';
        ctx.beginPath(); ctx.moveTo(sx[segs[2 * s]], sy[segs[2 * s]]); ctx.lineTo(sx[segs[2 * s + 1]], sy[segs[2 * s + 1]]); ctx.stroke();
        ctx.lineCap = 'butt';
      } else if (kind[it] === 2) {
        drawSphere(colliders[index[it]]);
        lastFill = '';
      } else {
        drawCapsule(colliders[index[it]]);
      }
    }

    // Joints (not cloth particles, too many to mark), fixed points and effectors on top.
    if (!isCloth) {
      ctx.fillStyle = 'rgb(50,50,60)';
      for (let i = 0; i < nPoints; i++) {
        ctx.beginPath(); ctx.arc(sx[i], sy[i], 3.5, 0, 2 * Math.PI); ctx.fill();
      }
    }
    ctx.fillStyle = 'rgb(30,30,30)';
    for (const i of data.fixed) ctx.fillRect(sx[i] - 3.5, sy[i] - 3.5, 7, 7);
    ctx.fillStyle = 'rgb(240,140,20)';
    for (const i of data.effectors) {
      ctx.beginPath(); ctx.arc(sx[i], sy[i], 5, 0, 2 * Math.PI); ctx.fill();
    }
    const gbase = f * nGoals * 3;
    for (let g = 0; g < nGoals; g++) {
      project(goals[gbase + 3 * g], goals[gbase + 3 * g + 1], goals[gbase + 3 * g + 2], tmp);
      drawGoal(tmp[0], tmp[1], 6);
    }
    drawAxes();
    return [strainLo, strainHi];
  }

  // ---- Charts: each drawn once into an offscreen canvas, then the cursor on top. ----
  const chartFrames = data.chartFrames;   // null: one value per frame of the run
  const charts = data.charts.map((s) => {
    const box = document.createElement('div');
    box.className = 'chart';
    const title = document.createElement('div');
    title.className = 'title';
    const c = document.createElement('canvas');
    box.appendChild(title);
    box.appendChild(c);
    document.getElementById('charts').appendChild(box);
    const values = decodeF32(s.values);
    return { s: s, values: values, title: title, canvas: c, ctx: c.getContext('2d'), base: null };
  });
  const PAD = { left: 58, right: 10, top: 8, bottom: 22 };
  function chartX(chart, frameIndex) {
    const w = chart.w - PAD.left - PAD.right;
    return PAD.left + (total > 1 ? (frameIndex / (total - 1)) * w : 0.5 * w);
  }
  // Index into the chart's values of the sample nearest to original frame k.
  function chartSample(k) {
    if (!chartFrames) return k;
    let a = 0, b = chartFrames.length - 1;
    while (b - a > 1) { const m = (a + b) >> 1; if (chartFrames[m] <= k) a = m; else b = m; }
    return k - chartFrames[a] <= chartFrames[b] - k ? a : b;
  }
  function axisValue(chart, v) {
    if (!chart.s.log) return v;
    return v > 0 ? Math.log10(v) : chart.floor;
  }
  function formatValue(v) {
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(2);
    return String(Number(v.toPrecision(4)));
  }
  function layoutCharts() {
    for (const chart of charts) {
      const cssWidth = Math.max(260, chart.canvas.clientWidth || 340);
      const cssHeight = 150;
      const dpr = window.devicePixelRatio || 1;
      chart.canvas.width = Math.round(cssWidth * dpr);
      chart.canvas.height = Math.round(cssHeight * dpr);
      chart.canvas.style.height = cssHeight + 'px';
      chart.w = cssWidth; chart.h = cssHeight; chart.dpr = dpr;
      const off = document.createElement('canvas');
      off.width = chart.canvas.width; off.height = chart.canvas.height;
      const g = off.getContext('2d');
      g.setTransform(dpr, 0, 0, dpr, 0, 0);
      const vals = chart.values;
      let positiveMin = Infinity;
      for (const v of vals) if (v > 0) positiveMin = Math.min(positiveMin, v);
      chart.floor = isFinite(positiveMin) ? Math.log10(positiveMin) : 0;
      let lo = Infinity, hi = -Infinity;
      for (const v of vals) { const y = axisValue(chart, v); lo = Math.min(lo, y); hi = Math.max(hi, y); }
      if (!(hi > lo)) { lo -= 0.5; hi += 0.5; }
      chart.lo = lo; chart.hi = hi;
      const plotH = cssHeight - PAD.top - PAD.bottom;
      chart.yOf = (y) => PAD.top + (1 - (y - lo) / (hi - lo)) * plotH;
      g.fillStyle = '#fff';
      g.fillRect(0, 0, cssWidth, cssHeight);
      g.strokeStyle = '#bbb';
      g.lineWidth = 1;
      g.strokeRect(PAD.left, PAD.top, cssWidth - PAD.left - PAD.right, plotH);
      g.fillStyle = '#444';
      g.font = '11px sans-serif';
      g.textAlign = 'right';
      for (let k = 0; k <= 2; k++) {
        const y = lo + (k / 2) * (hi - lo);
        const label = formatValue(chart.s.log ? Math.pow(10, y) : y);
        g.fillText(label, PAD.left - 4, chart.yOf(y) + 4);
      }
      g.textAlign = 'left';
      g.fillText('frame 1', PAD.left, cssHeight - 6);
      g.textAlign = 'right';
      g.fillText('frame ' + total, cssWidth - PAD.right, cssHeight - 6);
      g.strokeStyle = 'rgb(40, 90, 200)';
      g.lineWidth = 1.5;
      g.beginPath();
      for (let k = 0; k < vals.length; k++) {
        const x = chartX(chart, chartFrames ? chartFrames[k] : k);
        const y = chart.yOf(axisValue(chart, vals[k]));
        if (k === 0) g.moveTo(x, y); else g.lineTo(x, y);
      }
      g.stroke();
      chart.base = off;
    }
  }
  function drawCharts() {
    const k = shown[current];
    for (const chart of charts) {
      const g = chart.ctx;
      g.setTransform(1, 0, 0, 1, 0, 0);
      g.drawImage(chart.base, 0, 0);
      g.setTransform(chart.dpr, 0, 0, chart.dpr, 0, 0);
      const x = chartX(chart, k);
      const v = chart.values[chartSample(k)];
      g.strokeStyle = 'rgb(200, 30, 30)';
      g.lineWidth = 1;
      g.beginPath(); g.moveTo(x, PAD.top); g.lineTo(x, chart.h - PAD.bottom); g.stroke();
      g.fillStyle = 'rgb(200, 30, 30)';
      g.beginPath(); g.arc(x, chart.yOf(axisValue(chart, v)), 3, 0, 2 * Math.PI); g.fill();
      const unit = chart.s.unit ? ' ' + chart.s.unit : '';
      chart.title.textContent = chart.s.name + ': ' + formatValue(v) + unit + ' at frame ' + (k + 1) +
        (chart.s.log ? ' (log scale)' : '');
    }
  }
  // The shown frame nearest to original frame k.
  function nearestShown(k) {
    let a = 0, b = nShown - 1;
    while (b - a > 1) { const m = (a + b) >> 1; if (shown[m] <= k) a = m; else b = m; }
    return k - shown[a] <= shown[b] - k ? a : b;
  }
  for (const chart of charts) {
    chart.canvas.addEventListener('click', (ev) => {
      const rect = chart.canvas.getBoundingClientRect();
      const x = ev.clientX - rect.left;
      const w = chart.w - PAD.left - PAD.right;
      const frac = Math.max(0, Math.min(1, (x - PAD.left) / w));
      stop();
      setFrame(nearestShown(Math.round(frac * (total - 1))));
    });
  }

  // ---- Frame changes, playback ----
  let lastDrawMs = 0;
  function render() {
    const started = performance.now();
    const range = draw(current);
    lastDrawMs = performance.now() - started;
    const k = shown[current];
    let text = 'frame ' + (k + 1) + ' of ' + total + '  t = ' + times[current].toFixed(3) + ' s';
    if (hasStrain && isFinite(range[0])) {
      text += '  strain ' + formatValue(range[0]) + ' .. ' + formatValue(range[1]);
    }
    caption.textContent = text;
    frameLabel.textContent = (current + 1) + ' / ' + nShown + ' shown';
    drawCharts();
  }
  function setFrame(f) {
    current = Math.max(0, Math.min(nShown - 1, f));
    slider.value = String(current);
    render();
  }
  slider.addEventListener('input', () => { stop(); setFrame(Number(slider.value)); });

  // Playback runs at 30 frames of the original run per second times the speed, so its
  // pace does not depend on how many frames the page keeps; it loops at the end.
  let playing = false, position = 0, lastTime = 0;
  function tick(now) {
    if (!playing) return;
    const dt = Math.min(0.25, (now - lastTime) / 1000);
    lastTime = now;
    position += 30 * Number(speedSelect.value) * dt;
    if (position > shown[nShown - 1]) position = 0;
    let f = nearestShown(Math.floor(position));
    if (shown[f] > position && f > 0) f -= 1;
    if (f !== current) setFrame(f);
    requestAnimationFrame(tick);
  }
  function stop() { playing = false; playButton.textContent = 'Play'; }
  playButton.addEventListener('click', () => {
    if (playing) { stop(); return; }
    playing = true;
    playButton.textContent = 'Pause';
    position = current === nShown - 1 ? 0 : shown[current];
    lastTime = performance.now();
    requestAnimationFrame(tick);
  });

  // Keys: arrows step one shown frame, Home and End jump to the ends, space plays.
  // The slider handles its own arrows when it has the focus, so those are left to it.
  document.addEventListener('keydown', (ev) => {
    if (ev.target === slider || ev.target === speedSelect || ev.altKey || ev.ctrlKey || ev.metaKey) return;
    // A focused button already answers the space bar itself.
    if (ev.key === ' ' && ev.target.tagName === 'BUTTON') return;
    const step = { ArrowLeft: -1, ArrowRight: 1 }[ev.key];
    if (step) setFrame(current + step);
    else if (ev.key === 'Home') setFrame(0);
    else if (ev.key === 'End') setFrame(nShown - 1);
    else if (ev.key === ' ') playButton.click();
    else return;
    if (ev.key !== ' ') stop();
    ev.preventDefault();
  });

  // ---- Orbit, pan, zoom ----
  let drag = null;
  canvas.addEventListener('contextmenu', (ev) => ev.preventDefault());
  canvas.addEventListener('pointerdown', (ev) => {
    drag = { x: ev.clientX, y: ev.clientY, pan: ev.shiftKey || ev.button === 2 };
    canvas.setPointerCapture(ev.pointerId);
    canvas.classList.add('dragging');
  });
  canvas.addEventListener('pointermove', (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    drag.x = ev.clientX; drag.y = ev.clientY;
    if (drag.pan) {
      cam.panX += dx; cam.panY += dy;
    } else {
      cam.yaw -= 0.01 * dx;
      // Elevation stays short of the poles, where "up" on screen would flip.
      cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + 0.01 * dy));
    }
    render();
  });
  const endDrag = () => { drag = null; canvas.classList.remove('dragging'); };
  canvas.addEventListener('pointerup', endDrag);
  canvas.addEventListener('pointercancel', endDrag);
  canvas.addEventListener('wheel', (ev) => {
    ev.preventDefault();
    cam.zoom = Math.max(0.05, Math.min(50, cam.zoom * Math.exp(-0.0015 * ev.deltaY)));
    render();
  }, { passive: false });
  canvas.addEventListener('dblclick', () => { Object.assign(cam, home); render(); });

  if (hasStrain) {
    legend.innerHTML = 'strain <span>-' + formatValue(strainScale) + '</span><span class="bar"></span><span>+' +
      formatValue(strainScale) + '</span>';
  }
  window.addEventListener('resize', () => { resize(); layoutCharts(); render(); });
  resize();
  layoutCharts();
  setFrame(0);
  // Read by tests that drive the page from outside.
  window.sinewViewer = {
    ready: true, shownFrames: nShown, totalFrames: total, setFrame: setFrame,
    lastDrawMs: () => lastDrawMs,
  };
})();
