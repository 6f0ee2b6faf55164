"""Schmid's method of conditions equals the collinearity bundle adjustment (DESIGN section 4).

The conditions method (no object points among the unknowns) and an independent bundle adjustment
(tests/reference_bundle.py: object points as unknowns, central-difference Jacobian, no code shared
with conditions/linearise/adjustment) minimise the same v^T P v over the same observations, so at
convergence they must give the same orientations, residuals, v^T P v, redundancy and precision.

Tolerances. Both adjustments stop when every correction is below 1e-10 of the standard deviation
the element would have if all others were known, so two converged solutions differ by round-off,
orders of magnitude below a standard deviation. We require differences below 1e-6 of a standard
deviation of each quantity (and at least the brief's figures: positions within 1e-6 of the flying
height, rotation matrices to 1e-9, v^T P v relative 1e-6). For noise-free data the truth is the
exact solution: recovered to 1e-9 (positions relative to the flying height, angles in radians).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from reference_bundle import bundle_adjust
from scipy.spatial.transform import Rotation
from synthetic_pairs import (
    NATIONAL_GRID,
    NoiseOptions,
    PairOptions,
    make_pair,
    mixed_points,
    schmid_minimal_points,
    strip_points,
)

from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.errors import NumericalFailure
from striptri.geometry.rotations import opk_from_R

H = 1500.0  # flying height of the synthetic pairs (m)
STAT = 1e-6  # agreement between two converged solutions, in standard deviations

# name -> (geometry, observation noise, adjustment options)
CASES = {
    "fixed control": (PairOptions(), NoiseOptions(), AdjustmentOptions()),
    "fixed control, Schmid's xz scales": (PairOptions(), NoiseOptions(), AdjustmentOptions.of(scale_form="xz")),
    "weighted control": (PairOptions(points=mixed_points(weighted=True)), NoiseOptions(), AdjustmentOptions()),
    "fixed and weighted, GNSS, national grid": (
        PairOptions(points=mixed_points(weighted="alternate"), grid_offset=NATIONAL_GRID),
        NoiseOptions(sigma_gnss=0.1),
        AdjustmentOptions(),
    ),
    "weighted control, GNSS": (
        PairOptions(points=mixed_points(n_tie=8, weighted=True)), NoiseOptions(sigma_gnss=0.05), AdjustmentOptions()
    ),
    "oblique omega 40 kappa 120": (
        PairOptions(nominal_opk_deg=(40.0, 0.0, 120.0)), NoiseOptions(), AdjustmentOptions()
    ),
    "horizontal view (phi 90), national grid": (
        PairOptions(scene_rotvec=(0.0, np.pi / 2, 0.0), grid_offset=NATIONAL_GRID),
        NoiseOptions(),
        AdjustmentOptions(),
    ),
    "strip of three (scale transfer)": (
        PairOptions(n_photos=3, points=strip_points()), NoiseOptions(), AdjustmentOptions()
    ),
    "strip of three, Schmid's xz scales": (
        PairOptions(n_photos=3, points=strip_points()), NoiseOptions(), AdjustmentOptions.of(scale_form="xz")
    ),
}
HAS_GNSS = {name for name, (_, noise, _) in CASES.items() if noise.sigma_gnss is not None}


def _photo_Q(result):
    """6x6 blocks of N^-1 per photo (a-priori sigma0 = 1), fixed elements zero."""
    cols = result.layout.photo_cols
    Qp = np.pad(result.Qxx, ((0, 1), (0, 1)))
    return Qp[cols[:, :, None], cols[:, None, :]]


def _rotation_angle(Ra, Rb):
    """Angle (rad) of the rotation between two attitudes, batched."""
    return np.linalg.norm(Rotation.from_matrix(np.swapaxes(Ra, -1, -2) @ Rb).as_rotvec(), axis=-1)


@pytest.fixture(scope="module")
def solved():
    """Both adjustments of every case, computed once."""
    out = {}
    for seed, (name, (geometry, noise, options)) in enumerate(CASES.items()):
        truth, project = make_pair(geometry, noise, seed=100 + seed)
        out[name] = (truth, project, adjust(project, options), bundle_adjust(project))
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_conditions_equal_bundle(solved, name):
    truth, project, res, ref = solved[name]
    assert res.converged and ref.converged
    # the same problem: counts
    assert res.redundancy == ref.redundancy > 0
    assert res.n_observations == ref.n_observations

    # orientations
    Q = _photo_Q(res)
    sig_xyz = np.sqrt(np.einsum("nii->ni", Q[:, :3, :3])) * res.sigma0
    dxyz = np.abs(res.state.xyz0 + res.offset - ref.xyz0)
    assert dxyz.max() < 1e-6 * H
    assert np.all(dxyz < STAT * sig_xyz)
    assert np.abs(res.state.R_ground_from_cam - ref.R_ground_from_cam).max() < 1e-9
    sig_rot = np.sqrt(np.einsum("nii->ni", Q[:, 3:, 3:])).min(axis=1) * res.sigma0
    assert np.all(_rotation_angle(res.state.R_ground_from_cam, ref.R_ground_from_cam) < STAT * sig_rot)

    # v^T P v, sigma0, residuals of every plate coordinate
    assert res.vtpv == pytest.approx(ref.vtpv, rel=1e-6)
    assert res.sigma0 == pytest.approx(ref.sigma0, rel=1e-6)
    sigma_xy = project.image_points.sigma_xy
    assert np.abs(res.plate_residuals - ref.plate_residuals).max() < STAT * sigma_xy.min()

    # adjusted weighted control = the bundle's estimate of those coordinates
    weighted = np.isfinite(project.points.sigma_given)
    if weighted.any():
        d = np.abs(res.control_adjusted + res.offset - ref.points)[weighted]
        assert np.all(d < STAT * project.points.sigma_given[weighted])

    # precision: N^-1 of the conditions = photo blocks of the bundle's (J^T J)^-1 (Schur complement)
    d = np.sqrt(np.einsum("nii->ni", Q))
    corr_diff = np.abs(Q - ref.Q_photo) / (d[:, :, None] * d[:, None, :])
    assert corr_diff.max() < 1e-6  # limited by the bundle's central-difference Jacobian


@pytest.mark.parametrize("name", list(CASES))
def test_schmid_final_checks(solved, name):
    """Schmid (58-59) after convergence: B^T k = 0, v^T P v = [LL.u], every condition (including
    the observation equations of observed centres) satisfied by the adjusted observations."""
    _, _, res, _ = solved[name]
    assert res.checks.max_BTk_sigma < 1e-8
    assert res.checks.vtpv_reduction_relative_difference < 1e-8
    assert res.checks.max_condition_misclosure_sigma < 1e-8


def test_case_coverage(solved):
    """The cases contain what their names promise (guards against a generator that drifts)."""
    kinds_seen = set()
    single_photo_full = False
    for _, project, _, _ in solved.values():
        counts = np.bincount(project.image_points.point_index, minlength=len(project.points))
        kinds_seen |= set(project.points.kind.tolist())
        single_photo_full |= bool(np.any((project.points.kind == model.FULL) & (counts == 1)))
    assert kinds_seen >= {model.TIE, model.HEIGHT, model.PLAN, model.FULL}
    assert single_photo_full
    truth = solved["horizontal view (phi 90), national grid"][0]
    phi = np.degrees(np.arcsin(truth.R_ground_from_cam[:, 0, 2]))
    assert np.all(np.abs(phi) > 80.0)  # near the gimbal lock of omega-phi-kappa
    assert np.all(np.abs(truth.xyz0[:, 1]) > 4e6)
    truth = solved["oblique omega 40 kappa 120"][0]
    tilt = np.degrees(np.arccos(truth.R_ground_from_cam[:, 2, 2]))  # camera axis from the vertical
    assert np.all(tilt > 30.0)
    p = solved["strip of three (scale transfer)"][1]
    assert np.bincount(p.image_points.point_index).max() == 3


# ---------------------------------------------------------------------------------------------
# noise-free data: the truth is the solution

NOISE_FREE = {
    "fixed control": PairOptions(),
    "weighted control, GNSS, national grid": PairOptions(points=mixed_points(weighted=True), grid_offset=NATIONAL_GRID),
    "oblique omega 40 kappa 120": PairOptions(nominal_opk_deg=(40.0, 0.0, 120.0)),
    "horizontal view (phi 90)": PairOptions(scene_rotvec=(0.0, np.pi / 2, 0.0)),
    "looking up-side down (omega 180)": PairOptions(scene_rotvec=(np.pi, 0.0, 0.0)),
    "strip of three": PairOptions(n_photos=3, points=strip_points()),
}


def _assert_truth_recovered(res, truth):
    assert res.converged
    assert np.abs(res.state.xyz0 + res.offset - truth.xyz0).max() < 1e-9 * H
    assert _rotation_angle(res.state.R_ground_from_cam, truth.R_ground_from_cam).max() < 1e-9


@pytest.mark.parametrize("name", list(NOISE_FREE))
def test_noise_free_recovers_truth(name):
    gnss = 0.05 if "GNSS" in name else None
    truth, project = make_pair(NOISE_FREE[name], NoiseOptions(noisy=False, sigma_gnss=gnss), seed=7)
    start_error = _rotation_angle(project.photos.R_ground_from_cam, truth.R_ground_from_cam)
    assert start_error.max() > 0.01  # the approximations are really off (about a degree)
    res = adjust(project)
    _assert_truth_recovered(res, truth)
    assert res.vtpv < 1e-12 * res.redundancy


# ---------------------------------------------------------------------------------------------
# Schmid's minimal configuration: 12 conditions for 12 unknowns


def test_schmid_minimal_configuration_noise_free():
    truth, project = make_pair(PairOptions(points=schmid_minimal_points()), NoiseOptions(noisy=False), seed=3)
    res = adjust(project)
    assert res.n_conditions == 12 and res.n_unknowns == 12 and res.redundancy == 0
    _assert_truth_recovered(res, truth)


def test_schmid_minimal_configuration_is_unique_and_exact():
    """With noise the 12 conditions still have exactly one nearby solution: it fits the data
    exactly (v = 0), equals the bundle's (redundancy 0 too) and does not depend on the start."""
    _, project = make_pair(PairOptions(points=schmid_minimal_points()), NoiseOptions(), seed=3)
    res = adjust(project)
    assert res.redundancy == 0 and res.converged
    assert np.abs(res.plate_residuals).max() < 1e-9 * project.image_points.sigma_xy.min()
    ref = bundle_adjust(project)
    assert ref.redundancy == 0
    assert np.abs(res.state.xyz0 + res.offset - ref.xyz0).max() < 1e-9 * H
    assert np.abs(res.state.R_ground_from_cam - ref.R_ground_from_cam).max() < 1e-9
    # another start: approximate orientations moved by tens of metres and about a degree
    turn = Rotation.from_rotvec([[0.02, -0.015, 0.01], [-0.01, 0.02, -0.02]]).as_matrix()
    R_other = project.photos.R_ground_from_cam @ turn
    photos = replace(
        project.photos, xyz0=project.photos.xyz0 + [[40.0, -30.0, 20.0], [-25.0, 35.0, -30.0]],
        R_ground_from_cam=R_other, angles=opk_from_R(R_other),
    )
    res2 = adjust(replace(project, photos=photos))
    assert np.abs(res2.state.xyz0 + res2.offset - (res.state.xyz0 + res.offset)).max() < 1e-9 * H
    assert _rotation_angle(res2.state.R_ground_from_cam, res.state.R_ground_from_cam).max() < 1e-9


def test_schmid_minimal_configuration_minus_one_tie_point_is_refused():
    points = schmid_minimal_points()[:-1]
    _, project = make_pair(PairOptions(points=points), NoiseOptions(), seed=3)
    with pytest.raises(NumericalFailure, match="too few conditions"):
        adjust(project)


# ---------------------------------------------------------------------------------------------
# the result does not depend on how a group's conditions are scaled or recombined


class RandomRecombination:
    """condition_transform: seeded random invertible (m, nc, nc) matrices U diag(s) V (U, V random
    orthogonal, s from 10^-1.5 to 10^1.5), the same for a batch at every call. Counts its calls."""

    def __init__(self, seed: int):
        self.seed, self.calls = seed, 0

    def __call__(self, batch):
        self.calls += 1
        key = [self.seed, batch.k, batch.n_conditions, len(batch), int(batch.point_index[0])]
        rng = np.random.default_rng(key + [int(a) for a in batch.given_axes])
        m, nc = len(batch), batch.n_conditions
        U = np.linalg.qr(rng.normal(size=(m, nc, nc)))[0]
        V = np.linalg.qr(rng.normal(size=(m, nc, nc)))[0]
        s = 10.0 ** rng.uniform(-1.5, 1.5, size=(m, nc))
        return U @ (s[..., None] * V)


@pytest.mark.parametrize(
    "geometry, noise",
    [
        (
            PairOptions(points=mixed_points(weighted="alternate"), grid_offset=NATIONAL_GRID),
            NoiseOptions(sigma_gnss=0.1),
        ),
        (PairOptions(n_photos=3, points=strip_points()), NoiseOptions()),
    ],
    ids=["pair", "strip of three"],
)
def test_invariant_to_recombining_conditions(geometry, noise):
    _, project = make_pair(geometry, noise, seed=11)
    plain = adjust(project)
    transform = RandomRecombination(seed=5)
    mixed = adjust(project, AdjustmentOptions.of(condition_transform=transform))
    assert transform.calls > 0
    assert plain.converged and mixed.converged
    sig_xyz = np.sqrt(np.einsum("nii->ni", _photo_Q(plain)[:, :3, :3])) * plain.sigma0
    assert np.all(np.abs(mixed.state.xyz0 - plain.state.xyz0) < STAT * sig_xyz)
    assert np.abs(mixed.state.R_ground_from_cam - plain.state.R_ground_from_cam).max() < 1e-9
    assert mixed.vtpv == pytest.approx(plain.vtpv, rel=1e-9)
    assert np.abs(mixed.plate_residuals - plain.plate_residuals).max() < STAT * project.image_points.sigma_xy.min()
    corr_diff = np.abs(_photo_Q(mixed) - _photo_Q(plain)).max() / np.abs(_photo_Q(plain)).max()
    assert corr_diff < 1e-8


@pytest.mark.parametrize("name", list(CASES))
def test_point_precision_equals_the_bundle(solved, name):
    """The ground points' cofactors, Schmid's split (90) and the rigorous joint form (92), equal the
    point blocks of the independent bundle's (J^T J)^-1 (points as unknowns there)."""
    from striptri.pipeline import triangulate_result
    from striptri.precision.residuals import joint_point_covariance

    _, project, res, ref = solved[name]
    tri = triangulate_result(project, res)
    q90 = tri.cov_measurement + tri.cov_orientation
    q92 = joint_point_covariance(project, res, tri)
    unknown = np.abs(np.einsum("nii->ni", ref.Q_points)).sum(axis=1) > 0
    sel = unknown & tri.determined
    assert sel.sum() >= 5
    scale = np.sqrt(np.einsum("nii->ni", ref.Q_points[sel]))  # standard deviations (sigma0 = 1)
    for q in (q90, q92):
        diff = (q[sel] - ref.Q_points[sel]) / (scale[:, :, None] * scale[:, None, :] + 1e-300)
        assert np.abs(np.nan_to_num(diff)).max() < 1e-5
