"""Peak memory of one film scan in ``striptri match``'s feature stage (issue 28: "a 20,000 x 20,000
px film scan must not need its full-resolution array in memory more than once").

    python scripts/bench/bench_scan_memory.py [--size 20000] [--scale 0.25] [--work DIR]

Writes a textured 8-bit TIFF scan of size x size px once (uncompressed, strips of 64 rows; not
timed), then runs the feature task of
a scan (match.stages.find_features: read once at full resolution, SIFT at --scale) in a process of
its own, and prints its peak resident memory against the size of one full-resolution 8-bit array:
as striptri reads a scan (tifffile, SIFT over tiles: match.features) and, for comparison, as it did
before (OpenCV's decoder, SIFT over the whole image), in the same run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

TASK = """
import sys, time
import striptri.match.features as features
from striptri.match.stages import FeatureTask, find_features
if sys.argv[4] == "whole":  # as before: OpenCV's TIFF decoder, SIFT over the whole image
    features.TILE, features._tiff_grey = 10 ** 9, lambda path: None
t = time.perf_counter()
xy, _ = find_features(FeatureTask(0, sys.argv[1], sys.argv[2], float(sys.argv[3]), 8000))
print(len(xy), time.perf_counter() - t)
"""


def scan(path: Path, size: int) -> None:
    """A size x size 8-bit scan: a 2,048 px texture of smoothed noise, tiled with offsets."""
    import cv2
    import numpy as np
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(0)
    tile = gaussian_filter(rng.normal(size=(2048, 2048)), 2.0) + 0.5 * gaussian_filter(rng.normal(size=(2048, 2048)), 8.0)
    tile = (255 * (tile - tile.min()) / np.ptp(tile)).astype(np.uint8)
    image = np.empty((size, size), dtype=np.uint8)
    for r in range(0, size, 2048):
        for c in range(0, size, 2048):
            block = np.roll(tile, (r // 7, c // 5), axis=(0, 1))
            image[r:r + 2048, c:c + 2048] = block[:min(2048, size - r), :min(2048, size - c)]
    cv2.imwrite(str(path), image, [cv2.IMWRITE_TIFF_ROWSPERSTRIP, 64, cv2.IMWRITE_TIFF_COMPRESSION,
                                   cv2.IMWRITE_TIFF_COMPRESSION_NONE])  # strips of 64 rows, as scanners write


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20000)
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--work", default="/tmp/striptri-bench-scan")
    a = parser.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"scan_{a.size}_strips.tif"
    if not path.is_file():
        scan(path, a.size)
    print("| scan px | scale | read, SIFT | features | task s | whole s | one 8-bit array MB | peak MB | peak / array |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for how, label in (("tiles", "tifffile, tiles"), ("whole", "OpenCV, whole image")):
        t = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", TASK, str(path), str(work), str(a.scale), how],
                                stdout=subprocess.PIPE, text=True)
        out = proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            sys.exit("the feature task failed")
        features, seconds = out.split()
        array_mb = a.size * a.size / 2 ** 20
        peak = usage.ru_maxrss / 1024.0
        print(f"| {a.size:,} x {a.size:,} | {a.scale} | {label} | {int(features):,} | {float(seconds):.1f} | "
              f"{time.perf_counter() - t:.1f} | {array_mb:,.0f} | {peak:,.0f} | {peak / array_mb:.2f} |")

if __name__ == "__main__":
    main()
