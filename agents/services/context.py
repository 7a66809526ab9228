"""What every service implementation receives besides its request: who calls, and shared state.

`ServiceState` is created once by the Platform Agent and shared by all calls (thread-safe stores);
`ServiceContext` is built per call with the token owner's user name.
"""
from __future__ import annotations

import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from .maps import MapStore
from .obstacles import ObstacleLayers
from .saved import SavedArrays, SavedData, keep_obstacles

DATA_DIR = Path(__file__).resolve().parent / "data"
SAVED_ARRAYS = frozenset({"speech_noise_profiles"})  # {(user, name): array} stores kept as they are


@dataclass(eq=False)
class ServiceState:
    """Per-user stores shared across calls. `work_dir` holds per-user files (maildirs...). With
    `saved` (agents/services/saved.py) every per-user datum is kept there and read back at the next
    start: `ServiceState.keeping(folder)`."""

    data_dir: Path = DATA_DIR
    work_dir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="rapp-services-")))
    maps: MapStore = field(default_factory=MapStore)
    obstacles: ObstacleLayers = field(default_factory=ObstacleLayers)  # temporary marks per (user, map)
    saved: SavedData | None = None
    _stores: dict[str, Any] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        if self.saved is not None:
            self.maps.keep_in(self.saved)
            keep_obstacles(self.obstacles, self.saved)

    @classmethod
    def keeping(cls, folder: str | Path, **kw) -> "ServiceState":
        """A state whose per-user data lives in `folder` (services.db, blobs/) and its files in
        folder/services: what a Platform with a data directory runs on."""
        folder = Path(folder)
        return cls(work_dir=folder / "services", saved=SavedData(folder), **kw)

    def close(self) -> None:
        if self.saved is not None:
            self.saved.close()

    def store(self, name: str, factory: Callable[[], Any]) -> Any:
        """The named store (learned objects, exercise history, providers), created on first use
        (a {(user, name): array} one named in SAVED_ARRAYS is kept in `saved`)."""
        with self._lock:
            if name not in self._stores:
                self._stores[name] = SavedArrays(self.saved, name) if self.saved is not None and \
                    name in SAVED_ARRAYS else factory()
            return self._stores[name]

    def replace_stores(self, stores: dict[str, Any]) -> None:
        """Every named store at once: a pool worker's state gets the caller's with each job."""
        with self._lock:
            self._stores = stores

    def stores_named(self, names: Iterable[str]) -> dict[str, Any]:
        """The named stores that exist (a pool worker gives back what a job changed)."""
        with self._lock:
            return {name: self._stores[name] for name in names if name in self._stores}

    def preload_maps(self, folder: str | Path) -> list[str]:
        """Register every map_server YAML found in folder as a shared map (id = file stem)."""
        folder = Path(folder)
        return self.maps.preload_dir(folder) if folder.is_dir() else []


@dataclass(frozen=True)
class ServiceContext:
    user: str
    state: ServiceState
