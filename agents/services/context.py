"""What every service implementation receives besides its request: who calls, and shared state.

`ServiceState` is created once by the Platform Agent and shared by all calls (thread-safe stores);
`ServiceContext` is built per call with the token owner's user name.
"""
from __future__ import annotations

import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .maps import MapStore
from .obstacles import ObstacleLayers

DATA_DIR = Path(__file__).resolve().parent / "data"


@dataclass(eq=False)
class ServiceState:
    """Per-user stores shared across calls. `work_dir` holds per-user files (maildirs...)."""

    data_dir: Path = DATA_DIR
    work_dir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="rapp-services-")))
    maps: MapStore = field(default_factory=MapStore)
    obstacles: ObstacleLayers = field(default_factory=ObstacleLayers)  # temporary marks per (user, map)
    _stores: dict[str, Any] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def store(self, name: str, factory: Callable[[], Any]) -> Any:
        """The named store (learned objects, exercise history, providers), created on first use."""
        with self._lock:
            if name not in self._stores:
                self._stores[name] = factory()
            return self._stores[name]

    def preload_maps(self, folder: str | Path) -> list[str]:
        """Register every map_server YAML found in folder as a shared map (id = file stem)."""
        folder = Path(folder)
        return self.maps.preload_dir(folder) if folder.is_dir() else []


@dataclass(frozen=True)
class ServiceContext:
    user: str
    state: ServiceState
