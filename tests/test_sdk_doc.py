"""docs/sdk.md shows real code: each code block is a file of an example (whose test runs in the
suite) or of the `rapp new --cloud` scaffold (tests/test_scaffold.py runs it), verbatim."""
from __future__ import annotations

import re
from pathlib import Path

from rapps.scaffold import create

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "sdk.md").read_text()
BLOCKS = re.findall(r"<!-- (file|scaffold): (\S+) -->\n```\w*\n(.*?)```", DOC, re.S)


def test_every_code_block_of_the_guide_is_a_checked_file(tmp_path):
    create("my-rapp", tmp_path / "my-rapp", cloud=True)
    assert len(BLOCKS) >= 5
    for kind, path, text in BLOCKS:
        real = ROOT / path if kind == "file" else tmp_path / "my-rapp" / path
        assert text == real.read_text(), f"docs/sdk.md: the block of {path} differs from the file"
    python_blocks = len(re.findall(r"```python\n", DOC))
    assert python_blocks == sum(1 for _, p, _ in BLOCKS if p.endswith(".py")), "a Python block with no file"
