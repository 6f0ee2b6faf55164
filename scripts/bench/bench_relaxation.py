"""Relaxation over strips (strip-pcg) against the direct solver, adjusted end to end (issue 12).

    python scripts/bench/bench_relaxation.py                  # b5k (5,000-photo block), s10k (10,000-photo strip)
    python scripts/bench/bench_relaxation.py --cases b1k b5k s10k b20k

Per case (scale_cases.py; built on first use into DATA_DIR): ``striptri.adjustment.adjust`` with
the direct solver (``auto``: banded for a strip, CHOLMOD for a block) and with ``strip-pcg``, each
in its own process (so that peak memory is its own; one BLAS thread). Printed: outer iterations,
inner iterations summed over them (CG iterations: one preconditioner solve, one product with N
each), solve seconds, adjust() seconds, peak resident memory of the process, and the largest
difference of the adjusted projection centres between the two, divided by the flying height.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
SRC = HERE.parents[1] / "src"
sys.path[:0] = [str(HERE), str(SRC)]

import scale_cases  # noqa: E402

FLYING_HEIGHT = 1500.0  # m, the simulator's default (striptri simulate)
DEFAULT_CASES = ("b5k", "s10k")


def worker(project: str, solver: str, out: str) -> None:
    """One adjustment in this process; writes the result's numbers and centres to ``out`` (npz)."""
    import resource
    import time

    import numpy as np

    from striptri.adjustment import AdjustmentOptions, adjust
    from striptri.io import read_project

    p = read_project(project)
    t = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = adjust(p, AdjustmentOptions(solver=solver))
    seconds = time.perf_counter() - t
    inner = [h.solver_info.inner_iterations or 0 for h in r.history]
    info = {
        "solver": r.solver, "converged": bool(r.converged), "iterations": int(r.iterations),
        "inner": [int(i) for i in inner], "inner_converged": [h.solver_info.converged is not False
                                                             for h in r.history],
        "solve_s": r.timings.solve, "final_checks_s": r.timings.final_checks or 0.0, "adjust_s": seconds,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "vtpv": float(r.vtpv),
        "warnings": sorted({type(w.message).__name__ for w in caught}),
        "last_info": {k: v for k, v in r.history[-1].solver_info.as_dict().items()
                      if isinstance(v, (int, float, str, bool))},
    }
    np.savez(out, xyz0=r.state.xyz0 + r.offset, info=json.dumps(info))


def run(project: Path, solver: str, workdir: Path) -> tuple[dict, object]:
    import numpy as np

    out = workdir / f"{project.parent.name}-{solver}.npz"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           "PYTHONPATH": str(SRC)}
    subprocess.run([sys.executable, __file__, "--worker", str(project), solver, str(out)], check=True, env=env)
    z = np.load(out)
    return json.loads(str(z["info"])), z["xyz0"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", choices=list(scale_cases.CASES), default=list(DEFAULT_CASES))
    ap.add_argument("--solvers", nargs="+", default=["auto", "strip-pcg"], help="first: the reference")
    ap.add_argument("--data-dir", type=Path, default=scale_cases.default_data_dir())
    ap.add_argument("--json", type=Path, help="every measurement")
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(*args.worker)
        return
    import numpy as np

    workdir = args.data_dir / "relaxation"
    workdir.mkdir(parents=True, exist_ok=True)
    rows, everything = [], {}
    for name in args.cases:
        project = scale_cases.build_case(scale_cases.CASES[name], args.data_dir)
        ref_xyz = None
        for solver in args.solvers:
            info, xyz = run(project, solver, workdir)
            diff = 0.0 if ref_xyz is None else float(np.abs(xyz - ref_xyz).max()) / FLYING_HEIGHT
            ref_xyz = xyz if ref_xyz is None else ref_xyz
            info["centre_difference_over_height"] = diff
            everything[f"{name}/{solver}"] = info
            rows.append([name, info["solver"], str(info["iterations"]) + ("" if info["converged"] else " (n.c.)"),
                         f"{sum(info['inner'])}" + ("" if all(info["inner_converged"]) else " *"),
                         f"{info['solve_s']:.2f}", f"{info['adjust_s']:.2f}", f"{info['peak_mb']:.0f}",
                         "reference" if diff == 0.0 and solver == args.solvers[0] else f"{diff:.1e}"])
            print(f"{name} {solver}: {json.dumps(info)}", file=sys.stderr, flush=True)
    header = ["case", "solver", "outer iterations", "inner iterations (sum)", "solve s", "adjust() s", "peak MB",
              "max |centre difference| / flying height"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(r) + " |")
    print("\n* an inner solve ended above its tolerance (the rounding floor of N's condition); the outer "
          "iteration corrects it")
    path = args.json or workdir / "bench_relaxation.json"
    path.write_text(json.dumps(everything, indent=1) + "\n")


if __name__ == "__main__":
    main()
