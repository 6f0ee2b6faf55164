"""Benchmark of everything around the computation of ``striptri adjust``: reading the project, the
CSV tables, report.html (per section) and the import time, each for two source trees in the same
run (docs/benchmarks.md, "Reading, tables, report and imports").

    python scripts/bench/bench_output.py /work/benchdata/b5k /work/benchdata/b20k --base-src /tmp/base/src

PROJECT: project folders. The adjustment, the reliability measures and the point precision are
computed once per project (by the striptri on the path) and cached as a pickle (``--cache``); each
phase is then timed in its own process for every source tree (``--base-src``, e.g. ``git archive
COMMIT src | tar -x -C /tmp/base``, and this checkout's ``src``), alternating, ``--repeats`` times,
and the medians of CPU and wall seconds reported. The tables of both trees are compared byte for
byte. Without --base-src only this checkout is measured.

Phases: import (the sum of the top-level imports of a whole ``striptri adjust`` run of the shipped
strip8, python -X importtime), read (read_project), tables (format_csv of photos, cameras, points,
residuals; MB/s beside the time to write the same bytes to a file and fsync it), structure (the
normal matrix figure), report (html_report and its sections where the tree times them). The
figure phases start with matplotlib loaded (its import is in the phase "import").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
SRC = HERE.parents[2] / "src"
STRIP8 = HERE.parents[2] / "data" / "synthetic_strips" / "strip8"
TABLES = ("photos.csv", "cameras.csv", "points.csv", "residuals.csv")


# --------------------------------------------------------------------------- the worker (one phase, one tree)


def _snapshot(cache: Path):
    with open(cache, "rb") as f:
        return pickle.load(f)


def _tables(snap) -> dict:
    from striptri import pipeline

    det, points = snap["det"], snap["points"]
    return {
        "photos.csv": pipeline.photo_table(det.project, det.result),
        "cameras.csv": pipeline.camera_table(det.project, det.result),
        "points.csv": pipeline.point_table(det.project, det.result, points),
        "residuals.csv": pipeline.residual_table(snap["project"], det),
    }


def _timed(fn):
    c, w = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c, time.perf_counter() - w


def worker(phase: str, arg: str) -> dict:
    """Run one phase in this process (the tree on sys.path) -> a JSON-able dict."""
    if phase == "read":
        from striptri.io.project_reader import read_project

        project, cpu, wall = _timed(lambda: read_project(arg))
        return {"cpu": cpu, "wall": wall, "rows": len(project.image_points)}
    snap = _snapshot(Path(arg))
    if phase == "tables":
        from striptri.io.csvtable import format_csv

        out = {"cpu": 0.0, "wall": 0.0, "bytes": 0, "write": 0.0, "sha256": {}}
        for name, cols in _tables(snap).items():
            text, cpu, wall = _timed(lambda: format_csv(cols))
            data = text.encode("utf-8")
            with tempfile.NamedTemporaryFile(dir=os.environ.get("BENCH_TMP")) as f:
                _, _, write = _timed(lambda: (f.write(data), f.flush(), os.fsync(f.fileno())))
            out["cpu"] += cpu
            out["wall"] += wall
            out["bytes"] += len(data)
            out["write"] += write
            out["sha256"][name] = hashlib.sha256(data).hexdigest()
            out[f"{name} cpu"] = cpu
        return out
    from striptri.report import figures, html as report
    from striptri import pipeline

    # matplotlib loaded before the clock starts, in both trees (the phase "import" counts it)
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401
    import matplotlib.pyplot  # noqa: F401

    det, points = snap["det"], snap["points"]
    project, result = det.project, det.result
    summary = pipeline.summary_of(project, result, points)
    summary["blunders"] = pipeline.blunder_summary(det)
    summary["warnings"] = []
    try:  # the typed summary of the trees that have it (issue 27); a dict before
        from striptri.core.runs import RunSummary
    except ImportError:
        pass
    else:
        summary = RunSummary(**summary, version="bench", started="", project=None, options={})
    if phase == "structure":
        _, cpu, wall = _timed(lambda: figures.normal_matrix_structure(result.N, result.layout.block_starts(),
                                                                      len(project.photos)))
        return {"cpu": cpu, "wall": wall}
    if phase == "report":
        sections: dict = {}
        if hasattr(report, "ReportParts"):  # the trees since issue 27
            kwargs = {"parts": report.ReportParts(timings=sections)}
        else:
            kwargs = {"timings": sections} if "timings" in report.html_report.__code__.co_varnames else {}
        text, cpu, wall = _timed(lambda: report.html_report(project, result, summary, det.w[det.rows], points=points,
                                                            flags=det.flag[det.rows], **kwargs))
        return {"cpu": cpu, "wall": wall, "bytes": len(text.encode()), "sections": sections}
    raise ValueError(phase)


def import_seconds(src: Path) -> float:
    """Sum of the top-level imports of a whole `striptri adjust` run of strip8 (python -X importtime)."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "PYTHONPATH": str(src)}
        done = subprocess.run([sys.executable, "-X", "importtime", "-m", "striptri", "adjust", str(STRIP8), "--out",
                               str(Path(tmp) / "out")], env=env, capture_output=True, text=True, check=True)
    total = 0
    for line in done.stderr.splitlines():
        fields = line.split("|")
        if line.startswith("import time:") and fields[1].strip().isdigit():
            name = fields[2]
            if name.startswith(" ") and not name.startswith("  "):  # a top-level import: its cumulative time
                total += int(fields[1])
    return total / 1e6


# --------------------------------------------------------------------------- the driver


def make_snapshot(project_dir: Path, cache: Path) -> None:
    """Adjust (blunders off), reliability measures and point precision of a project, pickled."""
    code = (
        "import pickle, sys\n"
        "from striptri import pipeline\n"
        "from striptri.io.project_reader import read_project\n"
        "from striptri.reliability import BlunderOptions, detect_blunders\n"
        "project = read_project(sys.argv[1])\n"
        "det = detect_blunders(project, pipeline.options_for(project), BlunderOptions(method='off'))\n"
        "points = pipeline.triangulate_result(det.project, det.result)\n"
        "pickle.dump(dict(project=project, det=det, points=points), open(sys.argv[2], 'wb'), protocol=5)\n"
    )
    cache.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-c", code, str(project_dir), str(cache)], check=True,
                   env={**os.environ, "PYTHONPATH": str(SRC)})


def run_worker(src: Path, phase: str, arg: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, str(HERE), "--worker", phase, arg], env=env, capture_output=True,
                          text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def median(values) -> float:
    return float(statistics.median(values))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("projects", nargs="*", type=Path)
    ap.add_argument("--base-src", type=Path, help="the source tree to compare with (before)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "striptri-bench-output")
    ap.add_argument("--json", type=Path, help="write every measurement here")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(*args.worker)))
        return
    trees = {"before": args.base_src, "after": SRC} if args.base_src else {"after": SRC}
    every: dict = {"load": [], "trees": {k: str(v) for k, v in trees.items()}, "projects": {}}
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    imports = {k: [] for k in trees}
    for _ in range(args.repeats):
        for k, src in trees.items():
            imports[k].append(import_seconds(src))
    every["import"] = imports
    print("import (s, sum of top-level imports of a strip8 run): "
          + ", ".join(f"{k} {median(v):.3f}" for k, v in imports.items()))
    for project_dir in args.projects:
        cache = args.cache / f"{project_dir.name}.pkl"
        if not cache.exists():
            print(f"{project_dir.name}: adjusting once for the snapshot ({cache}) ...", flush=True)
            make_snapshot(project_dir, cache)
        runs: dict = {k: {p: [] for p in ("read", "tables", "structure", "report")} for k in trees}
        for _ in range(args.repeats):
            for phase in ("read", "tables", "structure", "report"):
                for k, src in trees.items():
                    runs[k][phase].append(run_worker(src, phase, str(project_dir if phase == "read" else cache)))
        every["projects"][project_dir.name] = runs
        every["load"].append(os.getloadavg()[0])
        print(f"\n{project_dir.name} (median of {args.repeats}; CPU s / wall s)")
        print("| phase | " + " | ".join(trees) + " |")
        print("|---|" + "---|" * len(trees))
        for phase in ("read", "tables", "structure", "report"):
            cells = [f"{median(r['cpu'] for r in runs[k][phase]):.3f} / {median(r['wall'] for r in runs[k][phase]):.3f}"
                     for k in trees]
            print(f"| {phase} | " + " | ".join(cells) + " |")
        for k in trees:
            t = runs[k]["tables"]
            mb = t[0]["bytes"] / 1e6
            print(f"{k}: tables {mb:.1f} MB, {mb / median(r['cpu'] for r in t):.0f} MB/s formatting (CPU); writing "
                  f"and fsync of the same bytes {mb / median(r['write'] for r in t):.0f} MB/s")
            sections = runs[k]["report"][-1].get("sections")
            if sections:
                print(f"{k}: report sections (wall s, last run): "
                      + ", ".join(f"{s} {v:.3f}" for s, v in sections.items() if v >= 0.001))
        if len(trees) == 2:
            a, b = (runs[k]["tables"][0]["sha256"] for k in trees)
            print("tables byte for byte equal: " + ", ".join(f"{n} {a[n] == b[n]}" for n in TABLES))
    print(f"\nload average during the run: {', '.join(f'{x:.1f}' for x in every['load'])}")
    if args.json:
        args.json.write_text(json.dumps(every, indent=1))


if __name__ == "__main__":
    main()
