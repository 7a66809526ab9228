"""How the photographs in this folder were made (tests/data/faces/README.md): each face cut from its
source photograph with a margin of 60 % of the face's side around OpenCV's frontal-face box, scaled
so the face is 110 px wide, saved as JPEG (quality 90).

    python tests/data/faces/crop.py FACE_RECOGNITION_TESTS_DIR FACE_API_DEMO_DIR
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2

HERE = Path(__file__).resolve().parent
# (output name, source file, face box x, y, w, h in the source's pixels: OpenCV 4.14's frontal-face
# cascade, scaleFactor 1.1, minNeighbors 5, on the equalized gray image)
FACES = [
    ("obama-1", "fr:obama.jpg", None), ("obama-2", "fr:obama2.jpg", None), ("obama-3", "fr:obama3.jpg", None),
    ("biden-1", "fr:biden.jpg", None),
    ("stranger-01", "fa:sample1.jpg", (362, 367, 238, 238)), ("stranger-02", "fa:sample2.jpg", (1404, 164, 236, 236)),
    ("stranger-03", "fa:sample3.jpg", (1019, 219, 293, 293)), ("stranger-04", "fa:sample3.jpg", (1485, 315, 244, 244)),
    ("stranger-05", "fa:sample3.jpg", (552, 342, 245, 245)), ("stranger-06", "fa:sample4.jpg", (932, 201, 226, 226)),
    ("stranger-07", "fa:sample5.jpg", (1088, 216, 197, 197)), ("stranger-08", "fa:sample5.jpg", (773, 121, 204, 204)),
    ("stranger-09", "fa:sample5.jpg", (1358, 410, 246, 246)), ("stranger-10", "fa:sample5.jpg", (644, 458, 158, 158)),
    ("stranger-11", "fa:sample5.jpg", (355, 894, 239, 239)), ("stranger-12", "fa:sample6.jpg", (1445, 279, 273, 273)),
    ("stranger-13", "fa:sample6.jpg", (620, 349, 254, 254)), ("stranger-14", "fa:sample6.jpg", (1147, 331, 256, 256)),
    ("stranger-15", "fa:sample6.jpg", (241, 508, 260, 260)),
]
MARGIN, FACE_PX = 0.6, 110


def largest_face(img):
    cascade = cv2.CascadeClassifier(cv2.data.haarcascades + "haarcascade_frontalface_default.xml")
    gray = cv2.equalizeHist(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    return max(cascade.detectMultiScale(gray, 1.1, 5, minSize=(40, 40)), key=lambda r: r[2] * r[3])


def main(fr_dir: str, fa_dir: str) -> None:
    for name, source, box in FACES:
        folder, file = source.split(":")
        img = cv2.imread(str(Path(fr_dir if folder == "fr" else fa_dir) / file))
        x, y, w, h = box if box is not None else largest_face(img)
        m = int(MARGIN * w)
        x0, y0 = max(0, x - m), max(0, y - m)
        crop = img[y0:y + h + m, x0:x + w + m]
        k = FACE_PX / w
        crop = cv2.resize(crop, (round(crop.shape[1] * k), round(crop.shape[0] * k)), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(HERE / f"{name}.jpg"), crop, [cv2.IMWRITE_JPEG_QUALITY, 90])


if __name__ == "__main__":
    main(*sys.argv[1:3])
