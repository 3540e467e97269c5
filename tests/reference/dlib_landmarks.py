"""Test-only reference: dlib's own shape predictor on gray PNG frames and given boxes.

Usage: dlib_landmarks.py MODEL IMAGE:LEFT,TOP,RIGHT,BOTTOM ... ; prints one JSON line per
argument: {"image": path, "landmarks": [[x, y], ...]} (dlib's inclusive box corners, pixels).
Needs dlib's Python package (dlib-bin on PyPI, a prebuilt wheel).
"""
import json
import sys

import cv2
import dlib

predictor = dlib.shape_predictor(sys.argv[1])
for arg in sys.argv[2:]:
    path, box = arg.rsplit(":", 1)
    left, top, right, bottom = map(int, box.split(","))
    gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if gray is None:
        sys.exit(f"OpenCV could not read {path}")
    shape = predictor(gray, dlib.rectangle(left, top, right, bottom))
    points = [[shape.part(i).x, shape.part(i).y] for i in range(shape.num_parts)]
    print(json.dumps({"image": path, "landmarks": points}))
