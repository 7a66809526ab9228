"""A Cloud Agent's last request survives its process's crash (agents/crash_box.py); the box, in
the RApp's own directory, is read as untrusted."""
import os
import struct
import subprocess
import sys

from agents.crash_box import BOX_NAME, keep_crash_input, read_box

CRASHES_HOLDING = """
import os, sys
from agents.crash_box import CrashBox
box = CrashBox(sys.argv[1], size=1024)
box.hold("observe", '{"frame": "small"}')
box.hold("observe", '{"frame": "' + "x" * 300_000 + '"}')  # grows the file past its first size
os.abort()  # as a segmentation fault would end it: no clean-up runs
"""


def test_the_last_request_survives_a_crash(tmp_path):
    box = tmp_path / BOX_NAME
    proc = subprocess.run([sys.executable, "-c", CRASHES_HOLDING, str(box)], capture_output=True)
    assert proc.returncode < 0
    action, body = read_box(box)
    assert action == "observe" and body == '{"frame": "' + "x" * 300_000 + '"}'
    kept = keep_crash_input(box, tmp_path / "crashes" / "cloud-x.json")
    assert kept is not None and '"action": "observe"' in kept.read_text()


def test_a_box_that_is_a_link_or_lies_about_its_length_gives_nothing(tmp_path):
    secret = tmp_path / "secret"
    secret.write_bytes(struct.pack("<Q", 6) + b"a\nbody")
    link = tmp_path / BOX_NAME
    os.symlink(secret, link)
    assert read_box(secret) == ("a", "body") and read_box(link) is None  # a RApp's link is not followed
    os.unlink(link)
    link.write_bytes(struct.pack("<Q", 1 << 40) + b"x")  # claims a terabyte
    assert read_box(link) is None and keep_crash_input(link, tmp_path / "out.json") is None
    assert read_box(tmp_path / "none") is None
