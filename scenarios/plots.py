"""Plots of scenario runs (matplotlib, Agg backend): map, planned paths, driven trajectory,
landmarks, localizations and hazards."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_hazard_run(path: str | Path, grid, paths: list[dict], localizations: list[dict],
                    landmarks: dict, hazards: list[dict], hazard_specs: list, title: str = "",
                    trajectory: list | None = None, unmapped: list | None = None) -> Path:
    """grid: robots.gridmap.GridMap; paths: recorder paths (poses, trajectory); hazards: result rows;
    hazard_specs: HazardSpec list (standing poses and look-at points); trajectory: the whole run's
    true (x, y) poses, drawn under the rest; unmapped: boxes (robots.floorplan.Box) in the world but
    not on the map (robots/lived_in.py), outlined."""
    path = Path(path)
    h, w = grid.image.shape
    x0, y0 = grid.origin[0], grid.origin[1]
    extent = (x0, x0 + w * grid.resolution, y0, y0 + h * grid.resolution)
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    ax.imshow(grid.image, cmap="gray", vmin=0, vmax=255, extent=extent, origin="upper")
    for i, box in enumerate(unmapped or []):
        c = np.vstack([box.corners(), box.corners()[:1]])
        ax.plot(c[:, 0], c[:, 1], "-", color="tab:brown", lw=1.2, label="not on the map" if i == 0 else None)
    if trajectory:
        t = np.asarray(trajectory, float)
        ax.plot(t[:, 0], t[:, 1], "-", color="tab:gray", lw=0.8, alpha=0.8, label="whole run (true)")
        ax.plot(t[0, 0], t[0, 1], "o", color="tab:gray", ms=5)
    for i, p in enumerate(paths):
        poses, traj = np.asarray(p["poses"]), np.asarray(p["trajectory"])
        ax.plot(poses[:, 0], poses[:, 1], "--", color="tab:blue", lw=1.2, label="planned" if i == 0 else None)
        if len(traj):
            ax.plot(traj[:, 0], traj[:, 1], "-", color="tab:orange", lw=1.0, label="driven (true)" if i == 0 else None)
    for lm in landmarks.values():
        ax.plot(lm.x, lm.y, "s", color="tab:purple", ms=6)
    for i, loc in enumerate(localizations):
        ax.plot(*loc["estimate"][:2], "x", color="tab:red", ms=6, label="localization" if i == 0 else None)
    rows = {r["id"]: r for r in hazards}
    for spec in hazard_specs:
        r = rows.get(spec.id, {})
        ok = r.get("true_state") == r.get("reported_state")
        colour = "tab:green" if ok else "tab:red"
        ax.plot(spec.look_at[0], spec.look_at[1], "*", color=colour, ms=14)
        ax.plot(spec.stand.x, spec.stand.y, "o", mfc="none", color=colour, ms=8)
        label = f"{spec.id}: {r.get('reported_state', '?')}"
        if r.get("true_state") != r.get("reported_state"):
            label += f" (true {r.get('true_state')})"
        ax.annotate(label, (spec.look_at[0], spec.look_at[1]), fontsize=7, xytext=(4, 4),
                    textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
