"""RApp manifest: the metadata every package carries in ``manifest.yaml`` (or ``manifest.json``).

Contract: `parse_manifest` / `load_manifest` either return a validated `Manifest` or raise
`ManifestError` whose message names the offending field(s) and why. Unknown fields are refused
so typos surface. Keywords are normalised to lower case (the Core matches isolated commands
case-insensitively); list fields are de-duplicated keeping their order.
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .robot_actions import ROBOT_API_GROUPS  # the groups a Dynamic Agent may call on its Core Agent
# the robot types a RApp may target (ontology/robot_types.py; the Core and Store refuse any other)
from .robot_types import ROBOT_TYPES

#: Manifest file names looked up (in this order) in a source directory or an archive.
MANIFEST_NAMES: tuple[str, ...] = ("manifest.yaml", "manifest.json")

NAME_RE = re.compile(r"^[a-z][a-z0-9_-]{1,63}$")
VERSION_RE = re.compile(r"^(0|[1-9]\d{0,8})\.(0|[1-9]\d{0,8})\.(0|[1-9]\d{0,8})$")
_IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
ENTRY_POINT_RE = re.compile(rf"^{_IDENT}(\.{_IDENT})*:{_IDENT}$")
KEYWORD_RE = re.compile(r"^[^\W\d_][\w'-]{0,63}$")
SLOT_RE = re.compile(r"\{[a-z_][a-z0-9_]*\}")  # a parameter slot in a phrase: {room}
SERVICE_RE = re.compile(r"^[a-z][a-z0-9_.-]{0,63}$")
MAX_TIME_LIMIT_S = 24 * 3600.0


class ManifestError(ValueError):
    """A manifest could not be parsed or is invalid; the message gives the reason."""


def _dedupe(items: list[str]) -> list[str]:
    seen: dict[str, None] = {}
    for item in items:
        seen.setdefault(item, None)
    return list(seen)


def _check_entry_point(value: str | None, field: str) -> str | None:
    if value is None:
        return None
    if not ENTRY_POINT_RE.match(value):
        raise ValueError(f"{field} must look like 'package.module:Class', got {value!r}")
    return value


def entry_point_module_paths(entry_point: str) -> tuple[str, str]:
    """Archive paths that may hold the module of ``module:Class`` (``a/b.py`` or ``a/b/__init__.py``)."""
    module = entry_point.split(":", 1)[0].replace(".", "/")
    return f"{module}.py", f"{module}/__init__.py"


class Manifest(BaseModel):
    """Validated RApp manifest."""

    model_config = ConfigDict(extra="forbid", str_strip_whitespace=True)

    name: str = Field(description="the RApp's name in the Store: 2-64 of a-z, 0-9, '_', '-', from a letter")
    version: str = Field(description="MAJOR.MINOR.PATCH; the Store keeps every version, the Core takes the newest")
    description: str = Field("", description="what the RApp does, for its owner")
    robot_types: list[str] = Field(min_length=1, description=f"robots it runs on: {sorted(ROBOT_TYPES)}")
    keywords: list[str] = Field(default_factory=list, description=(
        "single words; one spoken or typed alone starts the RApp without the Platform's interpretation"))
    phrases: list[str] = Field(default_factory=list, description=(
        "command phrases the Platform's interpretation matches; a {slot} (lower-case name) takes one to "
        "three words of the command, which reach the RApp as parameters (runtime.params)"))
    entry_point: str = Field(description="'package.module:Class' of the task (a rapps.sdk.Behaviour)")
    cloud_entry_point: str | None = Field(None, description="'package.module:Class' of the Cloud Agent's part")
    cloud_restartable: bool = Field(False, description="the Platform starts a Cloud Agent that died once more")
    services: list[str] = Field(default_factory=list, description="Platform services the RApp may call (granted)")
    robot_api: list[str] = Field(default_factory=list, description=(
        f"robot action groups the RApp may call on its Core: {sorted(ROBOT_API_GROUPS)}"))
    params: dict[str, Any] = Field(default_factory=dict, description=(
        "the RApp's default parameters; a command's slot values override them"))
    time_limit_s: float = Field(600.0, description="the Core stops the RApp after this long (s)")
    author: str = ""

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not NAME_RE.match(v):
            raise ValueError(
                f"name must be 2-64 chars of a-z, 0-9, '_' or '-' starting with a letter, got {v!r}")
        return v

    @field_validator("version")
    @classmethod
    def _version(cls, v: str) -> str:
        if not VERSION_RE.match(v):
            raise ValueError(f"version must be MAJOR.MINOR.PATCH (e.g. 1.0.0), got {v!r}")
        return v

    @field_validator("robot_types")
    @classmethod
    def _robot_types(cls, v: list[str]) -> list[str]:
        unknown = [t for t in v if t not in ROBOT_TYPES]
        if unknown:
            raise ValueError(f"unknown robot type(s) {unknown}; known: {sorted(ROBOT_TYPES)}")
        return _dedupe(v)

    @field_validator("keywords")
    @classmethod
    def _keywords(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if not KEYWORD_RE.match(k)]
        if bad:
            raise ValueError(f"keywords must be single words, got {bad}")
        return _dedupe([k.lower() for k in v])

    @field_validator("phrases")
    @classmethod
    def _phrases(cls, v: list[str]) -> list[str]:
        if any(not p for p in v):
            raise ValueError("phrases must not be empty strings")
        bad = [p for p in v if SLOT_RE.sub("", p).count("{") + SLOT_RE.sub("", p).count("}")]
        if bad:
            raise ValueError(f"a slot is a lower-case name in braces, like {{room}}; got {bad}")
        return _dedupe(v)

    @field_validator("entry_point")
    @classmethod
    def _entry_point(cls, v: str) -> str:
        return _check_entry_point(v, "entry_point")  # type: ignore[return-value]

    @field_validator("cloud_entry_point")
    @classmethod
    def _cloud_entry_point(cls, v: str | None) -> str | None:
        return _check_entry_point(v, "cloud_entry_point")

    @field_validator("services")
    @classmethod
    def _services(cls, v: list[str]) -> list[str]:
        bad = [s for s in v if not SERVICE_RE.match(s)]
        if bad:
            raise ValueError(f"service names must match {SERVICE_RE.pattern}, got {bad}")
        return _dedupe(v)

    @field_validator("robot_api")
    @classmethod
    def _robot_api(cls, v: list[str]) -> list[str]:
        unknown = [g for g in v if g not in ROBOT_API_GROUPS]
        if unknown:
            raise ValueError(f"unknown robot_api group(s) {unknown}; known: {sorted(ROBOT_API_GROUPS)}")
        return _dedupe(v)

    @field_validator("params")
    @classmethod
    def _params(cls, v: dict[str, Any]) -> dict[str, Any]:
        try:
            json.dumps(v, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"params must be JSON-serialisable: {exc}") from None
        return v

    @field_validator("time_limit_s")
    @classmethod
    def _time_limit(cls, v: float) -> float:
        if not (0 < v <= MAX_TIME_LIMIT_S):
            raise ValueError(f"time_limit_s must be in (0, {MAX_TIME_LIMIT_S:g}], got {v}")
        return v

    @property
    def version_tuple(self) -> tuple[int, int, int]:
        """Version as integers, for ordering."""
        major, minor, patch = (int(p) for p in self.version.split("."))
        return major, minor, patch

    @property
    def entry_module(self) -> str:
        return self.entry_point.split(":", 1)[0]

    @property
    def entry_class(self) -> str:
        return self.entry_point.split(":", 1)[1]

    def to_yaml(self) -> str:
        """Canonical YAML text (fixed field order) as stored in built archives."""
        text: str = yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False, allow_unicode=True)
        return text


def version_key(version: str) -> tuple[int, int, int]:
    """Sort key of a ``MAJOR.MINOR.PATCH`` string; `ManifestError` if malformed."""
    if not isinstance(version, str) or not VERSION_RE.match(version):
        raise ManifestError(f"version must be MAJOR.MINOR.PATCH, got {version!r}")
    major, minor, patch = (int(p) for p in version.split("."))
    return major, minor, patch


def _format_errors(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "manifest"
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}")
    return "; ".join(parts)


def manifest_from_dict(data: Any) -> Manifest:
    """Validate a mapping as a `Manifest`; `ManifestError` naming each bad field."""
    if not isinstance(data, dict):
        raise ManifestError(f"invalid manifest: top level must be a mapping, got {type(data).__name__}")
    try:
        return Manifest.model_validate(data)
    except ValidationError as exc:
        raise ManifestError(f"invalid manifest: {_format_errors(exc)}") from None


def parse_manifest(text: str | bytes, fmt: str = "yaml") -> Manifest:
    """Parse manifest text in ``fmt`` ("yaml" or "json"); `ManifestError` on any problem."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError:
            raise ManifestError("invalid manifest: not UTF-8 text") from None
    try:
        if fmt == "json":
            data = json.loads(text)
        elif fmt == "yaml":
            data = yaml.safe_load(text)
        else:
            raise ManifestError(f"unknown manifest format {fmt!r}")
    except (yaml.YAMLError, ValueError, RecursionError) as exc:
        if isinstance(exc, ManifestError):
            raise
        raise ManifestError(f"invalid manifest: cannot parse {fmt}: {exc}") from None
    return manifest_from_dict(data)


def manifest_format(filename: str) -> str:
    """"json" for ``*.json`` names, else "yaml"."""
    return "json" if filename.endswith(".json") else "yaml"


def load_manifest(path: str | Path) -> Manifest:
    """Load a manifest file, or the manifest of a source directory (``manifest.yaml``/``.json``)."""
    path = Path(path)
    if path.is_dir():
        found = [path / n for n in MANIFEST_NAMES if (path / n).is_file()]
        if not found:
            raise ManifestError(f"no manifest.yaml or manifest.json in {path}")
        if len(found) > 1:
            raise ManifestError(f"both manifest.yaml and manifest.json in {path}; keep one")
        path = found[0]
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ManifestError(f"cannot read manifest {path}: {exc}") from None
    return parse_manifest(raw, manifest_format(path.name))


def manifest_schema() -> dict[str, Any]:
    """The manifest's JSON Schema, generated from the model (docs/manifest.schema.json is its copy)."""
    schema = Manifest.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "RApp manifest (manifest.yaml)"
    return schema
