"""Schmid's worked strip (BRL Report 961, section V, Fig. 8 and the table after it), built with the
generator and counted by the condition machinery itself.

Schmid: "a strip of 5 photographs with 2/3 overlap ... Twelve points are common to two photographs
and 18 points are common to three photographs. Consequently, we have (12 * 2 + 18 * 3) * 2 = 156
residuals"; his table lists the observational equations point by point, 77 in all, "for
n * 6 = 5 * 6 = 30 unknown parameters".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.cli import main
from striptri.equations.groups import build_batches, rays_per_point
from striptri.io import read_project
from striptri.geometry.rotations import R_from_opk
from striptri.simulate import ControlDesign, FlightDesign, NoiseOptions, SimulateOptions, SyntheticDesign, simulate_project

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "schmid_fig8"

# Schmid's table: point number -> number of observational equations.
SCHMID_EQUATIONS = {
    1: 4, 2: 1, 3: 2, 4: 1, 5: 1, 6: 1,
    **{p: 3 for p in range(7, 14)}, 14: 4, 15: 3, 16: 6, **{p: 3 for p in range(17, 25)},
    **{p: 1 for p in range(25, 30)}, 30: 4,
}
FLYING_HEIGHT = FlightDesign().flying_height


def fig8(seed: int = 8, sigma_image: float = 0.005):
    design = SyntheticDesign(flight=FlightDesign(n_photos=5, overlap=2 / 3), control=ControlDesign(layout="schmid-fig8"))
    return simulate_project("strip", SimulateOptions(design, NoiseOptions(sigma_image=sigma_image)), seed)


def conditions_per_point(project: model.Project) -> dict[str, int]:
    counts = {}
    for batch in build_batches(project):
        for p in batch.point_index:
            counts[project.points.ids[p]] = batch.n_conditions
    return counts


def true_photos(truth):
    photos = truth["photos.csv"]
    xyz0 = np.column_stack([photos[c] for c in ("X0", "Y0", "Z0")])
    R = R_from_opk(np.radians(np.column_stack([photos[c] for c in ("omega", "phi", "kappa")])))
    return xyz0, R


def test_schmid_table_sums_to_77():
    # the expected numbers come from his table; its own sum is his 77
    assert len(SCHMID_EQUATIONS) == 30 and sum(SCHMID_EQUATIONS.values()) == 77


def test_points_and_rays_as_in_figure_8():
    project, _ = fig8()
    assert len(project.photos) == 5 and len(project.points) == 30
    rays = dict(zip(project.points.ids, rays_per_point(project)))
    assert sorted(rays.values()).count(2) == 12 and sorted(rays.values()).count(3) == 18
    assert all(rays[str(p)] == 2 for p in [*range(1, 7), *range(25, 31)])
    assert all(rays[str(p)] == 3 for p in range(7, 25))
    # three full points (two seen twice, one three times), two height points (one twice, one thrice)
    kinds = dict(zip(project.points.ids, project.points.kind))
    full = sorted(rays[p] for p, k in kinds.items() if k == model.FULL)
    height = sorted(rays[p] for p, k in kinds.items() if k == model.HEIGHT)
    assert full == [2, 2, 3] and height == [2, 3]
    assert sum(k == model.TIE for k in kinds.values()) == 25


def test_156_residuals_and_77_equations_counted_by_the_machinery():
    project, _ = fig8()
    assert 2 * len(project.image_points) == 156 == (12 * 2 + 18 * 3) * 2
    batches = build_batches(project)
    assert sum(len(b) * b.n_conditions for b in batches) == 77
    assert conditions_per_point(project) == {str(p): n for p, n in SCHMID_EQUATIONS.items()}


def test_30_unknowns_and_the_noise_free_strip_recovers_the_truth():
    project, truth = fig8(sigma_image=0.0)
    result = adjust(project, AdjustmentOptions())
    assert result.n_unknowns == 30 == 5 * 6
    assert result.n_conditions == 77 and result.redundancy == 77 - 30
    assert result.n_observations == 156
    assert result.converged
    xyz0, R = true_photos(truth)
    assert np.abs(result.state.xyz0 + result.offset - xyz0).max() < 1e-9 * FLYING_HEIGHT
    # a rotation error of t rad moves the ground point below the camera by about t * flying height
    assert np.abs(result.state.R_ground_from_cam - R).max() < 1e-9


def test_noisy_strip_adjusts_with_a_finite_sigma0():
    project, _ = fig8(sigma_image=0.005)
    result = adjust(project, AdjustmentOptions())
    assert result.converged and result.redundancy == 47
    # sigma0 estimates the injected 0.005 mm (stated in the files) from 47 degrees of freedom: its
    # 99.9 % range is about 0.69 .. 1.34
    assert np.isfinite(result.sigma0) and 0.6 < result.sigma0 < 1.4


def test_the_committed_folder_has_the_same_counts():
    project = read_project(DATA)
    assert 2 * len(project.image_points) == 156
    assert sum(len(b) * b.n_conditions for b in build_batches(project)) == 77
    assert conditions_per_point(project) == {str(p): n for p, n in SCHMID_EQUATIONS.items()}


def test_cli_forces_five_photos_and_two_thirds_overlap(tmp_path):
    runner = CliRunner()
    ok = runner.invoke(main, ["simulate", "strip", "--out", str(tmp_path / "f8"), "--control", "schmid-fig8", "--seed", "8"])
    assert ok.exit_code == 0, ok.output
    assert "5 photos, 30 points, 78 plate measurements" in ok.output
    for args in (["--photos", "6"], ["--overlap", "0.6"], ["--extra-ties", "2"]):
        bad = runner.invoke(main, ["simulate", "strip", "--out", str(tmp_path / "bad"), "--control", "schmid-fig8", *args])
        assert bad.exit_code == 2 and "schmid-fig8" in bad.output, args
    block = runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "bad"), "--control", "schmid-fig8"])
    assert block.exit_code == 2
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_pattern_holds_for_other_seeds(seed):
    project, _ = fig8(seed=seed)
    assert conditions_per_point(project) == {str(p): n for p, n in SCHMID_EQUATIONS.items()}
