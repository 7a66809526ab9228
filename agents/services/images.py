"""Decoding and encoding of images carried as base64 PNG/JPEG in requests."""
from __future__ import annotations

import base64
import binascii

import cv2
import numpy as np
from ontology.errors import ErrorCode

from .errors import ServiceError


def b64_bytes(text: str, field: str = "image") -> bytes:
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise ServiceError(f"{field} is not valid base64", ErrorCode.BAD_IMAGE) from None


def decode_image(b64: str, field: str = "image_b64", gray: bool = False) -> np.ndarray:
    """BGR (or gray) uint8 image from base64 PNG/JPEG; ServiceError if it cannot be decoded."""
    data = b64_bytes(b64, field)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise ServiceError(f"{field} could not be decoded as an image (PNG or JPEG expected)", ErrorCode.BAD_IMAGE)
    return img


def encode_image(img: np.ndarray, ext: str = ".png") -> str:
    ok, buf = cv2.imencode(ext, img)
    if not ok:
        raise ValueError("image encoding failed")
    return base64.b64encode(buf.tobytes()).decode("ascii")
