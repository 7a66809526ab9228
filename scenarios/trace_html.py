"""A run trace as ONE self-contained HTML page: an interactive SVG sequence diagram.

No network access is needed to view it (inline CSS and JS, no CDN). The deduplicated timeline
(scenarios.trace_report.timeline) is embedded as JSON in <script type="application/json"
id="trace-data">; the page draws agents as lifelines, messages as arrows (top to bottom in time
order), and structure/agent/behaviour/state/timeout/dropped records as coloured bands. Filters by
agent and conversation re-render the diagram; clicking an arrow or band shows its record.

Stable hooks (used by tests): arrows `g.msg[data-conv][data-performative]`, bands `g.structure`,
`#agent-filter` (checkboxes), `#agent-mode` (both|either), `#conv-filter` (select),
`#details`, `#msg-count[data-count]`.

    python -m scenarios.trace_html TRACE.jsonl -o trace.html [--title "run 3"]
"""
from __future__ import annotations

import argparse
import html
import json
from collections.abc import Iterable
from pathlib import Path

from agents.tracing import read_trace
from ontology.trace import CHAT, OPENING_OR_CHAT, AgentEvent, BehaviourEvent, RecordKind, StructureEvent
from scenarios.trace_report import display_names, note_label, participants, timeline

_CREATED = {StructureEvent.SPAWN, StructureEvent.CLOUD_SPAWN, StructureEvent.REGISTER, StructureEvent.DOWNLOAD,
            AgentEvent.STARTED}
_DESTROYED = {StructureEvent.DESTROY, StructureEvent.CLOUD_DESTROY, AgentEvent.STOPPED, AgentEvent.START_FAILED}


def note_category(rec: dict) -> str:
    """Colour class of a non-message record: created, destroyed, handoff, handback, activated,
    deactivated, state, problem or structure."""
    kind, event = rec.get("kind"), rec.get("event", "")
    if kind in (RecordKind.TIMEOUT, RecordKind.DROPPED):
        return "problem"
    if kind == RecordKind.STATE:
        return "state"
    if kind == RecordKind.BEHAVIOUR:
        return "activated" if event == BehaviourEvent.ACTIVATED else "deactivated"
    if event in _CREATED:
        return "created"
    if event in _DESTROYED:
        return "destroyed"
    if event == StructureEvent.HANDOFF:
        return "handoff"
    if event == StructureEvent.RESUME:
        return "handback"
    return "structure"


def page_data(records: Iterable[dict], title: str = "") -> dict:
    """What the page embeds: title, t0, agents [{jid, name}], items (timeline records, each with
    `_label`, and for non-messages `_category` and `_jids`)."""
    items = timeline(records)
    jids = participants(items)
    names = display_names(jids)
    out = []
    for it in items:
        it = dict(it)
        if it.get("kind") == RecordKind.MESSAGE:
            it["_label"] = " ".join(x for x in (it.get("performative") or CHAT, it.get("action")) if x)
        else:
            it["_label"] = note_label(it, names)
            it["_category"] = note_category(it)
            it["_jids"] = [j for j in participants([it]) if j in names]
        out.append(it)
    return {"title": title, "t0": items[0].get("t", 0) if items else 0,
            "agents": [{"jid": j, "name": names[j]} for j in jids], "items": out}


def script_json(value) -> str:
    """JSON safe inside a <script> element (no '</script>', '<!--', or line separators)."""
    text = json.dumps(value, ensure_ascii=False, default=str)
    for ch, esc in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026"),
                    ("\u2028", "\\u2028"), ("\u2029", "\\u2029")):
        text = text.replace(ch, esc)
    return text


def render_html(records: Iterable[dict], title: str = "Trace", scene: dict | None = None) -> str:
    """The whole page as a string; all text from the trace is inserted as text, never as HTML.
    `scene` (scene_data of the run folder): the map, poses, paths and camera frames the page shows
    for the message or time clicked."""
    data = page_data(records, title)
    data["scene"] = scene
    return (_PAGE.replace("{{TITLE}}", html.escape(title))
            .replace("{{CSS}}", _CSS + _SCENE_CSS).replace("{{JS}}", _JS + _SCENE_JS)
            .replace("{{DATA}}", script_json(data)))


FRAME_WIDTH = 320  # px of a camera frame as the page keeps it (re-encoded JPEG)


def scene_data(run_dir: str | Path, frames: bool = True) -> dict | None:
    """What the page's scene shows, from a recorded run folder's robot.jsonl (None without one): the
    map (PNG, resolution, origin, size), per robot its true poses [t, x, y, theta], estimates and
    planned paths [t, [[x, y]...]], and the camera frames [t, robot, data URL] (smaller JPEGs)."""
    import base64

    import cv2
    import numpy as np

    from agents.tracing import BLOBS, inflate
    from scenarios.recording import ROBOT_LOG

    path = Path(run_dir) / ROBOT_LOG
    if not path.exists():
        return None
    out: dict = {"map": None, "robots": {}, "frames": []}
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                s = json.loads(line)
                kind, t, robot = s["kind"], s["t"], s.get("robot", "")
                if kind == "map":
                    img = cv2.imdecode(np.frombuffer(base64.b64decode(s["png_b64"]), np.uint8), cv2.IMREAD_GRAYSCALE)
                    out["map"] = {"png": "data:image/png;base64," + s["png_b64"], "resolution": s["resolution"],
                                  "origin": s["origin"][:2], "width": int(img.shape[1]), "height": int(img.shape[0])}
                    continue
                r = out["robots"].setdefault(robot, {"poses": [], "estimates": [], "paths": []})
                if kind == "pose":
                    r["poses"].append([t, *s["pose"]])
                elif kind == "estimate":
                    r["estimates"].append([t, *s["pose"]])
                elif kind == "path":
                    r["paths"].append([t, [p[:2] for p in s["poses"]]])
                elif kind == "image" and frames:
                    s = json.loads(inflate(line, Path(run_dir) / BLOBS))
                    out["frames"].append([t, robot, _small_jpeg(s["data_b64"])])
            except (ValueError, KeyError, TypeError, OSError, cv2.error):
                continue  # a line cut short, a blob missing: left out
    return out if out["map"] or out["robots"] else None


def _small_jpeg(data_b64: str) -> str:
    import base64

    import cv2
    import numpy as np

    img = cv2.imdecode(np.frombuffer(base64.b64decode(data_b64), np.uint8), cv2.IMREAD_COLOR)
    if img.shape[1] > FRAME_WIDTH:
        img = cv2.resize(img, (FRAME_WIDTH, round(img.shape[0] * FRAME_WIDTH / img.shape[1])), interpolation=cv2.INTER_AREA)
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 75])
    return "data:image/jpeg;base64," + base64.b64encode(jpg.tobytes()).decode()


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{{TITLE}}</title>
<style>{{CSS}}</style></head>
<body>
<header><h1>{{TITLE}}</h1>
<span id="msg-count" data-count="0">0 messages</span></header>
<div id="controls">
  <fieldset><legend>Agents</legend>
    <div id="agent-filter"></div>
    <button type="button" id="agents-all">all</button>
    <button type="button" id="agents-none">none</button>
    <label>show messages <select id="agent-mode">
      <option value="both">between checked agents</option>
      <option value="either">involving a checked agent</option></select></label>
  </fieldset>
  <fieldset><legend>Conversation</legend>
    <select id="conv-filter"><option value="">all conversations</option></select>
  </fieldset>
  <fieldset class="legend"><legend>Marks</legend>
    <span class="sw created">created</span><span class="sw destroyed">destroyed</span>
    <span class="sw handoff">handed over</span><span class="sw handback">handed back</span>
    <span class="sw activated">activated</span><span class="sw deactivated">deactivated</span>
    <span class="sw state">state</span><span class="sw problem">timeout/dropped</span>
  </fieldset>
</div>
<main>
  <div id="diagram-scroll"><svg id="diagram-header" xmlns="http://www.w3.org/2000/svg"></svg>
    <svg id="diagram" xmlns="http://www.w3.org/2000/svg" data-count="0"></svg></div>
  <div id="side">
  <section id="scene" hidden>
    <div id="scene-head"><span id="scene-time" data-t="">-</span>
      <input type="range" id="scrub" min="0" max="1000" value="1000" aria-label="time"></div>
    <div id="scene-map"><img id="map-image" alt="map"><svg id="scene-svg" xmlns="http://www.w3.org/2000/svg"></svg></div>
    <figure id="camera"><img id="camera-frame" alt="the latest camera frame" data-t=""><figcaption id="camera-caption">no frame yet</figcaption></figure>
  </section>
  <aside id="details"><p class="hint">Click an arrow or a band to see its record.</p></aside>
  </div>
</main>
<script type="application/json" id="trace-data">{{DATA}}</script>
<script>{{JS}}</script>
</body></html>
"""

_CSS = """
* { box-sizing: border-box; }
body { margin: 0; font: 13px/1.35 system-ui, sans-serif; color: #222; display: flex;
       flex-direction: column; height: 100vh; }
header { display: flex; align-items: baseline; gap: 1em; padding: 4px 12px; background: #f4f4f8;
         border-bottom: 1px solid #ccd; }
h1 { font-size: 16px; margin: 0; }
#msg-count { color: #555; }
#controls { display: flex; flex-wrap: wrap; gap: 8px; padding: 4px 12px; border-bottom: 1px solid #ccd; }
fieldset { border: 1px solid #ccd; padding: 2px 8px 4px; margin: 0; }
legend { font-weight: 600; font-size: 12px; }
#agent-filter { display: inline-flex; flex-wrap: wrap; gap: 2px 10px; max-width: 60vw; }
#agent-filter label { white-space: nowrap; }
.sw { display: inline-block; padding: 0 5px; margin: 1px 2px; border-radius: 3px; font-size: 11px; }
main { flex: 1; display: flex; min-height: 0; }
#diagram-scroll { flex: 1; overflow: auto; position: relative; background: #fff; }
#diagram-header { position: sticky; top: 0; background: #fafafe; z-index: 2; display: block;
                  border-bottom: 1px solid #ccd; }
#diagram { display: block; }
#side { width: 380px; min-width: 260px; display: flex; flex-direction: column; border-left: 1px solid #ccd; }
#details { flex: 1; overflow: auto; padding: 8px 10px; background: #fcfcfc; }
#details dl { display: grid; grid-template-columns: max-content 1fr; gap: 1px 8px; margin: 0 0 8px; }
#details dt { color: #666; } #details dd { margin: 0; word-break: break-all; }
#details pre { background: #f2f2f2; padding: 6px; white-space: pre-wrap; word-break: break-all;
               max-height: 60vh; overflow: auto; margin: 0; }
.hint { color: #777; }
.head text { font-weight: 600; font-size: 12px; }
.lifeline { stroke: #99a; stroke-width: 1.2; }
.lifeline.off { stroke-dasharray: 3 4; stroke: #ccd; }
.msg { cursor: pointer; }
.msg .hit { fill: #fff; fill-opacity: 0; }
.msg .line { stroke-width: 1.6; fill: none; }
.msg.reply .line { stroke-dasharray: 6 3; }
.msg.one-sided .line { stroke-dasharray: 2 3; }
.msg text { font-size: 11px; paint-order: stroke; stroke: #fff; stroke-width: 3px; }
.msg:hover .line, .msg.selected .line { stroke-width: 3; }
.msg.selected text { font-weight: 700; }
.time { fill: #888; font-size: 10px; }
.structure { cursor: pointer; }
.structure text { font-size: 11px; fill: #333; }
.structure text.label { paint-order: stroke; stroke-width: 4px; stroke-linejoin: round; }
.structure.selected rect { stroke: #000; }
.created { background: #d8f3dc; fill: #d8f3dc; } .destroyed { background: #f8d7da; fill: #f8d7da; }
.handoff { background: #ffe8c2; fill: #ffe8c2; } .handback { background: #e3d7f5; fill: #e3d7f5; }
.activated { background: #d6eaff; fill: #d6eaff; } .deactivated { background: #e4e4e4; fill: #e4e4e4; }
.state { background: #f5f5dc; fill: #f5f5dc; } .problem { background: #ffc9c9; fill: #ffc9c9; }
.structure-other, .structure-band.structure { background: #eee; fill: #eee; }
"""

_JS = r"""
(function () {
  "use strict";
  const DATA = JSON.parse(document.getElementById("trace-data").textContent);
  const NS = "http://www.w3.org/2000/svg";
  const COL = 170, GUTTER = 80, HEAD = 34, MSG_ROW = 36, NOTE_ROW = 24, PAD = 10;
  const OPENING = {{OPENING}};
  const COLOURS = {request: "#1f5fbf", "query-ref": "#1f5fbf", subscribe: "#1f5fbf",
    agree: "#777", inform: "#2b8a3e", confirm: "#2b8a3e", failure: "#c92a2a",
    refuse: "#d9480f", "not-understood": "#862e9c", cancel: "#a61e4d", chat: "#222"};
  const BANDS = {created: "#d8f3dc", destroyed: "#f8d7da", handoff: "#ffe8c2", handback: "#e3d7f5",
    activated: "#d6eaff", deactivated: "#e4e4e4", state: "#f5f5dc", problem: "#ffc9c9", structure: "#eee"};
  const names = {};
  DATA.agents.forEach(a => { names[a.jid] = a.name; });
  const items = DATA.items.map((it, i) => Object.assign({_i: i}, it));
  const $ = id => document.getElementById(id);

  function el(tag, attrs, text) {
    const e = document.createElementNS(NS, tag);
    for (const k in attrs || {}) e.setAttribute(k, String(attrs[k]));
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function rel(t) { return t == null ? "" : "+" + ((t - DATA.t0) * 1000).toFixed(1) + " ms"; }
  function shortConv(c) { c = c || ""; return (c.startsWith("c-") ? c.slice(2) : c).slice(0, 8); }
  function isMsg(it) { return it.kind === "message"; }

  // -- controls -------------------------------------------------------------------------------
  function buildControls() {
    const box = $("agent-filter");
    DATA.agents.forEach(a => {
      const label = document.createElement("label");
      const cb = document.createElement("input");
      cb.type = "checkbox"; cb.value = a.jid; cb.checked = true; cb.name = "agent";
      label.title = a.jid;
      label.append(cb, " " + a.name);
      box.append(label);
    });
    const convs = new Map();
    items.filter(isMsg).forEach(m => {
      const c = m.conversation_id || "";
      if (!convs.has(c)) convs.set(c, {n: 0, action: m.action || m.performative || ""});
      convs.get(c).n += 1;
    });
    const sel = $("conv-filter");
    convs.forEach((v, c) => {
      const o = document.createElement("option");
      o.value = c === "" ? "(none)" : c;
      o.textContent = (c ? shortConv(c) : "(no id)") + " \u00b7 " + v.action + " \u00b7 " + v.n;
      o.title = c;
      sel.append(o);
    });
    box.addEventListener("change", render);
    $("agent-mode").addEventListener("change", render);
    sel.addEventListener("change", render);
    $("agents-all").addEventListener("click", () => setAll(true));
    $("agents-none").addEventListener("click", () => setAll(false));
  }
  function setAll(on) {
    $("agent-filter").querySelectorAll("input").forEach(cb => { cb.checked = on; });
    render();
  }

  // -- filtering ------------------------------------------------------------------------------
  function visibleItems() {
    const checked = new Set([...$("agent-filter").querySelectorAll("input:checked")].map(c => c.value));
    const both = $("agent-mode").value === "both";
    const conv = $("conv-filter").value;
    const msgs = items.filter(m => isMsg(m)
      && (both ? checked.has(m.sender) && checked.has(m.receiver)
               : checked.has(m.sender) || checked.has(m.receiver))
      && (!conv || (conv === "(none)" ? !m.conversation_id : m.conversation_id === conv)));
    let lo = -Infinity, hi = Infinity;
    if (conv) {
      lo = msgs.length ? msgs[0].t : Infinity;
      hi = msgs.length ? msgs[msgs.length - 1].t : -Infinity;
    }
    const notes = items.filter(n => !isMsg(n) && n.t >= lo && n.t <= hi
      && (!n._jids.length || n._jids.some(j => checked.has(j))));
    return msgs.concat(notes).sort((a, b) => (a.t - b.t) || (a._i - b._i));
  }

  // -- drawing --------------------------------------------------------------------------------
  function render() {
    const shown = visibleItems();
    const checked = new Set([...$("agent-filter").querySelectorAll("input:checked")].map(c => c.value));
    const used = new Set();  // columns: both ends of shown arrows, checked agents of shown bands
    shown.forEach(it => {
      if (isMsg(it)) { used.add(it.sender); used.add(it.receiver); }
      else it._jids.filter(j => checked.has(j)).forEach(j => used.add(j));
    });
    const cols = DATA.agents.map(a => a.jid).filter(j => used.has(j));
    const x = {};
    cols.forEach((j, i) => { x[j] = GUTTER + i * COL + COL / 2; });
    const width = Math.max(GUTTER + cols.length * COL + PAD, 400);
    let y = PAD;
    const rows = shown.map(it => { const r = y; y += isMsg(it) ? MSG_ROW : NOTE_ROW; return r; });
    const height = y + PAD;

    const head = $("diagram-header");
    head.replaceChildren();
    head.setAttribute("width", width); head.setAttribute("height", HEAD);
    cols.forEach(j => {
      const g = el("g", {class: "head"});
      g.append(el("title", {}, j));
      g.append(el("rect", {x: x[j] - COL / 2 + 8, y: 5, width: COL - 16, height: HEAD - 10,
                           rx: 4, fill: "#eef", stroke: "#99a"}));
      g.append(el("text", {x: x[j], y: HEAD / 2 + 4, "text-anchor": "middle"}, names[j] || j));
      head.append(g);
    });

    const svg = $("diagram");
    svg.replaceChildren();
    svg.setAttribute("width", width); svg.setAttribute("height", height);
    const lifelines = el("g", {class: "lifelines"}), bands = el("g", {class: "bands"}),
          arrows = el("g", {class: "arrows"}), times = el("g", {class: "times"});
    svg.append(bands, lifelines, arrows, times);
    cols.forEach(j => drawLifeline(lifelines, j, x[j], shown, rows, height));
    shown.forEach((it, k) => times.append(el("text", {class: "time", x: 4,
      y: rows[k] + (isMsg(it) ? MSG_ROW - 7 : NOTE_ROW / 2 + 4)}, rel(it.t))));
    let count = 0;
    shown.forEach((it, k) => {
      if (isMsg(it)) { arrows.append(drawMessage(it, rows[k], x)); count += 1; }
      else bands.append(drawNote(it, rows[k], x, width));
    });
    svg.setAttribute("data-count", count);
    const counter = $("msg-count");
    counter.setAttribute("data-count", count);
    counter.textContent = count + " of " + items.filter(isMsg).length + " messages";
  }

  function drawLifeline(parent, jid, cx, shown, rows, height) {
    let top = 0, bottom = height;
    shown.forEach((it, k) => {
      if (it.kind === "agent" && it.agent === jid) {
        if (it.event === "started") top = rows[k] + NOTE_ROW / 2;
        else bottom = rows[k] + NOTE_ROW / 2;
      }
    });
    if (top > 0) parent.append(el("line", {class: "lifeline off", x1: cx, x2: cx, y1: 0, y2: top}));
    parent.append(el("line", {class: "lifeline", x1: cx, x2: cx, y1: top, y2: bottom}));
    if (bottom < height) parent.append(el("line", {class: "lifeline off", x1: cx, x2: cx, y1: bottom, y2: height}));
  }

  function drawMessage(m, top, x) {
    const perf = m.performative || "chat";
    const colour = COLOURS[perf] || "#444";
    const cls = ["msg", OPENING.includes(perf) ? "opening" : "reply"];
    if (m.seen !== "both") cls.push("one-sided");
    const g = el("g", {class: cls.join(" "), "data-conv": m.conversation_id || "",
                       "data-performative": perf, "data-index": m._i,
                       "data-sender": m.sender, "data-receiver": m.receiver});
    const x1 = x[m.sender], x2 = x[m.receiver], ly = top + MSG_ROW - 10;
    const tip = m.sender + " \u2192 " + m.receiver + "  " + m._label + "  " + rel(m.t)
      + (m.latency != null ? "  latency " + (m.latency * 1000).toFixed(1) + " ms" : "")
      + (m.seen !== "both" ? "  (traced by " + m.seen + " side only)" : "");
    g.append(el("title", {}, tip));
    let d, head, labelX, anchor;
    if (x1 === x2) {
      d = `M${x1} ${ly - 8} h30 v12 h-28`;
      head = `M${x1 + 2} ${ly + 4} l7 -4 v8 z`;
      labelX = x1 + 36; anchor = "start";
    } else {
      const dir = x2 > x1 ? 1 : -1;
      d = `M${x1} ${ly} H${x2 - dir * 2}`;
      head = `M${x2} ${ly} l${-dir * 9} -4.5 v9 z`;
      labelX = (x1 + x2) / 2; anchor = "middle";
    }
    g.append(el("path", {class: "line", d: d, stroke: colour}));
    g.append(el("path", {class: "head", d: head, fill: colour}));
    const text = m._label + (m.conversation_id ? "  [" + shortConv(m.conversation_id) + "]" : "");
    g.append(el("text", {x: labelX, y: ly - 5, "text-anchor": anchor, fill: colour}, text));
    const hx = Math.min(x1, x2) - 4, hw = Math.max(Math.abs(x2 - x1), 40) + 8;
    g.append(el("rect", {class: "hit", x: hx, y: ly - 18, width: hw, height: 24}));  // on top
    g.addEventListener("click", () => { showDetails(m, g); if (window.rappScene) window.rappScene.at(m.t); });
    return g;
  }

  function drawNote(n, top, x, width) {
    const cat = n._category || "structure";
    const g = el("g", {class: "structure " + "kind-" + n.kind, "data-kind": n.kind,
                       "data-event": n.event || "", "data-category": cat, "data-index": n._i});
    g.append(el("title", {}, n._label));
    g.append(el("rect", {class: cat === "structure" ? "structure-other" : cat, x: GUTTER - 6, y: top + 2,
                         width: width - GUTTER, height: NOTE_ROW - 4, rx: 3, "fill-opacity": 0.85}));
    (n._jids || []).forEach(j => {
      if (x[j] !== undefined) g.append(el("circle", {cx: x[j], cy: top + NOTE_ROW / 2, r: 4, fill: "#555"}));
    });
    const first = (n._jids || []).map(j => x[j]).filter(v => v !== undefined)[0];
    const label = "\u25B8 " + n._label, guess = label.length * 6.3;  // ~px at 11px font
    let tx = first === undefined ? GUTTER : first + 8, anchor = "start";
    if (tx + guess > width - PAD && first !== undefined && first - 8 - guess > GUTTER) {
      tx = first - 8; anchor = "end";  // too long to the right of its marker: put it left
    } else if (tx + guess > width - PAD) tx = GUTTER;
    g.append(el("text", {class: "label", x: tx, y: top + NOTE_ROW / 2 + 4, "text-anchor": anchor,
                         stroke: BANDS[cat] || BANDS.structure}, label));
    g.addEventListener("click", () => { showDetails(n, g); if (window.rappScene) window.rappScene.at(n.t); });
    return g;
  }

  // -- details ----------------------------------------------------------------------------------
  const HIDDEN = new Set(["_i", "_label", "_category", "_jids", "content", "latency"]);
  function showDetails(rec, g) {
    document.querySelectorAll(".selected").forEach(e => e.classList.remove("selected"));
    g.classList.add("selected");
    const box = $("details");
    box.replaceChildren();
    const h = document.createElement("h2");
    h.style.fontSize = "14px"; h.style.margin = "0 0 6px";
    h.textContent = rec._label;
    const dl = document.createElement("dl");
    const add = (k, v) => {
      const dt = document.createElement("dt"), dd = document.createElement("dd");
      dt.textContent = k; dd.textContent = v; dl.append(dt, dd);
    };
    add("time", rel(rec.t));
    if (rec.latency != null) add("latency", (rec.latency * 1000).toFixed(3) + " ms");
    Object.keys(rec).forEach(k => {
      if (HIDDEN.has(k) || rec[k] === "" || rec[k] == null) return;
      add(k, typeof rec[k] === "object" ? JSON.stringify(rec[k]) : String(rec[k]));
    });
    box.append(h, dl);
    if (rec.content !== undefined) {
      const title = document.createElement("h3");
      title.style.fontSize = "13px"; title.style.margin = "4px 0";
      title.textContent = "content";
      const pre = document.createElement("pre");
      pre.id = "details-content";
      pre.textContent = pretty(rec.content);
      box.append(title, pre);
    }
  }
  function pretty(text) {
    if (typeof text !== "string") return JSON.stringify(text, null, 2);
    try { return JSON.stringify(JSON.parse(text), null, 2); } catch (e) { return text; }
  }

  buildControls();
  render();
})();
"""

_JS = _JS.replace("{{OPENING}}", json.dumps(OPENING_OR_CHAT))  # the ontology's, in the page's code

_SCENE_CSS = """
#scene { border-bottom: 1px solid #ccd; padding: 4px 8px; background: #fff; }
#scene-head { display: flex; gap: 6px; align-items: center; font-size: 12px; }
#scrub { flex: 1; }
#scene-map { position: relative; width: 100%; }
#map-image { width: 100%; display: block; image-rendering: pixelated; }
#scene-svg { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
#camera { margin: 4px 0 0; }
#camera-frame { max-width: 100%; display: block; }
#camera-caption { font-size: 11px; color: #666; }
.traj { fill: none; stroke: #1f5fbf; stroke-opacity: 0.5; }
.plan { fill: none; stroke: #e8590c; stroke-dasharray: 4 2; }
.robot { fill: #1f5fbf; } .heading { stroke: #1f5fbf; stroke-width: 2; }
.estimate { fill: none; stroke: #2b8a3e; stroke-width: 1.5; }
"""

# the scene: for the time of the record clicked (or the slider's), each robot's true pose and its
# trajectory so far, its latest planned path and estimate, and the latest camera frame then
_SCENE_JS = r"""
(function () {
  "use strict";
  const DATA = JSON.parse(document.getElementById("trace-data").textContent);
  const S = DATA.scene;
  if (!S || !S.map) return;
  const NS = "http://www.w3.org/2000/svg", $ = id => document.getElementById(id);
  const M = S.map;
  $("scene").hidden = false;
  $("map-image").src = M.png;
  const svg = $("scene-svg");
  svg.setAttribute("viewBox", "0 0 " + M.width + " " + M.height);
  const px = (x, y) => [(x - M.origin[0]) / M.resolution, M.height - (y - M.origin[1]) / M.resolution];
  const times = [];
  Object.values(S.robots).forEach(r => r.poses.forEach(p => times.push(p[0])));
  S.frames.forEach(f => times.push(f[0]));
  const lo = Math.min(...times, DATA.t0 || Infinity), hi = Math.max(...times);
  function el(tag, attrs) {
    const e = document.createElementNS(NS, tag);
    for (const k in attrs) e.setAttribute(k, String(attrs[k]));
    return e;
  }
  function latest(list, t) {  // the last entry at or before t (lists are in time order)
    let found = null;
    for (const e of list) { if (e[0] <= t) found = e; else break; }
    return found;
  }
  function at(t) {
    svg.replaceChildren();
    const r = M.resolution;
    Object.entries(S.robots).forEach(([name, R]) => {
      const past = R.poses.filter(p => p[0] <= t);
      if (past.length > 1) svg.append(el("polyline", {class: "traj", "stroke-width": 0.04 / r,
        points: past.map(p => px(p[1], p[2]).join(",")).join(" ")}));
      const plan = latest(R.paths, t);
      if (plan) svg.append(el("polyline", {class: "plan", "stroke-width": 0.03 / r,
        points: plan[1].map(p => px(p[0], p[1]).join(",")).join(" ")}));
      const est = latest(R.estimates, t);
      if (est) { const [ex, ey] = px(est[1], est[2]);
        svg.append(el("circle", {class: "estimate", cx: ex, cy: ey, r: 0.15 / r, "data-x": est[1], "data-y": est[2]})); }
      const pose = latest(R.poses, t) || R.poses[0];
      if (pose) {
        const [cx, cy] = px(pose[1], pose[2]), len = 0.35 / r;
        const g = el("g", {id: "robot-pose", "data-robot": name, "data-x": pose[1], "data-y": pose[2], "data-t": pose[0]});
        g.append(el("line", {class: "heading", x1: cx, y1: cy, x2: cx + len * Math.cos(pose[3]),
                             y2: cy - len * Math.sin(pose[3]), "stroke-width": 0.05 / r}));
        g.append(el("circle", {class: "robot", cx: cx, cy: cy, r: 0.12 / r}));
        svg.append(g);
      }
    });
    const frame = latest(S.frames, t);
    const img = $("camera-frame");
    if (frame) { if (img.getAttribute("data-t") !== String(frame[0])) img.src = frame[2];
      img.setAttribute("data-t", frame[0]); img.hidden = false;
      $("camera-caption").textContent = frame[1] + " camera, " + (t - frame[0]).toFixed(1) + " s before"; }
    else { img.hidden = true; img.setAttribute("data-t", ""); $("camera-caption").textContent = "no frame yet"; }
    const label = $("scene-time");
    label.setAttribute("data-t", t);
    label.textContent = "+" + (t - (DATA.t0 || lo)).toFixed(2) + " s";
    $("scrub").value = hi > lo ? Math.round(1000 * (t - lo) / (hi - lo)) : 1000;
  }
  $("scrub").addEventListener("input", e => at(lo + (hi - lo) * e.target.value / 1000));
  window.rappScene = {at: at};
  at(hi);
})();
"""


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Render a trace (JSON Lines) as an HTML page.")
    p.add_argument("trace")
    p.add_argument("-o", "--output", help="HTML file (default: TRACE with .html)")
    p.add_argument("--title")
    a = p.parse_args(argv)
    out = Path(a.output or Path(a.trace).with_suffix(".html"))
    out.write_text(render_html(read_trace(a.trace, validate=True), a.title or Path(a.trace).name), encoding="utf-8")
    print(out)


if __name__ == "__main__":
    main()
