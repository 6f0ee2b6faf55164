"""Benchmark of striptri's adjustment against pycolmap's bundle adjustment (Ceres).

    python scripts/bench/bench_adjust.py            # all cases: 8 minutes on 2 idle cores, 13 at load 5
    python scripts/bench/bench_adjust.py --quick    # the 100-photo cases only (30 s)
    python scripts/bench/bench_adjust.py --cases strip-1000 block-1000 --solvers sparse cholmod

Cases (scripts/bench/adjust_cases.py): strips of 100, 1,000 and 10,000 photos, blocks of 100 (5 x 20) and
1,000 (10 x 100) photos; 60 % overlap, 30 % sidelap, von Gruber points plus 4 ties per model, full
control every 4 models (strips) or on the perimeter every 4 models (blocks), plate sigma 0.005 mm,
approximations off by 3 m and 0.5 deg.

Per case, every striptri solver (striptri.solvers.SOLVERS) with the method of conditions, the
collinearity bundle (method "bundle", when striptri has it) and pycolmap, each in its own
process (scripts/bench/adjust_worker.py) so that the peak memory (VmHWM) is that run's own. The
time per iteration is split into evaluating the conditions, assembling N and solving (from
AdjustmentResult.timings divided by the iterations). Cases of up to 1,000 photos are run ``--repeats``
times (in the same process) and the median is reported.

Skips: dense above 3,000 unknowns; a solver whose time, extrapolated from the previous case of the
same kind, exceeds ``--max-seconds``; a run still going after ``--max-seconds`` is stopped (all
said in the table). pycolmap is optional: ``pip install pycolmap`` (measured with 4.2.1).

Threads: OPENBLAS_NUM_THREADS / OMP_NUM_THREADS = ``--threads`` (default 1) in every run, and Ceres'
num_threads the same. On this shared 2-core machine OpenBLAS' own threading can make dense calls
much slower under load, and one thread keeps both programs on equal terms.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import adjust_cases as bench_cases  # noqa: E402
import colmap_ba  # noqa: E402
from striptri import adjustment, solvers  # noqa: E402
from striptri.equations.parameters import build_layout  # noqa: E402

DENSE_MAX_UNKNOWNS = 3000
# How a run's time grows with the number of photos, for the extrapolation that decides a skip:
# about linearly for every solver on these banded / block problems (measured; Gauss-Seidel's sweeps
# per solve hardly grow along a strip with control every few models).
GROWTH = {}
REFERENCE_SOLVERS = ("cholmod", "sparse", "banded", "dense")  # for the comparison with pycolmap


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the 100-photo cases only (smoke run)")
    parser.add_argument("--cases", nargs="+", choices=list(bench_cases.CASES), help="cases to run (default: all)")
    parser.add_argument("--solvers", nargs="+", help="striptri solvers (default: all but auto)")
    parser.add_argument("--bundle-solvers", nargs="*", default=None,
                        help="solvers for striptri's bundle method (default: the fastest direct solver available)")
    parser.add_argument("--no-pycolmap", action="store_true", help="skip pycolmap")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement of a case of <= 1000 photos")
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads and Ceres threads (default 1)")
    parser.add_argument("--max-seconds", type=float, default=150.0, help="time limit of one run")
    parser.add_argument("--tolerance", type=float, help="striptri's convergence tolerance (default: its own, 1e-8)")
    parser.add_argument("--ceres-initial-radius", type=float,
                        help="Ceres' initial trust region radius (default: COLMAP's, 1e4)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, help="write every measurement to this file")
    return parser.parse_args(argv)


def machine_line() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{os.cpu_count()} cores ({cpu}), {mem:.0f} GiB, Python {platform.python_version()}"


def pycolmap_version() -> str | None:
    """pycolmap's version if it is installed (not imported here: the runs import it)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pycolmap")
    except PackageNotFoundError:
        return None


def versions_line(pycolmap) -> str:
    import scipy

    parts = [f"numpy {np.__version__}", f"scipy {scipy.__version__}"]
    try:
        import sksparse  # noqa: F401
        from importlib.metadata import version

        parts.append(f"scikit-sparse {version('scikit-sparse')}")
    except Exception:
        pass
    parts.append(f"pycolmap {pycolmap}" if pycolmap else f"pycolmap not installed ({colmap_ba.INSTALL_HINT})")
    return ", ".join(parts)


def child_env(threads: int) -> dict:
    env = dict(os.environ)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = str(threads)
    return env


def run_child(case_file: Path, engine: str, solver: str, repeats: int, args, out: Path) -> dict:
    cmd = [sys.executable, str(HERE / "adjust_worker.py"), str(case_file), engine, solver, str(repeats), str(args.threads), str(out),
           "-" if args.tolerance is None else repr(args.tolerance),
           "-" if args.ceres_initial_radius is None else repr(args.ceres_initial_radius)]
    t0 = time.perf_counter()
    load_before = os.getloadavg()[0]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.max_seconds * repeats + 60,
                              env=child_env(args.threads))
    except subprocess.TimeoutExpired:
        return {"skipped": f"stopped after {args.max_seconds * repeats + 60:.0f} s"}
    wall = time.perf_counter() - t0
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return {"failed": tail[:160]}
    report = json.loads(lines[-1])
    report["process_seconds"] = wall
    report["load_average"] = max(load_before, os.getloadavg()[0])
    return report


def planned_runs(args, n_unknowns: int, pycolmap) -> list[tuple[str, str]]:
    names = [s for s in solvers.SOLVERS if s != "auto"]
    chosen = args.solvers or names
    runs = [("conditions", s) for s in chosen if s in names]
    if "bundle" in adjustment.METHODS:
        if args.bundle_solvers is None:
            fast = [s for s in ("cholmod", "banded", "sparse") if s in names]
            bundle = fast[:1]
        else:
            bundle = [s for s in args.bundle_solvers if s in names]
        runs += [("bundle", s) for s in bundle]
    if pycolmap and not args.no_pycolmap:
        runs.append(("pycolmap", "-"))
    return runs


def skip_reason(engine, solver, case, n_unknowns, history, max_seconds) -> str | None:
    if solver == "dense" and n_unknowns > DENSE_MAX_UNKNOWNS:
        return f"dense: skipped above {DENSE_MAX_UNKNOWNS} unknowns"
    previous = history.get((engine, solver, case.kind))
    if previous is None:
        return None
    prev_case, prev = previous
    if "seconds" not in prev:
        return f"skipped: did not finish on {prev_case.name}"
    growth = GROWTH.get(solver, 1.0)
    took = prev.get("cpu_seconds", prev["seconds"])
    predicted = took * (case.total_photos / prev_case.total_photos) ** growth
    if predicted > max_seconds:
        return f"skipped: ~{predicted:.0f} s predicted from {prev_case.name} ({took:.1f} s)"
    return None


def per_iteration_ms(report: dict) -> tuple:
    t, it = report.get("timings", {}), max(report.get("iterations", 1), 1)
    if "linearisation_and_reduction" in t:  # the bundle: linearisation and point elimination in one
        return (None, 1e3 * t["linearisation_and_reduction"] / it, 1e3 * t["solve"] / it)
    if not t:
        return (None, None, None)
    return (1e3 * t["conditions"] / it, 1e3 * t["assembly"] / it, 1e3 * t["solve"] / it)


def fmt(value, spec: str, empty: str = "-") -> str:
    return empty if value is None else format(value, spec)


def angle_between(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Rotation angle of Ra^T Rb (rad), from its skew part (accurate for small angles)."""
    d = np.swapaxes(Ra, 1, 2) @ Rb
    w = np.stack([d[:, 2, 1] - d[:, 1, 2], d[:, 0, 2] - d[:, 2, 0], d[:, 1, 0] - d[:, 0, 1]], -1) / 2
    return np.arcsin(np.clip(np.linalg.norm(w, axis=1), 0, 1))


def main(argv=None) -> int:
    args = parse_args(argv)
    names = list(bench_cases.QUICK) if args.quick else (args.cases or list(bench_cases.CASES))
    pycolmap = None if args.no_pycolmap else pycolmap_version()
    print(f"machine: {machine_line()}")
    print(f"versions: {versions_line(pycolmap)}")
    print(f"threads: OPENBLAS_NUM_THREADS={args.threads}, Ceres num_threads={args.threads}")
    if pycolmap is None and not args.no_pycolmap:
        print(f"pycolmap: not installed, its column is skipped ({colmap_ba.INSTALL_HINT})")
    if any(bench_cases.CASES[n].n_photos > bench_cases.MAX_PHOTOS_PER_STRIP for n in names):
        ok = bench_cases.check_long_strip_generator()
        print(f"long-strip generator reproduces simulate.make_truth on a 100-photo strip: {'yes' if ok else 'NO'}")
    print()
    t_bench = time.perf_counter()
    rows, verification, history, blas = [], [], {}, set()
    with tempfile.TemporaryDirectory(prefix="striptri-bench-") as tmp:
        tmp = Path(tmp)
        for name in names:
            case = bench_cases.CASES[name]
            t0 = time.perf_counter()
            project, true_xyz0, true_R = bench_cases.make_case(case, args.seed)
            gen_seconds = time.perf_counter() - t0
            n_unknowns = build_layout(project).n_unknowns
            case_file = tmp / f"{name}.pkl"
            with open(case_file, "wb") as fh:
                pickle.dump((project, true_xyz0, true_R), fh, protocol=pickle.HIGHEST_PROTOCOL)
            n_control = int(np.count_nonzero(np.isfinite(project.points.xyz_given[:, 0])))
            info = (f"{case.total_photos} photos, {len(project.points)} points ({n_control} full control), "
                    f"{len(project.image_points)} image points, {n_unknowns} unknowns; generated in {gen_seconds:.1f} s")
            print(f"== {name}: {info}", flush=True)
            repeats = args.repeats if case.total_photos <= 1000 else 1
            results = {}
            for engine, solver in planned_runs(args, n_unknowns, pycolmap):
                reason = skip_reason(engine, solver, case, n_unknowns, history, args.max_seconds)
                if reason:
                    report = {"skipped": reason}
                else:
                    out = tmp / f"{name}-{engine}-{solver}.npz"
                    report = run_child(case_file, engine, solver, repeats, args, out)
                    if "seconds" in report:
                        with np.load(out) as z:
                            report["_xyz0"], report["_R"] = z["xyz0"], z["R"]
                        blas.update(report.get("blas", []))
                    history[(engine, solver, case.kind)] = (case, report)
                results[(engine, solver)] = report
                print("   " + one_line(engine, solver, report), flush=True)
            rows.append((case, n_unknowns, results, repeats))
            verification.append((case, compare(results)))
    total = time.perf_counter() - t_bench
    loads = [rep["load_average"] for _, _, res, _ in rows for rep in res.values() if "load_average" in rep]
    print()
    print(table(rows))
    print()
    print(verification_text(verification))
    print()
    print("thread pools in the runs (threadpoolctl): " + ("; ".join(sorted(blas)) or "?"))
    if loads:
        print(f"1-minute load average around the runs: {min(loads):.1f} to {max(loads):.1f} "
              f"(median {statistics.median(loads):.1f}) on {os.cpu_count()} cores; above ~1.5 other work shared the CPU")
    print(f"benchmark wall time: {total:.0f} s")
    if args.json:
        dump = [
            {"case": c.name, "photos": c.total_photos, "unknowns": n, "repeats": r,
             "runs": [{"engine": e, "requested_solver": s, **{k: v for k, v in rep.items() if not k.startswith("_")}}
                      for (e, s), rep in res.items()]}
            for c, n, res, r in rows
        ]
        args.json.write_text(json.dumps(dump, indent=1, default=float))
    return 0


def one_line(engine, solver, report) -> str:
    label = f"{engine}/{solver}" if engine != "pycolmap" else "pycolmap"
    if "seconds" not in report:
        return f"{label}: {report.get('skipped') or report.get('failed')}"
    return (f"{label}: {report['seconds']:.2f} s, {report['iterations']} it, peak {report['peak_mib']:.0f} MiB, "
            f"RMS centres {report['rms_centres']:.4f} m (load average {report['load_average']:.1f})")


def compare(results: dict) -> dict:
    """pycolmap's and the bundle's adjusted orientations against striptri's reference solver."""
    ref_key = next((("conditions", s) for s in REFERENCE_SOLVERS if "_xyz0" in results.get(("conditions", s), {})), None)
    if ref_key is None:
        return {}
    ref = results[ref_key]
    out = {"reference": f"conditions/{ref_key[1]}"}
    for key, rep in results.items():
        if key == ref_key or "_xyz0" not in rep:
            continue
        label = "pycolmap" if key[0] == "pycolmap" else f"{key[0]}/{key[1]}"
        out[label] = {
            "max_centre_difference_m": float(np.max(np.abs(rep["_xyz0"] - ref["_xyz0"]))),
            "max_angle_difference_rad": float(np.max(angle_between(rep["_R"], ref["_R"]))),
            "vtpv_relative_difference": abs(rep["vtpv"] - ref["vtpv"]) / ref["vtpv"],
        }
    return out


def table(rows) -> str:
    head = ("| case | unknowns | engine / solver | iters | conditions ms/it | assembly ms/it | solve ms/it "
            "| total s | CPU s | peak MiB (Δ) | RMS centres m | sigma0 | vTPv | striptri / pycolmap (CPU) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    notes = []
    for case, n_unknowns, results, repeats in rows:
        colmap = results.get(("pycolmap", "-"), {})
        for (engine, solver), rep in results.items():
            label = "pycolmap (Ceres, SPARSE_SCHUR)" if engine == "pycolmap" else f"{engine} / {solver}"
            name = case.name + (f" (median of {repeats})" if repeats > 1 else "")
            if "seconds" not in rep:
                lines.append(f"| {name} | {n_unknowns} | {label} | {rep.get('skipped') or 'failed: ' + rep.get('failed', '?')} "
                             "| | | | | | | | | | |")
                continue
            c, a, s = per_iteration_ms(rep)
            redundancy = results_redundancy(results)
            sigma0 = rep.get("sigma0")
            if engine == "pycolmap" and redundancy:
                sigma0 = float(np.sqrt(rep["vtpv"] / redundancy))
            ratio = "-"
            if engine != "pycolmap" and "seconds" in colmap:
                ratio = f"{rep['cpu_seconds'] / colmap['cpu_seconds']:.1f}"
            peak = f"{rep['peak_mib']:.0f} ({rep['peak_mib'] - rep['loaded_mib']:.0f})"
            it = str(rep["iterations"]) + ("" if rep.get("converged", True) else " (not converged)")
            extra = rep.get("solver_info_totals") or {}
            if extra:
                notes.append(f"{case.name} {label}: " + ", ".join(
                    f"{k} {v} in all" if k == "inner_iterations" else f"{k} {v}" for k, v in extra.items()))
            if not rep.get("converged", True):
                notes.append(f"{case.name} {label}: " + stall_note(rep))
            if engine == "pycolmap":
                notes.append(
                    f"{case.name} pycolmap: Ceres cost {rep['initial_cost']:.6g} -> {rep['final_cost']:.6g} "
                    f"(vTPv = 2 x final cost), {rep['termination']}, Ceres' own time {rep['ceres_seconds']:.2f} s, "
                    f"building the Reconstruction {rep['build_seconds']:.2f} s"
                )
            lines.append(
                f"| {name} | {n_unknowns} | {label} | {it} | {fmt(c, '.1f')} | {fmt(a, '.1f')} | {fmt(s, '.1f')} "
                f"| {rep['seconds']:.2f} | {rep['cpu_seconds']:.2f} | {peak} | {rep['rms_centres']:.4f} | {fmt(sigma0, '.4f')} | {rep['vtpv']:.6g} | {ratio} |"
            )
    text = "\n".join(lines)
    text += (
        "\n\nms/it: AdjustmentResult.timings / iterations (bundle: linearisation and point elimination together "
        "under assembly). total s: wall time of the whole adjust() call (pycolmap: adjuster set-up and Ceres solve, "
        "without building the Reconstruction in Python). CPU s: the same in CPU time of the run's process; every run "
        "is single-threaded, so this is what it would take alone on the machine, and the ratio uses it. peak MiB: "
        "peak resident memory of the run's own process (VmHWM; ru_maxrss would include the parent's, see "
        "adjust_worker.py); (Δ): above its size after loading the project and the libraries. pycolmap's vTPv is twice "
        "Ceres' final cost (one pixel is one sigma) and its sigma0 uses striptri's redundancy."
    )
    if notes:
        text += "\n\nnotes:\n" + "\n".join("- " + n for n in notes)
    return text


def stall_note(rep: dict) -> str:
    """Why a run did not converge: where its convergence criterion stopped falling."""
    crit = rep.get("criterion_history")
    if not crit:
        return f"not converged ({rep.get('termination', '?')})"
    floor = min(crit)
    first = next(i for i, c in enumerate(crit) if c < 3 * floor) + 1
    return (f"not converged: max |dx| sqrt(N_ii) levelled off at {floor:.1e} (tolerance {rep['tolerance']:.0e}) "
            f"from iteration {first} of {len(crit)}")


def results_redundancy(results: dict):
    for rep in results.values():
        if rep.get("redundancy"):
            return rep["redundancy"]
    return None


def verification_text(verification) -> str:
    lines = ["Agreement with striptri (method of conditions, reference solver):"]
    for case, comp in verification:
        if not comp:
            continue
        for label, d in comp.items():
            if label == "reference":
                continue
            lines.append(
                f"  {case.name}: {label} vs {comp['reference']}: max |dO| {d['max_centre_difference_m']:.2e} m, "
                f"max rotation difference {d['max_angle_difference_rad']:.2e} rad, "
                f"vTPv relative difference {d['vtpv_relative_difference']:.1e}"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
