"""Run every shipped example through the command and compare its outputs with a saved snapshot.

A restructuring must not change a result (issue 27). This script runs ``striptri adjust`` (and, for
the synthetic strips, both methods and snooping) on every project under data/, and writes for
each run the CSV files and summary.json with the fields that change from run to run removed
(timings, the start time, the version, the project's absolute path). ``--save DIR`` writes a
snapshot; ``--against DIR`` compares with one, byte for byte, and exits 1 naming every difference.

    python scripts/check_outputs_unchanged.py --save /tmp/before     # on the old tree
    python scripts/check_outputs_unchanged.py --against /tmp/before  # on the new one
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VOLATILE = ("timings_s", "started", "version", "project", "blas", "factorisation")
RUNS = [(p, args) for p in sorted((ROOT / "data" / "synthetic_strips").iterdir()) if p.is_dir()
        for args in ([], ["--method", "bundle"], ["--blunders", "snoop"], ["--point-precision", "joint92"])]
RUNS += [(ROOT / "data" / "film_strip", []), (ROOT / "data" / "close_range", [])]


def _stable(summary: dict) -> dict:
    """summary.json without what differs between two runs of the same code."""
    out = {k: v for k, v in summary.items() if k not in VOLATILE}
    for h in out.get("history", []):
        h.pop("seconds", None)
    # a warning that names an input file names it by its absolute path: the tree's place is not the result
    out["warnings"] = [w.replace(str(ROOT), "<root>") for w in out.get("warnings", [])]
    return out


def _run(project: Path, args: list[str], into: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        run = subprocess.run(["striptri", "adjust", str(project), "--out", str(out), *args],
                             capture_output=True, text=True)
        into.mkdir(parents=True)
        (into / "exit_status").write_text(f"{run.returncode}\n")
        if not out.exists():
            return
        for f in sorted(out.glob("*.csv")):
            shutil.copy(f, into / f.name)
        summary = out / "summary.json"
        if summary.exists():
            text = json.dumps(_stable(json.loads(summary.read_text())), indent=1, sort_keys=True)
            (into / "summary.json").write_text(text + "\n")


def snapshot(folder: Path) -> None:
    for project, args in RUNS:
        name = project.name + ("_" + "_".join(a.strip("-") for a in args) if args else "")
        _run(project, args, folder / name)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path, help="write a snapshot into this (new) folder")
    group.add_argument("--against", type=Path, help="compare with the snapshot in this folder")
    args = parser.parse_args()
    if args.save:
        snapshot(args.save)
        print(f"snapshot of {len(RUNS)} runs in {args.save}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        now = Path(tmp) / "now"
        snapshot(now)
        before = {p.relative_to(args.against) for p in args.against.rglob("*") if p.is_file()}
        after = {p.relative_to(now) for p in now.rglob("*") if p.is_file()}
        differ = sorted(str(p) for p in before & after if (args.against / p).read_bytes() != (now / p).read_bytes())
        missing, extra = sorted(map(str, before - after)), sorted(map(str, after - before))
    for label, files in (("differs", differ), ("missing now", missing), ("new", extra)):
        for f in files:
            print(f"{label}: {f}")
    print(f"{len(RUNS)} runs, {len(before)} files: {len(differ)} differ, {len(missing)} missing, {len(extra)} new")
    return 1 if differ or missing or extra else 0


if __name__ == "__main__":
    sys.exit(main())
