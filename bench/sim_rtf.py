"""Simulation benchmark: N robots in the full house, each driving and capturing a 320x240 frame every
100 ms of simulation time through RobotAPI; reports the real-time factor (sim s / wall s) for 1, 2, 4
robots and the ratio to a floor measured in the same run (bare pybullet: the same kinematic base updates
and getCameraImage calls in a plain loop, no API / asyncio / thread hand-off, all in one thread).
Images are rendered in render processes (World render="process", the default) or in the world's
pybullet thread (--render inline). The stall measurement renders one 1280x960 frame while a coroutine
ticks every 10 ms and reports the coroutine's maximum lateness (event-loop stall).

    python -m bench.sim_rtf [--sim-seconds 5] [--house house] [--render process|inline] [--stall]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import time

from robots.pybullet_quiet import p

from ontology.robot import MoveVel
from robots import RobotAPI, World

KINDS = ["nao", "elektron", "nao", "elektron"]
FRAME_PERIOD = 0.1


async def api_run(house: str, n: int, sim_seconds: float, render: str = "process") -> float:
    world = World.from_file(house, seed=1, rtf=0.0, render=render)
    apis = [RobotAPI(world.add_robot(KINDS[i], name=f"r{i}")) for i in range(n)]
    await asyncio.to_thread(world.start_renderer, n)  # process start-up is not part of the measurement
    for a in apis:
        await a.move_vel(MoveVel(x=0.05, theta=0.2))

    frames = [0]

    async def camera_loop(api: RobotAPI) -> None:
        next_frame = 0.0
        while next_frame < sim_seconds:
            await api.capture_array(resolution="320x240")
            frames[0] += 1
            next_frame += FRAME_PERIOD
            await world.sleep(max(next_frame - world.time, 0.0))

    t0, s0 = time.perf_counter(), world.time
    await asyncio.gather(*(camera_loop(a) for a in apis))
    rtf = (world.time - s0) / (time.perf_counter() - t0)
    world.close()
    expected = n * round(sim_seconds / FRAME_PERIOD)
    assert frames[0] >= expected, (frames[0], expected)
    return rtf


async def loop_stall(house: str, render: str, resolution: str = "1280x960") -> dict:
    """Max lateness of a 10 ms ticker while one frame renders (the world's first frame is not measured)."""
    world = World.from_file(house, seed=1, render=render)
    api = RobotAPI(world.add_robot("nao", name="r0"))
    await api.capture_array(resolution="160x120")
    loop = asyncio.get_running_loop()
    late: list[float] = []

    async def ticker() -> None:
        while True:
            t = loop.time()
            await asyncio.sleep(0.01)
            late.append(loop.time() - t - 0.01)

    task = asyncio.create_task(ticker())
    await asyncio.sleep(0.05)
    t0 = time.perf_counter()
    await api.capture_array(resolution=resolution)
    took = time.perf_counter() - t0
    await asyncio.sleep(0.03)
    task.cancel()
    world.close()
    return {"render": render, "frame": resolution, "frame_s": round(took, 3),
            "max_loop_lateness_ms": round(max(late) * 1e3, 1)}


def floor_run(house: str, n: int, sim_seconds: float) -> float:
    world = World.from_file(house, seed=1, rtf=0.0)
    robots = [world.add_robot(KINDS[i], name=f"r{i}") for i in range(n)]

    def loop() -> float:
        dt, t, steps = world.clock.step, 0.0, round(FRAME_PERIOD / world.clock.step)
        t0 = time.perf_counter()
        while t < sim_seconds:
            for r in robots:
                cam = next(iter(r.cameras.values()))
                T = cam.link_pose()
                eye, fwd, up = T[:3, 3], T[:3, 0], T[:3, 2]
                _, vfov = cam.fov(320, 240)
                view = p.computeViewMatrix(eye.tolist(), (eye + fwd).tolist(), up.tolist(), physicsClientId=world.cid)
                proj = p.computeProjectionMatrixFOV(math.degrees(vfov), 320 / 240, 0.02, 40.0, physicsClientId=world.cid)
                p.getCameraImage(320, 240, view, proj, renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK,
                                 physicsClientId=world.cid)
            for _ in range(steps):
                for r in robots:
                    x, y, th = r.pose
                    r.set_base_pose(x + 0.05 * math.cos(th) * dt, y + 0.05 * math.sin(th) * dt, th + 0.2 * dt)
                t += dt
        return sim_seconds / (time.perf_counter() - t0)

    rtf = world.run_sync(loop)
    world.close()
    return rtf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim-seconds", type=float, default=5.0)
    ap.add_argument("--house", default="house")
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--render", choices=["process", "inline"], default="process")
    ap.add_argument("--stall", action="store_true", help="only measure the event-loop stall (both render modes)")
    a = ap.parse_args()
    if a.stall:
        for mode in ("inline", "process"):
            print(json.dumps(asyncio.run(loop_stall(a.house, mode))))
        return
    results = []
    for n in a.robots:
        floor = floor_run(a.house, n, a.sim_seconds)
        rtf = asyncio.run(api_run(a.house, n, a.sim_seconds, a.render))
        results.append({"robots": n, "rtf": round(rtf, 3), "floor_rtf": round(floor, 3),
                        "ratio_vs_floor": round(rtf / floor, 3), "target_met": rtf >= 1.0})
        print(f"{n} robot(s): rtf {rtf:6.2f}   floor (bare pybullet) {floor:6.2f}   ratio {rtf / floor:5.2f}")
    print(json.dumps({"bench": "sim_rtf", "house": a.house, "render": a.render, "frame": "320x240", "frame_period_s": FRAME_PERIOD,
                      "sim_seconds": a.sim_seconds, "results": results}))


if __name__ == "__main__":
    main()
