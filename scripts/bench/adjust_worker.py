"""One benchmark run in its own process (bench_adjust.py starts it), so that its peak memory is its own.

    python scripts/bench/adjust_worker.py CASE.pkl ENGINE SOLVER REPEATS THREADS OUT.npz [TOLERANCE] [CERES_RADIUS]

CASE.pkl: (project, true centres, true R_ground_from_cam) as adjust_cases.make_case returns them.
ENGINE: "conditions" or "bundle" (striptri methods; SOLVER one of striptri.solvers.SOLVERS) or
"pycolmap" (SOLVER ignored). The BLAS thread count is set by the parent in the environment
(OPENBLAS_NUM_THREADS etc.) before numpy loads; THREADS also sets Ceres' num_threads.
TOLERANCE: striptri's convergence tolerance ("-" for its default); CERES_RADIUS: Ceres' initial
trust region radius ("-" for COLMAP's default).
Prints one JSON line; writes the adjusted centres and rotations to OUT.npz.
"""

from __future__ import annotations

import json
import pickle
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _status_mib(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def rss_mib() -> float:
    """Current resident set size (MiB)."""
    return _status_mib("VmRSS")


def peak_mib() -> float:
    """Peak resident set size of this process (MiB).

    VmHWM, not ru_maxrss: Linux carries ru_maxrss across execve (it takes the high-water mark of
    the memory image exec replaces, here the parent's, since subprocess forks with vfork), so a
    child's ru_maxrss is never below the parent's peak. VmHWM belongs to the new memory image only.
    ru_maxrss is kept in the report for comparison."""
    return _status_mib("VmHWM")


def ru_maxrss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def blas_info() -> list[str]:
    """The thread pools loaded in this process, as threadpoolctl sees them."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return ["threadpoolctl not installed"]
    return sorted(
        f"{i.get('internal_api')} {i.get('version') or ''} {i.get('architecture') or ''} "
        f"({Path(i.get('filepath', '?')).name}) threads={i.get('num_threads')}".replace("  ", " ")
        for i in threadpool_info()
    )


def rms_centres(xyz0: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((xyz0 - truth) ** 2, axis=1))))


def run_striptri(project, true_xyz0, method: str, solver: str, repeats: int, out: Path, tolerance) -> dict:
    from striptri.adjustment import AdjustmentOptions, adjust

    options = AdjustmentOptions(method=method, solver=solver)
    if tolerance is not None:
        options = AdjustmentOptions(method=method, solver=solver, tolerance=tolerance)
    runs, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        result = adjust(project, options)
        wall = time.perf_counter() - t0
        cpus.append(time.process_time() - c0)
        runs.append((wall, result))
    walls = [w for w, _ in runs]
    median = sorted(range(repeats), key=lambda i: walls[i])[repeats // 2]
    result = runs[median][1]
    timings = {k: statistics.median(r.timings.as_dict().get(k, 0.0) for _, r in runs) for k in result.timings.as_dict()}
    xyz0 = result.state.xyz0 + result.offset
    np.savez(out, xyz0=xyz0, R=result.state.R_ground_from_cam)
    inner = {}  # the solver's counters: inner iterations summed over the outer ones, others as last reported
    for h in result.history:
        for key, value in h.solver_info.as_dict().items():
            if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
                inner[key] = inner.get(key, 0) + int(value) if key == "inner_iterations" else int(value)
    return {
        "solver": result.solver,
        "iterations": result.iterations,
        "converged": bool(result.converged),
        "timings": timings,
        "seconds": statistics.median(walls),
        "seconds_all": walls,
        "cpu_seconds": statistics.median(cpus),
        "sigma0": result.sigma0,
        "vtpv": result.vtpv,
        "redundancy": result.redundancy,
        "n_unknowns": result.n_unknowns,
        "rms_centres": rms_centres(xyz0, true_xyz0),
        "solver_info_totals": inner,
        "tolerance": options.tolerance,
        "criterion_history": [h.max_correction for h in result.history],
    }


def run_pycolmap(project, true_xyz0, repeats: int, threads: int, out: Path, radius) -> dict:
    import colmap_ba

    pycolmap = colmap_ba.pycolmap_module()
    data = colmap_ba.prepare(project)
    runs = [colmap_ba.run(pycolmap, data, threads, radius) for _ in range(repeats)]
    secs = [r.seconds for r in runs]
    run = runs[sorted(range(repeats), key=lambda i: secs[i])[repeats // 2]]
    np.savez(out, xyz0=run.xyz0, R=run.R)
    return {
        "solver": f"Ceres {run.linear_solver}",
        "iterations": run.iterations,
        "converged": run.termination == "CONVERGENCE",
        "termination": run.termination,
        "seconds": statistics.median(secs),
        "seconds_all": secs,
        "cpu_seconds": statistics.median(r.cpu_seconds for r in runs),
        "ceres_seconds": statistics.median(r.ceres_seconds for r in runs),
        "build_seconds": statistics.median(r.build_seconds for r in runs),
        "initial_cost": run.initial_cost,
        "final_cost": run.final_cost,
        "vtpv": run.vtpv,
        "rms_centres": rms_centres(run.xyz0, true_xyz0),
        "pycolmap_version": pycolmap.__version__,
    }


def main(argv: list[str]) -> None:
    case_file, engine, solver, repeats, threads, out = argv[:6]
    repeats, threads, out = int(repeats), int(threads), Path(out)
    extra = argv[6:] + ["-", "-"]
    tolerance = None if extra[0] == "-" else float(extra[0])
    radius = None if extra[1] == "-" else float(extra[1])
    with open(case_file, "rb") as fh:
        project, true_xyz0, _ = pickle.load(fh)
    import scipy.sparse  # noqa: F401  (loaded before the baseline, as the adjustment needs it)

    if engine == "pycolmap":
        import colmap_ba  # noqa: F401

        colmap_ba.pycolmap_module()
    else:
        import striptri.adjustment  # noqa: F401
    loaded = rss_mib()
    if engine == "pycolmap":
        report = run_pycolmap(project, true_xyz0, repeats, threads, out, radius)
    else:
        report = run_striptri(project, true_xyz0, engine, solver, repeats, out, tolerance)
    report.update(peak_mib=peak_mib(), ru_maxrss_mib=ru_maxrss_mib(), loaded_mib=loaded, blas=blas_info())
    print(json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1:])
