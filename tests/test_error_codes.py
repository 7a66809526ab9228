"""One vocabulary of error codes (ontology/errors.py): every code the agents, the services, the
package format and the SDK can put in a refuse/failure/not-understood is an ErrorCode member, and
no code is written as a bare string where it is raised."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from ontology.errors import ErrorCode
from rapps.sdk import ErrorCode as SdkErrorCode

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [p for d in ("agents", "ontology", "robots", "rapps/sdk") for p in sorted((ROOT / d).rglob("*.py"))
           if p.name != "errors.py" or p.parent.name != "ontology"]
# an error built with a code given as a string literal: Refusal("...", "forbidden"), code="x"
ERRORS = (r"(?:ServiceError|Refusal|Failure|StoreError|RequestError|RequestRefused|RequestFailed|NotUnderstood|"
          r"RequestTimeout|CloudAgentLost|Reason|DirectoryError|PackageError|ChunkError|ManifestError)")
POSITIONAL = re.compile(ERRORS + r"\((?:[^()]|\([^()]*\))*?,\s*\"([a-z][a-z_-]*)\"\s*\)", re.S)
KEYWORD = re.compile(r"\bcode\s*=\s*\"([a-z][a-z_-]*)\"")
ATTRIBUTE = re.compile(r"^\s+code\s*=\s*\"([a-z][a-z_-]*)\"", re.M)  # class-level defaults
DEFAULT = re.compile(r"getattr\(e, \"code\", \"([a-z][a-z_-]*)\"\)")  # a fallback code


def bare_codes(text: str) -> list[str]:
    return POSITIONAL.findall(text) + KEYWORD.findall(text) + ATTRIBUTE.findall(text) + DEFAULT.findall(text)


def test_no_error_code_is_a_bare_string():
    found = {f"{p.relative_to(ROOT)}: {c!r}" for p in SOURCES for c in bare_codes(p.read_text())}
    unknown = sorted(f for f in found if f.split("'")[1] not in {c.value for c in ErrorCode})
    assert not unknown, f"codes that are not ErrorCode members: {unknown}"
    assert not found, f"use ErrorCode members, not strings: {sorted(found)[:10]}"


def test_the_scan_sees_a_bare_code():
    assert bare_codes('raise Refusal(f"no {x}", "forbidden")\nReason(reason=r, code="nope")') == ["forbidden", "nope"]
    assert bare_codes("raise Refusal(f'no {x}', ErrorCode.FORBIDDEN)") == []


def test_codes_are_unique_one_spelling_each_and_compare_as_strings():
    values = [c.value for c in ErrorCode]
    assert len(values) == len(set(values))
    squashed = [v.replace("_", "-") for v in values]
    assert len(squashed) == len(set(squashed)), "one code spelled two ways"
    assert ErrorCode.NOT_UNDERSTOOD == "not-understood" and f"{ErrorCode.FORBIDDEN}" == "forbidden"
    assert SdkErrorCode is ErrorCode


@pytest.mark.parametrize("code", list(ErrorCode))
def test_a_reason_carries_the_code_as_its_string_on_the_wire(code):
    from ontology.common import Reason
    from ontology.registry import encode

    assert f'"code":"{code.value}"' in encode(Reason(reason="x", code=code)).replace(" ", "")
