"""Docs that match the code: every `rapp ...` command shown in README.md and docs/*.md is run with
--help, and each option it shows must be one the command knows, so a renamed option fails CI."""
from __future__ import annotations

import contextlib
import functools
import io
import re
import shlex
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
NESTED = {"agent", "run", "trace", "package", "store", "platform"}  # take a second word


def shown_commands() -> list[tuple[str, str]]:
    """(doc, command) for each `rapp ...` in inline code or at the start of a code-block line."""
    found = []
    for doc in DOCS:
        text = doc.read_text()
        inline = re.findall(r"`(rapp [^`]+)`", text)
        blocks = re.findall(r"(?:^\s*(?:\$ )?|&& )((?:\.venv/bin/)?rapp [^\n|`]+)$", text, re.M)
        for cmd in inline + blocks:
            cmd = cmd.split(" && ")[-1].split(" #")[0].replace(".venv/bin/", "").strip()  # no comment
            if cmd.startswith("rapp "):
                found.append((doc.name, cmd))
    return sorted(set(found))


def _split(cmd: str) -> tuple[list[str], list[str]]:
    words = shlex.split(cmd.replace("[", " ").replace("]", " ").replace("|", " "))[1:]
    prefix = words[:1]
    if words[:1] and words[0] in NESTED and len(words) > 1 and re.fullmatch(r"[a-z][a-z0-9-]*", words[1]):
        prefix = words[:2]
    return prefix, [w.split("=")[0] for w in words if w.startswith("--")]


COMMANDS = shown_commands()


def test_the_docs_show_commands():
    assert len(COMMANDS) >= 15 and any("rapp agent core" in c for _, c in COMMANDS)


@functools.cache
def _help(prefix: tuple[str, ...]):
    """`rapp PREFIX --help`, once per prefix, in this process (132 commands shown, 34 prefixes: a
    process each took 80 s of a worker; test_cli runs `rapp ... --help` as processes)."""
    from cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([*prefix, "--help"])
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


@pytest.mark.parametrize("doc, cmd", COMMANDS, ids=[f"{d}:{c[:60]}" for d, c in COMMANDS])
def test_documented_command_and_its_options_exist(doc, cmd):
    prefix, options = _split(cmd)
    res = _help(tuple(prefix))
    assert res.returncode == 0, f"{doc}: `{cmd}`: {res.stdout[-500:]}{res.stderr[-500:]}"
    text = res.stdout + res.stderr
    missing = [o for o in options if o not in text and o != "--help"]
    assert not missing, f"{doc}: `{cmd}` shows {missing}, which `rapp {' '.join(prefix)} --help` does not know"
