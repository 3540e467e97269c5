"""Test-only reference: OpenCV's own Haar detector on gray PNG frames.

Usage: opencv_detect.py CASCADE MIN_SIZE IMAGE... ; prints one JSON object per image:
{"image": path, "faces": [[x, y, w, h], ...]} with scale factor 1.1 and 3 min neighbours.
Needs opencv-python-headless 4.x (OpenCV 5 moved the cascade classifier out of the main module).
"""
import json
import sys

import cv2

cascade = cv2.CascadeClassifier(sys.argv[1])
if cascade.empty():
    sys.exit(f"OpenCV could not read the cascade {sys.argv[1]}")
min_size = int(sys.argv[2])
for path in sys.argv[3:]:
    gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if gray is None:
        sys.exit(f"OpenCV could not read {path}")
    faces = cascade.detectMultiScale(gray, 1.1, 3, minSize=(min_size, min_size))
    print(json.dumps({"image": path, "faces": [list(map(int, f)) for f in faces]}))
