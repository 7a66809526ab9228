"""Two networks of face-api.js, run in NumPy from the weights the npm package @vladmandic/face-api
1.7.15 (MIT) ships (agents/services/data/models/README.md says where they come from and how to check
them):

- the 68-point landmark network (`landmarks`): a face crop, padded square and scaled to 112x112 ->
  68 (x, y) points; four dense blocks of depthwise separable convolutions, an average and a matrix
  (the package's src/faceFeatureExtractor and src/faceLandmarkNet); `dlib_box` turns the points into
  the square face-api aligns a face with (its FaceLandmarks.alignDlib: eyes and mouth);
- the face descriptor network (`descriptor`): a ResNet-29 port of dlib's face recognition model,
  150x150 RGB face chip -> 128 numbers; two faces of one person lie within ~0.6 of each other.

The layers follow the package's src/faceRecognitionNet: conv 7x7/2 (valid) + scale + ReLU, max pool
3x3/2, then residual blocks (two 3x3 convs with scale, the second without ReLU, plus the input) and
down blocks (3x3/2 valid first; the shortcut an average pool 2x2/2, zero-padded in channels, and the
convolution's output zero-padded by a row and a column where the pool's is larger), a global
average and a 256x128 matrix. About 0.4 GMAC: ~30 ms a face on one core.
"""
from __future__ import annotations

import json
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

MODEL_DIR = Path(__file__).resolve().parent / "data" / "models"
CHIP = 150  # the network's input side (pixels)
MEAN_RGB = np.array([122.782, 117.001, 104.298], np.float32)
BLOCKS = ("conv32_1", "conv32_2", "conv32_3", "conv64_down", "conv64_1", "conv64_2", "conv64_3",
          "conv128_down", "conv128_1", "conv128_2", "conv256_down", "conv256_1", "conv256_2", "conv256_down_out")


def load_weights(folder: Path = MODEL_DIR, name: str = "face_recognition_model") -> dict[str, np.ndarray]:
    """A tfjs weights manifest and its binary: name -> float32 array (uint8-quantized entries are
    dequantized as q * scale + min, as tfjs does)."""
    manifest = json.loads((folder / f"{name}-weights_manifest.json").read_text())
    out: dict[str, np.ndarray] = {}
    for group in manifest:
        data = b"".join((folder / p).read_bytes() for p in group["paths"])
        offset = 0
        for w in group["weights"]:
            count = int(np.prod(w["shape"])) if w["shape"] else 1
            q = w.get("quantization")
            if q:
                raw = np.frombuffer(data, np.uint8, count, offset).astype(np.float32)
                values = raw * np.float32(q["scale"]) + np.float32(q["min"])
                offset += count
            else:
                values = np.frombuffer(data, np.float32, count, offset).copy()
                offset += 4 * count
            out[w["name"]] = values.reshape(w["shape"])
        if offset != len(data):
            raise ValueError(f"{name}: the manifest names {offset} bytes, the files hold {len(data)}")
    return out


def _pad_same(x: np.ndarray, k: int, stride: int) -> np.ndarray:
    """TensorFlow's 'same' padding: the odd pixel after, not before."""
    pads = []
    for n in x.shape[:2]:
        total = max((-(-n // stride) - 1) * stride + k - n, 0)
        pads.append((total // 2, total - total // 2))
    return np.pad(x, (*pads, (0, 0)))


def conv2d(x: np.ndarray, filters: np.ndarray, stride: int, same: bool) -> np.ndarray:
    """x [H, W, C], filters [k, k, C, F] -> [H', W', F] (tf.conv2d)."""
    k = filters.shape[0]
    if same:
        x = _pad_same(x, k, stride)
    win = sliding_window_view(x, (k, k), axis=(0, 1))[::stride, ::stride]  # [H', W', C, k, k]
    h, w = win.shape[:2]
    cols = win.transpose(0, 1, 3, 4, 2).reshape(h * w, -1)  # rows ordered (ky, kx, c) like the filters
    return (cols @ filters.reshape(-1, filters.shape[-1])).reshape(h, w, -1)


def _conv(x: np.ndarray, p: dict, prefix: str, stride: int, relu: bool, same: bool) -> np.ndarray:
    """conv + bias, then scale (x * w + b), then ReLU if asked."""
    out = conv2d(x, p[f"{prefix}/conv/filters"], stride, same) + p[f"{prefix}/conv/bias"]
    out = out * p[f"{prefix}/scale/weights"] + p[f"{prefix}/scale/biases"]
    return np.maximum(out, 0, out=out) if relu else out


def _residual(x, p, name):
    out = _conv(x, p, f"{name}/conv1", 1, True, True)
    out = _conv(out, p, f"{name}/conv2", 1, False, True) + x
    return np.maximum(out, 0, out=out)


def _residual_down(x, p, name):
    out = _conv(x, p, f"{name}/conv1", 2, True, False)
    out = _conv(out, p, f"{name}/conv2", 1, False, True)
    h2, w2 = x.shape[0] // 2, x.shape[1] // 2
    pooled = x[:2 * h2, :2 * w2].reshape(h2, 2, w2, 2, -1).mean(axis=(1, 3))
    if pooled.shape[:2] != out.shape[:2]:  # the package pads by one row and one column of zeros
        out = np.pad(out, ((0, 1), (0, 1), (0, 0)))
    if pooled.shape[2] != out.shape[2]:
        pooled = np.pad(pooled, ((0, 0), (0, 0), (0, out.shape[2] - pooled.shape[2])))
    out = out + pooled
    return np.maximum(out, 0, out=out)


def _max_pool_3x3_2(x: np.ndarray) -> np.ndarray:
    return sliding_window_view(x, (3, 3), axis=(0, 1))[::2, ::2].max(axis=(3, 4))


@lru_cache(maxsize=2)
def weights(name: str = "face_recognition_model") -> dict[str, np.ndarray]:
    return load_weights(MODEL_DIR, name)


_lock = threading.Lock()


# ------------------------------------------------------------------ 68 landmarks
LANDMARK_INPUT = 112


def _separable(x: np.ndarray, p: dict, prefix: str, stride: int) -> np.ndarray:
    """tf.separableConv2d 'same' (depthwise 3x3, multiplier 1, then pointwise) + bias."""
    dw = p[f"{prefix}/depthwise_filter"][:, :, :, 0]  # [3, 3, C]
    win = sliding_window_view(_pad_same(x, 3, stride), (3, 3), axis=(0, 1))[::stride, ::stride]
    depth = np.einsum("hwcij,ijc->hwc", win, dw, optimize=True)
    pw = p[f"{prefix}/pointwise_filter"][0, 0]  # [C, F]
    return depth @ pw + p[f"{prefix}/bias"]


def _dense_block(x: np.ndarray, p: dict, name: str, first: bool) -> np.ndarray:
    if first:
        out1 = conv2d(x, p[f"{name}/conv0/filters"], 2, True) + p[f"{name}/conv0/bias"]
    else:
        out1 = _separable(x, p, f"{name}/conv0", 2)
    out1 = np.maximum(out1, 0)
    out2 = _separable(out1, p, f"{name}/conv1", 1)
    out3 = _separable(np.maximum(out1 + out2, 0), p, f"{name}/conv2", 1)
    out4 = _separable(np.maximum(out1 + out2 + out3, 0), p, f"{name}/conv3", 1)
    return np.maximum(out1 + out2 + out3 + out4, 0)


def landmarks(crop_rgb: np.ndarray) -> np.ndarray:
    """68 (x, y) points of the face filling an RGB uint8 crop, in the crop's pixels (the crop is
    padded square around its centre and scaled to 112x112 first, as face-api does)."""
    import cv2

    h, w = crop_rgb.shape[:2]
    side = max(h, w)
    top, left = (side - h) // 2, (side - w) // 2  # centred padding (face-api's padToSquare)
    square = np.zeros((side, side, 3), np.uint8)
    square[top:top + h, left:left + w] = crop_rgb
    img = cv2.resize(square, (LANDMARK_INPUT, LANDMARK_INPUT), interpolation=cv2.INTER_LINEAR)
    with _lock:
        p = weights("face_landmark_68_model")
    x = (img.astype(np.float32) - MEAN_RGB) / 255.0
    for i, name in enumerate(("dense0", "dense1", "dense2", "dense3")):
        x = _dense_block(x, p, name, first=i == 0)
    x = sliding_window_view(x, (7, 7), axis=(0, 1))[::2, ::2].mean(axis=(3, 4))  # avgPool 7x7/2 valid: 1x1
    out = (x.reshape(-1) @ p["fc/weights"] + p["fc/bias"]).reshape(68, 2)
    return out * side - np.array([left, top], np.float32)


def dlib_box(points: np.ndarray) -> tuple[float, float, float]:
    """The square face-api aligns a face with (FaceLandmarks.alignDlib): (x, y, side) from the centres
    of the eyes (points 36-41, 42-47) and the mouth (48-67)."""
    left, right, mouth = points[36:42].mean(0), points[42:48].mean(0), points[48:68].mean(0)
    eye_to_mouth = (np.linalg.norm(mouth - left) + np.linalg.norm(mouth - right)) / 2
    side = eye_to_mouth / 0.45
    ref = (left + right + mouth) / 3
    return float(ref[0] - 0.5 * side), float(ref[1] - 0.43 * side), float(side)


def descriptor(chip_rgb: np.ndarray) -> np.ndarray:
    """The 128-number descriptor of a 150x150 RGB uint8 face chip."""
    if chip_rgb.shape != (CHIP, CHIP, 3):
        raise ValueError(f"a face chip is {CHIP}x{CHIP}x3, not {chip_rgb.shape}")
    with _lock:  # the weights load once
        p = weights()
    x = (chip_rgb.astype(np.float32) - MEAN_RGB) / 255.0
    x = _max_pool_3x3_2(_conv(x, p, "conv32_down", 2, True, False))
    for name in BLOCKS:
        x = _residual_down(x, p, name) if "down" in name else _residual(x, p, name)
    return (x.mean(axis=(0, 1)) @ p["fc"]).astype(np.float32)
