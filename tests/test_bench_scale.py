"""The case builders of scripts/bench/bench_scale.py: the counts docs/benchmarks.md states, and a
close-range project that striptri reads and adjusts back to its truth. (No timings: the benchmark
is not a test.)"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from striptri.geometry import lens
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io import read_project

BENCH = Path(__file__).resolve().parents[1] / "scripts" / "bench"
sys.path.insert(0, str(BENCH))

import close_range  # noqa: E402
import scale_cases  # noqa: E402


def test_close_range_has_the_documented_network():
    """115 photos, 150 targets, ~66 rays per target (the issue's real project), six full points."""
    net = close_range.make_close_range()
    rays = net.rays_per_target
    assert len(net.xyz0) == 115 and len(net.xyz_ground) == 150 and len(net.control) == 6
    assert len(net.photo_index) == scale_cases.DOCUMENTED["close-range"]["measurements"]
    assert 64 <= rays.mean() <= 68 and rays.min() >= 20
    again = close_range.make_close_range()  # deterministic
    assert np.array_equal(again.xy_plate, net.xy_plate) and np.array_equal(again.xyz0_approx, net.xyz0_approx)


def test_close_range_project_adjusts_back_to_its_truth(tmp_path):
    """The small close-range case written, read by striptri and adjusted (bundle, self-calibration):
    sigma0 near 1 and the camera and centres recovered within a few standard deviations, so the
    generator's conventions (rotations, image-convention distortion, ids) are striptri's."""
    case = scale_cases.CASES["close-small"]
    net = close_range.make_close_range(case.photos, case.strips_or_targets, seed=scale_cases.CLOSE_SEED)
    project = read_project(close_range.write_close_range(tmp_path / "p", net))
    counts = scale_cases.summarise(tmp_path / "p")
    assert {k: counts[k] for k in scale_cases.DOCUMENTED["close-small"]} == scale_cases.DOCUMENTED["close-small"]
    assert counts["measurements"] == len(net.photo_index)
    assert np.allclose(project.photos.R_ground_from_cam, net.R_approx, atol=1e-12)
    assert np.isinf(project.cameras.sigma_interior[0, [lens.C, lens.XP, lens.YP, lens.K1, lens.K2]]).all()
    result = adjust(project, AdjustmentOptions(method="bundle"))
    assert result.converged and 0.8 < result.sigma0 < 1.2
    cam = result.layout.camera_cols[0]
    free = cam >= 0
    estimated = result.state.interior[0][free]
    sigma = result.sigma0 * np.sqrt(result.covariance.diag()[cam[free]])
    assert np.all(np.abs(estimated - net.interior[free]) < 5 * sigma)
    centres = result.state.xyz0 + result.offset
    assert np.sqrt(np.mean(np.sum((centres - net.xyz0) ** 2, axis=1))) < 0.005  # m, from 0.05 m approximations


def test_block_case_has_the_documented_counts_and_full_control_only(tmp_path):
    """b1k: the issue's 1,000-photo block (striptri simulate ... --seed 11) with its height points
    turned into tie points."""
    project = scale_cases.build_case(scale_cases.CASES["b1k"], tmp_path)
    counts = scale_cases.summarise(project)
    assert {k: counts[k] for k in scale_cases.DOCUMENTED["b1k"]} == scale_cases.DOCUMENTED["b1k"]
    assert 2 <= counts["rays_per_point"]["min"] and counts["rays_per_point"]["max"] <= 6
    assert 28 <= counts["measurements_per_photo"] <= 31
    kinds = scale_cases.read_columns(project / "control.csv", ["kind"])["kind"]
    assert set(kinds) == {"XYZ"}
    assert scale_cases.build_case(scale_cases.CASES["b1k"], tmp_path) == project  # reused, not rebuilt


@pytest.mark.parametrize("name", ["b1k", "b5k", "b20k"])
def test_block_recipes_are_the_issue_commands(name):
    case = scale_cases.CASES[name]
    recipe = " ".join(case.recipe())
    assert recipe.startswith("striptri simulate block") and "--extra-ties 6 --control perimeter --seed 11" in recipe
    assert case.n_photos == {"b1k": 1000, "b5k": 5000, "b20k": 20000}[name]


FORKS = """
import os, sys, time
import numpy as np
a = np.ones(12_500_000)  # 100 MB resident
if sys.argv[1] in ("fork", "fork-own"):  # a child that never execs: the parent's pages
    pid = os.fork()
    if pid == 0:
        if sys.argv[1] == "fork-own":  # and 50 MB of its own (striptri's early reader)
            b = np.ones(6_250_000)
        time.sleep(0.2)  # older than a vfork's child before its exec (bench_scale.FORK_MIN_AGE_S)
        print("ready", flush=True)
        time.sleep(30)
        os._exit(0)
    time.sleep(30)
    sys.exit()
else:  # a child that runs a program of its own, with 60 MB of its own
    import subprocess
    subprocess.Popen([sys.executable, "-c", "import numpy as np, time; b = np.ones(7_500_000); time.sleep(30)"])
print("ready", flush=True)
time.sleep(30)
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="the tree is read from /proc")
@pytest.mark.parametrize("kind", ["fork", "fork-own", "exec"])
def test_the_process_tree_counts_a_forked_child_once_and_an_execd_one_apart(kind):
    """bench_scale._tree_rss_mib: a child that still runs its parent's program (between a fork and
    an exec, or a fork that never execs) shares the parent's pages and adds only its own private
    pages (the early reader's parse of the project); a child that runs a program of its own adds its
    own resident memory."""
    import subprocess
    import time

    import bench_scale

    proc = subprocess.Popen([sys.executable, "-c", FORKS, kind], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        def rss(pid):
            with open(f"/proc/{pid}/status") as f:
                return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024
        children = []
        for _ in range(100):  # the exec'd child's own 60 MB, once it has them
            children = bench_scale._children(proc.pid)
            if children and (kind == "fork" or rss(children[0]) > 60):
                break
            time.sleep(0.1)
        assert len(children) == 1
        tree, parent = bench_scale._tree_rss_mib(proc.pid), rss(proc.pid)
        if kind == "fork":
            assert rss(children[0]) > 90  # the shared pages show in the child's own count
            assert tree == pytest.approx(parent, abs=5)
        elif kind == "fork-own":
            assert tree == pytest.approx(parent + 48, abs=5)  # 50 MB = 47.7 MiB of its own
        else:
            assert tree == pytest.approx(parent + rss(children[0]), abs=5)
            assert tree > parent + 60
    finally:
        for pid in bench_scale._children(proc.pid):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("methods", [["conditions", "bundle"], ["conditions"], ["bundle", "conditions"]])
@pytest.mark.parametrize("n_peer", [0, 2, 3, 10])
def test_each_striptri_run_follows_a_pycolmap_run(methods, n_peer):
    """bench_scale.run_plan: every run of the round once, the peer's in their order, and each
    striptri method right after a pycolmap run (a striptri run right after another finds its
    memory still warm: the 5,000-photo block's factorisations took 0.70-0.73 s there against a
    median 0.86 s after pycolmap), except where there are fewer peer runs than methods."""
    import bench_scale

    peers = [(t, tol) for t in (1, 2) for tol in ("ceres-default", "1e-8", "1e-10", "1e-12", "1e-16")][:n_peer]
    plan = bench_scale.run_plan(methods, peers)
    every = [("striptri", m) for m in methods] + [("pycolmap", s) for s in peers]
    assert sorted(map(str, plan)) == sorted(map(str, every))
    assert [what for engine, what in plan if engine == "pycolmap"] == peers
    assert [what for engine, what in plan if engine == "striptri"] == methods
    for i, (engine, _) in enumerate(plan):
        if engine == "striptri" and n_peer >= len(methods):
            assert i > 0 and plan[i - 1][0] == "pycolmap", plan
