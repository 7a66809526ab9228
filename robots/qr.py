"""QR-code textures for landmark panels, generated with OpenCV's QRCodeEncoder into a cache dir."""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
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


def qr_texture(text: str, wear: Wear | None = None) -> Path:
    """PNG texture of the QR code with quiet zone, worn as `wear` says; cached by content."""
    key = f"{text}|{QUIET_MODULES}|{PIXELS_PER_MODULE}" + (f"|{wear}" if wear else "")
    name = hashlib.sha1(key.encode()).hexdigest()[:16]
    path = cache_dir() / f"qr_{name}.png"
    if not path.exists():
        sym = qr_symbol(text)
        big = cv2.resize(sym, (sym.shape[1] * PIXELS_PER_MODULE, sym.shape[0] * PIXELS_PER_MODULE),
                         interpolation=cv2.INTER_NEAREST)
        img = cv2.cvtColor(big, cv2.COLOR_GRAY2BGR)
        if wear:
            img = wear.apply(img, PIXELS_PER_MODULE)
        tmp = path.with_suffix(f".{os.getpid()}.png")
        cv2.imwrite(str(tmp), img)
        os.replace(tmp, path)
    return path


@dataclass(frozen=True)
class Wear:
    """What years on a wall did to a printed label (robots/lived_in.py draws it): ink faded (black
    prints as grey), a print or a laminate that blurs the module edges, a glossy spot where a lamp
    reflects (baked into the print: the renderer has no specular light, so the spot does not move
    with the viewer), and a share of the symbol covered from one side (a plant, a sticker, a frame)."""
    fade: float = 0.0  # 0..1: black prints as this share of white
    blur_modules: float = 0.0  # print blur, 1 sigma in modules
    glare: float = 0.0  # 0..1: brightness added at the spot's centre
    glare_at: tuple[float, float] = (0.5, 0.5)  # the spot, as fractions of the texture
    cover: float = 0.0  # share of the texture's side covered
    cover_side: str = "left"  # left, right, top, bottom

    def __bool__(self) -> bool:
        return any((self.fade, self.blur_modules, self.glare, self.cover))

    def apply(self, img: np.ndarray, px_per_module: int) -> np.ndarray:
        out = img.astype(np.float32)
        out = 255.0 * self.fade + out * (1.0 - self.fade)
        if self.blur_modules:
            out = cv2.GaussianBlur(out, (0, 0), self.blur_modules * px_per_module)
        if self.glare:
            h, w = out.shape[:2]
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            cx, cy = self.glare_at[0] * w, self.glare_at[1] * h
            spot = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (0.12 * w) ** 2))
            out = out + (255.0 * self.glare * spot)[..., None]
        if self.cover:
            h, w = out.shape[:2]
            n = int(round(self.cover * (w if self.cover_side in ("left", "right") else h)))
            region = {"left": np.s_[:, :n], "right": np.s_[:, w - n:], "top": np.s_[:n, :],
                      "bottom": np.s_[h - n:, :]}[self.cover_side]
            out[region] = (70.0, 110.0, 60.0)  # BGR: a leaf-green cover
        return np.clip(out, 0, 255).astype(np.uint8)
