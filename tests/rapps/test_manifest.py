"""Manifest parsing and validation."""
from __future__ import annotations

import json

import pytest
import yaml
from hypothesis import given, settings, strategies as st

from ontology.manifest import (ROBOT_TYPES, Manifest, ManifestError, load_manifest, manifest_from_dict,
                            parse_manifest, version_key)
from tests.rapps.helpers import manifest


def test_valid_manifest_defaults_and_normalisation():
    m = manifest_from_dict(manifest(keywords=["Wave", "wave", "HELLO"], robot_types=["nao", "nao", "elektron"]))
    assert isinstance(m, Manifest)
    assert m.keywords == ["wave", "hello"]
    assert m.robot_types == ["nao", "elektron"]
    assert m.time_limit_s == 600
    assert m.cloud_entry_point is None and m.params == {} and m.services == []
    assert (m.entry_module, m.entry_class) == ("demo.task", "DemoTask")
    assert m.version_tuple == (1, 0, 0)


def test_yaml_and_json_parse_alike(tmp_path):
    data = manifest(params={"speed": 0.5}, cloud_entry_point="demo.cloud:Helper", services=["speech.asr"])
    y = parse_manifest(yaml.safe_dump(data))
    j = parse_manifest(json.dumps(data), "json")
    assert y == j
    (tmp_path / "manifest.json").write_text(json.dumps(data))
    assert load_manifest(tmp_path) == y
    assert parse_manifest(y.to_yaml()) == y


@pytest.mark.parametrize("field,value,reason", [
    ("name", "Bad Name", "name"),
    ("name", "x", "name"),
    ("version", "1.0", "MAJOR.MINOR.PATCH"),
    ("version", "01.0.0", "MAJOR.MINOR.PATCH"),
    ("robot_types", [], "robot_types"),
    ("robot_types", ["roomba"], "unknown robot type"),
    ("keywords", ["two words"], "single words"),
    ("entry_point", "demo.task", "entry_point"),
    ("entry_point", "../x:Y", "entry_point"),
    ("cloud_entry_point", "nope", "cloud_entry_point"),
    ("robot_api", ["teleport"], "unknown robot_api group"),
    ("services", ["Bad Service"], "service names"),
    ("time_limit_s", 0, "time_limit_s"),
    ("time_limit_s", 10 ** 9, "time_limit_s"),
    ("phrases", [""], "phrases"),
    ("phrases", ["check the lamp in the {Room}"], "slot"),
    ("phrases", ["check the lamp in the {room"], "slot"),
    ("unexpected", 1, "unexpected"),
])
def test_invalid_fields_name_the_reason(field, value, reason):
    with pytest.raises(ManifestError) as exc:
        manifest_from_dict(manifest(**{field: value}))
    assert reason in str(exc.value)
    assert field in str(exc.value)


def test_missing_required_field():
    data = manifest()
    del data["entry_point"]
    with pytest.raises(ManifestError, match="entry_point"):
        manifest_from_dict(data)


@pytest.mark.parametrize("text", ["", "- a\n- b\n", "name: [unclosed", "just text", "\xff"])
def test_unparsable_or_non_mapping(text):
    with pytest.raises(ManifestError):
        parse_manifest(text)


def test_not_utf8_and_bad_json():
    with pytest.raises(ManifestError, match="UTF-8"):
        parse_manifest(b"\xff\xfe")
    with pytest.raises(ManifestError, match="json"):
        parse_manifest("{", "json")


def test_load_manifest_errors(tmp_path):
    with pytest.raises(ManifestError, match="no manifest"):
        load_manifest(tmp_path)
    (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(manifest()))
    (tmp_path / "manifest.json").write_text(json.dumps(manifest()))
    with pytest.raises(ManifestError, match="both"):
        load_manifest(tmp_path)


def test_version_key_orders_numerically():
    assert sorted(["1.10.0", "1.2.0", "0.9.9"], key=version_key) == ["0.9.9", "1.2.0", "1.10.0"]
    with pytest.raises(ManifestError):
        version_key("1.2")


def test_known_robot_types_are_the_robot_type_table():
    from ontology import robot_types

    assert ROBOT_TYPES is robot_types.ROBOT_TYPES and list(ROBOT_TYPES) == ["nao", "elektron"]
    with pytest.raises(ManifestError, match=r"unknown robot type\(s\) \['pepper'\]; known: \['elektron', 'nao'\]"):
        manifest_from_dict(manifest(robot_types=["pepper"]))


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                     lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=8), c, max_size=3),
                     max_leaves=10)


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(manifest()) + ["params", "time_limit_s", "x"]), _json, max_size=8))
def test_random_dicts_only_raise_manifest_error(data):
    try:
        manifest_from_dict(manifest(**data))
    except ManifestError:
        pass


@settings(max_examples=150, deadline=None)
@given(st.text(max_size=200))
def test_random_text_only_raises_manifest_error(text):
    try:
        parse_manifest(text)
    except ManifestError:
        pass


def test_slotted_phrases_are_valid():
    assert manifest_from_dict(manifest(phrases=["check the lamp in the {room}"])).phrases == [
        "check the lamp in the {room}"]


def test_the_schema_in_docs_is_the_models(tmp_path):
    """docs/manifest.schema.json is regenerated by `rapp package schema docs/manifest.schema.json`."""
    import json
    from pathlib import Path

    from ontology.manifest import manifest_schema

    doc = Path(__file__).resolve().parents[2] / "docs" / "manifest.schema.json"
    assert json.loads(doc.read_text()) == manifest_schema(), "run: rapp package schema docs/manifest.schema.json"
    assert set(manifest_schema()["required"]) == {"name", "version", "robot_types", "entry_point"}
