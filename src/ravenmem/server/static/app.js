// The ravenmem page: a map of where the robot went, search, ask, and live updates, for an operator:
// a time scrubber (the memories up to a time), a click on the map lists the memories nearest that
// spot (the position tool), and new frames appear in a panel as the robot adds them.
// Plain JS, no build step, nothing fetched from outside this service. With a token the service
// needs `Authorization: Bearer`: the page takes it from the URL fragment (#token=...) or the
// token box, keeps it in sessionStorage, and sends it on every call (pictures included, which
// are fetched and shown as blob URLs for that reason).
"use strict";

const state = {
  token: sessionStorage.getItem("ravenmem-token") || "",
  points: [],          // [id, t, x, y, yaw], chronological
  hits: [],            // last search results
  answer: null,        // last answer {x, y, yaw}
  live: [],            // ids added live (newest last)
  view: null,          // {cx, cy, scale} world centre and pixels per metre
  map: null,           // the occupancy map: {extent: [xmin, ymin, xmax, ymax], img}
  t0: null,
  until: null,         // the scrubber's time (Unix s): memories after it are not shown; null = all
  probe: null,         // the last map click {x, y} that ran the position tool
  mapId: null,         // the map the poses are in (/info map_id)
  mapName: "map",      // the header's words for it, with the poses' frame
};
const MAX_FRAMES = 12;  // live frames kept in their panel
const VLM_REASON = "needs a VLM: start the service with --model and --base-url (or RAVENMEM_VLM_*)";
const $ = (id) => document.getElementById(id);
const SVG = "http://www.w3.org/2000/svg";

// ------------------------------------------------------------------ talking to the service
function headers(extra) {
  const h = Object.assign({}, extra || {});
  if (state.token) h["Authorization"] = "Bearer " + state.token;
  return h;
}

async function api(path, options) {
  const opts = Object.assign({}, options || {});
  opts.headers = headers(opts.headers);
  const r = await fetch(path, opts);
  if (r.status === 401) {
    $("token-box").hidden = false;
    throw new Error("this memory needs a token");
  }
  let body = null;
  try { body = await r.json(); } catch (e) { body = null; }
  if (!r.ok) throw new Error((body && body.error) || ("HTTP " + r.status));
  return body;
}

const imageCache = new Map();
async function imageSrc(url) {
  if (!url) return "";
  if (imageCache.has(url)) return imageCache.get(url);
  const r = await fetch(url, { headers: headers() });
  if (!r.ok) return "";
  const src = URL.createObjectURL(await r.blob());
  imageCache.set(url, src);
  return src;
}

function say(text, isError) {
  const s = $("status");
  s.textContent = text || "";
  s.style.color = isError ? "#ff8a80" : "";
}

// ------------------------------------------------------------------ the map
function fit() {
  const pts = state.points;
  const xs = pts.map((p) => p[2]).concat(state.hits.map((h) => h.x));
  const ys = pts.map((p) => p[3]).concat(state.hits.map((h) => h.y));
  if (state.answer) { xs.push(state.answer.x); ys.push(state.answer.y); }
  if (!xs.length && state.map) {
    const e = state.map.extent; xs.push(e[0], e[2]); ys.push(e[1], e[3]);
  }
  const { width, height } = size();
  if (!xs.length) { state.view = { cx: 0, cy: 0, scale: 50 }; return; }
  const minx = Math.min(...xs), maxx = Math.max(...xs), miny = Math.min(...ys), maxy = Math.max(...ys);
  const span = Math.max(maxx - minx, maxy - miny, 0.5);
  state.view = { cx: (minx + maxx) / 2, cy: (miny + maxy) / 2, scale: 0.85 * Math.min(width, height) / span };
}

function visible() {
  // the memories up to the scrubber's time (all of them when it is at the end)
  return state.until === null ? state.points : state.points.filter((p) => p[1] <= state.until);
}

function size() {
  const wrap = $("map-wrap");
  return { width: wrap.clientWidth, height: wrap.clientHeight };
}

function fromScreen(sx, sy) {
  const { width, height } = size();
  const v = state.view;
  return [v.cx + (sx - width / 2) / v.scale, v.cy - (sy - height / 2) / v.scale];
}

function toScreen(x, y) {
  const { width, height } = size();
  const v = state.view;
  return [width / 2 + (x - v.cx) * v.scale, height / 2 - (y - v.cy) * v.scale];
}

function draw() {
  if (!state.view) fit();
  const canvas = $("map-canvas");
  const { width, height } = size();
  const dpr = window.devicePixelRatio || 1;
  canvas.width = width * dpr; canvas.height = height * dpr;
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, width, height);
  if (state.map && state.map.img.complete && state.map.img.naturalWidth) {
    const e = state.map.extent;
    const [x0, y0] = toScreen(e[0], e[3]), [x1, y1] = toScreen(e[2], e[1]);
    ctx.imageSmoothingEnabled = false;
    ctx.globalAlpha = 0.85;
    ctx.drawImage(state.map.img, x0, y0, x1 - x0, y1 - y0);
    ctx.globalAlpha = 1;
  }
  drawGrid(ctx, width, height);
  const pts = visible();
  if (pts.length < state.points.length) {  // what comes later, faint, so the scrubbed view keeps its context
    ctx.strokeStyle = "#e0e0e0"; ctx.lineWidth = 1; ctx.beginPath();
    state.points.slice(pts.length).forEach((p, i) => {
      const [sx, sy] = toScreen(p[2], p[3]); if (i) ctx.lineTo(sx, sy); else ctx.moveTo(sx, sy);
    });
    ctx.stroke();
  }
  if (pts.length) {
    ctx.strokeStyle = "#9e9e9e"; ctx.lineWidth = 1.5; ctx.beginPath();
    pts.forEach((p, i) => { const [sx, sy] = toScreen(p[2], p[3]); if (i) ctx.lineTo(sx, sy); else ctx.moveTo(sx, sy); });
    ctx.stroke();
    ctx.fillStyle = "#546e7a";
    const step = Math.max(1, Math.floor(pts.length / 4000));
    for (let i = 0; i < pts.length; i += step) {
      const [sx, sy] = toScreen(pts[i][2], pts[i][3]);
      ctx.fillRect(sx - 1.5, sy - 1.5, 3, 3);
    }
  }
  drawMarks();
}

function drawGrid(ctx, width, height) {
  const v = state.view;
  let stepM = Math.pow(10, Math.floor(Math.log10(120 / v.scale)));
  if (stepM * v.scale < 40) stepM *= 5;
  ctx.strokeStyle = "#eceff1"; ctx.lineWidth = 1; ctx.fillStyle = "#90a4ae"; ctx.font = "10px sans-serif";
  const [x0, y1] = [v.cx - width / 2 / v.scale, v.cy + height / 2 / v.scale];
  for (let gx = Math.ceil(x0 / stepM) * stepM; gx < x0 + width / v.scale; gx += stepM) {
    const [sx] = toScreen(gx, 0); ctx.beginPath(); ctx.moveTo(sx, 0); ctx.lineTo(sx, height); ctx.stroke();
    ctx.fillText(gx.toFixed(stepM < 1 ? 1 : 0) + " m", sx + 2, height - 4);
  }
  for (let gy = Math.floor(y1 / stepM) * stepM; gy > y1 - height / v.scale; gy -= stepM) {
    const [, sy] = toScreen(0, gy); ctx.beginPath(); ctx.moveTo(0, sy); ctx.lineTo(width, sy); ctx.stroke();
    ctx.fillText(gy.toFixed(stepM < 1 ? 1 : 0) + " m", 2, sy - 2);
  }
}

function el(name, attrs, parent) {
  const e = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}

function drawMarks() {
  const svg = $("map-marks");
  svg.replaceChildren();
  const byId = new Map(state.points.map((p) => [p[0], p]));
  for (const id of state.live.slice(-5)) {
    const p = byId.get(id); if (!p || (state.until !== null && p[1] > state.until)) continue;
    const [sx, sy] = toScreen(p[2], p[3]);
    const g = el("g", { class: "live-mark", "data-id": id }, svg);
    el("circle", { cx: sx, cy: sy, r: 7 }, g);
  }
  state.hits.forEach((h) => {
    const [sx, sy] = toScreen(h.x, h.y);
    const g = el("g", { class: "hit-mark", "data-id": h.id }, svg);
    el("circle", { cx: sx, cy: sy, r: 8 }, g);
    el("text", { x: sx, y: sy }, g).textContent = h.rank;
  });
  if (state.until !== null) {  // where the robot was at the scrubber's time, and its heading
    const pts = visible();
    const p = pts[pts.length - 1];
    if (p) {
      const [sx, sy] = toScreen(p[2], p[3]);
      const g = el("g", { class: "now-mark", "data-id": p[0] }, svg);
      const yaw = p[4] || 0, r = 9;
      const tip = [sx + r * Math.cos(yaw), sy - r * Math.sin(yaw)];
      const l = [sx + r * Math.cos(yaw + 2.5), sy - r * Math.sin(yaw + 2.5)];
      const rr = [sx + r * Math.cos(yaw - 2.5), sy - r * Math.sin(yaw - 2.5)];
      el("path", { d: `M${tip} L${l} L${rr} Z` }, g);
    }
  }
  if (state.probe) {
    const [sx, sy] = toScreen(state.probe.x, state.probe.y);
    const g = el("g", { class: "probe-mark" }, svg);
    el("circle", { cx: sx, cy: sy, r: 12 }, g);
  }
  if (state.answer) {
    const a = state.answer;
    const [sx, sy] = toScreen(a.x, a.y);
    const g = el("g", { class: "answer-mark" }, svg);
    if (a.yaw !== null && a.yaw !== undefined) {
      el("line", { x1: sx, y1: sy, x2: sx + 24 * Math.cos(a.yaw), y2: sy - 24 * Math.sin(a.yaw) }, g);
    }
    el("circle", { cx: sx, cy: sy, r: 9 }, g);
  }
}

function setupMapInput() {
  const wrap = $("map-wrap");
  let drag = null, down = null, clickTimer = null;
  wrap.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; down = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", (e) => {
    drag = null;
    // a click (not a drag) on the map: the memories nearest that spot, unless it was a double-click
    if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4 && wrap.contains(e.target)) {
      const box = wrap.getBoundingClientRect();
      const [x, y] = fromScreen(e.clientX - box.left, e.clientY - box.top);
      clearTimeout(clickTimer);  // the second click of a double-click only fits the view
      if (e.detail < 2) clickTimer = setTimeout(() => searchNear(x, y), 250);
    }
    down = null;
  });
  window.addEventListener("mousemove", (e) => {
    if (!drag || !state.view) return;
    state.view.cx -= (e.clientX - drag[0]) / state.view.scale;
    state.view.cy += (e.clientY - drag[1]) / state.view.scale;
    drag = [e.clientX, e.clientY];
    draw();
  });
  wrap.addEventListener("wheel", (e) => {
    e.preventDefault();
    if (state.view) { state.view.scale *= e.deltaY < 0 ? 1.2 : 1 / 1.2; draw(); }
  }, { passive: false });
  wrap.addEventListener("dblclick", () => { clearTimeout(clickTimer); fit(); draw(); });
  window.addEventListener("resize", draw);
}

// ------------------------------------------------------------------ cards (hits and evidence)
function fmtTime(row) {
  const off = state.t0 !== null ? ` (+${(row.t - state.t0).toFixed(1)} s)` : "";
  return (row.time || new Date(row.t * 1000).toISOString()) + off;
}

function card(row, label) {
  const c = document.createElement("div");
  c.className = "card"; c.dataset.id = row.id;
  const img = document.createElement("img");
  img.alt = "memory " + row.id;
  imageSrc(row.image).then((src) => { if (src) img.src = src; });
  const yawDeg = row.yaw_deg !== undefined ? row.yaw_deg : (row.yaw * 180 / Math.PI);
  const lines = [label, fmtTime(row), `x ${row.x.toFixed(2)} y ${row.y.toFixed(2)} z ${row.z.toFixed(2)} yaw ${yawDeg.toFixed(0)}°`];
  c.appendChild(img);
  for (const text of lines) {
    const m = document.createElement("div"); m.className = "meta"; m.textContent = text; c.appendChild(m);
  }
  c.addEventListener("click", () => {
    document.querySelectorAll(".card.active").forEach((e) => e.classList.remove("active"));
    c.classList.add("active");
    if (state.view) { state.view.cx = row.x; state.view.cy = row.y; draw(); }
  });
  return c;
}

// ------------------------------------------------------------------ search and ask
function untilParams(params) {
  // searches look only at what the robot had seen by the scrubber's time
  if (state.until !== null) params.set("before", String(state.until));
  return params;
}

function showHits(rows, title, query) {
  state.hits = rows;
  $("hits-title").hidden = false;
  $("hits-title").textContent = title;
  // a text search's verdict (the rule `ask` declines by): nothing supported is said plainly
  const none = rows.length > 0 && rows.every((h) => h.supported === false);
  $("hits-note").hidden = !none;
  $("hits-note").textContent = none ? `Not found: nothing in this memory supports "${query}". ` +
    "No hit scores above what things that are not there reach; these are only the least unlike." : "";
  $("hits").replaceChildren(...rows.map((h) => {
    const how = h.distance !== null && h.distance !== undefined ? ` ${h.distance.toFixed(2)} m away`
      : h.score === null || h.score === undefined ? "" : ` score ${h.score.toFixed(3)}`;
    const c = card(h, `#${h.rank}${how}${h.ocr_match ? " (text)" : ""}${h.supported === false ? " not found" : ""}`);
    if (h.supported === false) c.classList.add("unsupported");
    return c;
  }));
}

async function search(ev) {
  ev.preventDefault();
  const q = $("q").value.trim();
  if (!q) return;
  say("searching...");
  try {
    const params = untilParams(new URLSearchParams({ query: q, k: $("k").value || "8" }));
    const data = await api("/search/text?" + params);
    state.probe = null;
    showHits(data.results, `"${q}": ${data.results.length} hit(s), best first` + untilNote(), q);
    say(`${data.results.length} hit(s) for "${q}"`);
    fit(); draw();
    reveal($("ask-form"));  // the next step: ask about it
    if (!$("question").value) $("question").value = `Where did I see ${q}?`;
  } catch (e) { say(e.message, true); }
}

async function searchNear(x, y) {
  say("searching near the spot...");
  try {
    const params = untilParams(new URLSearchParams({ x: x.toFixed(3), y: y.toFixed(3), k: $("k").value || "8" }));
    const data = await api("/search/position?" + params);
    state.probe = { x, y };
    showHits(data.results, `nearest x ${x.toFixed(2)} y ${y.toFixed(2)}: ${data.results.length} memories` + untilNote());
    say(`${data.results.length} memories near x ${x.toFixed(2)} y ${y.toFixed(2)}`);
    draw();
    reveal($("hits-title"));
  } catch (e) { say(e.message, true); }
}

function reveal(el) {
  // scrollIntoView rounds the scroll to whole pixels: a fraction may stay below the fold
  el.scrollIntoView({ block: "nearest" });
  const over = el.getBoundingClientRect().bottom - window.innerHeight;
  if (over > 0 && el.getBoundingClientRect().top - over >= 0) window.scrollBy(0, Math.ceil(over));
}

function untilNote() {
  return state.until === null ? "" : ` (up to ${new Date(state.until * 1000).toISOString()})`;
}

async function ask(ev) {
  ev.preventDefault();
  const question = $("question").value.trim();
  if (!question) return;
  say("thinking...");
  try {
    const data = await api("/ask", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ question, method: $("method").value || null }),
    });
    showAnswer(data);
    say(`answered by ${data.method} in ${data.cost.wall_s.toFixed(2)} s`);
    reveal($("answer"));
  } catch (e) { say(e.message, true); }
}

function showAnswer(a) {
  $("answer").hidden = false;
  $("answer-text").textContent = a.text || (a.found ? "found" : "not found");
  const facts = [`${a.question_type} question`, a.found ? "found" : "not found"];
  if (a.position) facts.push(`at x ${a.position[0].toFixed(2)} y ${a.position[1].toFixed(2)}` +
    (a.yaw !== null ? `, heading ${(a.yaw * 180 / Math.PI).toFixed(0)}°` : ""));
  if (a.time !== null) facts.push("seen " + new Date(a.time * 1000).toISOString());
  if (a.duration !== null) facts.push(`for ${a.duration.toFixed(1)} s`);
  if (a.error) facts.push("error: " + a.error);
  $("answer-facts").textContent = facts.join(" · ");
  $("evidence").replaceChildren(...a.evidence.map((e) => card(e, `evidence ${e.id}` +
    (e.score !== null && e.score !== undefined ? ` score ${e.score.toFixed(3)}` : ""))));
  state.answer = a.position ? { x: a.position[0], y: a.position[1], yaw: a.yaw } : null;
  fit(); draw();
}

// ------------------------------------------------------------------ live updates
function logLine(text) {
  const li = document.createElement("li");
  li.textContent = text;
  const log = $("log");
  log.prepend(li);
  while (log.children.length > 50) log.lastChild.remove();
}

function onEvent(kind, data) {
  if (kind === "hello") { $("live").className = "on"; return; }
  if (kind === "memory") {
    const m = data.memory;
    if (!state.points.length || state.points[state.points.length - 1][0] < m.id) {
      state.points.push([m.id, m.t, m.x, m.y, m.yaw]);
    }
    if (state.t0 === null) state.t0 = m.t;
    state.live.push(m.id);
    $("count").textContent = String(Number($("count").textContent || 0) + 1);
    logLine(`memory ${m.id} at x ${m.x.toFixed(2)} y ${m.y.toFixed(2)}`);
    addFrame(m);
    setScrubber();
    draw();
  } else if (kind === "skipped") {
    logLine(`frame skipped: ${data.skipped}`);
  } else if (kind === "answer") {
    logLine(`answered: ${data.answer.question} -> ${data.answer.text}`);
  }
}

function addFrame(m) {
  // the newest frames the robot added, newest first
  $("frames-empty").hidden = true;
  const box = $("frames");
  box.prepend(card(m, `live ${m.id}`));
  while (box.children.length > MAX_FRAMES) box.lastChild.remove();
}

// ------------------------------------------------------------------ the time scrubber
function span() {
  const p = state.points;
  return p.length ? [p[0][1], p[p.length - 1][1]] : [0, 0];
}

function setScrubber() {
  // keep the slider's time when it is not at the end; at the end it follows new memories
  const [t0, t1] = span(), s = $("until");
  if (state.until !== null && t1 > t0) s.value = String(Math.round(1000 * (state.until - t0) / (t1 - t0)));
  const shown = visible().length, all = state.points.length;
  const to = state.until === null ? t1 : state.until;
  $("until-label").textContent = all ? (state.until === null ? `all ${all} memories, to ` : `${shown} of ${all} memories, up to `) +
    new Date(to * 1000).toISOString() + (state.t0 !== null ? ` (+${(to - state.t0).toFixed(1)} s)` : "") : "no memories yet";
}

function onScrub() {
  const [t0, t1] = span(), v = Number($("until").value);
  state.until = v >= 1000 ? null : t0 + (t1 - t0) * v / 1000;
  setScrubber();
  draw();
}

async function listen() {
  for (let wait = 1000; ; wait = Math.min(wait * 2, 30000)) {
    try {
      const r = await fetch("/events", { headers: headers() });
      if (r.ok && r.body) {
        wait = 1000;
        const reader = r.body.getReader();
        const dec = new TextDecoder();
        let buf = "";
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          buf += dec.decode(value, { stream: true });
          let cut;
          while ((cut = buf.indexOf("\n\n")) >= 0) {
            const block = buf.slice(0, cut); buf = buf.slice(cut + 2);
            let kind = "message", data = "";
            for (const line of block.split("\n")) {
              if (line.startsWith("event: ")) kind = line.slice(7);
              else if (line.startsWith("data: ")) data += line.slice(6);
            }
            if (data) onEvent(kind, JSON.parse(data));
          }
        }
      } else if (r.status === 401) {
        $("token-box").hidden = false;
      }
    } catch (e) { /* reconnect below */ }
    $("live").className = "off";
    await new Promise((res) => setTimeout(res, wait));
  }
}

// ------------------------------------------------------------------ start
async function load() {
  const info = await api("/info");
  $("memory-name").textContent = info.name || info.path;
  $("memory-name").title = `folder ${info.path}; ravenmem name --memory ... NAME sets the name`;
  document.title = `${info.name || info.path} - ravenmem`;
  $("count").textContent = String(info.memories);
  state.t0 = info.t_min !== undefined ? info.t_min : null;
  // the map the poses are in (`ravenmem ingest --map-id`, `ravenmem align`), and its frame
  state.mapId = info.map_id || null;
  state.mapName = info.map_id ? `map ${info.map_id} (frame ${info.frame_id || "map"})` : "map";
  // methods that need a VLM are shown, disabled with the reason, when the service has none
  const needs = new Set(info.ask.needs_vlm || []), noVlm = !info.ask.vlm;
  const methods = $("method");
  methods.replaceChildren(...info.ask.methods.map((m) => {
    const o = document.createElement("option"); o.value = m;
    o.disabled = noVlm && needs.has(m);
    o.textContent = o.disabled ? `${m} (needs a VLM)` : m;
    o.title = o.disabled ? `${m} ${VLM_REASON}` : "";
    o.selected = m === info.ask.default_method; return o;
  }));
  const off = info.ask.methods.filter((m) => noVlm && needs.has(m));
  $("method-note").hidden = !off.length;
  $("method-note").textContent = off.length ? `${off.join(", ")}: ${VLM_REASON}.` : "";
  const traj = await api("/trajectory");
  state.points = traj.points;
  setScrubber();
  fit(); draw();
  if (info.has_map) loadMap(); else showNoMap();  // never a /map request that can only 404
}

function showNoMap() {
  state.map = null;
  $("map-id").hidden = state.mapName === "map";
  $("map-id").textContent = `${state.mapName}, no occupancy map`;
}

async function loadMap() {
  try {
    const m = await api("/map");
    const img = new Image();
    img.onload = draw;
    img.src = await imageSrc(m.image);
    state.map = { extent: m.extent, img };
    const env = m.env && m.env !== state.mapId ? m.env + ", " : "";
    $("map-id").hidden = false;
    $("map-id").textContent = `${state.mapName}: ${env}${m.kind || "occupancy"}, ${m.resolution} m cells`;
  } catch (e) {  // the map went away since /info: its identity is still shown
    showNoMap();
  }
}

function takeToken() {
  const m = /(?:^|[#&])token=([^&]+)/.exec(location.hash);
  if (m) {
    state.token = decodeURIComponent(m[1]);
    sessionStorage.setItem("ravenmem-token", state.token);
    history.replaceState(null, "", location.pathname + location.search);
  }
}

async function main() {
  takeToken();
  setupMapInput();
  $("search-form").addEventListener("submit", search);
  $("ask-form").addEventListener("submit", ask);
  $("until").addEventListener("input", onScrub);
  $("token-box").addEventListener("submit", (ev) => {
    ev.preventDefault();
    state.token = $("token").value.trim();
    sessionStorage.setItem("ravenmem-token", state.token);
    $("token-box").hidden = true;
    start();
  });
  start();
}

let listening = false;
async function start() {
  try {
    await load();
    say("");
    if (!listening) { listening = true; listen(); }
  } catch (e) { say(e.message, true); }
}

main();
