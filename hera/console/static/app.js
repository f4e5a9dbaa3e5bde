// Hera's live web view: polls /api/poll about four times a second and draws the cluster,
// the applications' views and the chosen streams on canvases. No library, no build step.
"use strict";

const POLL_MS = 250;
const WINDOW_S = 30;
const TRAIL = 60;
const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf",
  "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"];

// What the tests read: how many polls, points (buckets) received per stream, when the
// first points came.
const hera = window.hera = {
  opened: performance.now(), polls: 0, errors: 0, firstPointsMs: null,
  points: {}, selected: [], streams: [], lastPoll: null,
};

const series = new Map();  // stream -> Map(bucket index -> point)
const trails = new Map();  // panel title -> Map(label -> [[x, y], ...])
let streamInfo = new Map();
let bucketS = 0.1;
let serverTime = null;
let chosenByUser = null;   // null: the default choice

const $ = (id) => document.getElementById(id);
const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", "\"": "&quot;"})[c]);
const fmt = (v) => (v === null || v === undefined || !isFinite(v)) ? "-" :
  (Math.abs(v) >= 1000 || (Math.abs(v) < 0.01 && v !== 0) ? v.toExponential(2) : v.toPrecision(4));
const clock = (t) => new Date(t * 1000).toLocaleTimeString([], {hour12: false});

// -- choosing streams ---------------------------------------------------------------------
function initialChoice() {
  const q = new URLSearchParams(location.search).get("streams");
  if (q) chosenByUser = new Set(q.split(",").filter(Boolean));
}

function defaultChoice(streams) {
  // the models of one node (the first that has any), else the first few streams
  const models = streams.filter((s) => s.model);
  if (models.length) {
    const node = models.map((s) => s.node).sort()[0];
    return models.filter((s) => s.node === node).map((s) => s.stream).slice(0, 8);
  }
  return streams.slice(0, 6).map((s) => s.stream);
}

function selected() {
  if (chosenByUser) return [...chosenByUser];
  return defaultChoice(hera.streams);
}

function renderPicker() {
  const list = $("stream-list");
  const filter = $("filter").value.trim().toLowerCase();
  const chosen = new Set(selected());
  const known = new Set([...list.querySelectorAll("input")].map((i) => i.value));
  const wanted = hera.streams.filter((s) => !filter || s.stream.toLowerCase().includes(filter) ||
    s.label.toLowerCase().includes(filter));
  if (wanted.length !== known.size || wanted.some((s) => !known.has(s.stream))) {
    list.innerHTML = wanted.map((s) =>
      `<label title="${esc(s.columns.join(", "))}"><input type="checkbox" value="${esc(s.stream)}">` +
      ` ${esc(s.label)}/${esc(s.node)} <span class="meta">${fmt(s.rate_hz)} Hz</span></label>`).join("");
  }
  for (const box of list.querySelectorAll("input")) box.checked = chosen.has(box.value);
  $("chosen-count").textContent = chosen.size;
}

function onPick(ev) {
  if (ev.target.type !== "checkbox") return;
  const chosen = new Set(selected());
  if (ev.target.checked) chosen.add(ev.target.value); else chosen.delete(ev.target.value);
  chosenByUser = chosen;
  const q = new URLSearchParams(location.search);
  q.set("streams", [...chosen].join(","));
  history.replaceState(null, "", "?" + q.toString());
  poll(true);
}

// -- polling ------------------------------------------------------------------------------
let inFlight = false;
let timer = null;

async function poll(now) {
  if (inFlight) return;
  if (now && timer) clearTimeout(timer);
  inFlight = true;
  const wanted = selected();
  let since = null;
  for (const s of wanted) {
    const pts = series.get(s);
    if (!pts || pts.size === 0) { since = null; break; }
    const last = Math.max(...pts.keys()) * bucketS;
    since = since === null ? last : Math.min(since, last);
  }
  const url = "/api/poll?streams=" + encodeURIComponent(wanted.join(",")) +
    (since === null ? "" : "&since=" + since.toFixed(3));
  try {
    const res = await fetch(url, {cache: "no-store"});
    if (!res.ok) throw new Error(res.status + " " + res.statusText);
    const body = await res.json();
    hera.polls += 1;
    hera.lastPoll = body;
    update(body, wanted);
    $("live").className = "ok";
    $("live").textContent = "live";
    document.body.classList.remove("stale");
    hera.lastAnswer = Date.now() / 1000;
  } catch (e) {
    hera.errors += 1;
    $("live").className = "stale";
    $("live").textContent = "no answer from the view server";
    // what is on the page is from the last answer: greyed, and the summary says since when
    // (the cluster may be gone: a stopped hera up takes its view server with it)
    document.body.classList.add("stale");
    if (hera.lastAnswer) {
      $("summary").textContent = `no answer since ${clock(hera.lastAnswer)}: ` +
        "the nodes and plots below are as they were then";
    }
  } finally {
    inFlight = false;
    timer = setTimeout(poll, POLL_MS);
  }
}

function update(body, wanted) {
  bucketS = body.bucket_s;
  serverTime = body.time;
  hera.streams = body.streams;
  streamInfo = new Map(body.streams.map((s) => [s.stream, s]));
  for (const [stream, d] of Object.entries(body.data)) {
    let pts = series.get(stream);
    if (!pts) series.set(stream, pts = new Map());
    let fresh = 0;
    for (const p of d.points) {
      if (!pts.has(p[0])) fresh += 1;
      pts.set(p[0], p);  // the last bucket again, grown since
    }
    const oldest = Math.floor((body.time - WINDOW_S - 5) / bucketS);
    for (const k of pts.keys()) if (k < oldest) pts.delete(k);
    hera.points[stream] = (hera.points[stream] || 0) + fresh;
    if (hera.firstPointsMs === null && d.points.length) {
      hera.firstPointsMs = performance.now() - hera.opened;
    }
  }
  for (const s of [...series.keys()]) if (!wanted.includes(s)) series.delete(s);
  hera.selected = wanted;
  renderCluster(body.cluster);
  renderPicker();
  renderCharts(wanted);
  renderPanels(body.panels);
}

// -- the cluster --------------------------------------------------------------------------
function renderCluster(c) {
  document.title = `Hera: ${c.name}`;
  $("title").textContent = `Hera: ${c.name}`;
  const up = c.nodes.filter((n) => n.state === "up").length;
  $("summary").textContent = `${up}/${c.nodes.length} nodes up, view open ${Math.round(c.uptime_s)} s`;
  $("nodes").tBodies[0].innerHTML = c.nodes.map((n) => {
    const ms = Object.values(n.measures);
    const running = ms.filter((m) => m.state === "running").length;
    return `<tr data-node="${esc(n.name)}" data-state="${esc(n.state)}"><td>${esc(n.name)}</td>` +
      `<td class="state">${esc(n.state)}</td><td>${n.pid ?? "-"}</td><td>${n.restarts}</td>` +
      `<td>${n.state === "up" ? running + "/" + ms.length : "-"}</td><td>${fmt(n.rate_hz)}</td>` +
      `<td>${n.rejected}</td><td>${n.peers}</td></tr>`;
  }).join("");
  $("sync").textContent = c.sync.join(" · ");
  $("problems").textContent = c.problems.join(" ");
  $("events").innerHTML = c.events.slice().reverse().map((e) =>
    `<li data-kind="${esc(e.kind)}" data-node="${esc(e.node)}"><span class="time">${clock(e.t)}</span>` +
    `<b>${esc(e.node)}</b> ${esc(e.kind)}: ${esc(e.text)}</li>`).join("") ||
    `<li class="empty">nothing has happened yet</li>`;
}

// -- charts -------------------------------------------------------------------------------
function canvasFor(container, key, height) {
  let box = container.querySelector(`[data-key="${CSS.escape(key)}"]`);
  if (!box) {
    box = document.createElement("div");
    box.dataset.key = key;
    box.innerHTML = "<h3></h3><canvas></canvas>";
    container.appendChild(box);
  }
  const canvas = box.querySelector("canvas");
  const ratio = window.devicePixelRatio || 1;
  const width = Math.max(200, box.clientWidth);
  if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
    canvas.style.height = height + "px";
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  return {box, ctx, width, height};
}

function renderCharts(wanted) {
  const charts = $("charts");
  for (const el of [...charts.children]) if (!wanted.includes(el.dataset.key)) el.remove();
  if (!wanted.length) {
    charts.innerHTML = `<p class="empty">no stream chosen</p>`;
    return;
  }
  charts.querySelector(".empty")?.remove();
  for (const stream of wanted) drawStream(charts, stream);
}

function drawStream(charts, stream) {
  const info = streamInfo.get(stream);
  const pts = [...(series.get(stream) || new Map()).values()].sort((a, b) => a[0] - b[0]);
  const cols = info ? info.columns : (pts.length ? pts[0][3].map((_, i) => `v${i + 1}`) : []);
  const lane = 58;
  const {box, ctx, width} = canvasFor(charts, stream, Math.max(1, cols.length) * lane + 16);
  box.className = "chart";
  box.dataset.points = pts.length;
  const last = pts.length ? pts[pts.length - 1] : null;
  box.querySelector("h3").innerHTML = `${esc(info ? info.label : stream.split("/")[0])}` +
    ` <span class="meta">on ${esc(stream.split("/")[1])} · ${fmt(info ? info.rate_hz : 0)} Hz` +
    (last ? ` · ${clock(last[1])}` : " · no data yet") + "</span>";
  const t1 = serverTime || (last ? last[1] : 0);
  const t0 = t1 - WINDOW_S;
  const x = (t) => 4 + (width - 8) * (t - t0) / (t1 - t0);
  cols.forEach((col, i) => {
    const top = 4 + i * lane;
    const h = lane - 18;
    const within = pts.filter((p) => p[1] >= t0);
    let lo = Infinity, hi = -Infinity;
    for (const p of within) {
      lo = Math.min(lo, p[4][i]); hi = Math.max(hi, p[5][i]);
      if (p[6] && p[6][i] !== null) { lo = Math.min(lo, p[6][i]); hi = Math.max(hi, p[6][i]); }
    }
    if (!isFinite(lo)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-12) { lo -= 0.5; hi += 0.5; }
    const pad = 0.08 * (hi - lo);
    lo -= pad; hi += pad;
    const y = (v) => top + 12 + h * (1 - (v - lo) / (hi - lo));
    ctx.strokeStyle = "#eceef1";
    ctx.strokeRect(4, top + 12, width - 8, h);
    const color = COLORS[i % COLORS.length];
    // envelope (min .. max of each bucket)
    ctx.fillStyle = color + "22";
    ctx.beginPath();
    within.forEach((p, k) => k ? ctx.lineTo(x(p[1]), y(p[5][i])) : ctx.moveTo(x(p[1]), y(p[5][i])));
    for (let k = within.length - 1; k >= 0; k--) ctx.lineTo(x(within[k][1]), y(within[k][4][i]));
    ctx.fill();
    // truth, dashed, under the mean
    const truth = within.filter((p) => p[6] && p[6][i] !== null);
    if (truth.length) {
      ctx.strokeStyle = "#444"; ctx.setLineDash([4, 3]); ctx.lineWidth = 1.2;
      ctx.beginPath();
      truth.forEach((p, k) => k ? ctx.lineTo(x(p[1]), y(p[6][i])) : ctx.moveTo(x(p[1]), y(p[6][i])));
      ctx.stroke(); ctx.setLineDash([]);
    }
    ctx.strokeStyle = color; ctx.lineWidth = 1.5;
    ctx.beginPath();
    let prev = null;
    for (const p of within) {
      const gap = prev !== null && p[1] - prev > Math.max(1.0, 10 * bucketS);
      gap || prev === null ? ctx.moveTo(x(p[1]), y(p[3][i])) : ctx.lineTo(x(p[1]), y(p[3][i]));
      prev = p[1];
    }
    ctx.stroke();
    const now = within.length ? within[within.length - 1] : null;
    let label = `${col}  ${now ? fmt(now[3][i]) : "-"}`;
    if (now && now[6] && now[6][i] !== null) label += `  truth ${fmt(now[6][i])}  err ${fmt(now[3][i] - now[6][i])}`;
    ctx.fillStyle = "#1d2126"; ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(label, 6, top + 10);
    tag(ctx, fmt(hi), width - 6, top + 23);
    tag(ctx, fmt(lo), width - 6, top + 12 + h - 3);
  });
}

function tag(ctx, text, right, baseline) {
  // a scale label on a light background, right-aligned at ``right``
  const w = ctx.measureText(text).width;
  ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
  ctx.fillRect(right - w - 3, baseline - 10, w + 4, 13);
  ctx.fillStyle = "#69707a";
  ctx.fillText(text, right - w - 1, baseline);
}

// -- the applications' views --------------------------------------------------------------
function renderPanels(panels) {
  const box = $("panels");
  const titles = panels.map((p) => p.title);
  for (const el of [...box.children]) if (!titles.includes(el.dataset.key)) el.remove();
  if (!panels.length) {
    box.innerHTML = `<p class="empty">no application view for this cluster</p>`;
    return;
  }
  box.querySelector(".empty")?.remove();
  for (const p of panels) {
    if (p.kind === "plane") drawPlane(box, p);
    else if (p.kind === "attitude") drawAttitude(box, p);
    else if (p.kind === "grid") drawGrid(box, p);
    else {
      const {box: el} = canvasFor(box, p.title, 20);
      el.querySelector("h3").textContent = p.title;
    }
  }
}

function colorOf(labels, label) {
  const i = labels.indexOf(label);
  return COLORS[(i < 0 ? 0 : i) % COLORS.length];
}

const PLANE_MIN_SPAN = 0.5;  // m: a scene of a few centimetres would zoom in on the noise

function planeBounds(points, shapes, trailMap) {
  // the shapes, the points and their trails (so the scale holds while the trails last),
  // padded by a tenth, at least PLANE_MIN_SPAN wide and high
  let xs = [], ys = [];
  for (const s of shapes) {
    if (s.circle) { const [cx, cy, r] = s.circle; xs.push(cx - r, cx + r); ys.push(cy - r, cy + r); }
    if (s.line) for (const [px, py] of s.line) { xs.push(px); ys.push(py); }
  }
  for (const p of points) { xs.push(p.x); ys.push(p.y); }
  for (const t of trailMap ? trailMap.values() : []) for (const [px, py] of t) { xs.push(px); ys.push(py); }
  if (!xs.length) return [-1, 1, -1, 1];
  let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 0.1 * Math.max(x1 - x0, y1 - y0);
  [x0, x1, y0, y1] = [x0 - pad, x1 + pad, y0 - pad, y1 + pad];
  const grow = (a, b) => b - a >= PLANE_MIN_SPAN ? [a, b] : [(a + b - PLANE_MIN_SPAN) / 2, (a + b + PLANE_MIN_SPAN) / 2];
  [x0, x1] = grow(x0, x1);
  [y0, y1] = grow(y0, y1);
  return [x0, x1, y0, y1];
}

function drawPlane(container, panel) {
  const d = panel.data, points = d.points || [], shapes = d.shapes || [];
  const {box, ctx, width, height} = canvasFor(container, panel.title, 300);
  box.className = "panel";
  box.dataset.kind = "plane";
  box.dataset.points = points.length;
  box.querySelector("h3").textContent = panel.title;
  let tr = trails.get(panel.title);
  if (!tr) trails.set(panel.title, tr = new Map());
  for (const p of points) {
    const t = tr.get(p.label) || [];
    const lastP = t[t.length - 1];
    if (!lastP || lastP[0] !== p.x || lastP[1] !== p.y) t.push([p.x, p.y]);
    while (t.length > TRAIL) t.shift();
    tr.set(p.label, t);
  }
  const [x0, x1, y0, y1] = planeBounds(points, shapes, tr);
  box.dataset.bounds = [x0, x1, y0, y1].map((v) => v.toFixed(3)).join(",");
  const per = width < 480 ? 2 : 3;
  const legend = 16 * Math.ceil(points.length / per);
  const s = Math.min((width - 8) / (x1 - x0), (height - 8 - legend) / (y1 - y0));
  const ox = (width - s * (x1 - x0)) / 2, oy = (height - legend - s * (y1 - y0)) / 2;
  const X = (v) => ox + s * (v - x0), Y = (v) => oy + s * (y1 - v);
  ctx.strokeStyle = "#9aa0a8"; ctx.lineWidth = 1;
  for (const sh of shapes) {
    ctx.beginPath();
    if (sh.circle) ctx.arc(X(sh.circle[0]), Y(sh.circle[1]), s * sh.circle[2], 0, 2 * Math.PI);
    if (sh.line) sh.line.forEach(([px, py], k) => k ? ctx.lineTo(X(px), Y(py)) : ctx.moveTo(X(px), Y(py)));
    ctx.stroke();
  }
  const labels = points.filter((p) => !p.truth).map((p) => p.label);
  for (const p of points) {
    const color = p.truth ? "#111" : colorOf(labels, p.label);
    const t = tr.get(p.label) || [];
    ctx.strokeStyle = color + "66"; ctx.lineWidth = 1;
    ctx.beginPath();
    t.forEach(([px, py], k) => k ? ctx.lineTo(X(px), Y(py)) : ctx.moveTo(X(px), Y(py)));
    ctx.stroke();
    ctx.fillStyle = color;
    ctx.beginPath();
    ctx.arc(X(p.x), Y(p.y), p.truth ? 6 : 4, 0, 2 * Math.PI);
    p.truth ? (ctx.lineWidth = 2, ctx.strokeStyle = color, ctx.stroke()) : ctx.fill();
    if (p.heading !== undefined && p.heading !== null) {
      ctx.beginPath(); ctx.strokeStyle = color; ctx.lineWidth = 1.5;
      ctx.moveTo(X(p.x), Y(p.y));
      ctx.lineTo(X(p.x) + 14 * Math.cos(p.heading), Y(p.y) - 14 * Math.sin(p.heading));
      ctx.stroke();
    }
  }
  ctx.font = "11px system-ui, sans-serif";
  points.forEach((p, k) => {
    const col = k % per, row = Math.floor(k / per);
    const lx = 6 + col * (width / per), ly = height - legend + 12 + 16 * row;
    ctx.fillStyle = p.truth ? "#111" : colorOf(labels, p.label);
    ctx.fillRect(lx, ly - 8, 8, 8);
    ctx.fillStyle = "#1d2126";
    ctx.fillText(p.label, lx + 12, ly);
  });
}

function drawAttitude(container, panel) {
  // one row per body: an artificial horizon (roll, pitch), a compass (yaw), the numbers
  const bodies = panel.data.bodies || [];
  const row = 112;
  const {box, ctx, width} = canvasFor(container, panel.title, row * Math.max(1, bodies.length));
  box.className = "panel";
  box.dataset.kind = "attitude";
  box.dataset.points = bodies.length;
  box.querySelector("h3").textContent = panel.title;
  const r = Math.min(44, width / 6);
  const deg = (v) => (v * 180 / Math.PI).toFixed(1);
  // yaw turns counter-clockwise about the world's up axis from its x axis; the compass
  // shows the heading, clockwise from north (north: the world's angle of it, +y by default)
  const north = typeof panel.data.north === "number" ? panel.data.north : Math.PI / 2;
  const heading = (b) => {
    const h = (north - b.yaw) % (2 * Math.PI);
    return h < 0 ? h + 2 * Math.PI : h;
  };
  box.dataset.headings = bodies.map((b) => deg(heading(b))).join(",");
  bodies.forEach((b, k) => {
    const cy = row * k + r + 6, hx = r + 6, cx = 3 * r + 16;
    const color = b.truth ? "#111" : COLORS[k % COLORS.length];
    ctx.save();
    ctx.beginPath(); ctx.arc(hx, cy, r, 0, 2 * Math.PI); ctx.clip();
    ctx.translate(hx, cy); ctx.rotate(-b.roll);
    const shift = r * Math.max(-1, Math.min(1, b.pitch / (Math.PI / 2)));
    ctx.fillStyle = "#9cc3e6"; ctx.fillRect(-2 * r, -2 * r + shift, 4 * r, 2 * r);
    ctx.fillStyle = "#c9a77c"; ctx.fillRect(-2 * r, shift, 4 * r, 2 * r);
    ctx.restore();
    ctx.strokeStyle = "#333"; ctx.lineWidth = 1;
    ctx.beginPath(); ctx.moveTo(hx - r / 2, cy); ctx.lineTo(hx + r / 2, cy); ctx.stroke();
    ctx.beginPath(); ctx.arc(hx, cy, r, 0, 2 * Math.PI); ctx.stroke();
    ctx.beginPath(); ctx.arc(cx, cy, r, 0, 2 * Math.PI); ctx.stroke();
    ctx.fillStyle = "#69707a"; ctx.font = "10px system-ui, sans-serif";
    ctx.fillText("N", cx - 3, cy - r + 11);
    ctx.beginPath(); ctx.moveTo(cx, cy);
    const h = heading(b);
    ctx.lineTo(cx + (r - 6) * Math.sin(h), cy - (r - 6) * Math.cos(h));
    ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.stroke(); ctx.lineWidth = 1;
    ctx.fillStyle = color; ctx.font = "12px system-ui, sans-serif";
    const tx = cx + r + 12;
    ctx.fillText(b.label, tx, cy - 28);
    ctx.fillStyle = "#1d2126"; ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(`roll ${deg(b.roll)} deg`, tx, cy - 12);
    ctx.fillText(`pitch ${deg(b.pitch)} deg`, tx, cy + 3);
    ctx.fillText(`yaw ${deg(b.yaw)} deg`, tx, cy + 18);
    ctx.fillText(`heading ${deg(h)}\u00b0`, tx, cy + 33);
  });
}

function drawGrid(container, panel) {
  const d = panel.data, rows = d.values || [];
  const {box, ctx, width, height} = canvasFor(container, panel.title, 300);
  box.className = "panel";
  box.dataset.kind = "grid";
  box.dataset.points = rows.length;
  box.querySelector("h3").textContent = panel.title;
  const nr = rows.length, nc = nr ? rows[0].length : 0;
  if (!nr || !nc) return;
  const flat = rows.flat().filter((v) => v !== null && isFinite(v));
  const lo = d.min ?? Math.min(...flat), hi = d.max ?? Math.max(...flat);
  const cell = Math.min((width - 8) / nc, (height - 8) / nr);
  for (let i = 0; i < nr; i++) for (let j = 0; j < nc; j++) {
    const v = rows[i][j];
    if (v === null || !isFinite(v)) { ctx.fillStyle = "#eee"; } else {
      const a = hi > lo ? (v - lo) / (hi - lo) : 0.5;
      ctx.fillStyle = `hsl(${(1 - Math.max(0, Math.min(1, a))) * 240}, 70%, 50%)`;
    }
    ctx.fillRect(4 + j * cell, 4 + (nr - 1 - i) * cell, Math.ceil(cell), Math.ceil(cell));
  }
  const [gx, gy] = d.origin || [0, 0], size = d.cell || 1;
  ctx.fillStyle = "#111";
  for (const p of d.points || []) {
    ctx.beginPath();
    ctx.arc(4 + (p.x - gx) / size * cell, 4 + (nr - (p.y - gy) / size) * cell, 4, 0, 2 * Math.PI);
    ctx.fill();
  }
}

// -- start ----------------------------------------------------------------------------------
initialChoice();
$("stream-list").addEventListener("change", onPick);
$("filter").addEventListener("input", renderPicker);
poll(true);
