"""`rapp house check FILE`: validate a house file (robots/house_file.py, then the world's own loader)
and draw it as a PNG (walls, rooms, doors with their swing and check poses, lamps, landmarks with their
sizes, furniture, robot starts); `rapp house new NAME`: a house file to start from (docs/houses.md)."""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import yaml

from ontology.robot_types import ROBOT_TYPES
from robots.floorplan import load_plan
from robots.house_file import check, template

ROBOT_RADIUS_M = {name: row.body_radius_m for name, row in ROBOT_TYPES.items()}  # the bodies' footprints


def read(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no house file {str(path)!r}")
    try:
        desc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML: {e}") from None
    if isinstance(desc, dict) and "disturbances" in desc and "walls" not in desc:
        raise ValueError(f"{path} is a disturbance file, not a house file (docs/disturbances.md)")
    return desc


def check_file(path: str | Path, seed: int = 0) -> tuple[object, list[str]]:
    """(the world's plan at `seed`, the problems found): ValueError when the file cannot be read at all."""
    desc = read(path)
    _, problems = check(desc)
    plan = load_plan(desc, seed=seed, overrides=_run_overrides(path, seed))
    from scenarios.home_setup import doorway  # the check poses a RApp reads in HomeInfo
    for d in plan.doors:
        for c in doorway(plan, d).checks:
            if c.room is None:
                problems.append(f"door {d.id!r}: its {c.side} check pose ({c.stand.x:.2f}, {c.stand.y:.2f}) is in no room")
            elif c.clearance_m is not None and c.clearance_m < max(ROBOT_RADIUS_M.values()):
                problems.append(f"door {d.id!r}: its {c.side} check pose is {c.clearance_m:.2f} m from a wall or "
                                "furniture: a robot cannot stand there")
    for name, spec in plan.robots.items():
        try:
            plan.start_pose(name, name, ROBOT_RADIUS_M.get(name, 0.3))
        except ValueError as e:
            problems.append(f"robots.{name}: {e}")
    return plan, problems


def _run_overrides(path, seed: int) -> dict | None:
    """What scenario_world draws for a run of this house at `seed` (its hazard layout's doors and
    lamps), so the drawing is the run's world."""
    from scenarios.home_setup import LAYOUTS, hazard_overrides

    name = Path(path).stem if Path(path).stem in LAYOUTS else str(path)
    try:
        return hazard_overrides(name, seed)
    except KeyError:
        return None


def summary(plan) -> str:
    sizes = Counter(m.size for m in plan.landmarks)
    qr = ", ".join(f"{n} of {s:g} m" for s, n in sorted(sizes.items()))
    x0, y0, x1, y1 = plan.bounds
    counts = ", ".join(f"{len(items)} {one if len(items) == 1 else many}" for items, one, many in (
        (plan.rooms, "room", "rooms"), (plan.doors, "door", "doors"), (plan.lamps, "lamp", "lamps"),
        (plan.furniture, "piece of furniture", "pieces of furniture"), (plan.landmarks, "landmark", "landmarks")))
    return f"{plan.name}: {x1 - x0:.1f} m x {y1 - y0:.1f} m, {counts}" + (f" ({qr})" if qr else "")


def draw(plan, out: str | Path) -> Path:
    """The house at the plan's seed, from above: check poses as arrows (F front, S swing)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Arc, Polygon

    from scenarios.home_setup import doorway

    out = Path(out)
    x0, y0, x1, y1 = plan.bounds
    scale = 9.0 / max(x1 - x0, y1 - y0)
    fig, ax = plt.subplots(figsize=(max(4.0, (x1 - x0) * scale + 1), max(4.0, (y1 - y0) * scale + 1)), dpi=110)
    for r in plan.rooms:
        rx0, ry0, rx1, ry1 = r.rect
        ax.add_patch(Polygon([(rx0, ry0), (rx1, ry0), (rx1, ry1), (rx0, ry1)], closed=True, fc="#f4f1e8", ec="none"))
        ax.text((rx0 + rx1) / 2, (ry0 + ry1) / 2, r.name, ha="center", va="center", color="#888", fontsize=10)
    for b in plan.walls:
        ax.add_patch(Polygon(b.corners(), closed=True, fc="#444", ec="none"))
    for b in plan.furniture:
        ax.add_patch(Polygon(b.corners(), closed=True, fc=b.color, ec="#333", lw=0.5, alpha=0.8))
    for d in plan.doors:
        yaw = d.closed_yaw
        ax.add_patch(Polygon(d.leaf_box().corners(), closed=True, fc="#8b5a2b", ec="none"))
        lo, hi = sorted((math.degrees(yaw), math.degrees(yaw) + d.sign * 90.0))
        ax.add_patch(Arc(d.hinge, 2 * d.width, 2 * d.width, theta1=lo, theta2=hi, color="#8b5a2b", lw=0.6, ls=":"))
        ax.text(d.hinge[0], d.hinge[1], f" {d.id} ({d.angle:.0f}°)", fontsize=6, color="#5a3a1b")
        for c in doorway(plan, d).checks:
            ax.annotate("", xy=(c.stand.x + 0.35 * math.cos(c.stand.theta), c.stand.y + 0.35 * math.sin(c.stand.theta)),
                        xytext=(c.stand.x, c.stand.y), arrowprops=dict(arrowstyle="->", color="tab:blue", lw=1))
            ax.text(c.stand.x, c.stand.y, "F" if c.side == "front" else "S", fontsize=6, color="tab:blue",
                    ha="right", va="top")
    for lp in plan.lamps:
        ax.plot(lp.x, lp.y, "o", ms=8, mfc="gold" if lp.on else "white", mec="#996", mew=1)
        ax.text(lp.x, lp.y, f" {lp.id}", fontsize=6, color="#996")
    for m in plan.landmarks:
        (ax_, ay, _), (bx, by, _) = m.corners()[0], m.corners()[1]
        ax.plot([ax_, bx], [ay, by], "-", color="tab:purple", lw=3 if m.size >= 0.3 else 1.8, solid_capstyle="butt")
        ax.plot([m.x, m.x + 0.25 * math.cos(m.yaw)], [m.y, m.y + 0.25 * math.sin(m.yaw)], "-", color="tab:purple", lw=0.5)
    for name in plan.robots:
        try:
            x, y, th = plan.start_pose(name, name, ROBOT_RADIUS_M.get(name, 0.3))
        except ValueError:
            continue
        ax.plot(x, y, "o", color="tab:green", ms=6)
        ax.annotate(name, (x, y), (x + 0.4 * math.cos(th), y + 0.4 * math.sin(th)), fontsize=7, color="tab:green",
                    arrowprops=dict(arrowstyle="<-", color="tab:green", lw=1))
    ax.set_aspect("equal")
    ax.set_xlim(x0 - 0.3, x1 + 0.3)
    ax.set_ylim(y0 - 0.3, y1 + 0.3)
    ax.set_title(f"{plan.name} (seed {plan.seed}): doors' check poses F = front, S = swing side; "
                 "QR codes purple (thick: 0.35 m)", fontsize=7)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


def new_file(name: str, path: str | Path | None = None) -> Path:
    """Write a house file to start from (a valid two-room flat) named `name`; refuses to overwrite."""
    if not name or not all(c.isalnum() or c in "-_" for c in name):
        raise ValueError(f"house name {name!r}: letters, digits, '-' and '_' only")
    path = Path(path) if path else Path(f"{name}.yaml")
    if path.is_dir():
        path = path / f"{name}.yaml"
    if path.exists():
        raise ValueError(f"{path} exists: not overwritten")
    path.write_text(template(name, str(path)))
    return path
