"""Fleet: N robots (nao/elektron alternately) each running the hazard-detection RApp at once, on one
Platform, one Store and one XMPP server. Each robot lives in its own copy of the small house (one
World per robot, seeded door and lamp states), so the tasks compete for the agents, the server and
the two cores, not for doorways. Rounds with growing N (full: 1, 1, 1 and GOAL = 50; quick: 1, 1, 1
and QUICK_GOAL = 8; robots are added between rounds, and the robots of earlier rounds run again from
where they stopped); a round passes when every task finishes ("hazard-detection finished") and every
request of every Dynamic Agent is answered (from the trace), or failed because its Cloud Agent died
and the Dynamic Agent was told so (such crashes are reported per round). Whether every hazard was
classified correctly is reported per round too. A round ends, said so, when the machine's available
memory falls below MIN_AVAILABLE_MB (the kernel's OOM killer would otherwise pick a process).

Reports the largest passing N (`fleet`; floor = the goal; ratio = goal / N, <= 1 met) and the
Platform service latency p95 at that N (`fleet_service_p95`; floor = the same p95 with 1 robot, over
FLOOR_ROUNDS rounds measured first in the same run), with the p95 of each service; and per round the
CPU seconds and memory (Pss) of one robot-task by process kind (KINDS, sampled from /proc by
bench/proc_cpu.py), the messages and bytes the agents sent. `python -m bench.capacity` runs the same
rounds at other sizes for docs/capacity.md.

Deployed as a fleet would be (`run(apart=True)`, the default): the Store and the Platform run as
`rapp agent store` / `rapp agent platform --warm-workers N` processes, the Platform keeping a started
Cloud Agent process per robot that may ask for one at once (one per robot, idle or running: a worker
handed a run is replaced when the run ends); the simulated cameras' render processes (RENDER_SHARED,
shared by the worlds) run in sessions of their own, under Linux's SCHED_IDLE with their scheduling
group at nice 19 (they get the CPU only when no agent wants it). What that stands for:
real robots render nothing and bring their own CPUs, while here the simulations and their render
processes share the Platform's two cores (agents/priority.py: Linux's autogroup schedules each
session as one group, so a render in this process's session would only yield to the Cores).
The Cores and Dynamic Agents stay at normal priority (at nice 10 they missed heartbeats). The
owners upload their homes over XMPP, as the owner's app does.
"""
from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path

from ontology.trace import FINAL_ANSWERS, RecordKind

from .common import log, metric, ms, percentile, quiet_logs, ratio
from .proc_cpu import ProcessKinds, ProcessSampler, mem_available_mb

CLOUD_LIFECYCLE = ("start_cloud_agent", "stop_cloud_agent")  # reported apart as context, still judged
FLOOR_ROUNDS = 3
GOAL = 50  # issue 46 item 5 (20 until then)
QUICK_GOAL = 8
HOUSE = "small"
# a fleet too large for the machine's memory ends its round, said so, before the kernel's OOM killer
# picks a process (of this run or of anyone else's on the machine)
MIN_AVAILABLE_MB = 2048
RENDER_WORKERS = 1  # per world, when the worlds do not share (RENDER_SHARED = 0)
# render processes all the worlds share (robots/render_process.py SharedRenderer: the same house, each
# world's state set before its frame): one per core. One per world held ~140 MB (Pss) a robot, the
# most of any kind (bench/RESULTS.md "fleet memory")
RENDER_SHARED = 2
# what each process kind of the measured tree stands for (bench/proc_cpu.py classifies them)
KINDS = {"cores": "this process: the Cores, their simulations (World steps) and the owners' chat clients",
         "dynamic": "Dynamic Agents and the Cores' warm Dynamic workers (agents.runtime under this process)",
         "platform": "the Platform Agent's process (`rapp agent platform`)",
         "cloud": "Cloud Agents and the Platform's warm Cloud workers (agents.runtime under the Platform)",
         "store": "the Store Agent's process and its builds",
         "render": "the simulated cameras' render processes (a real robot renders nothing)",
         "xmpp_server": "the XMPP server (the embedded pyjabber)"}


def request_latencies(trace: list[dict], since: float, platform: str) -> tuple[dict, int]:
    """Per Dynamic Agent request after `since`: latency by target kind; and the unanswered count."""
    sends, answers, down = {}, {}, {}
    for r in trace:
        if r["kind"] == RecordKind.STRUCTURE and r.get("event") == "cloud-down" and r["t"] >= since:
            down.setdefault((r["agent"], r["cloud"]), []).append(r["t"])  # told its Cloud Agent died: calls in flight failed
        if r["kind"] != RecordKind.MESSAGE or r["t"] < since or not r["agent"].startswith("dyn-"):
            continue
        if r["dir"] == "send" and r["performative"] == "request":
            sends[r["conversation_id"]] = r
        elif r["dir"] == "recv" and r["performative"] in FINAL_ANSWERS and not r.get("feedback"):
            answers.setdefault(r["conversation_id"], r)
    lat = {"platform": [], "robot": [], "other": [], "by_action": {}, "failed_by_crash": []}
    missing, lost_status = [], []
    for conv, s in sends.items():
        a = answers.get(conv)
        if a is None and any(t >= s["t"] for t in down.get((s["agent"], s["receiver"]), ())):
            lat["failed_by_crash"].append(f"{s['agent'].split('@')[0]}:{s['action']}")  # not lost: failed, and said so
            continue
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
        if kind == "platform":
            lat["by_action"].setdefault(s["action"], []).append(a["t"] - s["t"])
    lat["lost_status_acks"] = lost_status
    lat["services"] = [x for a, v in lat["by_action"].items() if a not in CLOUD_LIFECYCLE for x in v]
    return lat, missing


def agent_kind(jid: str) -> str:
    """core, dyn, cloud, platform, store, owner... (the local part's first word)."""
    return jid.split("@")[0].split("-")[0]


def traffic(records: list[dict]) -> dict:
    """The messages the agents sent (as traced: one record per send), by the sender's kind: count
    and bytes of their bodies."""
    out: dict[str, list[int]] = {}
    for r in records:
        if r["kind"] == RecordKind.MESSAGE and r.get("dir") == "send":
            c = out.setdefault(agent_kind(r["agent"]), [0, 0])
            c[0] += 1
            c[1] += int(r.get("size") or 0)
    return {"messages": sum(c[0] for c in out.values()), "bytes": sum(c[1] for c in out.values()),
            "by_sender": {k: {"messages": c[0], "bytes": c[1]} for k, c in sorted(out.items())}}


def per_task(usage: dict, n: int) -> dict:
    """A round's CPU seconds and peak memory by process kind, per robot-task."""
    cpu = usage["cpu_s"]
    return {"cpu_s": {k: round(v / n, 2) for k, v in cpu.items()}, "cpu_s_total": round(sum(cpu.values()) / n, 2),
            "pss_mb": {k: round(v / n, 1) for k, v in usage["pss_mb_peak"].items()},
            "pss_mb_total": round(usage["pss_mb_peak_total"] / n, 1)}


def keep_trace(trace: Path, directory: Path | None = None) -> Path:
    """A copy of a failed round's trace, outside the run's temporary directory (deleted at its end),
    named by the time: what was lost or late can be looked up afterwards."""
    directory = Path(directory or tempfile.gettempdir())
    kept = directory / f"bench-fleet-failed-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.jsonl"
    shutil.copyfile(trace, kept)
    return kept


IDLE_GROUP_NICE = 19


def run_when_idle(pid: int) -> None:
    """Every thread of `pid` under SCHED_IDLE (no privilege needed to lower one's own children), and
    its session's scheduling group (a render process leads one of its own) at nice 19: with Linux's
    autogroup a thread's policy only counts inside its session, so in this process's session the
    renders yielded to the Cores alone and took 0.8-1.2 of the two cores in a 20-robot round."""
    from agents.priority import each_thread, set_group_nice

    each_thread(pid, lambda tid: os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0)))
    set_group_nice(pid, IDLE_GROUP_NICE, retry_s=0.5)  # in a thread: an unprivileged writer waits its turn


class HazardFleet:
    """One RappSystem with the hazard-detection RApp published; robots added on demand, robot i
    (kind nao/elektron alternately) in its own World (small house, seed i + 1), owned by its own
    user whose home description is on the Platform."""

    def __init__(self, workdir: Path, platform_kw: dict | None = None, apart: bool = False):
        self.workdir = Path(workdir)
        self.platform_kw = platform_kw or {}  # PlatformAgent options (services, service_workers, ...)
        # apart: the Store and the Platform in their own processes (`rapp agent store/platform`), the
        # simulated cameras' render processes at a lower CPU priority. Real robots bring their own
        # CPUs and render nothing; here 20 simulations share the Platform's two cores, and in one
        # process the Platform also shared their interpreter lock. (All of the robots' side at
        # nice 10 starved the Dynamic Agents: missed heartbeats ended tasks.)
        self.apart = apart
        self.processes = None  # scenarios/launch.py LoggedProcesses: the Store and Platform apart
        self.trace_file = self.workdir / "trace.jsonl"
        self.system = self.state = self.home = None
        self.worlds, self.robots = [], []
        self.kinds = ProcessKinds(os.getpid(), "cores", runtime_kind={"cores": "dynamic", "platform": "cloud"})
        self.sampler: ProcessSampler | None = None  # CPU and memory by process kind (bench/proc_cpu.py)
        self.renderer = None  # the worlds' shared render processes (RENDER_SHARED)
        self._idle_renders: set[int] = set()  # render processes already named and set to SCHED_IDLE

    async def __aenter__(self) -> "HazardFleet":
        from agents.services.context import ServiceState
        from scenarios.hazard import RAPP_DIR
        from scenarios.system import RappSystem

        quiet_logs()
        self.state = ServiceState(work_dir=self.workdir / "services")
        self.system = RappSystem(self.workdir / "system", trace_file=self.trace_file, store_and_platform=not self.apart,
                                 services=self.platform_kw.get("services"),
                                 platform_kw={"services_state": self.state,
                                              **{k: v for k, v in self.platform_kw.items() if k != "services"}})
        await self.system.start()
        if self.system.server is not None and self.system.server.proc is not None:
            self.kinds.name(self.system.server.proc.pid, "xmpp_server")
        if self.apart:
            await self._start_apart()
        self.sampler = await asyncio.to_thread(ProcessSampler(self.kinds).start)
        await self.system.publish(RAPP_DIR)
        platform = self.system.platform
        if platform is not None and platform.warm_pool.size > 1:  # sized to the fleet: filled first
            platform.start_cloud_workers()
            await platform.warm_pool.wait_ready(timeout=30.0 * platform.warm_pool.size)
        return self

    async def _start_apart(self) -> None:
        """`rapp agent store` and `rapp agent platform` as a deployment runs them, on this run's
        server and credentials; returns when both run and the Cloud workers asked for are ready."""
        import sys

        from scenarios.launch import LoggedProcesses

        env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_")}
        env.update(self.system.settings.to_env(), XDG_DATA_HOME=str(self.workdir / "data"),
                   PYTHONPATH=str(Path(__file__).resolve().parent.parent))
        self.processes = LoggedProcesses(self.workdir, env, [sys.executable, "-m", "cli.main", "agent"],
                                         die_with_parent=True)
        warm = self.platform_kw.get("warm_workers")
        self.kinds.name(self.processes.start("store", "store").pid, "store")
        self.kinds.name(self.processes.start("platform", "platform", *(["--warm-workers", str(warm)] if warm else [])).pid,
                        "platform")
        await self.processes.wait_log("store", "running", 60)
        await self.processes.wait_log("platform", "running", 60)
        if warm:
            await self.processes.wait_log("platform", "cloud workers", 60 + 10 * warm)

    async def add_robots(self, count: int) -> None:
        from robots import OdometryNoise, RobotAPI, World
        from robots.render_process import SharedRenderer
        from scenarios.home_setup import hazard_overrides, home_description, upload_home, upload_home_over_xmpp
        from scenarios.runner import listening
        from scenarios.system import wait_until

        new = []
        for _ in range(count):
            i = len(self.robots) + len(new)
            if mem_available_mb() < MIN_AVAILABLE_MB:
                raise MemoryError(f"robot {i + 1} not added: {mem_available_mb():.0f} MB available "
                                  f"(< {MIN_AVAILABLE_MB} MB) with {i} robots")
            kind, seed = ("nao", "elektron")[i % 2], i + 1
            if RENDER_SHARED and self.renderer is None:
                self.renderer = SharedRenderer(RENDER_SHARED, name="fleet")
            # without sharing, one render process per world (a World's default is two): its one robot
            # renders a frame at a time
            world = await asyncio.to_thread(World.from_file, HOUSE, seed=seed, overrides=hazard_overrides(HOUSE, seed),
                                            render_workers=RENDER_WORKERS, renderer=self.renderer)
            self.worlds.append(world)
            if self.apart:  # the simulation's camera renders, which real robots do not need, yield
                await asyncio.to_thread(world.start_renderer, own_session=True)
                for pid in set(world.render_pids()) - self._idle_renders:
                    self._idle_renders.add(pid)
                    self.kinds.name(pid, "render")
                    await asyncio.to_thread(run_when_idle, pid)
            robot = await asyncio.to_thread(world.add_robot, kind, odometry_noise=OdometryNoise.typical())
            if self.home is None:  # the same layout in every world: one map and hazard list
                self.home = await asyncio.to_thread(home_description, world, HOUSE, self.workdir / "home")
            user = f"owner-{kind}{i + 1}"
            if not self.apart:
                upload_home(self.state, user, *self.home)
            new.append(await self.system.add_robot(kind, api=RobotAPI(robot), robot_id=f"{kind}{i + 1}", user=user))
        for h in new:
            await h.user.watch_tasks(h.core.address)  # the Core's task records (ontology/results.py)
            await wait_until(lambda h=h: listening(h.core), 60, f"{h.robot_id} listening")
            if self.apart:  # as the owner's app does it: over XMPP, with the owner's token
                await upload_home_over_xmpp(h.core, h.core.platform, await h.core.fresh_token(), *self.home)
        self.robots.extend(new)

    async def check_hazards(self, i: int, timeout: float) -> dict:
        """Robot i's owner says "check the hazards"; how the task ended (its TaskRecord's state and reports)."""
        from scenarios.hazard import COMMAND
        from scenarios.runner import listening
        from scenarios.system import wait_until

        h = self.robots[i]
        start = len(h.user.ended)
        await h.user.say(h.core.address, COMMAND)
        record = await h.user.task_end(timeout, start)
        await wait_until(lambda: listening(h.core) and h.core.dynamic is None, 60, f"{h.robot_id} listening again")
        return {"finished": record.state == "Finished", "end": record.told or record.reason, "reports": record.reports}

    def all_correct(self, i: int, run: dict) -> bool:
        """Robot i's reports of this round against its world's truth."""
        from scenarios.hazard import hazard_reports, reported, score_hazards

        reports = hazard_reports(run["reports"])
        rows = score_hazards(self.home[0].hazards, self.worlds[i].ground_truth(), reported(reports))
        return all(r["true_state"] == r["reported_state"] for r in rows)

    async def __aexit__(self, *exc) -> None:
        if self.sampler is not None:
            self.sampler.stop()
        try:
            if self.system is not None:
                await self.system.stop()
        finally:
            for w in self.worlds:
                w.close()
            if self.renderer is not None:  # it ends processes and waits for them: off the loop
                await asyncio.to_thread(self.renderer.close)
            await asyncio.to_thread(self._stop_apart)

    def _stop_apart(self) -> None:
        if self.processes is not None:
            self.processes.stop_all(20.0)  # the Platform first, then the Store


async def watch_memory(work: asyncio.Future, period: float = 1.0) -> str | None:
    """Until `work` is done; if the machine's available memory falls below MIN_AVAILABLE_MB first,
    `work` is cancelled and what was seen is returned."""
    least = float("inf")
    while not work.done():
        least = min(least, mem_available_mb())
        if least < MIN_AVAILABLE_MB:
            work.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await work
            return f"round ended: {least:.0f} MB of memory available (< {MIN_AVAILABLE_MB} MB)"
        await asyncio.wait([work], timeout=period)
    return None


async def one_round(fleet: HazardFleet, n: int, timeout: float) -> dict:
    from agents.tracing import read_trace

    short = None
    if len(fleet.robots) < n:
        try:
            await fleet.add_robots(n - len(fleet.robots))
        except MemoryError as e:
            short = str(e)
            log(f"fleet N={n}: {short}")
    load_before = os.getloadavg()
    # a /proc scan takes tens of ms with a fleet's processes: off the loop the agents' beats run on
    mark = await asyncio.to_thread(fleet.sampler.mark) if fleet.sampler else None
    sim_before = [w.time for w in fleet.worlds[:n]]
    since = time.time()
    t0 = time.perf_counter()
    if short is None:
        tasks = asyncio.gather(*(fleet.check_hazards(i, timeout) for i in range(n)), return_exceptions=True)
        short = await watch_memory(tasks)
    runs = [MemoryError(short)] * n if short else await tasks
    wall = time.perf_counter() - t0
    usage = await asyncio.to_thread(fleet.sampler.since, mark) if fleet.sampler and mark else None
    # the robots' own time: what a task takes a real robot (the worlds run as fast as they can)
    sim_s = [w.time - t for w, t in zip(fleet.worlds, sim_before)]
    failed = [f"robot {i + 1}: {str(r)[:200]}" for i, r in enumerate(runs)
              if isinstance(r, BaseException) or not r["finished"]]
    records = [r for r in await asyncio.to_thread(read_trace, fleet.trace_file) if r["t"] >= since]  # this round
    wrong = [fleet.robots[i].robot_id for i, r in enumerate(runs)
             if isinstance(r, dict) and not fleet.all_correct(i, r)]
    lat, missing = request_latencies(records, since, fleet.system.platform_address)
    ok = not failed and not missing and len(lat["platform"]) >= n
    # silences of live Dynamic Agents the Core waited out instead of ending them (agents/liveness.py)
    late = [r for r in records if r["kind"] == RecordKind.STRUCTURE and r.get("event") == "heartbeat-late"]
    # Cloud Agents whose process died (a crash in native code): what the Platform recorded of it
    crashes = [f"{r['cloud'].split('@')[0]} code {r['exit_code']}: {next(iter((r.get('stderr') or '').splitlines()), '')}"
               for r in records if r["kind"] == RecordKind.STRUCTURE and r.get("event") == "cloud-lost"]
    usage_extra = {}
    if usage is not None:
        cpu_total = sum(usage["cpu_s"].values())
        usage_extra = {"usage": usage, "per_task": per_task(usage, n),
                       # CPU the round asked for per second of its wall time, against the 2 cores there are
                       "cpu_demand_cores": round(cpu_total / wall, 2), "cores": os.cpu_count(),
                       "sampling_cpu_s": round(fleet.sampler.sampling_cpu_s, 2) if fleet.sampler else None}
    res = {"n": n, "ok": ok, "wall_s": wall, "failed": failed, "misclassified": wrong,
           "load_before": [round(x, 2) for x in load_before], "load_after": [round(x, 2) for x in os.getloadavg()],
           "traffic": traffic(records), "sim_s_per_task": round(sum(sim_s) / len(sim_s), 1) if sim_s else None,
           **usage_extra,
           "heartbeats_late": len(late), "longest_late_silence_s": max((r["silence"] for r in late), default=None),
           "unanswered": len(missing), "unanswered_actions": missing[:5],
           "cloud_crashes": crashes, "failed_by_crash": lat["failed_by_crash"],
           "lost_status_acks": len(lat["lost_status_acks"]),
           "platform_ms": ms(lat["platform"]), "robot_ms": ms(lat["robot"]), "services_ms": ms(lat["services"]),
           # which services make the p95: per action, p95 ms and count
           "platform_p95_by_action": {a: [round(percentile(ms(v), 95), 1), len(v)]
                                      for a, v in sorted(lat["by_action"].items())}}
    log(f"fleet N={n}: {'ok' if ok else 'FAILED'} in {wall:.1f} s, {n - len(wrong)}/{n} all hazards correct, "
        f"platform p95 {percentile(res['platform_ms'], 95):.1f} ms, robot p95 {percentile(res['robot_ms'], 95):.1f} ms, "
        f"{len(late)} late-heartbeat silences waited out"
        + (f", Cloud Agents crashed {crashes} (calls failed by it {lat['failed_by_crash']})" if crashes else "")
        + (f"; failures {failed[:2]} unanswered {missing[:5]}" if not ok else "")
        + f"; p95 ms by service {res['platform_p95_by_action']}"
        + (f"; CPU-s per task by kind {res['per_task']['cpu_s']} ({res['per_task']['cpu_s_total']} in all,"
           f" {res['cpu_demand_cores']} cores busy on average)" if usage is not None else ""))
    return res


async def run_rounds(sizes: list[int], timeout: float = 1200.0, apart: bool = True) -> list[dict]:
    """One fleet, a round per size in order (robots added as needed); stops at the first failed round."""
    goal_n = max(sizes)
    rounds: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        # the Platform keeps a started Cloud Agent process per robot that may start one at once
        # (`rapp agent platform --warm-workers N`): a burst of cold starts is the fleet's worst p95
        async with HazardFleet(Path(tmp), {"warm_workers": goal_n}, apart=apart) as fleet:
            for n in sizes:
                r = await one_round(fleet, n, timeout)
                rounds.append(r)
                if not r["ok"]:
                    r["trace_kept"] = str(keep_trace(fleet.trace_file))  # the run's directory goes
                    log(f"fleet N={n}: the trace of the failed round is kept in {r['trace_kept']}")
                    break
    return rounds


async def run(quick: bool = True, sizes: list[int] | None = None, timeout: float = 1200.0,
              apart: bool = True) -> list[dict]:
    # quick mode judges a fleet of QUICK_GOAL, the full run GOAL. The floor's one robot runs
    # FLOOR_ROUNDS times: one round has 12 service calls, so its p95 fell between its two slowest
    # and moved by half between runs (36-65 ms)
    sizes = sizes or ([1] * FLOOR_ROUNDS + [QUICK_GOAL if quick else GOAL])
    return summarize(await run_rounds(sizes, timeout, apart), max(sizes))


def summarize(rounds: list[dict], goal_n: int) -> list[dict]:
    base = rounds[0]
    passed = [r for r in rounds if r["ok"]]
    best = passed[-1] if passed else None
    n_best = best["n"] if best else 0
    p95 = percentile(best["platform_ms"], 95) if best else None
    floor = [x for r in rounds if r["n"] == 1 and r["ok"] for x in r["platform_ms"]]  # every 1-robot round's calls
    base_p95 = percentile(floor, 95) if floor else None
    first_fail = next((r for r in rounds if not r["ok"]), None)
    tried = ",".join(str(r["n"]) for r in rounds)
    return [
        metric("fleet", n_best, "robots", goal_n, ratio(goal_n, n_best), len(rounds), rapp="hazard-detection",
               house=HOUSE, sizes_tried=tried,
               first_failure=(f"N={first_fail['n']}: {first_fail['failed'][:1]} unanswered={first_fail['unanswered']}"
                              f" {first_fail['unanswered_actions']}") if first_fail else None,
               failed_round_trace=first_fail.get("trace_kept") if first_fail else None,
               wall_s_at_n=best["wall_s"] if best else None,
               all_correct_at_n=(n_best - len(best["misclassified"])) if best else None,
               lost_final_status_acks=sum(r["lost_status_acks"] for r in rounds), capped_by_sizes=first_fail is None,
               # per round, in order: [robots, value]
               heartbeats_late_by_round=[[r["n"], r["heartbeats_late"]] for r in rounds],
               # CPU-s and memory (Pss MB) of one robot-task by process kind (KINDS), at the size reached
               per_task_at_n=best.get("per_task") if best else None,
               cpu_demand_cores_at_n=best.get("cpu_demand_cores") if best else None,
               per_task_by_round=[[r["n"], r.get("per_task")] for r in rounds],
               cloud_crashes_by_round=[[r["n"], r["cloud_crashes"]] for r in rounds]),
        metric("fleet_service_p95", p95, "ms", base_p95, ratio(p95, base_p95),
               len(best["platform_ms"]) if best else 0, samples=best["platform_ms"] if best else None,
               at_n=n_best, goal_n=goal_n, by_action_at_n=best["platform_p95_by_action"] if best else None,
               floor_by_action=base["platform_p95_by_action"], floor_n=len(floor),
               # context: the p95 without the Cloud Agents' starts and stops, which a fleet told at
               # once does in one burst (the goal is judged on every call, these included)
               services_p95_without_cloud_lifecycle_ms=percentile(best["services_ms"], 95) if best else None,
               floor_services_p95_without_cloud_lifecycle_ms=percentile(base["services_ms"], 95),
               robot_call_p95_ms=percentile(best["robot_ms"], 95) if best else None,
               rapp="hazard-detection", floor_meaning="platform service p95 with 1 robot, same run"),
    ]
