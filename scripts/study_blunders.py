"""Study of gross-error detection on the issue-18 blocks (docs/reliability.md, "Study").

The block of ``striptri simulate block --photos 20 --strips 5 --check-points 12`` (60 % / 30 %
overlap, perimeter control); a fraction of the plate measurements of points with >= 3 rays (not
check points) get a gross error of a given size (uniform in [lo, hi] sigma, random sign) in x or
in y. Per mode: blunders found (rejected alone or in their inseparable group, or flagged
"inseparable"), false alarms among the clean rows outside those groups, check-point RMS (3D) against
the blunder-free adjustment of the same measurements.

    PYTHONPATH=src python scripts/study_blunders.py --seeds 1 2 3 4 --modes snoop snoop-classic robust
    PYTHONPATH=src python scripts/study_blunders.py --table   # size x rate table of docs/reliability.md
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.model import CHECK
from striptri.reliability import FLAG_REJECTED, BlunderOptions, detect_blunders, triangulate_adjusted

SIGMA = 0.005


def block(seed: int, photos: int = 20, strips: int = 5, n_check: int = 12):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=photos, n_strips=strips, overlap=0.6, sidelap=0.3),
        control=sim.ControlDesign(layout="perimeter", n_check=n_check),
    )
    noise = sim.NoiseOptions(sigma_image=SIGMA, stated_sigma_image=SIGMA)
    return sim.simulate_project("block", sim.SimulateOptions(design, noise), seed)[0]


def spoil(project, rng, rate: float, lo: float, hi: float):
    """rate of the rows of non-check points with >= 3 rays get lo..hi sigma in x or y."""
    ip = project.image_points
    rays = np.bincount(ip.point_index, minlength=len(project.points.ids))
    eligible = np.flatnonzero((rays[ip.point_index] >= 3) & (project.points.kind[ip.point_index] != CHECK))
    n = max(1, int(round(rate * len(ip))))
    rows = rng.choice(eligible, n, replace=False)
    axis = rng.integers(0, 2, n)
    size = rng.uniform(lo, hi, n) * rng.choice([-1.0, 1.0], n) * ip.sigma_xy[rows, axis]
    xy = ip.xy.copy()
    xy[rows, axis] += size
    return replace(project, image_points=replace(ip, xy=xy)), rows


def check_errors(project, result):
    tri = triangulate_adjusted(project, result)
    ok = (project.points.kind == CHECK) & tri.determined
    return np.where(ok[:, None], tri.xyz + result.offset - project.points.xyz_given, np.nan)


MODES = {
    "snoop": dict(method="snoop"),
    "snoop-classic": dict(method="snoop", procedure="classic"),
    "robust": dict(method="robust"),
}


def run(seed: int, mode: str, rate: float, lo: float, hi: float, photos=20, strips=5, n_check=12, clean=None):
    project = block(seed, photos, strips, n_check)
    options = AdjustmentOptions(method="conditions")
    if clean is None:
        clean = check_errors(project, adjust(project, options))
    spoiled, rows = spoil(project, np.random.default_rng(10_000 + seed), rate, lo, hi)
    kwargs = dict(MODES[mode])
    try:
        bo = BlunderOptions(**kwargs)
    except TypeError:  # before the procedure option existed
        kwargs.pop("procedure", None)
        bo = BlunderOptions(**kwargs)
    t0 = time.perf_counter()
    out = detect_blunders(spoiled, options, bo)
    seconds = time.perf_counter() - t0
    m = len(project.image_points)
    is_b = np.zeros(m, dtype=bool)
    is_b[rows] = True
    grouped = np.zeros(m, dtype=bool)  # rows of inseparable groups (rejected together)
    for g in getattr(out, "groups", []):
        if len(g) > 1:
            grouped[g] = True
    removed = (out.flag == FLAG_REJECTED) | grouped
    found = removed | grouped
    after = check_errors(out.project, out.result)
    both = np.isfinite(clean).all(1) & np.isfinite(after).all(1)
    return dict(n_blunders=int(is_b.sum()), found=int((found & is_b).sum()), clean=int((~is_b & ~grouped).sum()),
                false=int((removed & ~is_b & ~grouped).sum()), se_clean=float(np.sum(clean[both] ** 2)),
                se_after=float(np.sum(after[both] ** 2)), n_check=int(both.sum()), seconds=seconds,
                rms_ratio=float(np.sqrt(np.sum(after[both] ** 2) / np.sum(clean[both] ** 2)))), clean


def summary(rs):
    nb = sum(r["n_blunders"] for r in rs)
    return dict(found=sum(r["found"] for r in rs), n_blunders=nb, detected=sum(r["found"] for r in rs) / nb,
                false_rate=sum(r["false"] for r in rs) / sum(r["clean"] for r in rs),
                false=sum(r["false"] for r in rs),
                rms_ratio=float(np.sqrt(sum(r["se_after"] for r in rs) / sum(r["se_clean"] for r in rs))),
                worst_rms_ratio=max(r["rms_ratio"] for r in rs), seconds=sum(r["seconds"] for r in rs))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--modes", nargs="+", default=list(MODES))
    ap.add_argument("--rate", type=float, default=0.02)
    ap.add_argument("--size", type=float, nargs=2, default=[10.0, 30.0])
    ap.add_argument("--table", action="store_true", help="sizes 5-30 sigma x rates 0.5-5 %%")
    a = ap.parse_args()
    cases = [(a.rate, *a.size)]
    if a.table:
        cases = [(rate, lo, hi) for rate in (0.005, 0.02, 0.05) for lo, hi in ((5, 10), (10, 20), (20, 30))]
    cleans = {}
    print("| mode | rate | size (sigma) | found | detected | false alarms | check-point RMS / blunder-free (all, worst seed) | s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for rate, lo, hi in cases:
        for mode in a.modes:
            rs = []
            for s in a.seeds:
                r, cleans[s] = run(s, mode, rate, lo, hi, clean=cleans.get(s))
                rs.append(r)
            t = summary(rs)
            print(f"| {mode} | {rate:.1%} | {lo:g}-{hi:g} | {t['found']}/{t['n_blunders']} | {t['detected']:.1%} | "
                  f"{t['false']} ({t['false_rate']:.2%}) | {t['rms_ratio']:.3f}, {t['worst_rms_ratio']:.3f} | "
                  f"{t['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
