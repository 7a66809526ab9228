"""pybullet, imported without its banner: its C module prints "pybullet build time: ..." on stderr when
it is first imported in a process. Every simulator module takes `p` from here (a render process's too), so
whichever comes first imports it with stderr closed for that moment."""
from __future__ import annotations

import os
import sys


def _import_quietly():
    if "pybullet" not in sys.modules:
        sys.stderr.flush()
        saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 2)
            import pybullet  # noqa: F401
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            os.close(null)
    return sys.modules["pybullet"]


p = _import_quietly()
