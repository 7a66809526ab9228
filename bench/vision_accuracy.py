"""Accuracy of the Platform's face and scene recognition (docs/face-recognition.md, docs/scene-recognition.md):

    python -m bench.vision_accuracy [--faces-only|--scenes-only] [--places N] [--seeds S1,S2,...]

- faces, photographs: every pair of the real photographs in tests/data/faces (one registered, the
  other asked), accepted at dlib's 0.6 or not: same-person pairs accepted, different-person pairs
  accepted (false accepts);
- faces, renders: a NAO at 1.5-2.2 m (seeded) looks at a simulated person wearing a registered
  person's face (a photograph other than the two registered) and at one wearing a stranger's face;
- scenes: in each house, learned from a look-around (4 headings) at 3 places per room, asked at N other
  places per room, with one view and with the look-around.
Seeds default to ones drawn now (printed), so the figures hold beyond a fixed list.
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import math
import random
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FACES = ROOT / "tests" / "data" / "faces"


def _read(path: Path) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_COLOR)


def face_photographs() -> None:
    from agents.services import faces

    d = {}
    for path in sorted(FACES.glob("*.jpg")):
        img = _read(path)
        d[path.stem] = faces.describe(img, faces.find_faces(img)[0])
    names = sorted(d)
    pairs = [(a, b, float(np.linalg.norm(d[a] - d[b]))) for a in names for b in names if a < b]
    same = [x for a, b, x in pairs if a.split("-")[0] == b.split("-")[0] != "stranger"]
    other = [x for a, b, x in pairs if not a.split("-")[0] == b.split("-")[0] != "stranger"]
    for threshold in (0.6, 0.5):
        print(f"photographs, threshold {threshold}: same person accepted {sum(x < threshold for x in same)}/{len(same)}"
              f" (distances {', '.join(f'{x:.2f}' for x in sorted(same))}); different people accepted "
              f"{sum(x < threshold for x in other)}/{len(other)} (nearest {min(other):.2f})")


async def face_renders(seeds: list[int]) -> None:
    from agents.services import faces
    from ontology.robot import CaptureImage, LookAtPoint
    from robots import RobotAPI, World

    known = {"Barack": np.array([faces.describe(img, faces.find_faces(img)[0])
                                 for img in (_read(FACES / "obama-1.jpg"), _read(FACES / "obama-2.jpg"))])}
    tmp = Path(tempfile.mkdtemp(prefix="faces-"))
    wearers = {"obama-3": "Barack", "stranger-03": "", "stranger-09": ""}
    for name in wearers:
        img = _read(FACES / f"{name}.jpg")
        x, y, w, h = faces.find_faces(img)[0]
        m = int(0.15 * w)
        cv2.imwrite(str(tmp / f"{name}.png"), img[y - m:y + h + m, x - m:x + w + m])
    right = seen = total = 0
    for seed in seeds:
        rng = random.Random(seed)
        spots = {"obama-3": (2.7, 2.4), rng.choice(["stranger-03", "stranger-09"]): (2.7, 1.2)}
        people = [{"kind": "person", "id": n, "route": [[x + 0.4, y], [x, y]], "speed": 1.0, "face": str(tmp / f"{n}.png")}
                  for n, (x, y) in spots.items()]
        world = World.from_file("small", seed=seed % 100, overrides={"doors": {"d1": 0}}, disturbances=people)
        try:
            distance, side = rng.uniform(1.5, 2.2), rng.uniform(-0.2, 0.2)
            api = RobotAPI(world.add_robot("nao", pose=(2.7 - distance, 1.8 + side, 0.0)))
            await world.sleep(1.0)
            for name, (x, y) in spots.items():
                await api.look_at_point(LookAtPoint(x=x, y=y, z=1.58))
                shot = await api.capture_image(CaptureImage(resolution="VGA"))
                img = cv2.imdecode(np.frombuffer(base64.b64decode(shot.data_b64), np.uint8), cv2.IMREAD_COLOR)
                boxes = faces.find_faces(img)
                total += 1
                if boxes:
                    seen += 1
                    person, dist = faces.nearest(known, faces.describe(img, boxes[0]))
                    right += (person if dist < 0.6 else "") == wearers[name]
        finally:
            world.close()
    print(f"renders (NAO, VGA, 1.5-2.2 m, seeds {seeds}): face found {seen}/{total}, named right {right}/{seen}")


async def scenes(house: str, kind: str, seed: int, asked: int) -> tuple[int, int, int]:
    from agents.services.scenes import RoomViews, orb_descriptors, rank_rooms, scene_descriptor
    from ontology.robot import CaptureImage
    from robots import RobotAPI, World

    world = World.from_file(house, seed=seed)
    try:
        robot = world.add_robot(kind)
        api = RobotAPI(robot)
        rng = random.Random(seed)
        known, tests = {}, []
        for room in world.plan.rooms:
            x0, y0, x1, y1 = room.rect
            spots = []
            for _ in range(500):
                x, y = rng.uniform(x0 + 0.3, x1 - 0.3), rng.uniform(y0 + 0.3, y1 - 0.3)
                if world.plan.clearance(x, y) > 0.45:
                    spots.append((x, y, rng.uniform(-math.pi, math.pi)))
                if len(spots) == 3 + asked:
                    break
            learned = []
            for i, (x, y, th) in enumerate(spots):
                shots = []
                for k in range(4):
                    world.run_sync(robot.set_base_pose, x, y, th + k * math.pi / 2)
                    reply = await api.capture_image(CaptureImage(resolution="320x240"))
                    shots.append(cv2.imdecode(np.frombuffer(base64.b64decode(reply.data_b64), np.uint8),
                                              cv2.IMREAD_COLOR))
                (learned.extend(shots) if i < 3 else tests.append((room.name, shots)))
            if learned:
                known[room.name] = RoomViews(np.array([scene_descriptor(i) for i in learned]),
                                             np.vstack([orb_descriptors(i) for i in learned]))
        one = sum(rank_rooms(known, shots[:1])[0].room == room for room, shots in tests)
        around = sum(rank_rooms(known, shots)[0].room == room for room, shots in tests)
        return one, around, len(tests)
    finally:
        world.close()


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--faces-only", action="store_true")
    a.add_argument("--scenes-only", action="store_true")
    a.add_argument("--places", type=int, default=8, help="places asked per room")
    a.add_argument("--seeds", help="comma-separated seeds (default: three drawn now)")
    args = a.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else [random.randrange(1, 10_000) for _ in range(3)]
    if not args.scenes_only:
        face_photographs()
        asyncio.run(face_renders([10 * s + k for s in seeds for k in range(3)]))
    if not args.faces_only:
        for house, kind, seed in [("house", "nao", seeds[0]), ("generated", "nao", seeds[1]),
                                  ("generated", "elektron", seeds[2])]:
            one, around, n = asyncio.run(scenes(house, kind, seed, args.places))
            print(f"scenes {house} (seed {seed}), {kind}: one view {one}/{n} = {one / n:.0%}, "
                  f"look-around {around}/{n} = {around / n:.0%}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
