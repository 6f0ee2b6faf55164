"""The case builders of scripts/bench/bench_scale.py: the counts docs/benchmarks.md states, and a
close-range project that striptri reads and adjusts back to its truth. (No timings: the benchmark
is not a test.)"""

from __future__ import annotations

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
