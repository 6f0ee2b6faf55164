"""striptri's whole command against the peer's, in pairs of runs (issue 29).

On a shared machine the load moves a 5-second run by a fifth between minutes, more than the
distance to a target. bench_scale.py compares medians taken over minutes; this script runs the
peer (pycolmap's bundle adjustment with the threads and tolerances given, by default bench_scale's
best peer at 5,000 photos: 2 threads, 1e-10) and then one striptri command, again and again, and
takes the ratio of each pair, whose two runs shared the machine's state of that moment. Each
striptri run follows a peer run, as in bench_scale.py (docs/decisions.md "The benchmark's run
order"). The cases are bench_scale.py's, made by it (its cache).

    python scripts/bench/bench_pairs.py --case b5k --pairs 7 --methods conditions bundle
    python scripts/bench/bench_pairs.py --case b5k --pairs 6 --methods bundle --against /path/to/other/src

``--against SRC``: each round also runs the striptri found in SRC (on PYTHONPATH), after its own peer
run, so that two versions are compared pair by pair.

The table gives, beside the median ratio, a distribution-free interval for it (the order statistics
that the sign test puts around a median: ``median_interval``, 95 % or the nearest above) and how
many pairs are below 1.0 with the one-sided sign test's p-value for "the median ratio is below 1"
(``sign_test_below``): whether a target of 1.0x is met beyond the machine's noise, not only in the
median. Beside it, pair by pair, striptri's adjust() (summary.json's total) over the peer's bundle
adjustment (``peer_seconds``): bench_scale.py's adjust() ratio, with its median's interval.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_scale as bs  # noqa: E402


def peer_seconds(peer: dict) -> float:
    """The peer's bundle adjustment alone (set-up and solve: colmap_worker.py's ``seconds``, the
    denominator of bench_scale.py's adjust() ratio), from its run's last line of output."""
    lines = peer.get("stdout", "").strip().splitlines()
    return float(json.loads(lines[-1])["seconds"]) if lines else float("nan")


def peer_run(case_dir: Path, threads: int, tolerance: str, scratch: Path) -> dict:
    command = [sys.executable, str(bs.HERE / "colmap_worker.py"), str(case_dir / "colmap.npz"), str(threads),
               str(scratch / "peer.npz"), "--tolerance", tolerance]
    return bs.measured_run(command, bs.child_env(threads), 3600, None, scratch / "peer.time")


def striptri_run(case_dir: Path, method: str, source: str | None, scratch: Path) -> tuple[dict, dict]:
    out = scratch / "out"
    shutil.rmtree(out, ignore_errors=True)
    env = bs.child_env(1)
    if source:
        env["PYTHONPATH"] = source
    command = [sys.executable, "-m", "striptri", "adjust", str(case_dir / "project"), "--out", str(out),
               "--method", method]
    run = bs.measured_run(command, env, 3600, None, scratch / "striptri.time")
    return run, json.loads((out / "summary.json").read_text())["timings_s"]


def _binomial_cdf(k: int, n: int) -> float:
    """P(X <= k) for X ~ Binomial(n, 1/2)."""
    return sum(math.comb(n, i) for i in range(k + 1)) / 2**n if k >= 0 else 0.0


def median_interval(values, level: float = 0.95) -> tuple[float, float, float]:
    """(low, high, coverage): the order statistics ``x_(k)``, ``x_(n+1-k)`` of ``values`` around their
    median, with the largest k whose coverage ``1 - 2 P(Bin(n, 1/2) <= k - 1)`` is at least
    ``level`` (the sign test's interval: no assumption on the distribution); the smallest and the
    largest value, with their coverage, when too few values reach ``level``."""
    x = sorted(values)
    n = len(x)
    if n == 0:
        return math.nan, math.nan, 0.0
    k = 1
    while k + 1 <= (n + 1) // 2 and 1.0 - 2.0 * _binomial_cdf(k, n) >= level:
        k += 1
    return x[k - 1], x[n - k], 1.0 - 2.0 * _binomial_cdf(k - 1, n)


def sign_test_below(values, limit: float = 1.0) -> tuple[int, float]:
    """(pairs below ``limit``, the one-sided sign test's p-value for "the median is below limit":
    P(Bin(n', 1/2) >= below) over the n' values not equal to limit)."""
    below = sum(v < limit for v in values)
    n = sum(v != limit for v in values)
    return below, 1.0 - _binomial_cdf(below - 1, n)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", default="b5k", help="a case of bench_scale.py, made there (default b5k)")
    parser.add_argument("--pairs", type=int, default=7)
    parser.add_argument("--methods", nargs="+", default=["conditions", "bundle"])
    parser.add_argument("--peer-threads", type=int, default=2)
    parser.add_argument("--peer-tolerance", default="1e-10")
    parser.add_argument("--against", default=None, help="another striptri's src folder, run in each round too")
    args = parser.parse_args(argv)
    case_dir = bs.scale_cases.default_data_dir() / args.case
    if not (case_dir / "colmap.npz").exists():
        sys.exit(f"{case_dir} has no colmap.npz: run bench_scale.py --cases {args.case} first")
    versions = {"this": None, **({"against": args.against} if args.against else {})}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        for k in range(args.pairs):
            for method in args.methods:
                for version, source in versions.items():
                    peer = peer_run(case_dir, args.peer_threads, args.peer_tolerance, scratch)
                    mine, timings = striptri_run(case_dir, method, source, scratch)
                    rows.append(dict(method=method, version=version, ratio=mine["wall_s"] / peer["wall_s"],
                                     striptri=mine["wall_s"], peer=peer["wall_s"], peak=mine["peak_mib"],
                                     peer_peak=peer["peak_mib"], report=timings.get("report", float("nan")),
                                     adjust_ratio=timings.get("total", float("nan")) / peer_seconds(peer)))
                    r = rows[-1]
                    print(f"pair {k + 1} {method} ({version}): striptri {r['striptri']:.2f} s, peer {r['peer']:.2f} s, "
                          f"ratio {r['ratio']:.3f}, peak {r['peak']:.0f} / {r['peer_peak']:.0f} MiB", flush=True)
    print()
    print("| method | version | pairs | whole / peer (median, range) | median's interval (coverage) | below 1.0 (p) "
          "| adjust() / peer's BA (median, interval) | striptri s | peer s | peak MiB (median, max) | memory / peer "
          "| report s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for method in args.methods:
        for version in versions:
            got = [r for r in rows if r["method"] == method and r["version"] == version]
            med = lambda key: statistics.median(r[key] for r in got)  # noqa: E731
            ratios = [r["ratio"] for r in got]
            low, high, coverage = median_interval(ratios)
            below, p = sign_test_below(ratios)
            a_low, a_high, _ = median_interval([r["adjust_ratio"] for r in got])
            print(f"| {method} | {version} | {len(got)} | {med('ratio'):.3f} ({min(ratios):.3f}-{max(ratios):.3f}) "
                  f"| {low:.3f}-{high:.3f} ({100 * coverage:.0f} %) | {below} of {len(got)} (p {p:.3f}) "
                  f"| {med('adjust_ratio'):.3f} ({a_low:.3f}-{a_high:.3f}) "
                  f"| {med('striptri'):.2f} | {med('peer'):.2f} | {med('peak'):.0f}, {max(r['peak'] for r in got):.0f} "
                  f"| {statistics.median(r['peak'] / r['peer_peak'] for r in got):.3f} | {med('report'):.3f} |")


if __name__ == "__main__":
    main()
