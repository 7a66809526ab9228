"""What a render process holds (robots/render_process.py): a NAO's body without SciPy, no freed frame
kept by the C library's heap, and one pool for a fleet's worlds of one house. Before either, a render process held ~250 MB (Pss) after one
1280x960 frame of a NAO; with both, ~140 (bench/RESULTS.md, the fleet's memory)."""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
# imports (56 MB), the small house (35), TinyRenderer's buffers at 1280x960 (47): 140 measured; the
# freed frames kept by the heap took it to 204 (SciPy's imports are the test above's)
RENDER_PSS_MAX_MB = 190


def pss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Pss:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no Pss for process {pid}")


def test_a_nao_body_imports_no_signal_processing():
    """The body (its URDF) is all a render process builds of a robot: the microphones' positions
    come with it, the listener's SciPy does not."""
    code = ("import sys; from robots.bodies import ROBOT_SPECS; ROBOT_SPECS['nao'].build_urdf(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'hearing')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60, check=True)
    assert "scipy" not in out.stdout and "hearing.steering" not in out.stdout, out.stdout


def test_a_render_process_keeps_no_freed_frame(make_world):
    world = make_world("small", seed=1, render_workers=1)
    nao = world.add_robot("nao", pose=(0.5, 0.0, math.pi / 2))
    cam = nao.cameras["top"]
    for _ in range(3):  # the heap's threshold rises with the first frames' freed arrays
        world.capture_sync(cam, 1280, 960)
        world.capture_sync(cam, 320, 240)
    (pid,) = world.render_pids()
    assert pss_mb(pid) < RENDER_PSS_MAX_MB


def test_worlds_of_one_house_share_a_renderer_and_each_sees_only_its_own_robot(make_world):
    """A fleet's worlds (same house, own doors, lamps and robots) render in one pool: the frames are the
    ones each world's own render process gives, whichever world rendered last."""
    from robots.render_process import SharedRenderer

    shared = SharedRenderer(size=1)
    try:
        a = make_world("small", seed=1, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}}, renderer=shared)
        b = make_world("small", seed=2, overrides={"doors": {"d1": 80}, "lamps": {"l1": False}}, renderer=shared)
        alone = make_world("small", seed=2, overrides={"doors": {"d1": 80}, "lamps": {"l1": False}}, render_workers=1)
        # a's NAO faces the door; b's NAO and Elektron stand where a's camera would see them
        na = a.add_robot("nao", pose=(0.5, 0.0, math.pi / 2))
        for w in (b, alone):
            w.add_robot("nao", pose=(0.5, 0.0, math.pi / 2))
            w.add_robot("elektron", pose=(0.5, 1.2, -math.pi / 2))
        cam_b, cam_alone = b.robots["nao"].cameras["top"], alone.robots["nao"].cameras["top"]
        own_b = alone.capture_sync(cam_alone, 320, 240).astype(int)
        for _ in range(2):  # after a's frame and after b's own
            seen_a = a.capture_sync(na.cameras["top"], 320, 240).astype(int)
            seen_b = b.capture_sync(cam_b, 320, 240).astype(int)
            assert np.abs(seen_b - own_b).mean() < 0.5
        inline_a = a.run_sync(na.cameras["top"].capture, 320, 240).astype(int)  # no Elektron, door closed, lamp on
        assert np.abs(seen_a - inline_a).mean() < 0.5
        assert np.abs(seen_a - seen_b).mean() > 5  # and the two views differ
        assert len(shared.pids()) == 1 and a.render_pids() == b.render_pids()
        a.close()  # a world's close leaves the shared processes to the others
        assert np.abs(b.capture_sync(cam_b, 320, 240).astype(int) - own_b).mean() < 0.5
    finally:
        shared.close()
    assert shared.pids() == []


def test_a_shared_renderer_refuses_another_house(make_world):
    from robots.render_process import SharedRenderer

    shared = SharedRenderer(size=1)
    try:
        make_world("small", seed=1, renderer=shared)
        with pytest.raises(ValueError, match="differs"):
            make_world("twodoors", seed=1, renderer=shared)
    finally:
        shared.close()
