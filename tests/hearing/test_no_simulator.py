"""Hearing, the Core and the Platform's services without the simulator: a Core driving a real robot,
or a Platform serving speech, must not need pybullet. In a fresh interpreter where pybullet cannot be
imported, every module of hearing, ontology and behaviours, the Core's modules and the Platform with
all its services import, and none of the simulator's modules (robots' world, bodies, API) is loaded."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import importlib, importlib.abc, json, pkgutil, sys

class NoSimulator(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "pybullet":
            raise ImportError(f"no {name} here: a robot without the simulator")
        return None

sys.meta_path.insert(0, NoSimulator())

def every_module(package):
    try:
        pkg = importlib.import_module(package)
    except Exception:
        return [package]  # reported below
    return [package] + [m.name for m in pkgutil.walk_packages(pkg.__path__, package + ".")]

names = [*every_module("hearing"), *every_module("ontology"), *every_module("behaviours"),
         "agents.core_agent", "agents.core_behaviours", "agents.core_commands", "agents.core_events",
         "agents.core_fsm", "agents.core_hearing", "agents.core_strategies",
         "agents.platform_agent", *every_module("agents.services")]
failed = {}
for name in names:
    try:
        importlib.import_module(name)
    except Exception as e:
        failed[name] = f"{type(e).__name__}: {e}"
simulator = sorted(m for m in sys.modules if m.split(".")[0] == "pybullet"
                   or m in ("robots.world", "robots.robot", "robots.api", "robots.sound", "robots.receptors"))
print(json.dumps({"imported": len(names) - len(failed), "failed": failed, "simulator": simulator}))
"""


def test_hearing_the_core_and_the_platform_import_without_pybullet():
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["failed"] == {} and got["simulator"] == [], got
    assert got["imported"] > 40  # every module of the packages above, not an empty walk
