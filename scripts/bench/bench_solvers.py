"""Time per solve of every normal-equation solver (DESIGN section 5, docs/solvers.md).

Cases:

* ``synthetic strip``: N of a strip of 100, 1000, 10000 photos with one self-calibrated camera
  (striptri.solvers.synthetic: 6x6 blocks within two photos of the diagonal, 3 camera columns last);
* ``simulated strip``: the real N of a simulated project (striptri.simulate, 60 % overlap, height
  control every 4 models, 2 extra tie points per model) after one iteration of the adjustment; the
  simulator allows at most 999 photos per strip, so 100 and 999;
* ``--blocks``: synthetic blocks of S strips x P photos numbered strip after strip (bandwidth about
  6 P): where ``banded`` stops paying, the rule of ``auto``.

For each solver: the first solve of a new solver object (with the symbolic work: CHOLMOD's analysis,
the sparse ordering) and the median of ``--repeats`` further solves on the same object (what every
later outer iteration costs). Iterative solvers start from zero and stop at the relative residual
1e-12 or after ``--max-inner`` iterations ("n.c." = not converged); their inner iterations are shown.
``dense`` is skipped above 7000 unknowns. Time in milliseconds.

BLAS runs single-threaded unless OPENBLAS_NUM_THREADS is set: on a 2-core machine shared with
other work, OpenBLAS's threads made LAPACK's banded Cholesky 3 to 15 times slower and the figures
irreproducible; single-threaded they are stable (SuperLU and CHOLMOD with Debian's reference BLAS
are single-threaded anyway).

    python scripts/bench/bench_solvers.py                 # strips, ~1.5 min on 2 cores
    python scripts/bench/bench_solvers.py --blocks --no-strips
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is imported (module doc)

import argparse
import statistics
import time
import warnings

import numpy as np

from striptri.adjustment import AdjustmentOptions, adjust
from striptri.simulate import ControlDesign, FlightDesign, PointDesign, SyntheticDesign
from striptri.simulate.pipeline import SimulateOptions, simulate_project
from striptri.solvers import (
    SOLVERS,
    SlowConvergenceWarning,
    SolverOptions,
    Structure,
    bandwidth,
    cholmod_available,
    make_solver,
    resolve_solver,
)
from striptri.solvers.synthetic import block_normal_matrix, strip_normal_matrix

DENSE_MAX = 7000
ITERATIVE = ("gauss-seidel", "pcg")


def simulated_strip(n_photos: int, seed: int):
    """(N, Structure) of a simulated strip after one outer iteration."""
    design = SyntheticDesign(
        flight=FlightDesign(n_photos=n_photos, overlap=0.6),
        points=PointDesign(extra_ties_per_model=2),
        control=ControlDesign(layout="every-k", every_k=4),
    )
    project, _ = simulate_project("strip", SimulateOptions(design=design), seed)
    result = adjust(project, AdjustmentOptions(solver="banded", max_iterations=1))
    return result.N, Structure(result.n_unknowns, result.layout.block_starts())


def time_solver(name, N, structure, repeats, max_inner):
    """(first solve s, median of further solves s or None, info of the last solve)."""
    options = SolverOptions(name, max_inner_iterations=max_inner)
    b = np.random.default_rng(0).normal(size=N.shape[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SlowConvergenceWarning)
        solver = make_solver(options, structure)
        t0 = time.perf_counter()
        result = solver.solve(N, b)
        first = time.perf_counter() - t0
        times = []
        # iterative solvers repeat the same work exactly; one run is enough when it is long
        n_more = repeats if (name not in ITERATIVE or first < 2.0) else 0
        for _ in range(n_more):
            t0 = time.perf_counter()
            result = solver.solve(N, b)
            times.append(time.perf_counter() - t0)
    return first, (statistics.median(times) if times else None), result.info


def cell(name, first, later, info) -> str:
    ms = (later if later is not None else first) * 1e3
    text = f"{ms:.1f}" if ms < 100 else f"{ms:.0f}"
    if name == "cholmod" or name == "sparse":
        text += f" ({first * 1e3:.0f} first)"
    if name in ITERATIVE:
        its = info["inner_iterations"]
        text += f" [{its}{'' if info['converged'] else ' n.c.'}]"
    return text


def run_table(cases, solvers, repeats, max_inner):
    header = ["case", "unknowns", "bandwidth", "auto"] + list(solvers)
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for label, (N, st) in cases:
        n = N.shape[0]
        k = n - 3 if label.startswith("synthetic") else n
        row = [label, str(n), str(bandwidth(N[:k, :k])), resolve_solver("auto", n, N, st)]
        for name in solvers:
            if name == "dense" and n > DENSE_MAX:
                row.append("-")
                continue
            first, later, info = time_solver(name, N, st, repeats, max_inner)
            row.append(cell(name, first, later, info))
        print("| " + " | ".join(row) + " |", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-inner", type=int, default=2000, help="cap of inner iterations")
    parser.add_argument("--no-strips", action="store_true")
    parser.add_argument("--no-real", action="store_true", help="skip the simulated projects")
    parser.add_argument("--blocks", action="store_true", help="the banded/sparse crossover on blocks")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)

    solvers = [s for s in SOLVERS if s != "auto" and (s != "cholmod" or cholmod_available())]
    print(f"solvers: {', '.join(solvers)}; cholmod {'installed' if cholmod_available() else 'not installed'}; "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print("time per solve in ms: median of later solves (first solve in parentheses where it differs),"
          " [inner iterations]\n")
    if not args.no_strips:
        cases = []
        for n in args.sizes:
            cases.append((f"synthetic strip {n}", strip_normal_matrix(n, np.random.default_rng(args.seed), n_cameras=1)))
        if not args.no_real:
            for n in sorted({min(n, 999) for n in args.sizes if n <= 1000}):
                cases.append((f"simulated strip {n}", simulated_strip(n, args.seed)))
        run_table(cases, solvers, args.repeats, args.max_inner)
    if args.blocks:
        print()
        direct = [s for s in solvers if s not in ITERATIVE and s != "dense"]
        cases = []
        for strips, photos in [(100, 10), (50, 20), (25, 40), (12, 80), (6, 160), (3, 320)]:
            cases.append((f"synthetic block {strips}x{photos}",
                          block_normal_matrix(strips, photos, np.random.default_rng(args.seed), n_cameras=1)))
        run_table(cases, direct, args.repeats, args.max_inner)


if __name__ == "__main__":
    main()
