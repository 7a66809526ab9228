"""The requests a Cloud Agent is working on, and the last one it took, survive its process's crash
(agents/crash_box.py); the box, in the RApp's own directory, is read as untrusted."""
import json
import os
import struct
import subprocess
import sys

from agents.crash_box import BOX_NAME, keep_crash_input, read_box

CRASHES_HOLDING = """
import os, sys
from agents.crash_box import CrashBox
box = CrashBox(sys.argv[1], size=1024)
first = box.hold("observe", '{"frame": "small"}')
second = box.hold("observe", '{"frame": "' + "x" * 300_000 + '"}')  # grows the file past its first size
third = box.hold("localize", "{}")
box.release(third)  # answered: no longer in progress
os.abort()  # as a segmentation fault would end it: no clean-up runs
"""
CRASHES_IDLE = """
import os, sys
from agents.crash_box import CrashBox
box = CrashBox(sys.argv[1], size=1024)
for n in range(3):
    box.release(box.hold("double", '{"value": %d}' % n))
os.abort()
"""


def _crash(script: str, box) -> None:
    proc = subprocess.run([sys.executable, "-c", script, str(box)], capture_output=True)
    assert proc.returncode < 0


def test_the_requests_in_progress_survive_a_crash(tmp_path):
    box = tmp_path / BOX_NAME
    _crash(CRASHES_HOLDING, box)
    big = '{"frame": "' + "x" * 300_000 + '"}'
    assert read_box(box) == [("observe", '{"frame": "small"}', True), ("observe", big, True), ("localize", "{}", False)]
    kept = keep_crash_input(box, tmp_path / "crashes" / "cloud-x.json")
    requests = json.loads(kept.read_text())["requests"]
    assert [(r["action"], r["in_progress"]) for r in requests] == [("observe", True), ("observe", True), ("localize", False)]


def test_an_idle_process_leaves_only_the_last_request_it_took(tmp_path):
    box = tmp_path / BOX_NAME
    _crash(CRASHES_IDLE, box)
    assert read_box(box) == [("double", '{"value": 2}', False)]


def test_a_box_that_is_a_link_or_lies_about_its_length_gives_nothing(tmp_path):
    secret = tmp_path / "secret"
    secret.write_bytes(struct.pack("<Q", 11) + struct.pack("<IB", 6, 1) + b"a\nbody")
    link = tmp_path / BOX_NAME
    os.symlink(secret, link)
    assert read_box(secret) == [("a", "body", True)] and read_box(link) is None  # a RApp's link is not followed
    os.unlink(link)
    link.write_bytes(struct.pack("<Q", 1 << 40) + b"x")  # claims a terabyte
    assert read_box(link) is None and keep_crash_input(link, tmp_path / "out.json") is None
    link.write_bytes(struct.pack("<Q", 11) + struct.pack("<IB", 1 << 30, 1) + b"a\nbody")  # a record that lies
    assert read_box(link) == [] and keep_crash_input(link, tmp_path / "out.json") is None
    assert read_box(tmp_path / "none") is None
