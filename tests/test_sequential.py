"""The instrument-style sequential method (Schut's procedures 1 and 2, DESIGN section 8): exact on
noise-free strips from either end, dependent on the starting end with noise, not more accurate than
the simultaneous adjustment, and a source of approximate values (--init sequential)."""

from dataclasses import replace

import numpy as np
import pytest

from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.errors import InputError, NumericalFailure
from striptri.pipeline import triangulate_result
from striptri.geometry.rotations import R_from_opk, log_so3, opk_from_R
from striptri.sequential import (
    SequentialOptions,
    adjust_sequential,
    sequential_approximations,
    triangulate_strip,
)

FLYING_HEIGHT = sim.FlightDesign().flying_height


def _strip(seed, layout="ends", sigma_image=0.0, n_photos=8, heading=0.0, extra_ties=0, n_strips=1):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=n_photos, heading_deg=heading, n_strips=n_strips),
        points=sim.PointDesign(extra_ties_per_model=extra_ties),
        control=sim.ControlDesign(layout=layout),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    project = sim.perturb(truth, sim.NoiseOptions(sigma_image=sigma_image), np.random.default_rng(seed + 1000))
    return project, truth


def _centre_rms(result, truth):
    return float(np.sqrt(np.mean(np.sum((result.state.xyz0 + result.offset - truth.xyz0) ** 2, axis=1))))


def _angle_error(result, truth):
    return float(np.abs(log_so3(np.swapaxes(truth.R_ground_from_cam, 1, 2) @ result.state.R_ground_from_cam)).max())


@pytest.mark.parametrize("layout", ["ends", "every-k"])
@pytest.mark.parametrize("direction", ["forward", "backward"])
@pytest.mark.parametrize("procedure", [1, 2])
def test_noise_free_strip_is_recovered_exactly(procedure, direction, layout):
    project, truth = _strip(seed=11, layout=layout)
    r = adjust_sequential(project, SequentialOptions(procedure=procedure, direction=direction))
    assert r.method == "sequential" and r.converged
    np.testing.assert_allclose(r.state.xyz0 + r.offset, truth.xyz0, atol=1e-6 * FLYING_HEIGHT)
    assert _angle_error(r, truth) < 1e-9
    assert np.abs(r.plate_residuals).max() < 1e-9  # plate units (mm)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_noise_free_strip_with_polynomial_correction(degree):
    """A strip without errors needs no correction: the polynomial fits zero residuals."""
    project, truth = _strip(seed=12, layout="every-k")
    sol = triangulate_strip(project, SequentialOptions(polynomial_degree=degree))
    assert all(np.abs(c).max() < 1e-6 for c in sol.polynomial.coefficients if len(c))
    r = adjust_sequential(project, SequentialOptions(procedure=2, polynomial_degree=degree))
    np.testing.assert_allclose(r.state.xyz0 + r.offset, truth.xyz0, atol=1e-6 * FLYING_HEIGHT)
    assert _angle_error(r, truth) < 1e-9


@pytest.mark.parametrize("heading", [90.0, 180.0, 225.0])
def test_strips_flown_in_any_direction(heading):
    project, truth = _strip(seed=13, heading=heading)
    for procedure in (1, 2):
        r = adjust_sequential(project, SequentialOptions(procedure=procedure, direction="backward"))
        np.testing.assert_allclose(r.state.xyz0 + r.offset, truth.xyz0, atol=1e-6 * FLYING_HEIGHT)
        assert _angle_error(r, truth) < 1e-9


@pytest.mark.parametrize("procedure", [1, 2])
def test_with_noise_the_result_depends_on_the_starting_end(procedure):
    project, truth = _strip(seed=3, sigma_image=0.005)
    f = adjust_sequential(project, SequentialOptions(procedure=procedure, direction="forward"))
    b = adjust_sequential(project, SequentialOptions(procedure=procedure, direction="backward"))
    assert np.abs(f.state.xyz0 - b.state.xyz0).max() > 0.05  # m; measured 0.31 (procedure 1)
    # both are a sound triangulation of the strip: errors of decimetres at 1500 m
    assert _centre_rms(f, truth) < 2.0 and _centre_rms(b, truth) < 2.0


def test_procedures_differ_with_noise():
    project, _ = _strip(seed=4, sigma_image=0.005)
    one = adjust_sequential(project, SequentialOptions(procedure=1))
    two = adjust_sequential(project, SequentialOptions(procedure=2))
    assert np.abs(one.state.xyz0 - two.state.xyz0).max() > 1e-3


def test_sequential_is_on_average_not_more_accurate_than_simultaneous():
    """Schut: only the simultaneous solution uses all conditions at once. RMS centre errors, 5 seeds."""
    errors = {"simultaneous": [], 1: [], 2: []}
    for seed in range(5):
        project, truth = _strip(seed=seed, sigma_image=0.005)
        errors["simultaneous"].append(_centre_rms(adjust(project), truth))
        for procedure in (1, 2):
            errors[procedure].append(_centre_rms(adjust_sequential(project, SequentialOptions(procedure)), truth))
    mean = {k: np.mean(v) for k, v in errors.items()}
    assert mean[1] > mean["simultaneous"] and mean[2] > mean["simultaneous"], mean


def test_result_fields_follow_their_definitions():
    project, _ = _strip(seed=5, sigma_image=0.005, extra_ties=2)
    sol = triangulate_strip(project, SequentialOptions(procedure=1))
    r = adjust_sequential(project, SequentialOptions(procedure=1))
    # procedure 1: pooled over the relative orientations, m - 5 each
    assert r.redundancy == sum(s.n_conditions - 5 for s in sol.steps) == sol.redundancy
    assert r.sigma0 == pytest.approx(np.sqrt(sol.vtpv / sol.redundancy))
    assert len(r.history) == len(project.photos) - 1
    np.testing.assert_allclose(r.plate_adjusted, project.image_points.xy + r.plate_residuals)
    # N: one positive-definite 6 x 6 block per photo, nothing between photos
    N = r.N.toarray()
    assert np.count_nonzero(N) <= 36 * len(project.photos)
    assert np.all(np.linalg.eigvalsh(N) > 0)
    sig_xyz, _ = r.photo_mean_errors("omega-phi-kappa")
    assert np.all(np.isfinite(sig_xyz)) and np.all(sig_xyz > 0)
    assert r.checks.absolute_orientation_redundancy > 0
    # the pipeline's triangulation takes the result as it takes a simultaneous one
    tri = triangulate_result(project, r)
    assert tri.determined.sum() > 0.9 * len(project.points)


def test_sigma0_of_procedure_1_estimates_the_plate_noise():
    """The relative orientations are adjustments of the plate measurements alone: their pooled
    variance factor is unbiased (sigma_image equals the stated sigma). 8 strips."""
    v, r = 0.0, 0
    for seed in range(8):
        project, _ = _strip(seed=seed, sigma_image=0.005, extra_ties=3)
        sol = triangulate_strip(project, SequentialOptions(procedure=1))
        v, r = v + sol.vtpv, r + sol.redundancy
    assert 0.75 < v / r < 1.25  # r = 8 * 7 * 4 = 224: the standard error of v/r is 0.09


def _rough(project, truth, position_error, kappa_error_deg, seed=5):
    """Centres off by `position_error` metres in random directions, kappa off by +/- the given angle."""
    n = len(project.photos)
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    angles = opk_from_R(truth.R_ground_from_cam)
    angles[:, 2] += np.radians(kappa_error_deg) * np.where(np.arange(n) % 2, 1.0, -1.0)
    photos = replace(project.photos, xyz0=truth.xyz0 + position_error * d, angles=angles,
                     R_ground_from_cam=R_from_opk(angles))
    return replace(project, photos=photos)


@pytest.mark.parametrize("position_error, kappa_error", [(200.0, 10.0), (800.0, 60.0)])
@pytest.mark.parametrize("procedure", [1, 2])
def test_init_sequential_reaches_the_simultaneous_solution_from_rough_values(procedure, position_error, kappa_error):
    """From (800 m, 60 deg) the plain adjustment took 23 iterations on this strip (and failed for other
    noise draws); from the sequential values every case takes 4."""
    project, truth = _strip(seed=3, sigma_image=0.005)
    reference = adjust(project)
    rough = _rough(project, truth, position_error, kappa_error)
    r = adjust(sequential_approximations(rough, SequentialOptions(procedure=procedure)))
    assert r.converged and r.iterations <= 6
    np.testing.assert_allclose(r.state.xyz0 + r.offset, reference.state.xyz0 + reference.offset, atol=1e-6)
    assert r.vtpv == pytest.approx(reference.vtpv, rel=1e-9)


def test_options_are_validated():
    with pytest.raises(ValueError, match="procedure"):
        SequentialOptions(procedure=3)
    with pytest.raises(ValueError, match="direction"):
        SequentialOptions(direction="sideways")
    with pytest.raises(ValueError, match="polynomial"):
        SequentialOptions(polynomial_degree=5)


def test_a_block_is_refused():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4, n_strips=2),
                                 control=sim.ControlDesign(layout="perimeter"))
    project, _ = sim.simulate_project("block", sim.SimulateOptions(design, sim.NoiseOptions()), 1)
    with pytest.raises(InputError, match="one strip"):  # bad input for this method (issue 26), not numerics
        adjust_sequential(project)


def test_too_little_control_is_explained():
    project, _ = _strip(seed=6, layout="none")
    with pytest.raises(NumericalFailure, match="absolute orientation"):
        adjust_sequential(project)


def test_polynomial_degree_is_lowered_to_the_control_positions_along_the_strip():
    """sparse-height: full points in pairs across the strip at its two ends only, so X and Y get a
    line at most, Z (heights at every k-th column) the full degree; the correction stays sane."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=10), control=sim.ControlDesign(layout="sparse-height"))
    project, _ = sim.simulate_project("strip", sim.SimulateOptions(design, sim.NoiseOptions(sigma_image=0.005)), 7)
    sol = triangulate_strip(project, SequentialOptions(procedure=2, polynomial_degree=3))
    assert [len(c) for c in sol.polynomial.coefficients] == [2, 2, 4]
    plain = triangulate_strip(project, SequentialOptions(procedure=2))
    assert np.abs(sol.xyz0_ground - plain.xyz0_ground).max() < 2.0  # metres, at 1500 m
