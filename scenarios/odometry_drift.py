"""How far a robot's odometry (`get_global_pose` without localization) drifts from the truth on a
walk of a few metres, on each robot: the figures of docs/sdk.md, "Where the robot is".

    python -m scenarios.odometry_drift --seeds 5

Each robot walks the same route in the full house's hall (4 m straight, a 90 degree left turn, 2 m
straight) with its failure modes (the NAO's sway and foot slip, the Elektron's wheel slip:
robots/failure_modes.py), once as `rapp run rapp` runs it (odometry = the commanded motion) and once
with the odometry's own calibration errors on top (OdometryNoise.typical(), as hazard-detection runs
it). Printed: the position and heading error at 4 m and at 6 m, mean and worst over the seeds."""
from __future__ import annotations

import argparse
import asyncio
import math

from ontology import robot_types
from ontology.robot import MoveAlongPath
from ontology.services.common import Pose2D
from robots import OdometryNoise, RobotAPI, World

START = (2.0, 11.8, 0.0)
ROUTE = [(2.0, 11.8, 0.0), (6.0, 11.8, 0.0), (6.0, 11.8, math.pi / 2), (6.0, 13.8, math.pi / 2)]
CORNER = 2  # the route's pose after the first 4 m


def error(robot) -> tuple[float, float]:
    (ox, oy, oth), (tx, ty, tth) = robot.odometry.estimate, robot.pose
    return math.hypot(ox - tx, oy - ty), abs(math.remainder(oth - tth, math.tau))


async def walk(kind: str, seed: int, noise: OdometryNoise | None) -> list[tuple[float, float]]:
    world = World.from_file("house", seed=seed)
    try:
        robot = world.add_robot(kind, pose=START, odometry_noise=noise)
        api = RobotAPI(robot)
        out = []
        for leg in (ROUTE[:CORNER], ROUTE[CORNER - 1:]):
            try:
                await api.handle(MoveAlongPath(poses=[Pose2D(x=x, y=y, theta=t) for x, y, t in leg]))
            except Exception as e:
                raise RuntimeError(f"{kind} seed {seed}: {e} at true {robot.pose}, odometry {robot.odometry.estimate}") from e
            out.append(error(robot))
        return out
    finally:
        world.close()


async def measure(seeds: int) -> list[dict]:
    rows = []
    for kind in robot_types.names():
        for label, noise in (("rapp run rapp", None), ("hazard-detection", OdometryNoise.typical())):
            runs = [await walk(kind, seed, noise) for seed in range(1, seeds + 1)]
            row = {"robot": kind, "odometry": label}
            for k, at in enumerate(("4m", "6m")):
                pos = [r[k][0] for r in runs]
                head = [math.degrees(r[k][1]) for r in runs]
                row[at] = (sum(pos) / len(pos), max(pos), sum(head) / len(head), max(head))
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios.odometry_drift", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    rows = asyncio.run(measure(args.seeds))
    print("| robot | odometry | after 4 m: position, heading | after 6 m (one 90 deg turn): position, heading |")
    print("|---|---|---|---|")
    for r in rows:
        cells = [f"{a * 100:.0f} cm (worst {b * 100:.0f}), {c:.1f} deg (worst {d:.1f})" for a, b, c, d in (r["4m"], r["6m"])]
        print(f"| {r['robot']} | {r['odometry']} | {cells[0]} | {cells[1]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
