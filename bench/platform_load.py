"""Platform-only load test: the service requests of one real hazard-detection run, replayed for
many robots at once without their simulations (issue #20, item 3).

1. Record: one robot runs the hazard-detection RApp in the small house (bench/fleet.py's
   HazardFleet); the Platform's services are wrapped to record each request (action, fields, when
   it started and ended). A run makes ~10 requests: home_get_info, plan_path_2d per leg, door and
   light checks on the camera's real rendered frames, obstacle marks.
2. Replay: `robots` simulated robots, each its own user with its own copy of the home (the same
   house, a map of its own: the origin is offset by a nanometre per robot, so no Platform shares
   one robot's cost maps with another), send the recorded requests in order over XMPP, each after
   the recorded pause since the previous answer (times `time_scale`), all starting within the first
   second. Against:
   - `threads`: one Platform running every service in threads (the code before the process pool: the floor),
   - `pool`: one Platform with its process pool (one worker per core),
   - `two`: a primary and a replica Platform agent (each with its pool), clients choosing by load
     (agents/platform_directory.py; the stateful services stay on the primary).
   One robot alone against `pool` gives the reference p95.

Metrics: platform_load_<config> = service p95 (ms) at `robots` robots; floor = one robot's p95;
ratio = p95 / floor (goal: <= 3 for pool and two); throughput_rps = requests answered / wall time
of the replay; errors = requests not answered with a reply.
platform_capacity_<config> = requests/s when the same robots replay without any pause (each
request as soon as the previous answer came): what each configuration can serve; floor = the
threads configuration's (ratio = floor / value, > 1: fewer than threads).
"""
from __future__ import annotations

import asyncio
import dataclasses
import random
import tempfile
import time
from pathlib import Path

from .common import log, metric, ms, percentile, quiet_logs, ratio

ROBOTS = 50
CLIENTS = 10  # agents the simulated robots' requests leave from (each robot: its own user and token)
GOAL_RATIO = 3.0
SATURATED_RUNS = 10  # runs per robot in the replay without pauses (quick mode: 3)


@dataclasses.dataclass
class Recorded:
    action: str
    fields: dict  # the request without its token
    think_s: float  # from the previous answer (or the run's first request) to this request
    service_s: float  # how long the service took in the recorded run


def _recording(run, name: str, calls: list):
    def wrapped(req, ctx):
        t0 = time.monotonic()
        try:
            return run(req, ctx)
        finally:
            calls.append((t0, time.monotonic(), name, req.model_dump(mode="json", exclude={"token"})))
    return wrapped


async def record(workdir: Path, timeout: float = 900.0) -> tuple[list[Recorded], tuple]:
    """The Platform requests of one hazard-detection run, and the home (info, png, yaml) it used."""
    from agents.services import SERVICES

    from .fleet import HazardFleet

    calls: list = []
    services = {n: dataclasses.replace(s, run=_recording(s.run, n, calls)) for n, s in SERVICES.items()}
    async with HazardFleet(workdir, platform_kw={"services": services, "service_workers": 0}) as fleet:
        await fleet.add_robots(1)
        t0 = time.perf_counter()
        end = await fleet.check_hazards(0, timeout)
        log(f"recorded run: {end['end'][:80]!r} in {time.perf_counter() - t0:.1f} s, {len(calls)} requests")
        home = fleet.home
    calls.sort()
    out, last = [], calls[0][0] if calls else 0.0
    for start, stop, name, fields in calls:
        out.append(Recorded(name, fields, max(0.0, start - last), stop - start))
        last = stop
    return out, home


def _home_for(home: tuple, i: int) -> tuple:
    """Robot i's own copy of the home: its map's origin offset by i nanometres (another map to the
    Platform's caches, the same plans)."""
    import yaml

    info, png, yaml_text = home
    meta = yaml.safe_load(yaml_text)
    meta["origin"] = [float(meta["origin"][0]) + i * 1e-9] + [float(v) for v in meta["origin"][1:]]
    return info, png, yaml.safe_dump(meta)


async def replay(settings, workdir: Path, config: str, recorded: list[Recorded], home: tuple, robots: int,
                 time_scale: float, seed: int = 1, suffix: str = "", repeat: int = 1) -> dict:
    from agents.base import RappAgent
    from agents.platform_agent import PlatformAgent
    from agents.platform_directory import PlatformChooser
    from agents.errors import RequestError
    from agents.services.context import ServiceState
    from ontology import platform as P
    from rapps.sdk import PlatformProxy
    from scenarios.home_setup import upload_home
    from scenarios.system import wait_until

    tag = f"{config}{robots}{suffix}"
    state = ServiceState(work_dir=workdir / f"services-{tag}")
    primary_name = f"platform-{tag}"
    agents = [PlatformAgent(primary_name, settings=settings, services_state=state, workdir=workdir / primary_name,
                            service_workers=0 if config == "threads" else None,
                            replicas=[f"{primary_name}-r"] if config == "two" else ())]
    if config == "two":
        agents.append(PlatformAgent(f"{primary_name}-r", settings=settings, workdir=workdir / f"{primary_name}-r",
                                    primary=primary_name))
    clients = [RappAgent(f"load-{tag}-{k}", settings) for k in range(min(CLIENTS, robots))]
    try:
        await asyncio.gather(*(a.start() for a in agents), *(c.start() for c in clients))
        for a in agents:
            if a.service_pool is not None:
                await asyncio.to_thread(a.service_pool.wait_ready, 60)
        primary = agents[0]
        if config == "two":
            await wait_until(lambda: primary.platforms.live(), 10, "replica registered")
        proxies = []
        for i in range(robots):
            client, user = clients[i % len(clients)], f"robot{i}"
            await client.request(primary.address, P.RegisterUser(user=user, password="pw"))
            token = (await client.request(primary.address, P.Login(user=user, password="pw", ttl_s=3600))).token
            upload_home(state, user, *_home_for(home, i))
            if config == "two" and getattr(client, "platform_chooser", None) is None:
                client.platform_chooser = PlatformChooser(client, primary.address, token)
            proxies.append(PlatformProxy(client, primary.address, token))
        lat: list[float] = []
        errors: list[str] = []
        rng = random.Random(seed)

        async def robot(proxy) -> None:
            if time_scale > 0:
                await asyncio.sleep(rng.random())  # owners do not all speak in the same millisecond
            for rec in recorded * repeat:
                await asyncio.sleep(rec.think_s * time_scale)
                t0 = time.perf_counter()
                try:
                    # by action name, with the recorded fields as sent (the token included)
                    await proxy._call(rec.action, dict(rec.fields), 300.0)  # noqa: SLF001
                    lat.append(time.perf_counter() - t0)
                except RequestError as e:
                    errors.append(f"{rec.action}: {e.reason[:100]}")

        t0 = time.perf_counter()
        await asyncio.gather(*(robot(p) for p in proxies))
        wall = time.perf_counter() - t0
        served = {a.address.split("@")[0]: a.served for a in agents}
        res = {"config": config, "robots": robots, "lat_ms": ms(lat), "errors": errors, "wall_s": wall,
               "throughput_rps": len(lat) / wall if wall > 0 else 0.0, "served": served}
        log(f"platform_load {config} x{robots}: p95 {percentile(res['lat_ms'], 95):.1f} ms, median "
            f"{percentile(res['lat_ms'], 50):.1f} ms, {res['throughput_rps']:.1f} req/s over {wall:.1f} s, "
            f"{len(errors)} errors, served {served}")
        return res
    finally:
        for c in clients:
            await c.stop()
        for a in reversed(agents):
            await a.stop()


async def run(quick: bool = True, robots: int | None = None, time_scale: float | None = None,
              configs: tuple[str, ...] = ("threads", "pool", "two")) -> list[dict]:
    from xmpp_server import EmbeddedServer

    quiet_logs()
    robots = robots or ROBOTS
    time_scale = time_scale if time_scale is not None else (0.25 if quick else 1.0)
    with tempfile.TemporaryDirectory(prefix="bench-platform-load-") as tmp:
        work = Path(tmp)
        recorded, home = await record(work / "record")
        mix = {}
        for r in recorded:
            mix[r.action] = mix.get(r.action, 0) + 1
        log(f"request mix of one run: {mix}; recorded pauses {sum(r.think_s for r in recorded):.1f} s")
        server = EmbeddedServer(db=work / "xmpp.db")
        await server.astart()
        try:
            settings = server.settings(credentials_dir=work / "credentials")
            one = await replay(settings, work, "pool", recorded, home, 1, time_scale)
            rounds = [await replay(settings, work, c, recorded, home, robots, time_scale) for c in configs]
            # capacity: no pauses at all, each robot's next request as soon as its previous answer came
            # (every robot's run SATURATED_RUNS times over: a few seconds of full load, not one burst)
            saturated = [await replay(settings, work, c, recorded, home, robots, 0.0, suffix="s",
                                      repeat=3 if quick else SATURATED_RUNS) for c in configs]
        finally:
            await asyncio.to_thread(server.close)
    floor = percentile(one["lat_ms"], 95)
    out = []
    for r in rounds:
        p95 = percentile(r["lat_ms"], 95) if r["lat_ms"] else None
        out.append(metric(f"platform_load_{r['config']}", p95, "ms", floor, ratio(p95, floor), len(r["lat_ms"]),
                          samples=r["lat_ms"], robots=robots, time_scale=time_scale,
                          throughput_rps=r["throughput_rps"], wall_s=r["wall_s"], errors=len(r["errors"]),
                          first_errors="; ".join(r["errors"][:3]) or None, served=str(r["served"]),
                          one_robot_throughput_rps=one["throughput_rps"], requests_per_run=len(recorded),
                          request_mix=str(mix), floor_meaning="service p95 of one robot alone (pool), same run"))
    base = next((r["throughput_rps"] for r in saturated if r["config"] == "threads"), None)
    for r in saturated:
        out.append(metric(f"platform_capacity_{r['config']}", r["throughput_rps"], "req/s", base,
                          ratio(base, r["throughput_rps"]), len(r["lat_ms"]), robots=robots, wall_s=r["wall_s"],
                          p95_ms=percentile(r["lat_ms"], 95) if r["lat_ms"] else None,
                          median_ms=percentile(r["lat_ms"], 50) if r["lat_ms"] else None, errors=len(r["errors"]),
                          served=str(r["served"]), ratio_meaning="floor/value (>1: fewer requests/s than threads)",
                          floor_meaning="requests/s of one Platform running the services in threads, no pauses"))
    return out
