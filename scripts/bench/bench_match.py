"""``striptri match`` on rendered blocks against COLMAP's own pipeline (issue 28).

    python scripts/bench/bench_match.py [--photos 24,100,400] [--size 3000x2000] [--scale 0.5]
                                        [--features 8000] [--work DIR] [--no-colmap] [--limit S]

Each block is rendered once by ``striptri simulate block --images`` (JPEG quality 90, noise 2 grey
levels; 24 photos: 3 strips of 8, 100: 5 of 20, 400: 10 of 40) into --work, where later runs find
it again. Then, each in its own process (its peak memory its own, os.wait4):

* striptri: ``run_match`` (features at --scale on both cores, candidate pairs from the
  approximate orientations, verification, tracks, thinning, report), then ``striptri adjust
  --blunders snoop`` on its output (from images to an oriented block);
* COLMAP (pycolmap, if installed): SIFT at the same resolution (max_image_size) and number of
  features on all threads, matching and verification of the same candidate pairs
  (match_image_pairs), and its incremental mapping (orientations and points of its own).

Printed per block and tool: seconds per photo for the features, per pair for the matching, the
whole run, peak memory, tie points and rays per photo written (striptri thins to 3 x 3 cells of 4
per photo; COLMAP keeps every point it triangulates), and the growth exponents of time and memory
from block to block (t ~ n^k; a stopped run is left out). With --limit a run still going after S
seconds is stopped and reported with the stages it finished. The environment is the user's: no
thread variables are set.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

LAYOUT = {24: (3, 8), 100: (5, 20), 400: (10, 40)}  # photos -> (strips, photos per strip)
WORKER = Path(__file__).with_name("match_worker.py")


def measured(args: list[str], limit: float | None = None) -> tuple[str, float, float]:
    """Run args: -> (stdout, wall seconds, peak resident MB of the process). A run still going after
    ``limit`` seconds is stopped (SIGKILL); its output so far is returned and the wall time is the
    limit."""
    t = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    timer = threading.Timer(limit, proc.kill) if limit else None
    if timer:
        timer.start()
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    if timer:
        timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode == -signal.SIGKILL and limit:
        return out, limit, usage.ru_maxrss / 1024.0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed with exit status {proc.returncode}")
    return out, time.perf_counter() - t, usage.ru_maxrss / 1024.0


def rendered(work: Path, n: int, size: str) -> Path:
    """The rendered block of n photos (made once)."""
    strips, per = LAYOUT[n]
    folder = work / f"block{n}_{size}"
    if (folder / "photos.csv").is_file():
        return folder
    if folder.exists():
        shutil.rmtree(folder)
    t = time.perf_counter()
    subprocess.run(["striptri", "simulate", "block", "--strips", str(strips), "--photos", str(per), "--images",
                    "--image-size", size, "--image-noise", "2", "--jpeg-quality", "90", "--check-points", "4",
                    "--seed", "28", "--out", str(folder)], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    print(f"# rendered {n} photos of {size} px in {time.perf_counter() - t:.0f} s", flush=True)
    return folder


def run_case(work: Path, n: int, a) -> list[dict]:
    block = rendered(work, n, a.size)
    rows = []
    tools = ["striptri"] + ([] if a.no_colmap else ["colmap"])
    for tool in tools:
        out = work / f"out{n}_{tool}"
        if out.exists():
            shutil.rmtree(out)
        text, wall, peak = measured([sys.executable, str(WORKER), tool, str(block), str(block / "images"), str(out),
                                     str(a.scale), str(a.features)], a.limit)
        lines = text.strip().splitlines()
        # a stopped run: the stages it finished (none printed: stopped in its first stages)
        r = json.loads(lines[-1]) if lines else {"seconds": {}, "photos": n, "pairs": 0, "verified": 0, "matches": 0,
                                                 "tie_points": 0, "rays": 0, "stopped": "features or pair matching"}
        r.update(tool=tool, n=n, wall=wall, peak=peak)
        if tool == "striptri" and "stopped" not in r:
            adjusted = work / f"adj{n}"
            if adjusted.exists():
                shutil.rmtree(adjusted)
            _, r["adjust_s"], r["adjust_peak"] = measured(["striptri", "adjust", str(out), "--blunders", "snoop",
                                                           "--out", str(adjusted)])
            summary = json.loads((adjusted / "summary.json").read_text())
            r["registered"] = summary["n_photos"] if summary["converged"] else 0
        rows.append(r)
        print(_line(r), flush=True)
    return rows


HEADER = ("| photos | tool | features s/photo | pairs (verified) | matching ms/pair | later stages s | whole s | "
          "peak MB | tie points/photo | rays/photo | photos oriented | then adjust s |")


def _line(r: dict) -> str:
    s = r["seconds"]
    later = r["wall"] - s.get("features", 0.0) - s.get("pair matching", 0.0)
    adjust = f"{r['adjust_s']:.1f}" if "adjust_s" in r else ""
    tool = r["tool"] + (f" (stopped at {r['wall']:.0f} s in its {r['stopped']})" if "stopped" in r else "")
    return (f"| {r['n']} | {tool} | {s.get('features', float('nan')) / r['photos']:.2f} | "
            f"{r['pairs']} ({r['verified']}) | {1000 * s.get('pair matching', float('nan')) / max(r['pairs'], 1):.0f} | "
            f"{later:.1f} | {r['wall']:.1f} | {r['peak']:.0f} | {r['tie_points'] / r['photos']:.0f} | "
            f"{r['rays'] / r['photos']:.0f} | {r.get('registered', '')} | {adjust} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", default="24,100,400")
    parser.add_argument("--size", default="3000x2000")
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--features", type=int, default=8000)
    parser.add_argument("--work", default="/tmp/striptri-bench-match")
    parser.add_argument("--no-colmap", action="store_true")
    parser.add_argument("--limit", type=float, default=None,
                        help="stop a run after this many seconds (its finished stages are reported)")
    a = parser.parse_args()
    if not a.no_colmap and importlib.util.find_spec("pycolmap") is None:
        sys.exit("pycolmap is not installed (pip install pycolmap), or give --no-colmap")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"# {a.size} px, features at scale {a.scale}, {a.features} features per photo; cores: {os.cpu_count()}")
    print(HEADER)
    print("|" + " --- |" * (HEADER.count("|") - 1))
    rows = []
    for n in (int(v) for v in a.photos.split(",")):
        rows += run_case(work, n, a)
    print("\n# growth exponents (t ~ n^k) between consecutive blocks")
    for tool in sorted({r["tool"] for r in rows}):
        mine = [r for r in rows if r["tool"] == tool and "stopped" not in r]
        for r1, r2 in zip(mine, mine[1:]):
            k = math.log(r2["n"] / r1["n"])
            print(f"{tool}: {r1['n']} -> {r2['n']} photos: time {math.log(r2['wall'] / r1['wall']) / k:.2f}, "
                  f"memory {math.log(r2['peak'] / r1['peak']) / k:.2f}")


if __name__ == "__main__":
    main()
