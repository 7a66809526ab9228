"""`rapp doctor`: checks the installation and the configured XMPP server, says how to fix."""
from __future__ import annotations

import asyncio
import importlib
import sys

from xmpp_server.settings import XmppSettings

PINS = {"spade": "4.1.4", "pyjabber": "0.4.5", "slixmpp": None}


def _check(name: str, fn) -> bool:
    try:
        detail = fn()
        print(f"  ok    {name}{': ' + detail if detail else ''}")
        return True
    except Exception as e:  # noqa: BLE001 - every failure is reported, none stops the others
        print(f"  FAIL  {name}: {e}")
        return False


def _versions() -> str:
    from importlib.metadata import version
    out = []
    for dist, want in (("spade", "4.1.4"), ("pyjabber", "0.4.5"), ("slixmpp-multiplatform", "1.12.0")):
        got = version(dist)
        if got != want:
            raise RuntimeError(f"{dist} {got} installed, {want} expected: pip install -e . again")
        out.append(f"{dist} {got}")
    return ", ".join(out)


def _pybullet() -> str:
    import pybullet as p
    cid = p.connect(p.DIRECT)
    try:
        w, h, *_ = p.getCameraImage(32, 24, renderer=p.ER_TINY_RENDERER)
        return f"DIRECT mode renders {w}x{h}"
    finally:
        p.disconnect(cid)


def _opencv() -> str:
    import cv2
    missing = [n for n in ("CascadeClassifier", "HOGDescriptor", "QRCodeDetector") if not hasattr(cv2, n)]
    if missing:
        raise RuntimeError(f"OpenCV {cv2.__version__} lacks {', '.join(missing)}: install opencv-python-headless 4.x")
    return f"OpenCV {cv2.__version__}"


def _ompl() -> str:
    importlib.import_module("ompl.geometric")
    return "python bindings load"


def _server(settings: XmppSettings) -> str:
    from xmpp_server.probe import probe_login
    try:
        dt = asyncio.run(probe_login(settings.host, settings.port, settings.domain, timeout=5))
    except Exception as e:
        raise RuntimeError(f"{e}. Start one with `rapp server` or set RAPP_XMPP_HOST/PORT/DOMAIN") from None
    return f"login to {settings.host}:{settings.port} (domain {settings.domain}) in {dt * 1000:.0f} ms"


def run_checks() -> int:
    settings = XmppSettings.from_env()
    print(f"python {sys.version.split()[0]}")
    results = [_check("pinned SPADE / pyjabber / slixmpp", _versions), _check("PyBullet", _pybullet),
               _check("OpenCV", _opencv), _check("OMPL", _ompl),
               _check("configured XMPP server accepts logins", lambda: _server(settings))]
    print("all good" if all(results) else f"{results.count(False)} problem(s) found")
    return 0 if all(results) else 1
