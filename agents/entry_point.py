"""Loading a RApp's entry point (`module:Class`) from its unpacked package directory: what the
Dynamic and Cloud Agents (agents/dynamic_agent.py, agents/cloud_agent.py) and the runtime that
builds them (agents/runtime.py) share."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any

from behaviours import exception_text


class EntryPointError(RuntimeError):
    pass


def load_entry_point(package_dir: str | Path, entry_point: str) -> Any:
    """Import `module:Class` from the unpacked package directory."""
    module_name, _, class_name = entry_point.partition(":")
    root = str(Path(package_dir).resolve())
    _forget_other_copies(module_name.split(".")[0], root)
    if root not in sys.path:
        sys.path.insert(0, root)
    try:
        module = importlib.import_module(module_name)
    except (Exception, SystemExit) as e:  # noqa: BLE001 - any import failure of RApp code is reported as such
        raise EntryPointError(f"cannot import {module_name!r} from the package: {exception_text(e)}") from e
    cls = getattr(module, class_name, None)
    if cls is None:
        raise EntryPointError(f"module {module_name!r} has no {class_name!r}")
    return cls


def _forget_other_copies(top: str, root: str) -> None:
    """In-process runs import each RApp from its own unpack directory: drop earlier copies."""
    for name in [n for n in sys.modules if n == top or n.startswith(top + ".")]:
        origin = getattr(sys.modules[name], "__file__", None) or ""
        if not origin.startswith(root):
            del sys.modules[name]
    sys.path[:] = [p for p in sys.path if not (p.endswith("/package") and p != root and
                                               Path(p, top).exists())]
