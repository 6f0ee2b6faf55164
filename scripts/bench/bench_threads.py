"""Threads in a user's environment (issues 26 and 29): the whole ``striptri adjust`` of a block, run
interleaved in several settings, medians of the repeats.

* ``plain``: the environment as a user has it (no OPENBLAS_NUM_THREADS, no STRIPTRI_THREADS);
  striptri sets the threads itself (solvers.threads): the chunks of every sweep on all cores,
  one BLAS thread each, the factorisation on FACTORISATION_THREADS;
* ``--threads 1``: everything on one core (the chunks in the main thread);
* ``OPENBLAS_NUM_THREADS=1``: what .ci/run and the other benchmarks set;
* ``STRIPTRI_THREADS=2``: the chunks on two threads (a ceiling: the factorisation keeps one);
* ``STRIPTRI_FACTORISATION_THREADS=2``: the sparse factorisation on two BLAS threads.

    python scripts/bench/bench_threads.py [--photos 100 --strips 50] [--repeats 3] [--solver cholmod]

Prints one table: the whole command (wall clock) and each phase of summary.json's timings_s,
median over the repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

ENVIRONMENTS = {  # name: (environment, command-line options)
    "plain": ({}, []),
    "--threads 1": ({}, ["--threads", "1"]),
    "OPENBLAS_NUM_THREADS=1": ({"OPENBLAS_NUM_THREADS": "1"}, []),
    "STRIPTRI_THREADS=2": ({"STRIPTRI_THREADS": "2"}, []),
    "STRIPTRI_FACTORISATION_THREADS=2": ({"STRIPTRI_FACTORISATION_THREADS": "2"}, []),
}
PHASES = ("conditions", "assembly", "solve", "gross_errors", "point_precision", "final_checks", "tables", "report")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photos", type=int, default=100)
    ap.add_argument("--strips", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--solver", default="cholmod")
    ap.add_argument("--settings", nargs="+", choices=list(ENVIRONMENTS), default=list(ENVIRONMENTS))
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-threads-"))
    project = work / "block"
    subprocess.run(["striptri", "simulate", "block", "--photos", str(args.photos), "--strips", str(args.strips),
                    "--extra-ties", "6", "--control", "perimeter", "--seed", "11", "--out", str(project)],
                   check=True, capture_output=True)
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "STRIPTRI_THREADS",
                                                             "STRIPTRI_FACTORISATION_THREADS", "OMP_NUM_THREADS")}
    times: dict[str, list] = {name: [] for name in args.settings}
    for _ in range(args.repeats):
        for name in args.settings:
            extra, options = ENVIRONMENTS[name]
            out = work / "out"
            shutil.rmtree(out, ignore_errors=True)
            t0 = time.perf_counter()
            subprocess.run(["striptri", "adjust", str(project), "--out", str(out), "--solver", args.solver, "--quiet",
                            *options], check=True, env={**base, **extra}, capture_output=True)
            whole = time.perf_counter() - t0
            t = json.loads((out / "summary.json").read_text())["timings_s"]
            times[name].append((whole, *(t.get(p, float("nan")) for p in PHASES)))
    n = args.photos * args.strips
    print(f"{n:,}-photo block, solver {args.solver}, median of {args.repeats} interleaved runs, "
          f"load {os.getloadavg()[0]:.2f}")
    print("| setting | whole command (s) | " + " | ".join(p.replace("_", " ") for p in PHASES) + " |")
    print("| --- " * (len(PHASES) + 2) + "|")
    for name, rows in times.items():
        med = [statistics.median(r[i] for r in rows) for i in range(len(PHASES) + 1)]
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in med) + " |")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
