"""What a render process holds (robots/render_process.py): a NAO's body without SciPy, and no freed
frame kept by the C library's heap. Before either, a render process held ~250 MB (Pss) after one
1280x960 frame of a NAO; with both, ~140 (bench/RESULTS.md, the fleet's memory)."""
import math
import subprocess
import sys
from pathlib import Path

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
