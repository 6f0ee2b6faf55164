"""OpenCV's SIFT against pycolmap's (COLMAP's own), on rendered photographs with known truth
(issue 28, docs/decisions.md "Features for striptri match").

    python scripts/bench/bench_sift.py [--size 1000] [--features 4000] [--repeat 3]

A block is simulated and two pairs of its photos rendered (simulate.render): neighbours in a strip,
and neighbours across two strips flown the opposite way (turned by 180 degrees). Each library
finds features in both photos of a pair. The features are matched and verified by striptri's own
matcher (match.pair_matching), so that only the features differ. Every verified match is then
compared with the truth: its feature in the first photo is followed to the ground with the true
orientation and projected into the second, and the distance to its feature there is its error.
Printed per library and pair: features per photo, seconds per photo (median of --repeat), verified
matches, and the median, 90th percentile and RMS (below 1 px) of the error in pixels, and the
share of matches off by more than 1 px. pycolmap is needed (pip install pycolmap); it is not a
dependency of striptri.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def _pycolmap_features(image, n):
    import pycolmap

    from striptri.match.features import Features

    options = pycolmap.FeatureExtractionOptions()
    options.mergedict({"sift": {"max_num_features": n}})  # options.sift is a copy: set through mergedict
    options.num_threads = 1  # like OpenCV's, timed on one core
    sift = pycolmap.Sift(options, pycolmap.Device.cpu)
    keypoints, descriptors = sift.extract(np.ascontiguousarray(image))
    # COLMAP's keypoints are in its image convention: the top-left pixel's centre at (0.5, 0.5),
    # as striptri's (colmap.github.io/format.html); descriptors are normalised uint8-range floats
    return Features(keypoints[:, :2].astype(float), np.asarray(descriptors, dtype=np.float32), keypoints[:, 2])


def _opencv_features(image, n):
    from striptri.match.features import detect

    return detect(image, 1.0, n)


def _errors(truth, k1, k2, f1, f2, m, n, pixel):
    from striptri.geometry.camera import project, ray_ground
    from striptri.geometry.pixels import pixel_from_plate, plate_from_pixel
    from striptri.simulate.render import ground_of_rays

    size = np.array([n, n])
    plate = plate_from_pixel(f1.xy[m.i], size, pixel)
    ground = ground_of_rays(truth.xyz0[k1], ray_ground(truth.R_ground_from_cam[k1], plate, truth.interior), truth.terrain)
    predicted = pixel_from_plate(project(truth.R_ground_from_cam[k2], truth.xyz0[k2], truth.interior, ground), size, pixel)
    return np.linalg.norm(predicted - f2.xy[m.j], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1000)
    parser.add_argument("--features", type=int, default=4000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--noise", type=float, default=2.0)
    a = parser.parse_args()

    from striptri import simulate as sim
    from striptri.match.pair_matching import match_pair
    from striptri.simulate.render import ImageOptions, render_photo, texture_for, to_image

    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=3, n_strips=2),
                                 control=sim.ControlDesign(layout="perimeter"))
    truth = sim.make_truth(design, np.random.default_rng(7))
    pixel = design.camera.format / a.size
    scale = design.scale
    texture = texture_for(truth.terrain, pixel * scale, design.camera.format * scale, 11)
    rng = np.random.default_rng(0)
    ids = truth.photo_ids
    images = {k: to_image(render_photo(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, pixel, a.size,
                                       truth.terrain, texture), ImageOptions(a.size, a.noise), rng)
              for k in range(len(ids))}
    across = next(k for k in range(len(ids)) if truth.strip_ids[k] != truth.strip_ids[0]
                  and abs(truth.xyz0[k, 0] - truth.xyz0[0, 0]) < 0.3 * design.base)
    pairs = {"along a strip": (0, 1), "across strips (turned 180 deg)": (0, across)}
    print(f"rendered {a.size} x {a.size} px, noise {a.noise} grey levels, {a.features} features asked for")
    print(f"{'library':9} {'pair':32} {'features':>9} {'s/photo':>8} {'matches':>8} {'median':>7} {'p90':>7} "
          f"{'rms<1':>7} {'>1px':>6}")
    for name, find in (("OpenCV", _opencv_features), ("pycolmap", _pycolmap_features)):
        for label, (k1, k2) in pairs.items():
            seconds = []
            for _ in range(a.repeat):
                t = time.perf_counter()
                f1 = find(images[k1], a.features)
                seconds.append(time.perf_counter() - t)
            f2 = find(images[k2], a.features)
            m = match_pair(f1, f2)
            e = _errors(truth, k1, k2, f1, f2, m, a.size, pixel)
            inside = e[e < 1.0]
            print(f"{name:9} {label:32} {len(f1):9d} {np.median(seconds):8.2f} {len(m.i):8d} {np.median(e):7.3f} "
                  f"{np.percentile(e, 90):7.3f} {np.sqrt(np.mean(inside**2)):7.3f} {np.mean(e >= 1.0):6.1%}")


if __name__ == "__main__":
    main()
