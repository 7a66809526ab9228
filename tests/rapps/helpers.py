"""Helpers for the package tests: RApp source trees and hand-made (hostile) archives."""
from __future__ import annotations

import gzip
import io
import tarfile
from pathlib import Path

import yaml

BASE_MANIFEST = {
    "name": "demo",
    "version": "1.0.0",
    "description": "Demo application that waves",
    "robot_types": ["nao"],
    "keywords": ["wave"],
    "phrases": ["wave your hand"],
    "entry_point": "demo.task:DemoTask",
    "robot_api": ["communication"],
}


def manifest(**overrides) -> dict:
    data = dict(BASE_MANIFEST)
    data.update(overrides)
    return data


def make_src(root: Path, **overrides) -> Path:
    """A RApp source directory with a valid manifest (fields overridable) and its entry module."""
    m = manifest(**overrides)
    root.mkdir(parents=True, exist_ok=True)
    (root / "manifest.yaml").write_text(yaml.safe_dump(m))
    module = m["entry_point"].split(":")[0].replace(".", "/")
    (root / module).parent.mkdir(parents=True, exist_ok=True)
    (root / f"{module}.py").write_text("class DemoTask:\n    async def run(self):\n        return 1\n")
    (root / "data").mkdir(exist_ok=True)
    (root / "data" / "words.txt").write_text("wave\nhello\n")
    return root


def make_archive(entries: list[tuple[str, bytes | None, bytes]], *, gz: bool = True) -> bytes:
    """Raw tar.gz from (name, tar type (None = regular file), content or link target)."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for name, kind, content in entries:
            info = tarfile.TarInfo(name)
            if kind is None:
                info.size = len(content)
                tar.addfile(info, io.BytesIO(content))
            else:
                info.type = kind
                if kind in (tarfile.SYMTYPE, tarfile.LNKTYPE):
                    info.linkname = content.decode()
                tar.addfile(info)
    return gzip.compress(raw.getvalue(), mtime=0) if gz else raw.getvalue()


def valid_entries(**overrides) -> list[tuple[str, bytes | None, bytes]]:
    return [
        ("manifest.yaml", None, yaml.safe_dump(manifest(**overrides)).encode()),
        ("demo/task.py", None, b"class DemoTask:\n    pass\n"),
    ]
