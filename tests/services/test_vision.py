"""Face (Haar cascade) and human (HOG) detection on real photos shipped in tests/data."""
from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from agents.services import vision
from agents.services.images import encode_image
from ontology.services.vision import FaceDetect, HumanDetect

DATA = Path(__file__).resolve().parent.parent / "data"


def photo(name: str) -> str:
    return base64.b64encode((DATA / name).read_bytes()).decode("ascii")


def contains(box, x: int, y: int) -> bool:
    return box.x <= x <= box.x + box.width and box.y <= y <= box.y + box.height


def test_face_found_on_the_astronauts_face(ctx):
    boxes = vision.face_detection(FaceDetect(image_b64=photo("astronaut.jpg")), ctx).boxes
    assert len(boxes) == 1
    face = boxes[0]
    assert contains(face, 112, 55)  # between the eyes (256x256 image)
    assert 40 <= face.width <= 80 and abs(face.width - face.height) <= 2


@pytest.mark.parametrize("name", ["coffee.jpg", "cameraman.jpg"])
def test_no_frontal_face_where_there_is_none(ctx, name):
    # the cameraman's face is in profile behind his camera: no frontal face
    assert vision.face_detection(FaceDetect(image_b64=photo(name)), ctx).boxes == []


def test_standing_cameraman_is_detected(ctx):
    boxes = vision.human_detection(HumanDetect(image_b64=photo("cameraman.jpg")), ctx).boxes
    assert boxes, "the cameraman is a person"
    best = boxes[0]
    assert contains(best, 100, 60) and contains(best, 60, 160)  # his head and his coat
    assert best.height > 150


def test_no_person_in_a_featureless_scene(ctx):
    # HOG is not a strong detector: on cluttered photos (coffee.jpg, astronaut.jpg) it returns
    # occasional low-score false positives, so only an image without structure is asserted empty
    wall = np.tile(np.linspace(60, 200, 320, dtype=np.uint8), (240, 1))
    img = encode_image(np.dstack([wall] * 3))
    assert vision.human_detection(HumanDetect(image_b64=img), ctx).boxes == []


@pytest.mark.parametrize("size", [(10, 10), (200, 63), (128, 64), (63, 200)])
def test_images_smaller_than_the_hog_window_do_not_crash(ctx, size):
    # OpenCV 4.14's HOG segfaults on images smaller than 64x128: the service pads them
    w, h = size
    img = encode_image(np.random.default_rng(0).integers(0, 255, (h, w, 3), np.uint8))
    assert vision.human_detection(HumanDetect(image_b64=img), ctx).boxes == []
    assert vision.face_detection(FaceDetect(image_b64=img), ctx).boxes == []


def test_padding_keeps_boxes_inside_the_image(ctx):
    boxes = vision.human_detection(HumanDetect(image_b64=photo("astronaut.jpg")), ctx).boxes
    for b in boxes:
        assert b.x >= 0 and b.y >= 0 and b.x + b.width <= 256 and b.y + b.height <= 256
