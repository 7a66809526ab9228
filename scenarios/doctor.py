"""`rapp doctor`: checks the installation and the configured XMPP server, says how to fix."""
from __future__ import annotations

import asyncio
import importlib
import sys

from xmpp_server.settings import XmppSettings

def _check(name: str, fn) -> bool:
    try:
        detail = fn()
        print(f"  ok    {name}{': ' + detail if detail else ''}")
        return True
    except Note as e:
        print(f"  note  {name}: {e}")
        return True
    except Exception as e:  # noqa: BLE001 - every failure is reported, none stops the others
        print(f"  FAIL  {name}: {e}")
        return False


def _versions() -> str:
    """Every exact pin of the project's requirements against what is installed."""
    from importlib.metadata import PackageNotFoundError, requires, version

    from xmpp_server.compat import check_pins

    check_pins()  # the ones xmpp_server/compat.py patches, with its message
    pins = [r.split(";")[0].replace(" ", "").split("==") for r in requires("rapp-agents") or []
            if "==" in r and "extra ==" not in r]
    out, bad = [], []
    for dist, want in pins:
        try:
            got = version(dist)
        except PackageNotFoundError:
            got = "missing"
        (out if got == want else bad).append(f"{dist} {got}" + ("" if got == want else f" (pinned {want})"))
    if bad:
        raise RuntimeError(f"{', '.join(bad)}: run pip install -e . again")
    return ", ".join(out)


def _pybullet() -> str:
    from robots.pybullet_quiet import p
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


class Note(Exception):
    """Not a fault: something optional is absent, and what that means."""


class NoServer(Note):
    """Nothing listens where the settings point: normal on a machine that only runs `rapp run`."""


def _recognition() -> str:
    from importlib.metadata import version

    from hearing.decoder import PhraseDecoder
    dec = PhraseDecoder(["check the hazards"])
    if not dec.phrases:
        raise RuntimeError("pocketsphinx's US English dictionary lacks common words: reinstall pocketsphinx")
    return f"pocketsphinx {version('pocketsphinx')} loads its US English model"


def _synthesis() -> str:
    from hearing import tts
    from hearing.errors import SpeechUnavailable
    try:
        pcm = tts.synthesize("hello")
    except SpeechUnavailable:
        raise Note("eSpeak NG is not installed (the speech extra: pip install -e '.[speech]'). The NAO's "
                   "`say` refuses, `rapp run --speak` cannot speak for the owner, and keywords outside "
                   "pocketsphinx's dictionary cannot be heard") from None
    return f"eSpeak NG says 'hello' in {len(pcm) / 16000:.2f} s of audio"


def _server(settings: XmppSettings) -> str:
    import socket

    from xmpp_server.probe import probe_login
    try:
        socket.create_connection((settings.host, settings.port), timeout=2).close()
    except OSError:
        raise NoServer(f"no XMPP server at {settings.host}:{settings.port}. That is fine for `rapp run`, "
                       f"which starts its own; for `rapp agent` start one with `rapp server --port "
                       f"{settings.port}` (or Prosody/ejabberd) or set RAPP_XMPP_HOST/PORT/DOMAIN") from None
    try:
        dt = asyncio.run(probe_login(settings.host, settings.port, settings.domain, timeout=5))
    except Exception as e:  # noqa: BLE001 - any failure of the login is this check's finding, with a hint
        raise RuntimeError(f"{e}. Check RAPP_XMPP_DOMAIN and the server's settings (docs/deployment.md)") from None
    return f"login to {settings.host}:{settings.port} (domain {settings.domain}) in {dt * 1000:.0f} ms"


def run_checks() -> int:
    settings = XmppSettings.from_env()
    print(f"python {sys.version.split()[0]}")
    results = [_check("pinned versions", _versions), _check("PyBullet", _pybullet),
               _check("OpenCV", _opencv), _check("OMPL", _ompl),
               _check("speech recognition", _recognition), _check("text to speech", _synthesis),
               _check("configured XMPP server accepts logins", lambda: _server(settings))]
    print("all good" if all(results) else f"{results.count(False)} problem(s) found")
    return 0 if all(results) else 1
