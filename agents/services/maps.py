"""Occupancy grid maps as ROS map_server stores them (PNG + YAML) and a per-user, thread-safe store.

Grid convention: `blocked[iy, ix]`, iy growing with the world y axis (the PNG is flipped on load),
cell (ix, iy) centre at origin + ((ix + 0.5) * res, (iy + 0.5) * res). Unknown cells count as blocked.
"""
from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from ontology.errors import ErrorCode

from .errors import ServiceError


@dataclass(eq=False)
class GridMap:
    map_id: str
    blocked: np.ndarray  # bool [H, W], True = occupied or unknown
    resolution: float
    origin: tuple[float, float, float]
    shared: bool = False
    _cache: dict = field(default_factory=dict, repr=False)
    _lock: threading.RLock = field(default_factory=threading.RLock, repr=False)  # builds nest

    @property
    def height(self) -> int:
        return int(self.blocked.shape[0])

    @property
    def width(self) -> int:
        return int(self.blocked.shape[1])

    def world_to_cell(self, x: float, y: float) -> tuple[float, float]:
        """Continuous cell coordinates (cell centres at integers)."""
        return ((x - self.origin[0]) / self.resolution - 0.5, (y - self.origin[1]) / self.resolution - 0.5)

    def cell_to_world(self, cx, cy):
        return (self.origin[0] + (np.asarray(cx) + 0.5) * self.resolution,
                self.origin[1] + (np.asarray(cy) + 0.5) * self.resolution)

    def contains(self, x: float, y: float) -> bool:
        cx, cy = self.world_to_cell(x, y)
        return -0.5 <= cx < self.width - 0.5 and -0.5 <= cy < self.height - 0.5

    def peek(self, key):
        """What `cached` built for key, or None (never builds)."""
        with self._lock:
            return self._cache.get(key)

    def content_key(self) -> str:
        """A hash of the grid and its geometry (memoised): the service pool's workers cache a map
        under it, so a map is sent to each worker once, and a map uploaded again with other content
        is never mistaken for the old one."""
        def build() -> str:
            h = hashlib.sha1(np.ascontiguousarray(self.blocked).tobytes())
            h.update(repr((self.blocked.shape, self.resolution, tuple(self.origin))).encode())
            return h.hexdigest()
        return self.cached(("content-key",), build)

    def cached(self, key, build):
        """Per-map memo (cost maps, graphs) built once under a lock."""
        with self._lock:
            if key not in self._cache:
                self._cache[key] = build()
            return self._cache[key]


def grid_from_image(gray: np.ndarray, occupied_thresh: float = 0.65, free_thresh: float = 0.196,
                    negate: int = 0) -> np.ndarray:
    """ROS map_server trinary interpretation; returns blocked[iy, ix] (image rows flipped)."""
    p = gray.astype(np.float32) / 255.0
    occ = p if negate else 1.0 - p
    blocked = ~(occ < free_thresh)  # occupied and unknown are both blocked
    return np.ascontiguousarray(np.flipud(blocked))


def parse_map(map_id: str, png: bytes, yaml_text: str, shared: bool = False) -> GridMap:
    """Build a GridMap from PNG bytes and map_server YAML text; ServiceError if either is bad."""
    try:
        meta = yaml.safe_load(yaml_text)
    except yaml.YAMLError as e:
        raise ServiceError(f"map YAML is not valid YAML: {e}", ErrorCode.BAD_MAP) from None
    if not isinstance(meta, dict) or "resolution" not in meta or "origin" not in meta:
        raise ServiceError("map YAML needs at least 'resolution' and 'origin'", ErrorCode.BAD_MAP)
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ServiceError("map image could not be decoded (expected PNG/PGM)", ErrorCode.BAD_MAP)
    try:
        res = float(meta["resolution"])
        origin = tuple(float(v) for v in meta["origin"])[:3]
        origin = origin + (0.0,) * (3 - len(origin))
        blocked = grid_from_image(img, float(meta.get("occupied_thresh", 0.65)),
                                  float(meta.get("free_thresh", 0.196)), int(meta.get("negate", 0)))
    except (TypeError, ValueError) as e:
        raise ServiceError(f"map YAML has a bad value: {e}", ErrorCode.BAD_MAP) from None
    if res <= 0:
        raise ServiceError("map resolution must be positive", ErrorCode.BAD_MAP)
    return GridMap(map_id, blocked, res, origin, shared)  # type: ignore[arg-type]


def load_map_files(map_id: str, yaml_path: str | Path, shared: bool = True) -> GridMap:
    """Load a map_server YAML file; its `image` is relative to the YAML's folder."""
    yaml_path = Path(yaml_path)
    text = yaml_path.read_text()
    meta = yaml.safe_load(text) or {}
    image = yaml_path.parent / str(meta.get("image", yaml_path.with_suffix(".png").name))
    return parse_map(map_id, image.read_bytes(), text, shared)


def encode_map(blocked: np.ndarray, resolution: float, origin=(0.0, 0.0, 0.0),
               image_name: str = "map.png") -> tuple[bytes, str]:
    """Inverse of parse_map: PNG bytes (black occupied, white free) and YAML text."""
    img = np.where(np.flipud(blocked), 0, 254).astype(np.uint8)
    ok, png = cv2.imencode(".png", img)
    assert ok
    meta = {"image": image_name, "resolution": float(resolution), "origin": [float(v) for v in origin],
            "occupied_thresh": 0.65, "free_thresh": 0.196, "negate": 0}
    return png.tobytes(), yaml.safe_dump(meta)


class MapStore:
    """Shared (preloaded) maps plus maps uploaded by each user; a user sees shared + own maps.
    Kept in a SavedData (`keep_in`): users' maps as PNG blobs, read back at the next start (shared
    maps are preloaded from their folder at each start instead)."""

    KIND = "map"

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._shared: dict[str, GridMap] = {}
        self._user: dict[str, dict[str, GridMap]] = {}
        self._saved = None

    def keep_in(self, saved) -> int:
        """Write users' maps through to `saved` (agents/services/saved.py) and load those it holds."""
        loaded = 0
        for rec in saved.records(self.KIND):
            img = cv2.imdecode(np.frombuffer(rec.blob, np.uint8), cv2.IMREAD_GRAYSCALE)
            if img is None:
                continue
            with self._lock:
                self._user.setdefault(rec.user, {})[rec.key] = GridMap(
                    rec.key, grid_from_image(img), float(rec.meta["resolution"]), tuple(rec.meta["origin"]))
            loaded += 1
        self._saved = saved
        return loaded

    def add_shared(self, m: GridMap) -> None:
        m.shared = True
        with self._lock:
            self._shared[m.map_id] = m

    def add(self, user: str, m: GridMap) -> None:
        if self._saved is not None:  # first: a map the Platform answered for is one it keeps
            png, _ = encode_map(m.blocked, m.resolution, m.origin)
            self._saved.put(self.KIND, user, m.map_id,
                            {"resolution": m.resolution, "origin": [float(v) for v in m.origin]}, png)
        with self._lock:
            self._user.setdefault(user, {})[m.map_id] = m

    def get(self, user: str, map_id: str) -> GridMap | None:
        with self._lock:
            return self._user.get(user, {}).get(map_id) or self._shared.get(map_id)

    def visible(self, user: str) -> list[GridMap]:
        with self._lock:
            merged = dict(self._shared)
            merged.update(self._user.get(user, {}))
            return list(merged.values())

    def preload_dir(self, folder: str | Path) -> list[str]:
        """Register every map_server YAML in a folder (e.g. robots/houses exports) as shared."""
        loaded = []
        for y in sorted(Path(folder).glob("*.yaml")):
            try:
                meta = yaml.safe_load(y.read_text()) or {}
            except yaml.YAMLError:
                continue
            if not isinstance(meta, dict) or "resolution" not in meta or "image" not in meta:
                continue  # not a map_server file (e.g. a house description)
            self.add_shared(load_map_files(y.stem, y))
            loaded.append(y.stem)
        return loaded
