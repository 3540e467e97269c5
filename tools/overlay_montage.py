#!/usr/bin/env python3
"""Tiles frames of an annotated run (`face track ... --overlay DIR`) into one picture, each at
half size with its frame number, two to a row: how docs/megamind_tracks.png is made.

    python3 tools/overlay_montage.py OVERLAY_DIR OUT.png FRAME [FRAME ...]

    cargo run --release -p streampf -- face track \\
        /usr/share/doc/opencv-doc/examples/data/Megamind.avi --overlay runs/megamind-overlay
    python3 tools/overlay_montage.py runs/megamind-overlay docs/megamind_tracks.png 40 140 180 250

Needs numpy and OpenCV (target/media/pose-venv has both).
"""

import argparse
import os
import sys

import numpy as np


def tile(overlay_dir, frames):
    import cv2

    tiles = []
    for frame in frames:
        path = os.path.join(overlay_dir, f"overlay_{frame:05d}.png")
        image = cv2.imread(path)
        if image is None:
            sys.exit(f"cannot read {path} (is frame {frame} in the run?)")
        size = (image.shape[1] // 2, image.shape[0] // 2)
        half = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        label = f"frame {frame}"
        (w, h), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_PLAIN, 1.0, 1)
        cv2.rectangle(half, (0, 0), (w + 8, h + 8), (0, 0, 0), -1)
        cv2.putText(half, label, (4, h + 4), cv2.FONT_HERSHEY_PLAIN, 1.0, (255, 255, 255), 1)
        tiles.append(half)
    if len({t.shape for t in tiles}) != 1:
        sys.exit("the frames differ in size")
    if len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i : i + 2]) for i in range(0, len(tiles), 2)]
    return np.vstack(rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("overlay_dir")
    parser.add_argument("out")
    parser.add_argument("frames", type=int, nargs="+")
    args = parser.parse_args()
    import cv2

    if not cv2.imwrite(args.out, tile(args.overlay_dir, args.frames)):
        sys.exit(f"cannot write {args.out}")


if __name__ == "__main__":
    main()
