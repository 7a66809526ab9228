"""A scenario file (YAML) holds sections for different parts of a run: `disturbances:` for the world
(robots/disturbances.py), `speech:` for the owner's voice (scenarios/owner_voice.py). Each part reads
its own section and ignores the others."""
from __future__ import annotations

from pathlib import Path

import yaml


def read_section(path: str | Path, key: str, error: type[Exception], what: str = "scenario file") -> list:
    """The `key:` list of a scenario file ([] when absent); `error(message)` when the file cannot be
    read, is not a mapping, or the section is not a list."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise error(f"cannot read {what} {path}: {exc}") from None
    if not isinstance(data, dict):
        raise error(f"{what} {path}: expected a mapping with a '{key}' list")
    section = data.get(key) or []
    if not isinstance(section, list):
        raise error(f"{what} {path}: '{key}' must be a list")
    return section
