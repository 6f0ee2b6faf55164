"""Benchmark: a "Bundle Adjustment in the Large" problem by striptri and by pycolmap (Ceres).

    python scripts/bench/bench_bal.py [BAL_FILE] [--threads 1]

Default problem: ../shared/data/real/bal_ladybug49/problem-49-7776-pre.txt. Both adjusters start
from the BAL file's values and estimate, per camera, the orientation, f, k1 and k2 (BAL's camera);
the points are eliminated (striptri's bundle method, Ceres' SPARSE_SCHUR). The cost is BAL's
``1/2 sum r^2`` in pixels (sigma 1 px): striptri's ``v^T P v / 2``. The datum does not change the
minimum: striptri holds the first camera and one coordinate of the farthest one
(formats.scene.photo_datum), Ceres leaves the gauge free. Observations whose point lies behind its
camera at the start (31 in problem-49-7776, contributing 110.4 to the initial cost) are left out
of both: COLMAP's cost gives them no residual, so keeping them would compare different problems
(``--keep-behind`` keeps them for striptri).

pycolmap is not a dependency of striptri (``pip install pycolmap``, measured with 4.2.1); without it
the reference row is skipped. BLAS single-threaded (OPENBLAS_NUM_THREADS=1) on this shared machine.

pycolmap's reconstruction: one RADIAL camera per BAL camera (f, cx = cy = 0, k1, k2; principal
point held); COLMAP's camera frame is BAL's turned about x (D = diag(1, -1, -1)), so a BAL
observation (x, y) is the COLMAP pixel (x, -y), cam_from_world = (D R, D t).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import colmap_ba  # noqa: E402

from striptri.adjustment import AdjustmentOptions, adjust  # noqa: E402
from striptri.formats.bal import bal_cost, behind_camera, read_bal, without_observations  # noqa: E402
from striptri.formats.conversions import bal_to_project  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "bal_ladybug49" / "problem-49-7776-pre.txt"
D = np.diag([1.0, -1.0, -1.0])
# both stop when a step lowers the cost by less than this fraction (Ceres' function tolerance,
# striptri's AdjustmentOptions.cost_tolerance); the other criteria are set out of the way
COST_TOLERANCE = 1e-10


def run_striptri(bal, method: str, max_iterations: int):
    t0, c0 = time.perf_counter(), time.process_time()
    project = bal_to_project(bal).project
    result = adjust(project, AdjustmentOptions.of(method=method, max_iterations=max_iterations,
                                               cost_tolerance=COST_TOLERANCE))
    return {"adjuster": f"striptri {method}", "seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0,
            "iterations": result.iterations, "final_cost": result.vtpv / 2, "converged": result.converged,
            "note": f"solver {result.solver}"}


def run_pycolmap(bal, threads: int, max_iterations: int):
    try:
        import pycolmap
    except ImportError:
        return None
    t0 = time.perf_counter()
    rec = pycolmap.Reconstruction()
    config = pycolmap.BundleAdjustmentConfig()
    order = np.argsort(bal.camera_index, kind="stable")
    starts = np.searchsorted(bal.camera_index[order], np.arange(bal.n_cameras + 1))
    index_in_image = np.empty(bal.n_observations, dtype=int)
    R = bal.R_cam_from_world()
    extent = np.abs(bal.xy_pixel).max() * 2 + 2
    for i in range(bal.n_cameras):
        rows = order[starts[i]:starts[i + 1]]
        index_in_image[rows] = np.arange(len(rows))
        cam = pycolmap.Camera(model="RADIAL", width=int(extent), height=int(extent),
                              params=[float(bal.f[i]), 0.0, 0.0, float(bal.k1[i]), float(bal.k2[i])], camera_id=i + 1)
        rec.add_camera_with_trivial_rig(cam)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(D @ R[i]), D @ bal.t_cam_from_world[i])
        uv = np.column_stack([bal.xy_pixel[rows, 0], -bal.xy_pixel[rows, 1]])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=str(i), keypoints=uv, camera_id=i + 1, image_id=i + 1), pose)
        config.add_image(i + 1)
    rows = np.argsort(bal.point_index, kind="stable")
    bounds = np.searchsorted(bal.point_index[rows], np.arange(bal.n_points + 1))
    for j in range(bal.n_points):
        r = rows[bounds[j]:bounds[j + 1]]
        track = pycolmap.Track([pycolmap.TrackElement(int(bal.camera_index[k]) + 1, int(index_in_image[k])) for k in r])
        rec.add_point3D(bal.xyz_world[j], track)
    build = time.perf_counter() - t0
    opts = colmap_ba.options(pycolmap, threads, max_iterations=max_iterations, refine_intrinsics=True,
                             function_tolerance=COST_TOLERANCE)
    t1, c1 = time.perf_counter(), time.process_time()
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    summary = adjuster.solve()
    t2, c2 = time.perf_counter(), time.process_time()
    cs = summary.ceres_summary if hasattr(summary, "ceres_summary") else summary
    return {"adjuster": "pycolmap (Ceres)", "seconds": t2 - t1, "cpu": c2 - c1,
            "iterations": int(cs.num_successful_steps + cs.num_unsuccessful_steps),
            "final_cost": float(cs.final_cost), "converged": str(cs.termination_type).endswith(".CONVERGENCE"),
            "note": f"initial {float(cs.initial_cost):.6g}, {cs.termination_type}, build {build:.2f} s"}


def without_behind(bal):
    """The problem without the observations behind their camera at the start, and their number."""
    behind = behind_camera(bal)
    return without_observations(bal, behind), int(behind.sum())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bal_file", nargs="?", default=str(DEFAULT))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--max-iterations", type=int, default=100)
    ap.add_argument("--methods", default="bundle", help="striptri methods, comma-separated (bundle, conditions)")
    ap.add_argument("--keep-behind", action="store_true", help="keep observations behind their camera (striptri)")
    args = ap.parse_args(argv)
    bal = read_bal(args.bal_file)
    print(f"{Path(args.bal_file).name}: {bal.n_cameras} cameras, {bal.n_points} points, {bal.n_observations} "
          f"observations; initial cost 1/2 sum r^2 = {bal_cost(bal):.7g}")
    if not args.keep_behind:
        bal, n_behind = without_behind(bal)
        print(f"left out {n_behind} observations behind their camera: initial cost {bal_cost(bal):.7g}")
    rows = [run_striptri(bal, m, args.max_iterations) for m in args.methods.split(",") if m]
    ref = run_pycolmap(bal, args.threads, args.max_iterations)
    if ref is None:
        print("pycolmap not installed: pip install pycolmap (reference row skipped)", file=sys.stderr)
    else:
        rows.append(ref)
    print(f"{'adjuster':22s} {'wall s':>8s} {'cpu s':>8s} {'iter':>5s} {'final cost':>14s} {'conv':>5s}  note")
    for r in rows:
        print(f"{r['adjuster']:22s} {r['seconds']:8.2f} {r['cpu']:8.2f} {r['iterations']:5d} {r['final_cost']:14.10g} "
              f"{str(r['converged']):>5s}  {r['note']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
