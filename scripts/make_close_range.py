"""Write the worked example data/close_range (issue 17): a close-range calibration network as users
have it, without control: 24 convergent photos of 40 targets on a dome, the camera self-calibrated
(c, xp, yp, k1, k2 free), the scale from two scale bars (distances.csv) and the datum from inner
constraints on all targets (project.toml [datum] mode = "inner-points").

    python scripts/make_close_range.py [--out data/close_range] [--seed 3]

The network is scripts/bench/close_range.py's (the benchmark's close-range case, small); the bars
join the two pairs of targets farthest apart among four spread over the dome, their lengths the
true distances plus N(0, BAR_SIGMA). Truth in <out>/truth/ (photos, points, cameras, and
distances.csv with the true lengths). Re-running with the same seed writes the same files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
import close_range  # noqa: E402  (the benchmark's network generator)

PHOTOS, TARGETS = 24, 40
BAR_SIGMA = 2e-5  # m: an invar scale bar calibrated to 20 um
DATUM_TOML = '\n[datum]\nmode = "inner-points"             # a free network: inner constraints on every target\n'


def scale_bars(xyz: np.ndarray) -> np.ndarray:
    """(2, 2) target indices of two bars: four targets spread over the dome (farthest-point
    selection), paired so that each bar is long."""
    a, b, c, d = close_range._farthest_points(xyz, 4)
    pairs = [((a, b), (c, d)), ((a, c), (b, d)), ((a, d), (b, c))]
    length = [min(np.linalg.norm(xyz[p] - xyz[q]) for p, q in two) for two in pairs]
    return np.array(pairs[int(np.argmax(length))])


def write_example(out: Path, seed: int = 3) -> Path:
    net = close_range.make_close_range(PHOTOS, TARGETS, n_control=1, seed=seed)
    out = close_range.write_close_range(out, net)
    (out / "control.csv").unlink()  # no control: the datum is the targets' (inner-points)
    text = (out / "project.toml").read_text().replace("(scripts/bench/close_range.py)",
                                                      "(scripts/make_close_range.py)")
    (out / "project.toml").write_text(text + DATUM_TOML)
    ids = close_range.target_ids(TARGETS)
    bars = scale_bars(net.xyz_ground)
    true = np.linalg.norm(net.xyz_ground[bars[:, 0]] - net.xyz_ground[bars[:, 1]], axis=1)
    measured = true + np.random.default_rng(seed + 1000).normal(0.0, BAR_SIGMA, len(bars))
    header = ["point_from", "point_to", "distance", "sigma"]
    close_range._write(out / "distances.csv", header,
                       [[ids[p], ids[q], repr(float(m)), repr(BAR_SIGMA)] for (p, q), m in zip(bars, measured)])
    close_range._write(out / "truth" / "distances.csv", header[:3],
                       [[ids[p], ids[q], repr(float(t))] for (p, q), t in zip(bars, true)])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("data/close_range"))
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    out = write_example(args.out, args.seed)
    print(f"wrote {out}: {PHOTOS} photos, {TARGETS} targets, 2 scale bars, datum inner-points")


if __name__ == "__main__":
    main()
