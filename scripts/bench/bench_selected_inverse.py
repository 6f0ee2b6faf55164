"""Selected inversion (striptri.selected_inverse) against the dense inverse.

N: a synthetic strip normal matrix with the structure of DESIGN section 5 (6x6 photo blocks within
two photos of the diagonal, Schmid Fig. 10; optionally camera columns last, coupled to every photo),
or a block of parallel strips numbered strip by strip. It is ``G' G`` for random condition rows on
consecutive photos (pairs: 6 rows, triples: 9 rows per model), 6 control rows on every 4th photo,
columns in random units (1e-2..1e2). The timings are of ``selected_inverse(N, photo and camera
blocks, pairs)`` (all the 6x6 and camera blocks, the blocks of consecutive photos, the diagonal), median
of 3, with BLAS limited to one thread (threadpoolctl; on a shared 2-core machine multithreaded
OpenBLAS can be pathologically slow under load).

    python scripts/bench/bench_selected_inverse.py [--photos 100 1000 10000] [--cameras 1] [--reach 2]
    python scripts/bench/bench_selected_inverse.py --strips 100 --photos 100     # a 100 x 100 block
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import scipy.sparse as sp

from striptri.selected_inverse import selected_inverse
from striptri.solvers import cholmod_available, inverse

DENSE_MAX = 3000  # unknowns up to which the dense inverse is timed too


def strip_blocks(n_photos: int, n_cameras: int, rng: np.random.Generator, n_strips: int = 1, reach: int = 2):
    """(N, block starts, photos) of ``n_strips`` strips of ``n_photos`` photos each (numbered strip by
    strip), sidelap rows between neighbouring strips, then 3 camera columns per camera. Points are
    seen on ``reach + 1`` consecutive photos (2: 60 % overlap, a half-bandwidth of 17 columns)."""
    P = n_photos
    idx = np.arange(n_strips * P).reshape(n_strips, P)
    groups = [np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
              np.column_stack([idx[:, a: P - reach + a].ravel() for a in range(reach + 1)])]
    n_rows = [6, 9]
    if n_strips > 1:
        groups.append(np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()]))
        n_rows.append(5)
    n_ph = n_strips * P
    n = 6 * n_ph + 3 * n_cameras
    rows, cols, vals = [], [], []
    r0 = 0
    for g, nr in zip(groups, n_rows):
        m, k = g.shape
        a = rng.normal(size=(m, nr, k, 6))
        a -= a.mean(axis=2, keepdims=True)  # a datum defect, removed by the control
        c = np.broadcast_to((6 * g[:, None, :, None] + np.arange(6)), (m, nr, k, 6))
        r = np.broadcast_to(r0 + np.arange(m * nr).reshape(m, nr, 1, 1), (m, nr, k, 6))
        rows.append(r.ravel()), cols.append(c.ravel()), vals.append(a.ravel())
        if n_cameras:
            cam = g[:, 0] % n_cameras
            rows.append(np.repeat(r0 + np.arange(m * nr), 3))
            cols.append(np.repeat(6 * n_ph + 3 * cam, nr * 3) + np.tile(np.arange(3), m * nr))
            vals.append(0.3 * rng.normal(size=m * nr * 3))
        r0 += m * nr
    control = np.arange(0, n_ph, 4)
    rows.append(r0 + np.repeat(np.arange(6 * len(control)), 6))
    cols.append(np.repeat(6 * control[:, None] + np.arange(6), 6, axis=0).ravel())
    vals.append(rng.normal(size=36 * len(control)))
    r0 += 6 * len(control)
    if n_cameras:
        rows.append(r0 + np.arange(3 * n_cameras)), cols.append(np.arange(6 * n_ph, n)), vals.append(np.full(3 * n_cameras, 0.1))
        r0 += 3 * n_cameras
    G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, n))
    G = G @ sp.diags(10.0 ** rng.uniform(-2, 2, n))
    N = sp.csr_matrix(G.T @ G)
    starts = np.concatenate([np.arange(0, 6 * n_ph, 6), 6 * n_ph + np.arange(0, 3 * n_cameras, 3)])
    return N, starts, n_ph


def median_time(fn, repeat: int = 3) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photos", type=int, nargs="+", default=[100, 300, 1000, 10000], help="photos per strip")
    ap.add_argument("--cameras", type=int, default=1)
    ap.add_argument("--strips", type=int, nargs="+", default=[1], help="strips side by side (a block when > 1)")
    ap.add_argument("--reach", type=int, default=2, help="photos a point spans minus one (bandwidth 6 reach + 5)")
    ap.add_argument("--methods", nargs="+", default=["auto", "banded", "sparse", "cholmod"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (threadpoolctl)")
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=args.threads, user_api="blas"):
        print(f"BLAS threads: {args.threads} (threadpoolctl); median of {args.repeat}; reach {args.reach}; "
              f"cameras {args.cameras}; cholmod available: {cholmod_available()}")
        print(f"{'strips':>6} {'photos':>7} {'unknowns':>8} {'method':>8} {'route':>8} {'seconds':>9}  info")
        for n_strips in args.strips:
            for n_photos in args.photos:
                N, starts, n_ph = strip_blocks(n_photos, args.cameras, np.random.default_rng(n_photos), n_strips, args.reach)
                n = N.shape[0]
                pairs = [(s * n_photos + i, s * n_photos + i + 1) for s in range(n_strips) for i in range(n_photos - 1)]
                ref = None
                for method in args.methods:
                    if method == "cholmod" and not cholmod_available():
                        continue
                    if method == "banded" and n_strips > 1 and n_photos > 100:
                        continue  # the band of a block numbered strip by strip is a whole strip wide
                    t, inv = median_time(lambda: selected_inverse(N, starts, pairs, method=method), args.repeat)
                    print(f"{n_strips:>6} {n_ph:>7} {n:>8} {method:>8} {inv.method:>8} {t:>9.3f}  {inv.info}")
                    if ref is None and n <= DENSE_MAX:
                        ref = inverse(N).diagonal()
                    if ref is not None:
                        err = np.max(np.abs(inv.diag() - ref) / ref)
                        assert err < 1e-8, (method, err)
                if n <= DENSE_MAX:
                    t, _ = median_time(lambda: inverse(N), args.repeat)
                    print(f"{n_strips:>6} {n_ph:>7} {n:>8} {'dense':>8} {'inverse':>8} {t:>9.3f}  solvers.inverse (Jacobi-scaled Cholesky, n x n)")


if __name__ == "__main__":
    main()
