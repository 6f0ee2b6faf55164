"""Time per solve of every normal-equation solver (DESIGN section 5, docs/solvers.md).

Cases:

* ``synthetic strip``: N of a strip of 100, 1000, 10000 photos with one self-calibrated camera
  (striptri.solvers.synthetic: 6x6 blocks within two photos of the diagonal, 3 camera columns last);
* ``simulated strip``: the real N of a simulated project (striptri.simulate, 60 % overlap, height
  control every 4 models, 2 extra tie points per model) after one iteration of the adjustment; the
  simulator allows at most 999 photos per strip, so 100 and 999;
* ``--blocks``: synthetic blocks of S strips x P photos numbered strip after strip (bandwidth about
  6 P): where ``banded`` stops paying, the rule of ``auto``.

* ``--projects DIR ...``: the normal matrices of real projects (e.g. the benchmark blocks
  /work/benchdata/b1k, b5k, b20k of docs/benchmarks.md) at their approximate values
  (``striptri.adjustment.normal_matrix_at_approximations``, method of conditions), factorised by
  every CHOLMOD variant (simplicial / supernodal; AMD, METIS, NESDIS, COLAMD orderings) on every
  BLAS found (Debian's reference BLAS, OpenBLAS serial, OpenBLAS pthreads with 1 and 2 threads,
  chosen per run by LD_LIBRARY_PATH, whatever the system's default), and by the sparse
  factorisations a ``pip install`` can bring (scipy's SuperLU, cvxopt's CHOLMOD, and, when
  installed, pypardiso (MKL), qdldl, cholespy, and LAPACK's banded Cholesky in a reverse
  Cuthill-McKee order). Each run in its own process (``--worker``), so that the BLAS, the threads
  and the peak memory are its own; the runs are interleaved over ``--rounds`` rounds (on a shared
  machine, load drifts) and the table gives medians. See :func:`project_configs`.

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
    python scripts/bench/bench_solvers.py --no-strips --projects /work/benchdata/b1k /work/benchdata/b5k \
        /work/benchdata/b20k --rounds 3      # the factorisation table of docs/solvers.md, ~1 h
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is imported (module doc)

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from striptri.adjustment import AdjustmentOptions, adjust
from striptri.simulate import ControlDesign, FlightDesign, PointDesign, SyntheticDesign
from striptri.simulate.pipeline import SimulateOptions, simulate_project
from striptri.solvers import (
    SOLVERS,
    CholmodSolver,
    SlowConvergenceWarning,
    SolverOptions,
    Structure,
    bandwidth,
    cholmod_available,
    cvxopt_available,
    describe,
    jacobi_scaled,
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
    if name in ("cholmod", "cvxopt", "sparse"):
        text += f" ({first * 1e3:.0f} first)"
    if name in ITERATIVE:
        text += f" [{info.inner_iterations}{'' if info.converged else ' n.c.'}]"
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


# -- the normal matrices of real projects, every factorisation on every BLAS -----------------------

LIBDIR = Path("/usr/lib/x86_64-linux-gnu")
BLAS_DIRS = {  # Debian 12's BLAS implementations (packages libblas3, libopenblas0-serial, -pthread)
    "reference": [LIBDIR / "blas", LIBDIR / "lapack"],
    "openblas-serial": [LIBDIR / "openblas-serial"],
    "openblas-pthread": [LIBDIR / "openblas-pthread"],
}
ORDERINGS = ("amd", "metis", "nesdis", "colamd")


def project_configs(blas_variants) -> list[str]:
    """Every run of the project table: ``SOLVER[:MODE:ORDERING]@BLAS/THREADS``.

    CHOLMOD (scikit-sparse): simplicial (it calls no BLAS, so on the reference BLAS only) and
    supernodal with every ordering on every BLAS; OpenBLAS pthreads with 1 and 2 threads; and
    ``+omp4``: supernodal without striptri's OpenMP setting (CHOLMOD's compiled-in 4 threads,
    sparse_cholesky module doc). Then the
    pip-only candidates with the BLAS their wheels bring ('wheel'; cvxopt's OpenBLAS is built
    sequential, MKL's PARDISO runs 1 and 2 threads)."""
    configs = []
    if cholmod_available():
        for ordering in ORDERINGS:
            configs.append(f"cholmod:simplicial:{ordering}@reference/1")
        for blas in blas_variants:
            for threads in ((1, 2) if blas == "openblas-pthread" else (1,)):
                for ordering in ORDERINGS:
                    configs.append(f"cholmod:supernodal:{ordering}@{blas}/{threads}")
        # without striptri's OpenMP setting (sparse_cholesky.OPENMP_DYNAMIC): CHOLMOD's own 4 threads
        for blas in blas_variants:
            configs.append(f"cholmod:supernodal:nesdis+omp4@{blas}/{2 if blas == 'openblas-pthread' else 1}")
    configs += ["sparse@wheel/1", "cvxopt@wheel/1", "pardiso@wheel/1", "pardiso@wheel/2", "qdldl@wheel/1",
                "cholespy@wheel/1", "banded-rcm@wheel/1"]
    return configs


def _hwm_mb(key="VmHWM") -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024
    return float("nan")


def _raw_candidate(kind: str, N, structure):
    """(setup, step) for the pip-only factorisations that are not striptri solvers: setup() once,
    step(state, b) -> dx per outer iteration (numeric factorisation and solve, symbolic work kept
    where the library allows it)."""
    n = N.shape[0]
    if kind == "pardiso":
        import pypardiso

        def setup():
            solver = pypardiso.PyPardisoSolver(mtype=2)  # real symmetric positive definite
            return solver

        def step(solver, b):
            A, s = jacobi_scaled(N)
            upper = sp.triu(A, format="csr")
            upper.sort_indices()
            solver.factorize(upper)  # phase 12: PARDISO's analysis (METIS) and numeric factorisation
            return solver.solve(upper, b * s) * s
        return setup, step
    if kind == "qdldl":
        import qdldl

        def setup():
            return {}

        def step(state, b):
            A, s = jacobi_scaled(N)
            upper = sp.triu(A, format="csc")
            if "solver" not in state:
                state["solver"] = qdldl.Solver(upper)  # AMD and L D L'
            else:
                state["solver"].update(upper)  # numeric only
            return state["solver"].solve(b * s) * s
        return setup, step
    if kind == "cholespy":
        from cholespy import CholeskySolverD, MatrixType

        def setup():
            return None

        def step(_, b):
            A, s = jacobi_scaled(N)
            A = A.tocsc()
            solver = CholeskySolverD(n, A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data,
                                     MatrixType.CSC)  # analysis and factorisation: no numeric-only call
            x = np.zeros(n)
            solver.solve(np.ascontiguousarray(b * s), x)
            return x * s
        return setup, step
    if kind == "banded-rcm":
        from scipy.linalg import lapack
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        from striptri.solvers.banded import _band_storage
        from striptri.solvers.blocks import partition
        from striptri.solvers.direct import block_graph

        def setup():
            A, _ = jacobi_scaled(N)
            blocks = partition(structure, n)
            sequence = reverse_cuthill_mckee(block_graph(A, blocks), symmetric_mode=True)
            sizes = blocks.sizes[sequence]
            offsets = np.arange(sizes.sum()) - np.repeat(np.cumsum(sizes) - sizes, sizes)
            order = np.repeat(blocks.starts[sequence], sizes) + offsets
            return order, bandwidth(A[order][:, order])

        def step(state, b):
            order, w = state
            A, s = jacobi_scaled(N)
            Ap = A[order][:, order].tocsr()
            Ap.sort_indices()
            cb, info = lapack.dpbtrf(_band_storage(Ap, n, w), lower=1)
            if info:
                raise RuntimeError(f"dpbtrf info {info}")
            y, _ = lapack.dpbtrs(cb, (b * s)[order][:, None], lower=1)
            x = np.empty(n)
            x[order] = y[:, 0]
            return x * s
        return setup, step
    raise ValueError(f"unknown candidate {kind!r}")


def worker(npz: str, config: str, repeats: int) -> dict:
    """One run of ``config`` on the matrix in ``npz`` (N and the block starts): first solve with
    the symbolic work, then ``repeats`` numeric solves on the same object; seconds and the peak
    memory above the memory after loading N."""
    data = np.load(npz)
    N = sp.csr_matrix((data["data"], data["indices"], data["indptr"]), shape=tuple(data["shape"]))
    structure = Structure(N.shape[0], data["block_starts"])
    b = np.random.default_rng(0).normal(size=N.shape[0])
    solver_part = config.split("@")[0]
    if solver_part.endswith("+omp4"):
        from striptri.solvers import sparse_cholesky

        sparse_cholesky.OPENMP_DYNAMIC = False
        solver_part = solver_part[: -len("+omp4")]
    kind, *params = solver_part.split(":")
    try:  # reset the peak to the present size (Linux >= 4.0), so that loading N does not count
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass
    base = _hwm_mb("VmRSS")
    out = {"config": config}
    try:
        if kind in ("cholmod", "cvxopt", "sparse", "banded"):
            options = SolverOptions(kind)
            if kind == "cholmod":
                solver = CholmodSolver(options, structure, mode=params[0], ordering=params[1])
            else:
                solver = make_solver(options, structure)
            setup, step = (lambda: solver), (lambda state, rhs: state.solve(N, rhs).dx)
            out["blas"] = describe(kind)["blas"]
        else:
            setup, step = _raw_candidate(kind, N, structure)
    except ImportError as exc:
        return {**out, "skipped": f"not installed ({exc})"}
    t0 = time.perf_counter()
    state = setup()
    dx = step(state, b)
    out["first"] = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        dx = step(state, b)
        times.append(time.perf_counter() - t0)
    out["later"] = statistics.median(times) if times else None
    # relative residual of the Jacobi-scaled system: every factorisation must solve it to rounding
    A, s = jacobi_scaled(N)
    out["residual"] = float(np.linalg.norm(A @ (dx / s) - b * s) / np.linalg.norm(b * s))
    out["peak_mb"] = _hwm_mb() - base
    if "blas" not in out and kind == "cvxopt":
        out["blas"] = describe("cvxopt")["blas"]
    return out


def _run_worker(npz, config, repeats, timeout):
    blas, threads = config.split("@")[1].split("/")
    env = dict(os.environ, OPENBLAS_NUM_THREADS=threads, OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads)
    if blas in BLAS_DIRS:
        env["LD_LIBRARY_PATH"] = ":".join(str(d) for d in BLAS_DIRS[blas])
    cmd = [sys.executable, __file__, "--worker", npz, config, str(repeats)]
    try:
        proc = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"config": config, "skipped": f"longer than {timeout:.0f} s"}
    if proc.returncode != 0:
        return {"config": config, "skipped": "failed: " + (proc.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def project_matrices(dirs, workdir: Path):
    """[(label, npz path, n, nnz)]: N at the approximations of each project, saved for the workers."""
    from striptri.adjustment import normal_matrix_at_approximations
    from striptri.io import read_project

    out = []
    for d in dirs:
        N, layout = normal_matrix_at_approximations(read_project(d))
        N = sp.csr_matrix(N)
        path = workdir / f"{Path(d).name}.npz"
        np.savez(path, data=N.data, indices=N.indices, indptr=N.indptr, shape=np.array(N.shape),
                 block_starts=np.asarray(layout.block_starts()))
        out.append((Path(d).name, str(path), N.shape[0], N.nnz))
        del N
    return out


def run_projects(dirs, rounds, repeats, timeout, selected):
    variants = [v for v, paths in BLAS_DIRS.items() if all(p.is_dir() for p in paths)]
    configs = [c for c in project_configs(variants) if not selected or any(k in c for k in selected)]
    print(f"BLAS found: {', '.join(variants)}; {len(configs)} runs per matrix and round, {rounds} rounds, "
          f"{repeats} numeric solves after the first in each run\n")
    workdir = Path(tempfile.mkdtemp(prefix="bench_solvers_"))
    try:
        matrices = project_matrices(dirs, workdir)
        results = {(m[0], c): [] for m in matrices for c in configs}
        slow = set()  # (matrix, config) over the timeout once: not run again
        for r in range(rounds):
            for label, npz, _, _ in matrices:
                order = configs[r % len(configs):] + configs[:r % len(configs)]  # rotate: no fixed neighbours
                for config in order:
                    if (label, config) in slow:
                        continue
                    res = _run_worker(npz, config, repeats, timeout)
                    if "skipped" in res:
                        slow.add((label, config))
                    results[(label, config)].append(res)
                    print(f"  round {r + 1} {label} {config}: " + (res.get("skipped") or
                          f"first {res['first']:.3f} s, later {res['later'] if res['later'] is None else round(res['later'], 3)} s, "
                          f"peak +{res['peak_mb']:.0f} MB, residual {res['residual']:.1e}"), file=sys.stderr, flush=True)
        for label, _, n, nnz in matrices:
            print(f"\n{label}: {n} unknowns, {nnz} nonzeros in N; seconds per solve (median over rounds), "
                  f"first = with the symbolic analysis, later = numeric factorisation and solve only\n")
            print("| factorisation | BLAS / threads | first s | later s | peak MB | residual |")
            print("|---|---|---|---|---|---|")
            for config in configs:
                runs = [x for x in results[(label, config)] if "skipped" not in x]
                solver_part, blas = config.split("@")
                if not runs:
                    skipped = results[(label, config)]
                    print(f"| {solver_part} | {blas} | {skipped[0]['skipped'] if skipped else '-'} | | | |")
                    continue
                first = statistics.median(x["first"] for x in runs)
                later = [x["later"] for x in runs if x["later"] is not None]
                later_text = f"{statistics.median(later):.3f}" if later else "-"
                peak = max(x["peak_mb"] for x in runs)
                res = max(x["residual"] for x in runs)
                print(f"| {solver_part} | {blas} | {first:.3f} | {later_text} | {peak:.0f} | {res:.0e} |", flush=True)
            blases = sorted({x["blas"] for (m, c), v in results.items() if m == label for x in v if "blas" in x})
            print("\nBLAS libraries found at run time (striptri.solvers.describe): " + "; ".join(blases))
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-inner", type=int, default=2000, help="cap of inner iterations")
    parser.add_argument("--no-strips", action="store_true")
    parser.add_argument("--no-real", action="store_true", help="skip the simulated projects")
    parser.add_argument("--blocks", action="store_true", help="the banded/sparse crossover on blocks")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--projects", nargs="+", default=[], metavar="DIR",
                        help="project folders: the factorisation table on their N (see the module doc)")
    parser.add_argument("--rounds", type=int, default=3, help="--projects: interleaved rounds")
    parser.add_argument("--timeout", type=float, default=600.0, help="--projects: seconds per run")
    parser.add_argument("--only", nargs="+", default=[], metavar="TEXT",
                        help="--projects: only the runs whose name contains one of these")
    parser.add_argument("--worker", nargs=3, metavar=("NPZ", "CONFIG", "REPEATS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        npz, config, repeats = args.worker
        print(json.dumps(worker(npz, config, int(repeats))))
        return

    available = {"cholmod": cholmod_available(), "cvxopt": cvxopt_available()}
    solvers = [s for s in SOLVERS if s != "auto" and available.get(s, True)]
    print(f"solvers: {', '.join(solvers)}; not installed: {', '.join(k for k, v in available.items() if not v) or '-'}; "
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
    if args.projects:
        print()
        run_projects(args.projects, args.rounds, args.repeats, args.timeout, args.only)


if __name__ == "__main__":
    main()
