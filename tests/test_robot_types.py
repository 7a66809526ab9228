"""The robot type table (ontology/robot_types.py), read by everything that names robot types: the
answers written down from the code before the table existed (ontology/manifest.py ROBOT_TYPES,
robots/nao.py and elektron.py radius, agents/services/navigation.py ROBOT_RADIUS, rapps/sdk/ekf.py
ODOMETRY, robots/house_gen.py NAV_RADIUS) still hold; no other module states the types; and a third
robot type, one row plus a body, runs a RApp end to end."""
from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path

import pytest
import yaml

from ontology import robot_types
from ontology.manifest import ManifestError, manifest_from_dict
from ontology.robot_types import ROBOT_TYPES, Odometry, RobotType, UnknownRobotType

ROOT = Path(__file__).resolve().parents[1]

# ---------------------------------------------------------------- the answers before the table
OLD_BODY_RADIUS = {"nao": 0.17, "elektron": 0.26}  # RobotSpec.radius
OLD_CLEARANCE = {"nao": 0.35, "elektron": 0.30}  # navigation.ROBOT_RADIUS
OLD_ODOMETRY = {
    "nao": dict(trans_std=0.02, trans_rel=0.05, rot_std=0.05, rot_rel=0.05, heading_std=0.08, heading_drift=0.05),
    "elektron": dict(trans_std=0.01, trans_rel=0.02, rot_std=0.03, rot_rel=0.04, heading_std=0.02, heading_drift=0.05),
}
OLD_NAV_RADIUS = 0.30 + 0.05


def test_the_table_gives_the_answers_the_code_gave_before_it():
    from agents.services import navigation
    from rapps.sdk.ekf import ODOMETRY
    from robots import ROBOT_SPECS, house_gen

    assert robot_types.names() == ("nao", "elektron")
    for kind in ROBOT_TYPES:
        assert ROBOT_SPECS[kind].radius == OLD_BODY_RADIUS[kind]
        assert navigation.robot_radius(kind) == OLD_CLEARANCE[kind]
        assert dataclasses.asdict(ODOMETRY[kind]) == OLD_ODOMETRY[kind]
    assert house_gen.NAV_RADIUS == OLD_NAV_RADIUS


def test_every_row_has_its_body_and_keeps_clear_of_it():
    from robots import ROBOT_SPECS

    for kind, facts in ROBOT_TYPES.items():
        body = ROBOT_SPECS[kind]
        assert body.kind == kind and body.radius == facts.body_radius_m
        assert facts.clearance_radius_m >= facts.body_radius_m, kind  # the planner keeps at least the body free
        assert body.failures is not None, f"{kind}'s body has no failure modes"


def test_an_unknown_type_is_refused_by_name_everywhere():
    from agents.services import navigation
    from robots import ROBOT_SPECS

    with pytest.raises(UnknownRobotType, match=r"unknown robot type 'pepper' \(known: nao, elektron\)"):
        robot_types.robot_type("pepper")
    assert "pepper" not in ROBOT_SPECS
    with pytest.raises(KeyError):
        navigation.robot_radius("pepper")


def test_docs_show_the_table():
    assert robot_types.markdown_table() in (ROOT / "docs" / "architecture.md").read_text()


def test_the_choices_of_every_robot_option_are_the_table():
    from scenarios import disturbance_suite, hazard, hazard_validation, run_rapp

    for module in (disturbance_suite, hazard, hazard_validation, run_rapp):
        assert module.ROBOTS == robot_types.names(), module.__name__


# modules that may name robot types together (a tuple, list, set or dict of both), and why
STATED_TOGETHER = {
    "ontology/robot_types.py": "the table",
    "scenarios/two_robots.py": "the scenario's pair (one NAO, one Elektron) and which hazards each checks",
    "bench/common.py": "a fleet alternates the paper's two robots: figures stay comparable across runs",
    "bench/fleet.py": "as bench/common.py",
    "bench/sim_rtf.py": "as bench/common.py",
}


def _both_named(node: ast.AST) -> bool:
    elts = node.keys if isinstance(node, ast.Dict) else getattr(node, "elts", [])
    names = {e.value for e in elts if isinstance(e, ast.Constant)}
    return {"nao", "elektron"} <= names


def test_no_other_module_lists_the_robot_types():
    """The robot types are stated once: a collection naming both elsewhere is a second table."""
    found = []
    for pkg in ("ontology", "robots", "hearing", "behaviours", "agents", "rapps", "scenarios", "bench", "cli"):
        for f in sorted((ROOT / pkg).rglob("*.py")):
            rel = f.relative_to(ROOT).as_posix()
            if rel in STATED_TOGETHER or "/tests/" in rel:
                continue
            for node in ast.walk(ast.parse(f.read_text(), rel)):
                if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)) and _both_named(node):
                    found.append(f"{rel}:{node.lineno}")
    assert not found, f"robot types listed outside ontology/robot_types.py: {found}"


def _yaml_maps(value):
    if isinstance(value, dict):
        yield value
        for v in value.values():
            yield from _yaml_maps(v)
    elif isinstance(value, list):
        for v in value:
            yield from _yaml_maps(v)


def test_no_manifest_lists_the_robot_types():
    """A RApp's manifest may name the types it runs on (a list), but a per-type table of facts in its
    params is a second copy of ontology/robot_types.py (the paper's tracking figure was one)."""
    found = []
    for f in sorted(ROOT.glob("rapps/**/*.yaml")) + sorted(ROOT.glob("examples/**/*.yaml")):
        for mapping in _yaml_maps(yaml.safe_load(f.read_text())):
            if len(set(mapping) & set(robot_types.names())) >= 2:
                found.append(f.relative_to(ROOT).as_posix())
    assert not found, f"per-robot-type tables in manifests: {found}"


# ---------------------------------------------------------------- a third robot type
ROVER = RobotType("tests.robots.rover_body", body_radius_m=0.22, clearance_radius_m=0.32,
                  odometry=Odometry(trans_std=0.015, trans_rel=0.03, rot_std=0.04, rot_rel=0.04,
                                    heading_std=0.03, heading_drift=0.05),
                  description="a test's rover: the Elektron's parts on a narrower base")


@pytest.fixture
def rover(monkeypatch):
    """The third type as a developer adds one: a row in the table and a body module."""
    monkeypatch.setitem(ROBOT_TYPES, "rover", ROVER)
    return "rover"


def test_a_row_and_a_body_make_a_robot_type(rover):
    from agents.services import navigation
    from rapps.sdk.ekf import ODOMETRY
    from robots import ROBOT_SPECS, elektron

    body = ROBOT_SPECS[rover]
    assert body.radius == 0.22 and body.laser == elektron.SPEC.laser and body.failures == elektron.SPEC.failures
    assert navigation.robot_radius(rover) == 0.32
    assert dataclasses.asdict(ODOMETRY[rover])["trans_std"] == 0.015
    m = manifest_from_dict({"name": "x1", "version": "1.0.0", "robot_types": [rover], "entry_point": "x.t:T"})
    assert m.robot_types == ["rover"]
    with pytest.raises(ManifestError, match="unknown robot type"):
        manifest_from_dict({"name": "x1", "version": "1.0.0", "robot_types": ["rover2"], "entry_point": "x.t:T"})


async def test_a_rapp_runs_end_to_end_on_a_third_robot_type(rover, tmp_path):
    """Store, Core, Platform and world take the new type from the table: the Store registers a rover
    and lists its RApp, the world builds its body, the planner plans with its clearance radius, the
    RApp's SDK gives its odometry model. A type added at run time exists in this process only (a real
    one is a row in the file, so every process has it): the RApp and the services run in it here."""
    from scenarios.home_setup import home_description, scenario_world
    from scenarios.recorder import RecordingAPI
    from scenarios.runner import Owner, Run
    from robots import RobotAPI

    world = scenario_world("small", 1, render="inline")
    try:
        start = world.plan.start_pose("elektron", "elektron", ROVER.clearance_radius_m)  # the house has none for it
        api = RecordingAPI(RobotAPI(world.add_robot(rover, pose=start)), frames_dir=tmp_path / "frames")
        owner = Owner(rover, api, "owner-rover1", "rove", home=home_description(world, "small", tmp_path),
                      core_kw={"dynamic_mode": "inprocess"})
        run = Run(tmp_path, world, ROOT / "tests" / "fixtures" / "rover_check", [owner],
                  platform_kw={"service_workers": 0})
        await run.run(timeout_s=60)
        assert run.ok(owner), run.reason(owner)
        report = owner.reports[-1].data
        assert report["robot_type"] == "rover" and report["odometry"] == dataclasses.asdict(ROVER.odometry)
        assert report["length_m"] > 1.0
        assert api.robot.spec.radius == ROVER.body_radius_m
        x, y = api.robot.pose[:2]
        assert math.dist((x, y), report["goal"]) < 0.3, (x, y, report["goal"])
    finally:
        world.close()
