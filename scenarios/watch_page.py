"""The live page scenarios.watch serves: inline CSS and JS, no remote resource. It polls
/state.json (incremental trail, planned legs only when their number changed) and redraws a canvas:
the map (/map.png, placed by /map.json), the planned legs (grey; the one being driven orange), the
driven trail (blue) and the robot (a disc with its heading); the camera frame (/frame) is reloaded
when the capture count changes. Every text from the run is set with textContent (chat lines come
from users and RApps).

Stable hooks (used by tests): `#map[data-robot="px,py"][data-draws]`, `#pose`, `#core`, `#rapp`,
`#progress[data-fraction]`, `#progress-text`, `#chat li`, `#frame[data-n]`, `#status[data-ok]`.
"""

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>rapp run - live</title>
<style>
 body { font: 14px system-ui, sans-serif; margin: 12px; color: #222; background: #fafafa; }
 h1 { font-size: 17px; margin: 0 0 8px; }
 #wrap { display: flex; gap: 16px; align-items: flex-start; flex-wrap: wrap; }
 canvas { border: 1px solid #bbb; background: #fff; image-rendering: pixelated; }
 #side { min-width: 340px; max-width: 460px; }
 #side table { border-collapse: collapse; }
 #side td { padding: 2px 8px 2px 0; vertical-align: top; }
 #side td:first-child { font-weight: 600; color: #146; }
 #chat { margin: 4px 0; padding-left: 18px; max-height: 180px; overflow: auto; }
 #chat li { white-space: pre-wrap; word-break: break-word; }
 #frame { display: block; margin-top: 8px; max-width: 100%; border: 1px solid #bbb; }
 #status { color: #666; font-size: 12px; }
 #status[data-ok="0"] { color: #a30; }
 progress { width: 180px; }
</style></head>
<body>
<h1 id="title">rapp run</h1>
<div id="wrap">
 <canvas id="map" width="10" height="10" data-robot="" data-draws="0"></canvas>
 <div id="side">
  <table>
   <tr><td>Core</td><td id="core">-</td></tr>
   <tr><td>RApp</td><td id="rapp">-</td></tr>
   <tr><td>Robot</td><td id="pose">-</td></tr>
   <tr><td>Progress</td><td><progress id="progress" max="1" data-fraction=""></progress>
       <span id="progress-text"></span></td></tr>
   <tr><td>Time</td><td id="time">-</td></tr>
  </table>
  <div><b>Chat</b><ul id="chat"></ul></div>
  <div><b>Camera</b> <span id="frame-n"></span><img id="frame" alt="no camera frame yet" data-n="0"></div>
  <p id="status" data-ok="1">connecting...</p>
 </div>
</div>
<script>
"use strict";
const canvas = document.getElementById("map"), ctx = canvas.getContext("2d");
const mapImg = new Image();
let meta = null, scale = 1, trail = [], legs = [], legsKnown = -1, last = null, frameN = 0;

function px(x, y) {  // world metres -> canvas pixels (map row 0 is the top, at max y)
  return [(x - meta.origin[0]) / meta.resolution * scale,
          (meta.height - (y - meta.origin[1]) / meta.resolution) * scale];
}
function line(points, colour, width, dash) {
  if (!points || points.length < 2) return;
  ctx.beginPath(); ctx.setLineDash(dash || []); ctx.strokeStyle = colour; ctx.lineWidth = width;
  points.forEach((p, i) => { const [u, v] = px(p[0], p[1]); i ? ctx.lineTo(u, v) : ctx.moveTo(u, v); });
  ctx.stroke(); ctx.setLineDash([]);
}
function draw() {
  if (!meta || !mapImg.complete) return;
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(mapImg, 0, 0, canvas.width, canvas.height);
  legs.forEach(l => line(l, "#999", 2, [6, 4]));
  if (last && last.current_leg) line(last.current_leg, "#e67e00", 3);
  line(trail, "#1f6fd1", 2);
  if (last && last.pose) {
    const [u, v] = px(last.pose[0], last.pose[1]), r = Math.max(5, 0.18 / meta.resolution * scale);
    ctx.beginPath(); ctx.arc(u, v, r, 0, 2 * Math.PI); ctx.fillStyle = "rgba(200,30,30,0.85)"; ctx.fill();
    ctx.beginPath(); ctx.moveTo(u, v);
    ctx.lineTo(u + 2 * r * Math.cos(last.pose[2]), v - 2 * r * Math.sin(last.pose[2]));
    ctx.strokeStyle = "#600"; ctx.lineWidth = 3; ctx.stroke();
    canvas.dataset.robot = Math.round(u) + "," + Math.round(v);
  }
  canvas.dataset.draws = String(Number(canvas.dataset.draws) + 1);
}
function text(id, value) { document.getElementById(id).textContent = value; }
function showRun(run) {
  if (!run) return;
  text("core", run.core || "-");
  text("rapp", run.rapp ? run.rapp + ": " + run.rapp_state : "-");
  const bar = document.getElementById("progress");
  if (run.fraction === null || run.fraction === undefined) { bar.removeAttribute("value"); bar.dataset.fraction = ""; }
  else { bar.value = run.fraction; bar.dataset.fraction = String(run.fraction); }
  text("progress-text", (run.fraction === null || run.fraction === undefined ? "" :
       Math.round(run.fraction * 100) + "% ") + (run.progress_text || ""));
  const chat = document.getElementById("chat");
  chat.replaceChildren(...run.chat.map(c => { const li = document.createElement("li"); li.textContent = c; return li; }));
}
async function tick() {
  try {
    const r = await fetch("state.json?trail_from=" + trail.length + "&legs=" + legsKnown, {cache: "no-store"});
    if (!r.ok) throw new Error("HTTP " + r.status);
    const s = await r.json();
    if (s.trail_from !== trail.length) trail = trail.slice(0, s.trail_from);
    trail = trail.concat(s.trail);
    if (s.legs) { legs = s.legs; legsKnown = s.legs_total; }
    last = s;
    text("title", s.title);
    text("pose", s.pose ? "x " + s.pose[0].toFixed(2) + "  y " + s.pose[1].toFixed(2) + "  \\u03b8 " +
         Math.round(s.pose[2] * 180 / Math.PI) + "\\u00b0" : "-");
    const el = s.run ? s.run.elapsed_s.toFixed(1) + " s" : "";
    text("time", el + (s.sim_time !== undefined ? " (sim " + s.sim_time.toFixed(1) + " s)" : ""));
    showRun(s.run);
    if (s.captures !== frameN) {
      frameN = s.captures;
      const img = document.getElementById("frame");
      img.onload = () => { img.dataset.n = String(frameN); };
      img.src = "frame?n=" + frameN;
      text("frame-n", "#" + frameN);
    }
    draw();
    const st = document.getElementById("status"); st.dataset.ok = "1";
    st.textContent = "live, updated " + new Date().toLocaleTimeString();
    setTimeout(tick, 300);
  } catch (e) {
    const st = document.getElementById("status"); st.dataset.ok = "0";
    st.textContent = "not connected (" + e.message + "): the run may have ended; retrying";
    setTimeout(tick, 2000);
  }
}
async function start() {
  meta = await (await fetch("map.json", {cache: "no-store"})).json();
  const fit = Math.min(4, 760 / meta.width, 620 / meta.height);
  scale = fit >= 1 ? Math.floor(fit) : fit;
  canvas.width = meta.width * scale; canvas.height = meta.height * scale;
  mapImg.onload = () => { draw(); tick(); };
  mapImg.src = "map.png";
}
start();
</script>
</body></html>
"""
