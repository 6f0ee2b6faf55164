"""pycolmap's bundle adjustment of one case in its own process (bench_scale.py starts it).

    python scripts/bench/colmap_worker.py DATA.npz THREADS OUT.npz [--tolerance NAME] [--covariance]

DATA.npz: colmap_ba.ColmapData saved by colmap_ba.save (the parent prepared it with striptri, so
this process holds numpy and pycolmap only: its memory is pycolmap's). THREADS: Ceres'
num_threads. --tolerance: Ceres' stopping tolerances, a name of colmap_ba.TOLERANCES [1e-16]. --covariance: then pycolmap's covariance estimate (colmap_ba.covariance), timed
apart; the peak memory of the bundle adjustment is read before it.
Prints one JSON line; writes the adjusted centres (ground frame) to OUT.npz.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

T_START = time.perf_counter()

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import colmap_ba  # noqa: E402


def _status_mib(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main(argv: list[str]) -> None:
    data_file, threads, out = argv[0], int(argv[1]), Path(argv[2])
    with_covariance = "--covariance" in argv[3:]
    tolerance = argv[argv.index("--tolerance") + 1] if "--tolerance" in argv else "1e-16"
    pycolmap = colmap_ba.pycolmap_module()
    data = colmap_ba.load(data_file)
    loaded_seconds = time.perf_counter() - T_START
    loaded_mib = _status_mib("VmRSS")
    run, rec, adjuster, ids = colmap_ba.solve(pycolmap, data, threads, tolerance=tolerance)
    report = {
        "pycolmap_version": pycolmap.__version__,
        "threads": threads,
        "tolerance": tolerance,
        "import_and_load_seconds": loaded_seconds,
        "build_seconds": run.build_seconds,
        "seconds": run.seconds,
        "cpu_seconds": run.cpu_seconds,
        "ceres_seconds": run.ceres_seconds,
        "iterations": run.iterations,
        "initial_cost": run.initial_cost,
        "final_cost": run.final_cost,
        "vtpv": run.vtpv,
        "termination": run.termination,
        "linear_solver": run.linear_solver,
        "interior": colmap_ba.interior_from_params(data, run.camera_params),
        "loaded_mib": loaded_mib,
        "peak_mib": _status_mib("VmHWM"),
    }
    np.savez(out, xyz0=run.xyz0)
    if with_covariance:
        report["covariance"] = colmap_ba.covariance(pycolmap, rec, adjuster, ids, len(data.xyz0))
        report["peak_with_covariance_mib"] = _status_mib("VmHWM")
    report["process_seconds_inside"] = time.perf_counter() - T_START
    print(json.dumps(report, default=float))


if __name__ == "__main__":
    main(sys.argv[1:])
