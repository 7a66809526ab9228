"""Fleet: N robots (nao/elektron alternately, one shared World) each running a task at once, on one
Platform and one Store. Rounds with growing N (robots are added between rounds); a round passes when
every task finishes and every request of every Dynamic Agent is answered (from the trace).

Reports the largest passing N (`fleet`; floor = the goal, 20 robots; ratio = goal / N, <= 1 met) and
the Platform service latency p95 at that N (`fleet_service_p95`; floor = the same p95 with 1 robot,
measured first in the same run). The RApp is bench/rapps/rtt_probe with `calls` get_global_pose and
`calls` ping requests per robot (the echo_app fixture cannot run on an elektron: it calls `say`, which
an elektron lacks; hazard_detection needs an uploaded home and runs for minutes per robot).
"""
from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path

from .common import RTT_PROBE, RobotSystem, log, metric, ms, percentile, ratio

GOAL = 20


def request_latencies(trace: list[dict], since: float, platform: str) -> tuple[dict, int]:
    """Per Dynamic Agent request after `since`: latency by target kind; and the unanswered count."""
    sends, answers = {}, {}
    for r in trace:
        if r["kind"] != "message" or r["t"] < since or not r["agent"].startswith("dyn-"):
            continue
        if r["dir"] == "send" and r["performative"] == "request":
            sends[r["conversation_id"]] = r
        elif r["dir"] == "recv" and r["performative"] in ("inform", "refuse", "failure", "not-understood"):
            answers.setdefault(r["conversation_id"], r)
    lat = {"platform": [], "robot": [], "other": []}
    missing, lost_status = [], []
    for conv, s in sends.items():
        a = answers.get(conv)
        if a is None:
            # the final task_status (Finished) ack is often lost: the Core destroys the Dynamic
            # Agent as soon as it has the status, while the ack is still in flight (reported apart)
            if s["action"] != "task_status":
                missing.append(f"{s['agent'].split('@')[0]}:{s['action']}")
            else:
                lost_status.append(s["agent"])
            continue
        kind = "platform" if s["receiver"] == platform else "robot" if s["ontology"] == "robot" else "other"
        lat[kind].append(a["t"] - s["t"])
    lat["lost_status_acks"] = lost_status
    return lat, missing


async def one_round(rs: RobotSystem, n: int) -> dict:
    from agents.tracing import read_trace

    if len(rs.robots) < n:
        await rs.add_robots(n - len(rs.robots))
    since = time.time()
    t0 = time.perf_counter()
    replies = await asyncio.gather(*(rs.command(h, "rttprobe", "rtt-probe finished", timeout=180)
                                     for h in rs.robots[:n]), return_exceptions=True)
    wall = time.perf_counter() - t0
    failed = [str(r)[:200] for r in replies if isinstance(r, BaseException) or "problem" in r]
    lat, missing = request_latencies(read_trace(rs.trace_file), since, rs.system.platform.address)
    ok = not failed and not missing and len(lat["platform"]) >= n
    res = {"n": n, "ok": ok, "wall_s": wall, "failed": failed, "unanswered": len(missing), "unanswered_actions": missing[:5],
           "lost_status_acks": len(lat["lost_status_acks"]),
           "platform_ms": ms(lat["platform"]), "robot_ms": ms(lat["robot"])}
    log(f"fleet N={n}: {'ok' if ok else 'FAILED'} in {wall:.1f} s, platform p95 "
        f"{percentile(res['platform_ms'], 95):.1f} ms, robot p95 {percentile(res['robot_ms'], 95):.1f} ms"
        + (f"; failures {failed[:2]} unanswered {missing[:5]}" if not ok else ""))
    return res


async def run(quick: bool = True, sizes: list[int] | None = None, calls: int = 20) -> list[dict]:
    import shutil

    import yaml

    sizes = sizes or ([1, 2, 4] if quick else [1, 2, 4, 8, 12, 16, 20, 24, 28, 32])
    rounds = []
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        app = Path(tmp) / "rtt_probe"
        shutil.copytree(RTT_PROBE, app)
        manifest = yaml.safe_load((app / "manifest.yaml").read_text())
        manifest["params"].update(calls=calls, warmup=0)
        (app / "manifest.yaml").write_text(yaml.safe_dump(manifest))
        async with RobotSystem(Path(tmp) / "run", [app], robots=0, trace=True, house="house") as rs:
            await rs.command(*(await _warm(rs)), "rttprobe", "rtt-probe finished")  # warm-up, not counted
            for n in sizes:
                r = await one_round(rs, n)
                rounds.append(r)
                if not r["ok"]:
                    break
    base = rounds[0]
    passed = [r for r in rounds if r["ok"]]
    best = passed[-1] if passed else None
    n_best = best["n"] if best else 0
    p95 = percentile(best["platform_ms"], 95) if best else None
    base_p95 = percentile(base["platform_ms"], 95) if base["ok"] else None
    first_fail = next((r for r in rounds if not r["ok"]), None)
    tried = ",".join(str(r["n"]) for r in rounds)
    return [
        metric("fleet", n_best, "robots", GOAL, ratio(GOAL, n_best), len(rounds), rapp="rtt-probe",
               sizes_tried=tried, first_failure=(f"N={first_fail['n']}: {first_fail['failed'][:1]} "
                                                 f"unanswered={first_fail['unanswered']} {first_fail['unanswered_actions']}") if first_fail else None,
               wall_s_at_n=best["wall_s"] if best else None,
               lost_final_status_acks=sum(r["lost_status_acks"] for r in rounds), capped_by_sizes=first_fail is None),
        metric("fleet_service_p95", p95, "ms", base_p95, ratio(p95, base_p95),
               len(best["platform_ms"]) if best else 0, samples=best["platform_ms"] if best else None,
               at_n=n_best, robot_call_p95_ms=percentile(best["robot_ms"], 95) if best else None,
               rapp="rtt-probe", floor_meaning="platform service p95 with 1 robot, same run"),
    ]


async def _warm(rs: RobotSystem):
    if not rs.robots:
        await rs.add_robots(1)
    return (rs.robots[0],)
