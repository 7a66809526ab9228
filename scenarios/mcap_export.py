"""run.mcap: a run folder as one MCAP file for Foxglove, Lichtblick and other MCAP readers
(docs/recordings.md), written with the `mcap` package. Every channel's messages are JSON; the
robot's use Foxglove's well-known schemas (their JSON Schema text, scenarios/foxglove_schemas/):

  /map                      foxglove.Grid             the map under the run (occupancy 0..100, -1 unknown)
  /tf                       foxglove.FrameTransforms  map -> ROBOT/base_link, the true pose
  /ROBOT/pose               foxglove.PoseInFrame      the true pose (every 0.2 s simulated)
  /ROBOT/estimate           foxglove.PoseInFrame      the pose the RApp told the Core (set_global_pose)
  /ROBOT/path               foxglove.PosesInFrame     each path it was asked to follow
  /ROBOT/camera             foxglove.CompressedImage  every captured frame (left out: frames=False)
  /ROBOT/laser, /ROBOT/sonar  foxglove.LaserScan      scans, at most one per 0.5 s simulated each
  /log                      foxglove.Log              RApps' log lines
  /events                   foxglove.Log              the structure records (spawn, handoff, ended, ...)
  /chat                     foxglove.Log              the owners' chat
  /acl/AGENT                rapp.AclMessage           every ACL message, on its sender's channel

Times are the wall clock of the trace (log_time, ns since the epoch); robot samples carry the
simulation time too (metadata `sim` of the recording is not a channel). A folder recorded before
robot.jsonl existed gets its true trajectory from result.json (placed by the simulation time after
the first hand-off) and its frames from frames/ (by file time); a message without its whole body in
messages.jsonl has the trace's content (`truncated: true` where the trace capped it).
"""
from __future__ import annotations

import base64
import json
import math
import re
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from mcap.writer import Writer

from agents.tracing import BLOBS, BODIES, inflate, read_trace
from ontology.recording import AclMessage
from ontology.trace import CHAT, RecordKind

SCHEMAS = Path(__file__).resolve().parent / "foxglove_schemas"
ACL_SCHEMA = "rapp.AclMessage"
FOXGLOVE_LEVEL = {"debug": 1, "info": 2, "warning": 3, "error": 4}


@lru_cache(maxsize=None)
def schema_text(name: str) -> bytes:
    if name == ACL_SCHEMA:
        return json.dumps({"title": ACL_SCHEMA, **AclMessage.model_json_schema()}).encode()
    return (SCHEMAS / f"{name.removeprefix('foxglove.')}.json").read_bytes()


def stamp(t: float) -> dict:
    sec = int(t)
    return {"sec": sec, "nsec": int(round((t - sec) * 1e9)) % 1_000_000_000}


def pose(x: float, y: float, theta: float) -> dict:
    return {"position": {"x": x, "y": y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2), "w": math.cos(theta / 2)}}


class McapBuilder:
    """Messages gathered by channel, written in time order."""

    def __init__(self):
        self.items: list[tuple[int, str, str, bytes]] = []  # (ns, topic, schema, data)

    def add(self, t: float, topic: str, schema: str, msg: dict) -> None:
        self.items.append((int(t * 1e9), topic, schema, json.dumps(msg, separators=(",", ":"),
                                                                   default=str).encode()))

    def write(self, path: Path, metadata: dict[str, str]) -> dict[str, int]:
        self.items.sort(key=lambda i: i[0])
        counts: dict[str, int] = {}
        tmp = path.with_suffix(".mcap.part")
        with open(tmp, "wb") as f:
            w = Writer(f)
            w.start(profile="", library="rapp-agents")
            schemas: dict[str, int] = {}
            channels: dict[str, int] = {}
            for ns, topic, schema, data in self.items:
                if topic not in channels:
                    if schema not in schemas:
                        schemas[schema] = w.register_schema(name=schema, encoding="jsonschema",
                                                            data=schema_text(schema))
                    channels[topic] = w.register_channel(topic=topic, message_encoding="json",
                                                         schema_id=schemas[schema])
                counts[topic] = counts.get(topic, 0) + 1
                w.add_message(channels[topic], log_time=ns, data=data, publish_time=ns, sequence=counts[topic])
            w.add_metadata("rapp.run", metadata)
            w.finish()
        tmp.replace(path)
        return counts


def export_mcap(run_dir: str | Path, out: str | Path | None = None, frames: bool = True) -> Path:
    """Write `out` (default RUN_DIR/run.mcap) from the run folder; returns its path."""
    run = Path(run_dir)
    out = Path(out) if out else run / "run.mcap"
    records = read_trace(run / "trace.jsonl") if (run / "trace.jsonl").exists() else []
    b = McapBuilder()
    robot_log = run / "robot.jsonl"
    if robot_log.exists():
        robots = _robot_samples(b, robot_log, frames, run / BLOBS)
    else:
        robots = _from_result(b, run, records, frames)
    _trace_channels(b, records)
    _acl_channels(b, run, records)
    meta = {"robots": ",".join(sorted(robots)), "frames": str(bool(frames)).lower()}
    result = run / "result.json"
    if result.exists():
        try:
            r = json.loads(result.read_text())
            meta.update({k: str(r[k]) for k in ("rapp", "robot", "house", "seed", "command", "ok") if k in r})
        except ValueError:
            pass
    b.write(out, meta)
    return out


# -- the robot ------------------------------------------------------------------------------------
def _robot_samples(b: McapBuilder, path: Path, frames: bool, blobs: Path) -> set[str]:
    robots: set[str] = set()
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                s = json.loads(inflate(line, blobs) if frames else line)
                _sample(b, s, frames, robots)
            except (ValueError, KeyError, TypeError):
                continue  # a line cut by a crash
    return robots


def _sample(b: McapBuilder, s: dict, frames: bool, robots: set[str]) -> None:
    t, kind, robot = s["t"], s["kind"], s.get("robot", "")
    if robot:
        robots.add(robot)
    if kind == "map":
        b.add(t, "/map", "foxglove.Grid", grid_message(t, s["png_b64"], s["resolution"], s["origin"]))
    elif kind == "pose":
        x, y, th = s["pose"]
        b.add(t, f"/{robot}/pose", "foxglove.PoseInFrame",
              {"timestamp": stamp(t), "frame_id": "map", "pose": pose(x, y, th)})
        b.add(t, "/tf", "foxglove.FrameTransforms", {"transforms": [{
            "timestamp": stamp(t), "parent_frame_id": "map", "child_frame_id": f"{robot}/base_link",
            "translation": {"x": x, "y": y, "z": 0.0}, "rotation": pose(x, y, th)["orientation"]}]})
    elif kind == "estimate":
        b.add(t, f"/{robot}/estimate", "foxglove.PoseInFrame",
              {"timestamp": stamp(t), "frame_id": "map", "pose": pose(*s["pose"])})
    elif kind == "path":
        b.add(t, f"/{robot}/path", "foxglove.PosesInFrame",
              {"timestamp": stamp(t), "frame_id": "map", "poses": [pose(*p) for p in s["poses"]]})
    elif kind == "laser":
        n = len(s["ranges"])
        b.add(t, f"/{robot}/laser", "foxglove.LaserScan", {
            "timestamp": stamp(t), "frame_id": f"{robot}/base_link", "pose": pose(s.get("mount_x", 0.0), 0.0, 0.0),
            "start_angle": s["angle_min"], "end_angle": s["angle_min"] + s["angle_increment"] * max(n - 1, 0),
            "ranges": [r if math.isfinite(r) else s["range_max"] for r in s["ranges"]], "intensities": []})
    elif kind == "sonar":
        bearing = s.get("bearing", 0.0)
        b.add(t, f"/{robot}/sonar", "foxglove.LaserScan", {
            "timestamp": stamp(t), "frame_id": f"{robot}/base_link", "pose": pose(s.get("mount_x", 0.0), 0.0, 0.0),
            "start_angle": -bearing, "end_angle": bearing, "ranges": [s["right"], s["left"]], "intensities": []})
    elif kind == "image" and frames:
        b.add(t, f"/{robot}/camera", "foxglove.CompressedImage", {
            "timestamp": stamp(t), "frame_id": f"{robot}/camera", "data": s["data_b64"],
            "format": "jpeg" if s.get("encoding") == "jpeg" else "png"})


def grid_message(t: float, png_b64: str, resolution: float, origin) -> dict:
    """foxglove.Grid of a map image (ROS map_server values: 0 occupied, 254 free, 205 unknown; row 0
    at the top) as int8 occupancy (100 occupied, 0 free, -1 unknown), its first row at the origin."""
    img = cv2.imdecode(np.frombuffer(base64.b64decode(png_b64), np.uint8), cv2.IMREAD_GRAYSCALE)
    occ = np.where(img < 50, 100, np.where(img > 250, 0, -1)).astype(np.int8)[::-1]
    h, w = occ.shape
    return {"timestamp": stamp(t), "frame_id": "map", "pose": pose(origin[0], origin[1], 0.0),
            "column_count": int(w), "cell_size": {"x": resolution, "y": resolution},
            "row_stride": int(w), "cell_stride": 1,
            "fields": [{"name": "occupancy", "offset": 0, "type": 2}],  # INT8
            "data": base64.b64encode(np.ascontiguousarray(occ).tobytes()).decode()}


def _from_result(b: McapBuilder, run: Path, records: list[dict], frames: bool) -> set[str]:
    """An older run folder: the true trajectory of result.json and the frames in frames/."""
    try:
        result = json.loads((run / "result.json").read_text())
    except (OSError, ValueError):
        return set()
    robot = result.get("robot", "robot")
    handoff = next((r["t"] for r in records if r.get("event") == "handoff"), records[0]["t"] if records else 0.0)
    traj = (result.get("truth") or {}).get("trajectory") or []
    if isinstance(traj, dict):
        traj = traj.get(robot, [])
    if traj:
        t0 = traj[0][0]
        for sim, x, y, th in traj:
            _sample(b, {"t": handoff + sim - t0, "kind": "pose", "robot": robot, "pose": [x, y, th]}, frames, set())
    if frames and (run / "frames").is_dir():
        for f in sorted((run / "frames").iterdir()):
            if f.suffix in (".png", ".jpg"):
                b.add(f.stat().st_mtime, f"/{robot}/camera", "foxglove.CompressedImage", {
                    "timestamp": stamp(f.stat().st_mtime), "frame_id": f"{robot}/camera",
                    "data": base64.b64encode(f.read_bytes()).decode(), "format": "jpeg" if f.suffix == ".jpg" else "png"})
    return {robot}


# -- the trace ------------------------------------------------------------------------------------
def _log(t: float, name: str, level: int, message: str, topic_file: str = "") -> dict:
    return {"timestamp": stamp(t), "level": level, "message": message, "name": name, "file": topic_file, "line": 0}


def _local(jid: str) -> str:
    return (jid or "unknown").split("@", 1)[0].split("/", 1)[0] or "unknown"


def _trace_channels(b: McapBuilder, records: list[dict]) -> None:
    for r in records:
        kind, t = r.get("kind"), r.get("t", 0.0)
        if kind == RecordKind.LOG:
            level = FOXGLOVE_LEVEL.get(str(r.get("level", "")).lower(), 0)
            b.add(t, "/log", "foxglove.Log", _log(t, _local(r.get("agent", "")), level,
                                                   (f"[{r['state']}] " if r.get("state") else "") + str(r.get("message", ""))))
        elif kind == RecordKind.STRUCTURE:
            fields = {k: v for k, v in r.items() if k not in ("t", "kind", "pid", "agent", "event")}
            b.add(t, "/events", "foxglove.Log", _log(t, _local(r.get("agent", "")), 2,
                                                      f"{r.get('event')} {json.dumps(fields, default=str)}"))


def _bare(jid) -> str:
    return str(jid or "").split("/", 1)[0]


def own_account(r: dict) -> bool:
    """A record a trusted agent wrote, or a RApp's (stamped with its `origin` by its relay) of a
    message it sent itself: what a RApp's process says another agent sent or received is its claim
    only, and is left out (else a RApp could put words on its Core's channel)."""
    return not r.get("origin") or (r.get("dir") == "send" and _bare(r.get("sender")) == _bare(r["origin"]))


def _acl_channels(b: McapBuilder, run: Path, records: list[dict]) -> None:
    """Each message of the trace once (its sender's record where traced, else its receiver's), with
    its whole body where the run recorded one (messages.jsonl), else the trace's content; a RApp's
    records count only for the messages it sent (own_account)."""
    bodies: dict[tuple, str] = {}
    # a trusted agent's body first: a RApp's record of a message it sent counts only where no trusted
    # agent recorded that message (else a RApp could rewrite what it asked its Core for)
    for r in sorted(_bodies(run / BODIES, run / BLOBS), key=lambda r: bool(r.get("origin"))):
        if r.get("message_id") and own_account(r):
            bodies.setdefault((r.get("sender"), r.get("message_id")), r["body"])
    seen: set[tuple] = set()
    messages = [r for r in records if r.get("kind") == RecordKind.MESSAGE and own_account(r)]
    # trusted agents' records first, then senders' before receivers'
    messages.sort(key=lambda r: (bool(r.get("origin")), r.get("dir") != "send", r.get("t", 0.0)))
    for r in messages:
        key = (r.get("sender"), r.get("message_id")) if r.get("message_id") else \
            (r.get("sender"), r.get("receiver"), round(r.get("t", 0.0), 1), r.get("content"))
        if key in seen:
            continue
        seen.add(key)
        whole = bodies.get((r.get("sender"), r.get("message_id")))
        text = whole if whole is not None else r.get("content", "")
        t = r.get("t", 0.0)
        if r.get("performative") == CHAT:
            b.add(t, "/chat", "foxglove.Log", _log(t, _local(r.get("sender", "")), 2,
                                                    f"{_local(r.get('sender', ''))} -> {_local(r.get('receiver', ''))}: {text}"))
            continue
        try:
            content = json.loads(text) if text else None
        except ValueError:
            content = text
        msg = AclMessage(sender=r.get("sender", ""), receiver=r.get("receiver", ""),
                         performative=r.get("performative", ""), conversation_id=r.get("conversation_id", ""),
                         ontology=r.get("ontology", ""), action=r.get("action", ""),
                         message_id=r.get("message_id", ""), in_reply_to=r.get("in_reply_to", ""),
                         feedback=bool(r.get("feedback")), size=r.get("size", len(text or "")), content=content,
                         truncated=whole is None and bool(_CAPPED.search(text or "")))
        b.add(t, f"/acl/{_local(msg.sender)}", ACL_SCHEMA, msg.model_dump())


_CAPPED = re.compile(r"\.\.\.\[\+\d+ chars\]$")  # agents/tracing.py cap()


def _bodies(path: Path, blobs: Path) -> list[dict]:
    out = []
    if not path.exists():
        return out
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                rec = json.loads(line)
                if isinstance(rec, dict) and rec.get("kind") == "body":
                    rec["body"] = inflate(rec["body"], blobs)
                    out.append(rec)
            except (ValueError, KeyError, TypeError, OSError):
                continue
    return out
