"""QR-code textures for landmark panels, generated with OpenCV's QRCodeEncoder into a cache dir."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np

QUIET_MODULES = 2  # white border (in modules) around the symbol on the panel texture
PIXELS_PER_MODULE = 8


def cache_dir() -> Path:
    """Generated URDFs and QR textures, reused across runs: RAPP_ROBOTS_CACHE, else the user's
    cache directory (not /tmp, where another user could plant files first)."""
    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rapp" / "robots"
    d = Path(os.environ.get("RAPP_ROBOTS_CACHE") or default)
    d.mkdir(parents=True, exist_ok=True)
    return d


def qr_symbol(text: str) -> np.ndarray:
    """Binary QR symbol (uint8 0/255) with exactly QUIET_MODULES white modules around it."""
    enc = cv2.QRCodeEncoder.create() if hasattr(cv2.QRCodeEncoder, "create") else cv2.QRCodeEncoder()
    img = enc.encode(text)
    dark = np.argwhere(img < 128)
    (r0, c0), (r1, c1) = dark.min(0), dark.max(0)
    sym = img[r0:r1 + 1, c0:c1 + 1]
    return np.pad(sym, QUIET_MODULES, constant_values=255)


def symbol_fraction(text: str) -> float:
    """Side of the symbol (without quiet zone) as a fraction of the whole texture side."""
    sym = qr_symbol(text)
    return (sym.shape[0] - 2 * QUIET_MODULES) / sym.shape[0]


def qr_texture(text: str) -> Path:
    """PNG texture of the QR code with quiet zone; cached by content."""
    name = hashlib.sha1(f"{text}|{QUIET_MODULES}|{PIXELS_PER_MODULE}".encode()).hexdigest()[:16]
    path = cache_dir() / f"qr_{name}.png"
    if not path.exists():
        sym = qr_symbol(text)
        big = cv2.resize(sym, (sym.shape[1] * PIXELS_PER_MODULE, sym.shape[0] * PIXELS_PER_MODULE),
                         interpolation=cv2.INTER_NEAREST)
        tmp = path.with_suffix(f".{os.getpid()}.png")
        cv2.imwrite(str(tmp), cv2.cvtColor(big, cv2.COLOR_GRAY2BGR))
        os.replace(tmp, path)
    return path
