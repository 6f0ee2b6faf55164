"""Benchmark of the whole ``striptri adjust`` command at scale against pycolmap's bundle adjustment.

    python scripts/bench/bench_scale.py                      # b1k, b5k, b20k, close-range
    python scripts/bench/bench_scale.py --quick              # smoke run: a 100-photo block, a 24-photo close range
    python scripts/bench/bench_scale.py --cases b5k --repeats 3 --threads 1 --json b5k.json

Cases (scale_cases.py): blocks of 1,000, 5,000 and 20,000 photos made by ``striptri simulate block
... --extra-ties 6 --control perimeter --seed 11`` with the height points turned into tie points
(full control only, the same least-squares problem for pycolmap), and a synthetic close-range
block like the issue's real project (close_range.py: 115 convergent photos, 150 targets, ~66 rays
per target, self-calibration of c, xp, yp, k1, k2, six fixed full control points). Not run by
default: the long strips of issue 12, s10k and s100k (``striptri simulate strip --photos 10000 |
100000 --control every-k --every-k 20 --every-k-kind XYZ --seed 11``; ``--cases s10k s100k``), and
issue 29's 100,000-photo strip with full control every 50 models (``s100k-50``).

Per case, interleaved over ``--repeats`` rounds (medians reported), each striptri run right after a
pycolmap run (run_plan: never right after another striptri run, whose freed memory is still warm):

* ``striptri adjust CASE --out OUT --method M --keep-unconverged`` (M: conditions, the default, and
  bundle) as a subprocess under ``/usr/bin/time`` (peak resident memory of the process, CPU time)
  and coreutils ``timeout`` (``--time-limit``); its phases from summary.json ``timings_s``: read;
  the adjustment's own (conditions, assembly, solve, back_substitution, final_checks; the bundle's
  initial_points and linearisation_and_reduction in the first two columns) and its total;
  gross_errors (the reliability measures: residual cofactors and w-tests, beyond the adjustment);
  point_precision; tables (CSV); report (report.html); the remainder of the wall time is the
  interpreter's start, the imports and the writing of the files. Every run reads byte-compiled
  modules, as after a ``pip install`` (child_env: PYCACHE_DIR, even where PYTHONDONTWRITEBYTECODE is set).
* pycolmap's bundle adjustment of the same project (colmap_ba.py, SPARSE_SCHUR, Levenberg-Marquardt)
  in its own process (colmap_worker.py; it holds numpy and pycolmap only), swept over each of
  ``--threads`` Ceres threads (OpenBLAS threads the same) and each of ``--tolerances``, Ceres'
  stopping tolerances (colmap_ba.TOLERANCES: its defaults up to the 1e-16 of the earlier,
  handicapped benchmark); its time is the adjuster's set-up and solve, its memory the peak of its
  process up to the end of the solve. **The peer** of a case is the fastest of these runs that
  reaches striptri's solution (issue 29): RMS centre error equal to 3 significant digits and
  v^T P v within 1e-6 relative of striptri's conditions run. With one thread and the peer's
  tolerances, where the dense matrix fits (``--covariance-max-gb``), once more followed by
  pycolmap's covariance estimate (``pycolmap.estimate_ba_covariance``, every parameter), the peer
  of striptri's point precision (a run of its own, after the timed ones, so that it changes
  neither their time nor their memory).

Accuracy: the RMS of the projection centres against the simulator's truth and v^T P v of every run.

Printed: the counts of each case, a table of the runs with the issue's ratios to the peer (whole
command / peer, adjust() / peer, peak memory / the peer's), the sweep with the peer marked, a table
of the phases with the dominant one, the covariance peers, the growth exponents of time and memory
with the number of photos (log-log fit over the block sizes run) and the issue's targets. Everything
goes to ``--json`` (default DATA_DIR/bench_scale.json).

striptri runs with one BLAS thread (OPENBLAS_NUM_THREADS=OMP_NUM_THREADS=MKL_NUM_THREADS=1,
``--blas-threads``): on a shared 2-core machine OpenBLAS' threads wait for a busy core
(docs/benchmarks.md). Each run may be held to ``--memory-limit-gb`` of address space
(RLIMIT_AS): a run above it fails and says so.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SRC = HERE.parents[1] / "src"  # this checkout's striptri, here and in every run (child_env)
sys.path[:0] = [str(HERE), str(SRC)]

import colmap_ba  # noqa: E402  (numpy only: the tolerance sets)
import scale_cases  # noqa: E402

PYCACHE_DIR = scale_cases.default_data_dir() / "pycache"  # bytecode of every run (child_env)

TIME = "/usr/bin/time"
METHODS = ("conditions", "bundle")
STRIPTRI_PHASES = ("read", "conditions", "assembly", "solve", "back_substitution", "final_checks", "adjust_other",
                   "gross_errors", "point_precision", "tables", "report", "remainder")
COVARIANCE_RUN = "pycolmap 1 thread + covariance"
BUNDLE_NAMES = {"initial_points": "conditions", "linearisation_and_reduction": "assembly"}  # table columns
PIPELINE = ("read", "gross_errors", "point_precision", "tables", "report")
TARGETS = (  # issue 29's targets: (case, method or None for every method, quantity, limit, text)
    ("b5k", None, "whole_ratio", 1.0, "whole command within 1.0x of pycolmap's whole process"),
    ("b5k", None, "adjust_ratio", 0.6, "adjust() within 0.6x of pycolmap's bundle adjustment"),
    ("b5k", None, "memory_ratio", 1.2, "peak memory within 1.2x of pycolmap's"),
    ("b20k", None, "whole_ratio", 0.8, "whole command within 0.8x of pycolmap's whole process"),
    ("b20k", None, "memory_ratio", 1.2, "peak memory within 1.2x of pycolmap's"),
    ("b100k", None, "whole_ratio", 0.7, "whole command within 0.7x of pycolmap's whole process"),
    ("b100k", None, "memory_ratio", 1.0, "peak memory within 1.0x of pycolmap's"),
    ("s100k", None, "peak_gib", 3.0, "peak memory below 3 GB"),
    ("s100k-50", None, "peak_gib", 3.0, "peak memory below 3 GB"),
    ("close-range", "bundle", "whole_ratio", 3.0, "whole command within 3x of pycolmap's whole process"),
    # the conditions method against striptri's own bundle method on the same block, same run
    ("close-range", "conditions", "own_bundle_ratio", 3.0, "whole command within 3x of striptri's bundle method's"),
)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", choices=list(scale_cases.CASES), help="default: b1k b5k b20k close-range")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: cases b100 and close-small, one repeat, one Ceres thread (unless given)")
    ap.add_argument("--repeats", nargs="+", default=None, metavar="N|CASE=N",
                    help="rounds of runs, interleaved; medians. N for every case, CASE=N for one [1]")
    ap.add_argument("--threads", type=int, nargs="+", default=None, help="Ceres threads of the pycolmap runs [1 2]")
    ap.add_argument("--tolerances", nargs="+", default=None, choices=list(colmap_ba.TOLERANCES),
                    help="Ceres' stopping tolerances swept (colmap_ba.TOLERANCES) [all; --quick: ceres-default 1e-10]")
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS), help="striptri methods")
    ap.add_argument("--no-pycolmap", action="store_true", help="striptri only")
    ap.add_argument("--no-covariance", action="store_true", help="skip pycolmap's covariance estimate")
    ap.add_argument("--covariance-max-gb", type=float, default=1.0,
                    help="run pycolmap's covariance only when one dense matrix over the poses fits in this [1]")
    ap.add_argument("--time-limit", nargs="+", default=None, metavar="S|CASE=S",
                    help="seconds after which a striptri or pycolmap run is stopped; S for every case, CASE=S "
                         "for one [1800]")
    ap.add_argument("--memory-limit-gb", type=float, default=None,
                    help="address-space limit of every run (RLIMIT_AS) [none]")
    ap.add_argument("--blas-threads", type=int, default=1, help="BLAS threads of the striptri runs [1]")
    ap.add_argument("--data-dir", type=Path, default=scale_cases.default_data_dir(),
                    help=f"where the cases are built and the runs write [{scale_cases.default_data_dir()}]")
    ap.add_argument("--json", type=Path, help="every measurement [DATA_DIR/bench_scale.json]")
    args = ap.parse_args(argv)
    args.cases = args.cases or list(scale_cases.QUICK_CASES if args.quick else scale_cases.DEFAULT_CASES)
    args.repeats = per_case(args.repeats, int, 1, ap)
    args.time_limit = per_case(args.time_limit, float, 1800.0, ap)
    args.threads = args.threads or ([1] if args.quick else [1, 2])
    args.tolerances = args.tolerances or (["ceres-default", "1e-10"] if args.quick else list(colmap_ba.TOLERANCES))
    args.json = args.json or args.data_dir / "bench_scale.json"
    return args


def per_case(values: list[str] | None, kind, default, ap) -> dict:
    """["600", "close-range=900"] -> {None: 600, "close-range": 900} (None: every other case)."""
    out = {None: default}
    for v in values or []:
        name, _, number = v.rpartition("=")
        if name and name not in scale_cases.CASES:
            ap.error(f"unknown case {name!r} in {v!r}")
        try:
            out[name or None] = kind(number)
        except ValueError:
            ap.error(f"not a number: {v!r}")
    return out


def for_case(setting: dict, name: str):
    return setting.get(name, setting[None])


# --------------------------------------------------------------------------- environment

def machine() -> dict:
    cpu = "?"
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return {"cores": os.cpu_count(), "cpu": cpu, "memory_gib": round(mem, 1), "python": platform.python_version()}


def versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("numpy", "scipy", "scikit-sparse", "matplotlib", "pycolmap"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def child_env(blas_threads: int) -> dict:
    """The environment of every run: BLAS threads, this checkout's striptri, and byte-compiled
    modules. A ``pip install`` compiles every module once; a run from a source tree with
    PYTHONDONTWRITEBYTECODE (set in some sandboxes) would compile every striptri module in every run
    (0.15-0.2 s), so the bytecode goes to PYCACHE_DIR instead, written by the first run (the
    import measurement, import_seconds, which runs before any timed run)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(PYCACHE_DIR)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = str(blas_threads)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def _limit_memory(gb: float | None):
    if gb is None:
        return None

    def apply():
        limit = int(gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return apply


TREE_SAMPLE_S = 0.01  # how often the resident memory of a run's process tree is summed


def _children(pid: int) -> list[int]:
    """The child processes of pid (every thread's children)."""
    out = []
    try:
        for task in os.scandir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task.name}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


def _tree_rss_mib(root: int) -> float:
    """The resident memory of a process and all its descendants (MiB), summed: the run's command
    and the processes it started, also those in a session of their own (striptri's drawing
    worker, report.drawing, and its twin). A child that still runs its parent's program, other than
    the drawing worker's twin (the moment between a fork or vfork and the exec of a new program,
    or a fork that goes on without one: striptri's early reader, io.early_read), counts with its
    private pages only (:func:`_private_kib`): it shares its parent's other pages, and counting
    them once more doubled a sample (a 5,000-photo bundle run at 790 MiB against 395 MiB in its
    other rounds, fifteenth round of issue 29), but the early reader's parse of the project
    (100-120 MB at 5,000 photos) is its own (twentieth round). The child of a vfork (subprocess
    starting a program) shares its parent's memory itself until its exec, which comes within
    milliseconds: it shows the parent's private pages, so a child of the parent's program counts
    only from FORK_MIN_AGE_S on (counting a vfork's child doubled samples to 618-821 MiB)."""
    total, todo, seen = 0, [root], set()
    while todo:
        pid = todo.pop()
        if pid in seen:
            continue
        seen.add(pid)
        rss = _rss_kib(pid)
        if rss is None:
            continue
        total += rss
        children = _children(pid)
        command = _command_line(pid)
        if children and command and b"striptri.report.drawing" not in command:
            for child in children:
                if _command_line(child) == command:  # a fork without exec: its private pages (docstring)
                    seen.add(child)
                    if _age_s(child) >= FORK_MIN_AGE_S:  # not a vfork's child before its exec (docstring)
                        total += _private_kib(child)
                    children = children + _children(child)
        todo += children
    return total / 1024


FORK_MIN_AGE_S = 0.1  # _tree_rss_mib: a child of the parent's program counts from this age on


def _age_s(pid: int) -> float:
    """How long a process has run (s; 0 when it has gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            start = int(f.read().rsplit(")", 1)[1].split()[19]) / os.sysconf("SC_CLK_TCK")
        with open("/proc/uptime") as f:
            return float(f.read().split()[0]) - start
    except (OSError, ValueError, IndexError):
        return 0.0


def _rss_kib(pid: int) -> int | None:
    """VmRSS of a process, KiB (None when it has gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS"))
    except (OSError, ValueError, StopIteration):
        return None


def _private_kib(pid: int) -> int:
    """The pages a process does not share (Private_Clean + Private_Dirty of smaps_rollup), KiB."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            return sum(int(line.split()[1]) for line in f if line.startswith(("Private_Clean", "Private_Dirty")))
    except (OSError, ValueError):
        return 0


def _command_line(pid: int) -> bytes | None:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read()
    except OSError:
        return None


def _sample_tree(root: int, stop: threading.Event, peak: list) -> None:
    while not stop.wait(TREE_SAMPLE_S):
        peak[0] = max(peak[0], _tree_rss_mib(root))


def measured_run(cmd: list[str], env: dict, time_limit: float, memory_gb: float | None, time_file: Path) -> dict:
    """Run cmd under /usr/bin/time and timeout(1). -> wall s (this process' clock), peak MiB, CPU s
    (user + system), exit status, timed_out, the last line of stderr, the load average around it.

    The peak: the largest of /usr/bin/time's (the largest single process: the high-water mark, no
    sampling) and the sum of the resident memory of all the run's processes sampled every
    TREE_SAMPLE_S (``tree_peak_mib``: a command that draws its figures in a second process pays
    for both at once)."""
    full = [TIME, "-f", "%e %M %U %S", "-o", str(time_file),
            "timeout", "--foreground", "--signal=TERM", "--kill-after=10", f"{time_limit:.0f}"] + cmd
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(full, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_limit_memory(memory_gb))
    stop, tree_peak = threading.Event(), [0.0]
    sampler = threading.Thread(target=_sample_tree, args=(proc.pid, stop, tree_peak), daemon=True)
    sampler.start()
    try:
        out, err = proc.communicate(timeout=time_limit + 120)
    except subprocess.TimeoutExpired:  # timeout(1) itself did not end it: stop the group this run started
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
    except BaseException:  # e.g. Ctrl-C here: the run is in a session of its own, stop it too
        os.killpg(proc.pid, signal.SIGTERM)
        raise
    wall = time.perf_counter() - t0
    stop.set()
    sampler.join()
    # 124: ended by timeout's TERM; 137: killed 10 s later (a TERM is handled between Python bytecodes only)
    timed_out = proc.returncode == 124 or (proc.returncode == 137 and wall >= time_limit)
    rep = {"wall_s": wall, "exit_status": proc.returncode, "timed_out": timed_out,
           "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)], "stdout": out, "stderr_tail": ""}
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    if lines:
        rep["stderr_tail"] = lines[-1][:300]
    try:
        last = time_file.read_text().strip().splitlines()[-1].split()
        rep["peak_mib"] = int(last[1]) / 1024
        rep["cpu_s"] = float(last[2]) + float(last[3])
    except (OSError, IndexError, ValueError):
        pass
    rep["tree_peak_mib"] = tree_peak[0]
    rep["peak_mib"] = max(rep.get("peak_mib", 0.0), tree_peak[0])
    return rep


# --------------------------------------------------------------------------- the runs

def run_striptri(case_dir: Path, project: Path, method: str, args, truth, time_limit: float) -> dict:
    out = case_dir / f"out-{method}"
    if out.exists():
        shutil.rmtree(out)  # a previous run's output (this script made it)
    cmd = [sys.executable, "-m", "striptri", "adjust", str(project), "--out", str(out), "--method", method,
           "--keep-unconverged"]
    rep = measured_run(cmd, child_env(args.blas_threads), time_limit, args.memory_limit_gb,
                       case_dir / f"time-{method}.txt")
    rep["command"] = " ".join(["striptri"] + cmd[3:])
    rep.pop("stdout")
    summary = out / "summary.json"
    if rep["exit_status"] != 0 or not summary.is_file():
        rep["status"] = (f"stopped at the time limit ({time_limit:.0f} s)" if rep["timed_out"]
                         else f"failed (exit {rep['exit_status']}): {rep['stderr_tail']}")
        return rep
    s = json.loads(summary.read_text())
    t = dict(s["timings_s"])
    for old, new in BUNDLE_NAMES.items():
        if old in t:
            t[new] = t.pop(old)
    inner = sum(t.get(k, 0.0) for k in ("conditions", "assembly", "solve", "back_substitution", "final_checks"))
    t["adjust_other"] = max(t.get("total", 0.0) - inner, 0.0)
    t["remainder"] = rep["wall_s"] - t.get("total", 0.0) - sum(t.get(k, 0.0) for k in PIPELINE)
    rep.update(status="ok", phases=t, adjust_s=t.get("total"), iterations=s["iterations"], converged=s["converged"],
               vtpv=s["vtpv"], sigma0=s["sigma0"], redundancy=s["redundancy"], solver=s.get("solver"),
               rms_centres=scale_cases.rms_centres(out / "photos.csv", truth))
    return rep


_ADJUST_ALONE = """
import json, sys, time
t0 = time.perf_counter()
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io import read_project
project = read_project(sys.argv[1])
result = adjust(project, AdjustmentOptions(method=sys.argv[2], keep_unconverged=True))
print(json.dumps({"timings": result.timings.as_dict(), "iterations": result.iterations, "converged": bool(result.converged),
                  "vtpv": result.vtpv, "process_s": time.perf_counter() - t0}))
"""


def run_adjust_alone(case_dir: Path, project: Path, method: str, args, time_limit: float) -> dict:
    """adjust() alone (read_project, then striptri.adjustment.adjust), for a command that did not
    finish: how far the adjustment itself is from pycolmap."""
    cmd = [sys.executable, "-c", _ADJUST_ALONE, str(project), method]
    rep = measured_run(cmd, child_env(args.blas_threads), time_limit, args.memory_limit_gb,
                       case_dir / f"time-alone-{method}.txt")
    stdout = rep.pop("stdout").strip().splitlines()
    if rep["exit_status"] != 0 or not stdout:
        rep["status"] = (f"stopped at the time limit ({time_limit:.0f} s)" if rep["timed_out"]
                         else f"failed (exit {rep['exit_status']}): {rep['stderr_tail']}")
        return rep
    rep.update(json.loads(stdout[-1]), status="ok")
    rep["adjust_s"] = rep["timings"]["total"]
    return rep


def pycolmap_label(threads: int, tolerance: str) -> str:
    return f"pycolmap {threads} thread{'s' if threads > 1 else ''}, tolerance {tolerance}"


def run_pycolmap(case_dir: Path, data_file: Path, setting: tuple, covariance: bool, args, truth_xyz: np.ndarray,
                 time_limit: float) -> dict:
    """pycolmap's bundle adjustment with setting (Ceres threads, colmap_ba.TOLERANCES name)."""
    threads, tolerance = setting
    out = case_dir / f"colmap-{threads}-{tolerance}.npz"
    cmd = [sys.executable, str(HERE / "colmap_worker.py"), str(data_file), str(threads), str(out),
           "--tolerance", tolerance]
    if covariance:
        cmd.append("--covariance")
    rep = measured_run(cmd, child_env(threads), time_limit, args.memory_limit_gb,
                       case_dir / f"time-colmap-{threads}-{tolerance}.txt")
    stdout = rep.pop("stdout").strip().splitlines()
    if rep["exit_status"] != 0 or not stdout:
        rep["status"] = (f"stopped at the time limit ({time_limit:.0f} s)" if rep["timed_out"]
                         else f"failed (exit {rep['exit_status']}): {rep['stderr_tail']}")
        return rep
    worker = json.loads(stdout[-1])
    with np.load(out) as z:
        xyz0 = z["xyz0"]
    rep.update(status="ok", worker=worker, adjust_s=worker["seconds"], iterations=worker["iterations"],
               converged=worker["termination"] == "CONVERGENCE", vtpv=worker["vtpv"],
               ba_peak_mib=worker["peak_mib"], rms_centres=float(np.sqrt(np.mean(np.sum((xyz0 - truth_xyz) ** 2, 1)))))
    return rep


def prepare_colmap(project: Path, case: scale_cases.ScaleCase, data_file: Path, env: dict) -> float:
    """The ColmapData of the case, made in its own process (colmap_ba.py: striptri reads the
    project) -> the size of one dense covariance matrix in GB."""
    cmd = [sys.executable, str(HERE / "colmap_ba.py"), str(project), str(data_file)]
    if case.kind == "close":
        import close_range

        cmd += ["--format", *map(str, close_range.FORMAT), "--pixel-size", str(close_range.SIGMA_IMAGE)]
    done = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])["dense_covariance_bytes"] / 1e9


_LIST_MODULES = """
import json, sys
from striptri.cli import main
try:
    main([sys.argv[1], sys.argv[2], "--out", sys.argv[3]])
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m != "__main__")))
"""
_IMPORT = """
import importlib, json, sys
for name in json.loads(sys.argv[1]):
    try:
        importlib.import_module(name)
    except Exception:
        pass
"""


def import_seconds(project: Path, work: Path, env: dict, repeats: int = 3) -> dict:
    """Interpreter start and the imports of ``striptri adjust``, measured apart: the modules a run on
    ``project`` has loaded, imported in a fresh interpreter (median of ``repeats``)."""
    out = work / "out-imports"
    if out.exists():
        shutil.rmtree(out)
    listed = subprocess.run([sys.executable, "-c", _LIST_MODULES, "adjust", str(project), str(out)], env=env,
                            capture_output=True, text=True, check=True)
    modules = json.loads(listed.stdout.strip().splitlines()[-1])
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", _IMPORT, json.dumps(modules)], env=env, check=True)
        walls.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], env=env, check=True)
    return {"seconds": statistics.median(walls), "interpreter_seconds": time.perf_counter() - t0,
            "modules": len(modules), "all_seconds": walls}


def median_run(runs: list[dict]) -> dict:
    """The median of the successful runs: wall, CPU, peak, phases by their medians, the rest from
    the run of median wall time."""
    ok = [r for r in runs if r.get("status") == "ok"]
    if not ok:
        return dict(runs[-1], repeats=len(runs))
    order = sorted(ok, key=lambda r: r["wall_s"])
    med = dict(order[len(order) // 2])
    for key in ("wall_s", "cpu_s", "peak_mib", "adjust_s", "ba_peak_mib"):
        values = [r[key] for r in ok if r.get(key) is not None]
        if values:
            med[key] = statistics.median(values)
    if "phases" in med:
        med["phases"] = {k: statistics.median(r["phases"].get(k, 0.0) for r in ok) for k in med["phases"]}
    if "worker" in med and med["worker"].get("covariance"):
        covs = [r["worker"]["covariance"] for r in ok if r["worker"].get("covariance", {}).get("ok")]
        if covs:
            med["covariance_s"] = statistics.median(c["estimate_seconds"] + c["extract_seconds"] for c in covs)
    med["repeats"] = len(ok)
    med["all_wall_s"] = [r["wall_s"] for r in ok]
    return med


def run_case(name: str, args, log) -> dict:
    case = scale_cases.CASES[name]
    case_dir = args.data_dir / name
    t0 = time.perf_counter()
    project = scale_cases.build_case(case, args.data_dir, env=child_env(args.blas_threads))
    counts = scale_cases.summarise(project)
    truth = scale_cases.truth_centres(project)
    log(f"== {name}: {counts['photos']} photos, {counts['points']} points ({counts['full_control']} full control), "
        f"{counts['measurements']} measurements ({counts['measurements_per_photo']} per photo), rays per point "
        f"{counts['rays_per_point']['mean']} (min {counts['rays_per_point']['min']}, max {counts['rays_per_point']['max']}); "
        f"ready in {time.perf_counter() - t0:.1f} s")
    use_colmap = not args.no_pycolmap and scale_cases_pycolmap_available()
    cov_gb = None
    data_file = case_dir / "colmap.npz"
    if use_colmap:
        cov_gb = prepare_colmap(project, case, data_file, child_env(args.blas_threads))
        truth_xyz = np.array([truth[p] for p in _photo_ids(project)])  # ColmapData keeps the photos' order
    plan = run_plan(args.methods, [(t, tol) for t in args.threads for tol in args.tolerances] if use_colmap else [])
    covariance_wanted = use_colmap and not args.no_covariance and cov_gb <= args.covariance_max_gb
    runs: dict[str, list[dict]] = {}
    limit = for_case(args.time_limit, name)
    for _ in range(for_case(args.repeats, name)):
        for engine, what in plan:
            label = f"striptri {what}" if engine == "striptri" else pycolmap_label(*what)
            previous = runs.setdefault(label, [])
            if previous and previous[-1].get("status") != "ok":
                continue  # stopped or failed once: not again
            if engine == "striptri":
                rep = run_striptri(case_dir, project, what, args, truth, limit)
            else:
                rep = run_pycolmap(case_dir, data_file, what, False, args, truth_xyz, limit)
            previous.append(rep)
            log("   " + one_line(label, rep))
            if engine == "striptri" and rep["timed_out"]:
                rep["adjust_alone"] = alone = run_adjust_alone(case_dir, project, what, args, limit)
                log(f"   {label}, adjust() alone: " + (
                    f"{alone['adjust_s']:.2f} s, {alone['iterations']} it, vTPv {alone['vtpv']:.10g}, peak "
                    f"{alone['peak_mib']:.0f} MiB" if alone["status"] == "ok" else alone["status"]))
    result = {"case": name, "kind": case.kind, "n_photos": case.n_photos, "recipe": case.recipe(), "counts": counts,
              "runs": {label: median_run(v) for label, v in runs.items()}, "all_runs": runs}
    result["peer"] = best_peer(result)
    log(f"   the peer: {result['peer'] or 'no pycolmap run reached striptri solution'}")
    if covariance_wanted:  # a run of its own, after the timed ones: bundle adjustment, then the covariance
        tolerance = result["runs"][result["peer"]]["worker"]["tolerance"] if result["peer"] else args.tolerances[0]
        rep = run_pycolmap(case_dir, data_file, (1, tolerance), True, args, truth_xyz, limit)
        runs[COVARIANCE_RUN] = [rep]
        result["runs"][COVARIANCE_RUN] = median_run([rep])
        log("   " + one_line(COVARIANCE_RUN, rep))
    if use_colmap and not covariance_wanted and not args.no_covariance:
        result["covariance_skipped"] = (f"one dense matrix over the poses would take {cov_gb:.1f} GB "
                                        f"(> --covariance-max-gb {args.covariance_max_gb:g})")
    return result


def run_plan(methods: list[str], peer_settings: list[tuple]) -> list[tuple[str, object]]:
    """The runs of one round, in order: each striptri method right after a pycolmap run, never after
    another striptri run. A command that follows one of its own kind finds much of the memory it
    is about to touch still backed by the host (this VM hands a process's freed pages back to the
    host in the background, and touching a page anew costs 4-8 us): measured on the 5,000-photo
    block, its factorisations took 0.70-0.73 s right after another striptri run against 0.73-0.97 s
    (medians 0.86 and 0.88 s) right after pycolmap or after a 3 s pause; pycolmap's own time did
    not depend on what ran before it (docs/decisions.md "The benchmark's run order"). Until the
    eighteenth round of issue 29 the bundle method ran right after the method of conditions and
    had that advantage. The peer runs stay in their order, split into one stretch before each
    method (with fewer peer runs than methods, the last methods follow each other)."""
    if not peer_settings:
        return [("striptri", m) for m in methods]
    plan: list[tuple[str, object]] = []
    per = -(-len(peer_settings) // max(len(methods), 1))  # peer runs before each method (rounded up)
    for i, method in enumerate(methods):
        plan += [("pycolmap", s) for s in peer_settings[i * per:(i + 1) * per]] + [("striptri", method)]
    plan += [("pycolmap", s) for s in peer_settings[len(methods) * per:]]
    return plan


def _photo_ids(project: Path) -> list[str]:
    return scale_cases.read_columns(project / "photos.csv", ["photo_id"])["photo_id"]


def scale_cases_pycolmap_available() -> bool:
    from importlib.util import find_spec

    return find_spec("pycolmap") is not None


def one_line(label: str, rep: dict) -> str:
    load = "/".join(f"{x:.1f}" for x in rep.get("load_average", []))
    if rep.get("status") != "ok":
        peak = f", peak {rep['peak_mib']:.0f} MiB" if rep.get("peak_mib") else ""
        return f"{label}: {rep.get('status')} after {rep['wall_s']:.1f} s{peak} (load {load})"
    text = (f"{label}: {rep['wall_s']:.2f} s whole, {rep['adjust_s']:.2f} s adjust, peak {rep.get('peak_mib', 0):.0f} MiB, "
            f"{rep['iterations']} it, RMS centres {rep['rms_centres']:.5g} m, vTPv {rep['vtpv']:.10g} (load {load})")
    cov = rep.get("worker", {}).get("covariance")
    if cov:
        text += f"; covariance {cov['estimate_seconds']:.2f} + {cov.get('extract_seconds', 0):.2f} s"
    return text


# --------------------------------------------------------------------------- tables

def same_solution(a: dict, b: dict) -> tuple[bool, float]:
    """Two runs reach the same solution (issue 29): RMS centre error equal to 3 significant digits
    and v^T P v within 1e-6 relative. -> (same, relative difference of v^T P v)."""
    dv = abs(a["vtpv"] - b["vtpv"]) / b["vtpv"]
    return f"{a['rms_centres']:.3g}" == f"{b['rms_centres']:.3g}" and dv <= 1e-6, dv


def reference(result: dict) -> dict:
    """striptri's solution the peers are held to: the conditions method's run, else the bundle's."""
    for label in ("striptri conditions", "striptri bundle"):
        if result["runs"].get(label, {}).get("status") == "ok":
            return result["runs"][label]
    return {}


def best_peer(result: dict) -> str | None:
    """The label of the fastest pycolmap run (median bundle adjustment time) that reaches
    striptri's solution (same_solution), over the threads and tolerances swept; None when none does."""
    ref = reference(result)
    if not ref:
        return None
    fit = [(rep["adjust_s"], label) for label, rep in result["runs"].items()
           if label.startswith("pycolmap") and label != COVARIANCE_RUN and rep.get("status") == "ok"
           and same_solution(rep, ref)[0]]
    return min(fit)[1] if fit else None


def ratios(result: dict, label: str) -> dict:
    """The issue's ratios of one striptri run to the peer (best_peer)."""
    runs = result["runs"]
    s, p = runs.get(label, {}), runs.get(result.get("peer") or "", {})
    out = {}
    if s.get("status") == "ok":
        out["peak_gib"] = s["peak_mib"] / 1024
    if s.get("status") == "ok" and p.get("status") == "ok":
        # issue 29: the whole command against the peer's whole process, adjust() against its bundle adjustment
        out.update(whole_ratio=s["wall_s"] / p["wall_s"], adjust_ratio=s["adjust_s"] / p["adjust_s"],
                   memory_ratio=s["peak_mib"] / p["ba_peak_mib"])
        if s.get("cpu_s") and p["worker"].get("cpu_seconds"):
            out["whole_cpu_ratio"] = s["cpu_s"] / p["worker"]["cpu_seconds"]
    own = runs.get("striptri bundle", {})
    if label != "striptri bundle" and s.get("status") == "ok" and own.get("status") == "ok":
        out["own_bundle_ratio"] = s["wall_s"] / own["wall_s"]  # the same block by striptri's bundle method
    return out


def agreement(result: dict, label: str) -> str:
    runs = result["runs"]
    s, p = runs.get(label, {}), runs.get(result.get("peer") or "", {})
    if s.get("status") != "ok" or p.get("status") != "ok":
        return "-"
    same, dv = same_solution(s, p)
    return f"{'yes' if same else 'NO'} (vTPv {dv:.0e})"


def runs_table(results: list[dict]) -> str:
    head = ("| case | photos | run | iters | whole s | adjust() s | CPU s | peak MiB | RMS centres m | vTPv "
            "| whole / pycolmap | adjust() / pycolmap | memory / pycolmap | whole / pycolmap (CPU) | same accuracy |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for res in results:
        for label, rep in res["runs"].items():
            if rep.get("status") != "ok":
                lines.append(stopped_row(res, label, rep))
                continue
            it = f"{rep['iterations']}" + ("" if rep.get("converged", True) else " (not converged)")
            r = ratios(res, label) if label.startswith("striptri") else {}
            whole = rep["wall_s"]
            if label.startswith("pycolmap"):
                peak = f"{rep['peak_mib']:.0f} (BA {rep['ba_peak_mib']:.0f})"
            else:
                peak = f"{rep['peak_mib']:.0f}"
            lines.append(
                f"| {res['case']} | {res['n_photos']} | {label} | {it} | {whole:.2f} | {rep['adjust_s']:.2f} "
                f"| {rep.get('cpu_s', float('nan')):.2f} | {peak} | {rep['rms_centres']:.5g} | {rep['vtpv']:.10g} "
                f"| {_f(r.get('whole_ratio'))} | {_f(r.get('adjust_ratio'))} | {_f(r.get('memory_ratio'))} "
                f"| {_f(r.get('whole_cpu_ratio'))} "
                f"| {agreement(res, label) if label.startswith('striptri') else '-'} |")
    return "\n".join(lines)


def stopped_row(res: dict, label: str, rep: dict) -> str:
    """A run that did not finish: how long it ran, its peak so far and, when it was stopped at the
    time limit, adjust() alone."""
    peak = f"{rep['peak_mib']:.0f} (so far)" if rep.get("peak_mib") else "-"
    alone = rep.get("adjust_alone", {})
    p = res["runs"].get(res.get("peer") or "", {})
    adjust_s = vtpv = whole_ratio = adjust_ratio = same = ""
    if alone.get("status") == "ok":
        adjust_s = f"{alone['adjust_s']:.2f} (alone, {alone['iterations']} it)"
        vtpv = f"{alone['vtpv']:.10g}"
        if p.get("status") == "ok":
            adjust_ratio = f"{alone['adjust_s'] / p['adjust_s']:.2f}"
            dv = abs(alone["vtpv"] - p["vtpv"]) / p["vtpv"]
            same = f"{'yes' if dv < 1e-6 else 'NO'} (vTPv {dv:.0e}, adjust() alone)"
    if p.get("status") == "ok":
        whole_ratio = f"> {rep['wall_s'] / p['adjust_s']:.0f}"
    return (f"| {res['case']} | {res['n_photos']} | {label} | {rep.get('status')} | > {rep['wall_s']:.0f} "
            f"| {adjust_s} | | {peak} | | {vtpv} | {whole_ratio} | {adjust_ratio} | | | {same} |")


def sweep_table(results: list[dict]) -> str:
    """Every pycolmap run of the sweep (threads x Ceres tolerances) against striptri's solution
    (reference): the peer is the fastest that reaches it (best_peer)."""
    head = ("| case | Ceres threads | tolerances (function, gradient, parameter) | BA s | iterations | termination "
            "| RMS centres m | vTPv - striptri's (relative) | same solution | peer |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for res in results:
        ref = reference(res)
        for label, rep in res["runs"].items():
            if not label.startswith("pycolmap") or label == COVARIANCE_RUN:
                continue
            w = rep.get("worker", {})
            tol = w.get("tolerance", label.rsplit(" ", 1)[-1])
            triple = ", ".join(f"{v:g}" for v in colmap_ba.TOLERANCES.get(tol, ()))
            if rep.get("status") != "ok":
                lines.append(f"| {res['case']} | {label} | {tol} ({triple}) | {rep.get('status')} | | | | | | |")
                continue
            same, dv = same_solution(rep, ref) if ref else (False, float("nan"))
            lines.append(f"| {res['case']} | {w.get('threads')} | {tol} ({triple}) | {rep['adjust_s']:.2f} "
                         f"| {rep['iterations']} | {w.get('termination')} | {rep['rms_centres']:.5g} | {dv:.1e} "
                         f"| {'yes' if same else 'no'} | {'**peer**' if label == res.get('peer') else ''} |")
    return "\n".join(lines)


def _f(x, spec=".2f") -> str:
    return "-" if x is None else format(x, spec)


def phases_table(results: list[dict]) -> str:
    head = "| case | method | " + " | ".join(STRIPTRI_PHASES) + " | whole | dominant |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for res in results:
        for label, rep in res["runs"].items():
            if not label.startswith("striptri") or rep.get("status") != "ok":
                continue
            ph = rep["phases"]
            dominant = max(STRIPTRI_PHASES, key=lambda k: ph.get(k, 0.0))
            share = ph.get(dominant, 0.0) / rep["wall_s"]
            lines.append(f"| {res['case']} | {label.split()[1]} | " + " | ".join(
                f"{ph.get(k, 0.0):.2f}" for k in STRIPTRI_PHASES) + f" | {rep['wall_s']:.2f} | {dominant} ({share:.0%}) |")
    return "\n".join(lines)


def covariance_lines(results: list[dict]) -> list[str]:
    lines = []
    for res in results:
        p = res["runs"].get(COVARIANCE_RUN, {})
        cov = p.get("worker", {}).get("covariance") if p.get("status") == "ok" else None
        s = res["runs"].get("striptri conditions", {})
        peer = (f"striptri's point_precision {s['phases']['point_precision']:.2f} s, gross_errors (reliability) "
                f"{s['phases']['gross_errors']:.2f} s" if s.get("status") == "ok" else "striptri did not finish")
        if cov and cov.get("ok"):
            lines.append(f"{res['case']}: pycolmap covariance estimate {cov['estimate_seconds']:.2f} s + taking out "
                         f"{cov['poses']} pose and {cov['points']} point covariances {cov['extract_seconds']:.2f} s "
                         f"(peak {p['worker']['peak_with_covariance_mib']:.0f} MiB); {peer}")
        elif cov:
            lines.append(f"{res['case']}: pycolmap covariance estimate failed after {cov['estimate_seconds']:.2f} s; {peer}")
        elif res.get("covariance_skipped"):
            lines.append(f"{res['case']}: pycolmap covariance not run: {res['covariance_skipped']}; {peer}")
    return lines


def growth(results: list[dict]) -> dict:
    """Exponents b of y = a n^b (least squares in log-log) over the block cases run."""
    blocks = [r for r in results if r["case"] in scale_cases.BLOCK_SCALE]
    labels = sorted({label for r in blocks for label in r["runs"]})
    out = {}
    for label in labels:
        for key, name in (("wall_s", "whole time"), ("adjust_s", "adjust() / BA time"), ("peak_mib", "peak memory")):
            pts = [(r["n_photos"], r["runs"][label][key]) for r in blocks
                   if r["runs"].get(label, {}).get("status") == "ok" and r["runs"][label].get(key)]
            if len(pts) >= 2:
                x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
                out[f"{label}: {name}"] = {"exponent": float(np.polyfit(x, y, 1)[0]), "photos": [p[0] for p in pts]}
    return out


def targets(results: list[dict]) -> list[str]:
    by_case = {r["case"]: r for r in results}
    lines = []
    for case, only, key, limit, text in TARGETS:
        if case not in by_case:
            continue
        for method in ("conditions", "bundle") if only is None else (only,):
            label = f"striptri {method}"
            if label not in by_case[case]["runs"]:
                continue
            value = ratios(by_case[case], label).get(key)
            if value is None:
                state = by_case[case]["runs"][label].get("status", "?")
                lines.append(f"{case} {method}: {text}: not measured ({state})")
            else:
                met = value < limit if key == "peak_gib" else value <= limit
                unit = " GiB" if key == "peak_gib" else "x"
                lines.append(f"{case} {method}: {text}: {value:.2f}{unit} (limit {limit:g}) {'met' if met else 'NOT met'}")
    return lines


RUNS_NOTE = (
    "whole s: wall time of the whole process (striptri: the `striptri adjust` command; pycolmap: its worker, "
    "with the interpreter, loading and building the Reconstruction). adjust() s: striptri's adjustment "
    "(summary.json timings_s total); pycolmap: the bundle adjuster's set-up and solve. peak MiB: maximum "
    "resident set size of the process (/usr/bin/time); pycolmap's in brackets: up to the end of its "
    "bundle adjustment (VmHWM), the denominator of the memory ratio. CPU s: user + system time of the "
    "process. Ratios: to the peer, the fastest pycolmap run over the Ceres threads and tolerances swept that "
    "reaches striptri's solution (RMS centre error equal to 3 digits and vTPv within 1e-6; the sweep table) "
    "(the whole command against the peer's whole process, adjust() against its bundle adjustment, memory "
    "against its peak up to the end of the bundle adjustment; the CPU ratio: the whole command's CPU time to "
    "the peer's whole process's, steadier than wall time on a loaded machine)."
)
PHASES_NOTE = (
    "striptri's phases (s; summary.json timings_s, medians; for the bundle method the conditions column is "
    "its initial_points and assembly its linearisation_and_reduction (with the linearisation of each "
    "Gauss-Newton trial step since the ninth round of issue 29; before, back_substitution held it); "
    "adjust_other: the rest of the adjustment's total; remainder: whole wall time minus the phases, i.e. "
    "interpreter start, imports, writing the files; report: with a drawing worker, the wait for its figures):"
)


def report_text(results: list[dict], meta: dict) -> str:
    parts = [runs_table(results), "", RUNS_NOTE, "", "The peer's sweep (issue 29: Ceres at its best, not held to "
             "1e-16):", "", sweep_table(results), "", PHASES_NOTE, "", phases_table(results), ""]
    imp = meta.get("imports")
    if imp:
        parts += [f"Interpreter start and every import of `striptri adjust` ({imp['modules']} modules), measured apart "
                  f"in a fresh interpreter: {imp['seconds']:.2f} s (the interpreter alone {imp['interpreter_seconds']:.2f} s).",
                  ""]
    cov = covariance_lines(results)
    if cov:
        parts += ["Precision peers:"] + ["- " + c for c in cov] + [""]
    g = growth(results)
    if g:
        parts += ["Growth with the number of photos (exponent b of a n^b, log-log least squares):"]
        parts += [f"- {k}: {v['exponent']:.2f} (photos {', '.join(map(str, v['photos']))})" for k, v in g.items()]
        parts.append("")
    t = targets(results)
    if t:
        parts += ["The issue's targets (against the peer):"] + ["- " + x for x in t] + [""]
    loads = [x for r in results for v in r["all_runs"].values() for run in v for x in run.get("load_average", [])]
    if loads:
        parts.append(f"1-minute load average around the runs: {min(loads):.1f} to {max(loads):.1f} "
                     f"(median {statistics.median(loads):.1f}) on {meta['machine']['cores']} cores.")
    return "\n".join(parts)


def main(argv=None) -> int:
    args = parse_args(argv)
    if not Path(TIME).exists() or shutil.which("timeout") is None:
        print(f"needs {TIME} (GNU time) and timeout (coreutils)", file=sys.stderr)
        return 2
    args.data_dir.mkdir(parents=True, exist_ok=True)
    meta = {"command": " ".join(["python", "scripts/bench/bench_scale.py"] + (argv if argv is not None else sys.argv[1:])),
            "machine": machine(), "versions": versions(), "load_average_start": os.getloadavg(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "settings": {"repeats": {k or "*": v for k, v in args.repeats.items()}, "threads": args.threads,
                         "tolerances": args.tolerances,
                         "methods": args.methods, "time_limit_s": {k or "*": v for k, v in args.time_limit.items()},
                         "memory_limit_gb": args.memory_limit_gb,
                         "blas_threads": args.blas_threads}}
    print(f"machine: {meta['machine']}; versions: {meta['versions']}")
    print(f"load average at the start: {' '.join(f'{x:.2f}' for x in meta['load_average_start'])}", flush=True)
    if not args.no_pycolmap and not scale_cases_pycolmap_available():
        print("pycolmap not installed (pip install pycolmap): its runs are skipped")
    small = scale_cases.build_case(scale_cases.CASES["b100"], args.data_dir, env=child_env(args.blas_threads))
    meta["imports"] = import_seconds(small, args.data_dir / "b100", child_env(args.blas_threads))
    print(f"interpreter start and the imports of striptri adjust ({meta['imports']['modules']} modules, measured apart): "
          f"{meta['imports']['seconds']:.2f} s (the interpreter alone {meta['imports']['interpreter_seconds']:.2f} s)",
          flush=True)
    results = []
    t0 = time.perf_counter()
    for name in args.cases:
        results.append(run_case(name, args, lambda s: print(s, flush=True)))
        args.json.write_text(json.dumps({"meta": meta, "results": results}, indent=1, default=float))
    meta["seconds"] = time.perf_counter() - t0
    print()
    text = report_text(results, meta)
    print(text)
    print(f"\nbenchmark wall time {meta['seconds']:.0f} s; JSON: {args.json}")
    args.json.write_text(json.dumps({"meta": meta, "results": results, "growth": growth(results),
                                     "targets": targets(results)}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
