"""Occupancy grid export (ROS map_server PNG + YAML) from a house plan."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from .floorplan import Plan

OCCUPIED, FREE, UNKNOWN = 0, 254, 205


@dataclass
class GridMap:
    image: np.ndarray  # uint8, row 0 = top (max y), ROS convention: 0 occupied, 254 free, 205 unknown
    resolution: float
    origin: tuple[float, float, float]  # world pose of the lower-left pixel corner

    def world_to_cell(self, x: float, y: float) -> tuple[int, int]:
        col = int((x - self.origin[0]) / self.resolution)
        row = self.image.shape[0] - 1 - int((y - self.origin[1]) / self.resolution)
        return row, col

    def value_at(self, x: float, y: float) -> int:
        r, c = self.world_to_cell(x, y)
        return int(self.image[r, c])

    def save(self, directory: str | Path, name: str = "map") -> tuple[Path, Path]:
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        png, yml = d / f"{name}.png", d / f"{name}.yaml"
        cv2.imwrite(str(png), self.image)
        yml.write_text(yaml.safe_dump({
            "image": png.name, "resolution": self.resolution, "origin": list(self.origin),
            "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}, sort_keys=False))
        return png, yml


def build_grid_map(plan: Plan, resolution: float = 0.05, margin: float = 0.5,
                   include_doors: bool = False) -> GridMap:
    """Rasterise walls and furniture (and door leaves at their current angle if include_doors).
    Cells outside the outer walls (reachable from the map border) are marked unknown."""
    x0, y0, x1, y1 = plan.bounds
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    w, h = int(np.ceil((x1 - x0) / resolution)), int(np.ceil((y1 - y0) / resolution))
    img = np.full((h, w), FREE, np.uint8)

    def fill(target: np.ndarray, box) -> None:
        box = replace(box, sx=max(box.sx, resolution), sy=max(box.sy, resolution))  # thin leaves stay visible
        pts = box.corners()
        px = (pts[:, 0] - x0) / resolution - 0.5  # OpenCV pixel centres are at integer coordinates
        py = h - (pts[:, 1] - y0) / resolution - 0.5
        poly = np.round(np.stack([px, py], 1) * 16).astype(np.int32)
        cv2.fillPoly(target, [poly], OCCUPIED, lineType=cv2.LINE_8, shift=4)

    for box in plan.obstacles(include_doors=include_doors):
        fill(img, box)
    # outside = reachable from the border with every door closed
    closed = img.copy()
    for d in plan.doors:
        leaf = d.leaf_box(0.0)
        leaf.sx += 0.1
        leaf.sy = max(leaf.sy, 2 * resolution)
        fill(closed, leaf)
    mask = np.zeros((h + 2, w + 2), np.uint8)
    cv2.floodFill(closed, mask, (0, 0), UNKNOWN)
    img[closed == UNKNOWN] = UNKNOWN
    return GridMap(img, resolution, (x0, y0, 0.0))
