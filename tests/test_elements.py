"""Orientation elements fixed, free or observed; base components observed or enforced (Schmid 24);
interior orientation free per camera (Schmid's 18 unknowns); the mean error of a function of the
unknowns (Schmid 81-86).

The limits are the evidence: an element observed with a very large standard deviation must give
the free solution, one observed with a very small standard deviation the enforced one."""

from dataclasses import replace

import numpy as np
import pytest

from striptri import model
from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.model import BaseComponents
from striptri.pipeline import photo_table
from striptri.geometry.rotations import angles_from_R, angles_jacobian


def _pair(seed, sigma_image=0.005, relief=50.0, single=0, extra=6, layout="corners"):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=2),
        terrain=sim.TerrainDesign(relief=relief),
        points=sim.PointDesign(extra_ties_per_model=extra),
        control=sim.ControlDesign(layout=layout, n_single_photo=single),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    project = sim.perturb(truth, sim.NoiseOptions(sigma_image=sigma_image), np.random.default_rng(seed + 100))
    return project, truth


def _bases(photo_from, photo_to, axis, value, sigma):
    return BaseComponents(np.array([photo_from]), np.array([photo_to]), np.array([axis]),
                          np.array([float(value)]), np.array([float(sigma)]))


def _with_photo_sigmas(project, sigma_xyz0=None, sigma_angles=None, **photo_changes):
    ph = project.photos
    return replace(project, photos=replace(
        ph,
        sigma_xyz0=ph.sigma_xyz0 if sigma_xyz0 is None else sigma_xyz0,
        sigma_angles=ph.sigma_angles if sigma_angles is None else sigma_angles,
        **photo_changes,
    ))


def _positions(r):
    return r.state.xyz0 + r.offset


def test_enforced_base_component_holds_exactly_and_equals_the_heavy_weight_limit():
    p, truth = _pair(1)
    bz_true = truth.xyz0[1, 2] - truth.xyz0[0, 2]
    free = adjust(p)
    enforced = adjust(replace(p, bases=_bases(0, 1, 2, bz_true, np.nan)))
    heavy = adjust(replace(p, bases=_bases(0, 1, 2, bz_true, 1e-7)))
    light = adjust(replace(p, bases=_bases(0, 1, 2, bz_true, 1e7)))
    xyz = _positions(enforced)
    assert xyz[1, 2] - xyz[0, 2] == pytest.approx(bz_true, abs=1e-9)
    assert enforced.n_unknowns == free.n_unknowns - 1
    assert enforced.redundancy == free.redundancy + 1
    assert heavy.redundancy == free.redundancy + 1
    np.testing.assert_allclose(_positions(heavy), xyz, atol=1e-5)
    assert heavy.vtpv == pytest.approx(enforced.vtpv, rel=1e-6)
    np.testing.assert_allclose(_positions(light), _positions(free), atol=1e-6)
    assert light.vtpv == pytest.approx(free.vtpv, rel=1e-6)


def test_enforced_base_noise_free_recovers_truth():
    p, truth = _pair(2, sigma_image=0.0)
    bx = truth.xyz0[1, 0] - truth.xyz0[0, 0]
    r = adjust(replace(p, bases=_bases(0, 1, 0, bx, np.nan)))
    np.testing.assert_allclose(_positions(r), truth.xyz0, atol=1e-9 * 1500)


def test_observed_base_component_is_a_weighted_compromise():
    p, truth = _pair(3)
    free = adjust(p)
    xyz = _positions(free)
    bz_free = xyz[1, 2] - xyz[0, 2]
    sigma_free = free.base_component_mean_error(0, 1, 2) / free.sigma0
    bz_obs = bz_free + 0.5
    r = adjust(replace(p, bases=_bases(0, 1, 2, bz_obs, sigma_free)))
    xyz_r = _positions(r)
    bz = xyz_r[1, 2] - xyz_r[0, 2]
    # one scalar observation of a function of the unknowns with the same weight as the free
    # estimate: the adjusted value lies halfway (linear least squares, exact to linearisation)
    assert bz == pytest.approx(0.5 * (bz_free + bz_obs), abs=2e-3)
    assert r.parameter_residuals[0] == pytest.approx(bz - bz_obs, abs=1e-9)


def test_fixed_centre_element_is_held():
    p, truth = _pair(4)
    sig = np.full((2, 3), np.nan)
    sig[0, 0] = 0.0
    xyz0 = p.photos.xyz0.copy()
    xyz0[0, 0] = truth.xyz0[0, 0]
    q = _with_photo_sigmas(p, sigma_xyz0=sig, xyz0=xyz0)
    r = adjust(q)
    assert r.n_unknowns == 11
    assert _positions(r)[0, 0] == truth.xyz0[0, 0]


@pytest.mark.parametrize("convention", ["omega-phi-kappa", "alpha-omega-chi", "phi-omega-kappa"])
def test_partially_fixed_angles_are_held_and_match_the_heavy_weight_limit(convention):
    p, truth = _pair(5)
    p = replace(p, settings=replace(p.settings, rotation=convention))
    true_angles = angles_from_R(truth.R_ground_from_cam, convention)
    angles = p.photos.angles.copy()
    angles = angles_from_R(p.photos.R_ground_from_cam, convention)
    angles[1, 2] = true_angles[1, 2]
    from striptri.geometry.rotations import R_from_angles

    R = R_from_angles(angles, convention)
    sig = np.full((2, 3), np.nan)
    sig[1, 2] = 0.0
    fixed = adjust(_with_photo_sigmas(p, sigma_angles=sig, angles=angles, R_ground_from_cam=R))
    assert fixed.n_unknowns == 11
    assert angles_from_R(fixed.state.R_ground_from_cam, convention)[1, 2] == pytest.approx(true_angles[1, 2], abs=1e-12)
    sig[1, 2] = 1e-10
    heavy = adjust(_with_photo_sigmas(p, sigma_angles=sig, angles=angles, R_ground_from_cam=R))
    np.testing.assert_allclose(_positions(heavy), _positions(fixed), atol=1e-5)
    np.testing.assert_allclose(heavy.state.R_ground_from_cam, fixed.state.R_ground_from_cam, atol=1e-9)
    assert heavy.vtpv == pytest.approx(fixed.vtpv, rel=1e-6)


def test_observed_angles_with_large_sigma_equal_the_free_solution():
    p, _ = _pair(6)
    free = adjust(p)
    r = adjust(_with_photo_sigmas(p, sigma_angles=np.full((2, 3), 1e3)))
    np.testing.assert_allclose(r.state.R_ground_from_cam, free.state.R_ground_from_cam, atol=1e-9)
    assert r.redundancy == free.redundancy + 6


def test_interior_orientation_free_per_photo_gives_schmid_18_unknowns():
    """One camera per photo with c, xp, yp free: all 18 elements of the pair, recovered exactly from
    noise-free data (relief and single-photo control make c, xp, yp determinable)."""
    p, truth = _pair(0, sigma_image=0.0, relief=300.0, single=2, extra=10)
    true_interior = p.cameras.interior[0, :3]
    cams = model.Cameras(["a", "b"], true_interior + np.array([[0.5, 0.05, -0.05], [-0.3, 0.02, 0.04]]),
                         np.full((2, 3), np.inf))
    q = replace(p, cameras=cams, photos=replace(p.photos, camera_index=np.array([0, 1])))
    r = adjust(q)
    assert r.n_unknowns == 18
    np.testing.assert_allclose(r.state.interior[:, :3], np.tile(true_interior, (2, 1)), atol=1e-9)
    np.testing.assert_allclose(_positions(r), truth.xyz0, atol=1e-9 * 1500)


def test_observed_camera_constant_with_small_sigma_is_held():
    p, _ = _pair(7, relief=300.0, single=2, extra=10)
    cams = replace(p.cameras, sigma_interior=np.array([[1e-9, np.inf, np.inf]]))
    r = adjust(replace(p, cameras=cams))
    assert r.state.interior[0, 0] == pytest.approx(p.cameras.interior[0, 0], abs=1e-7)
    assert r.n_unknowns == 15


def test_mean_error_of_bx_matches_monte_carlo_scatter():
    """Schmid (85-86): m_bx = m sqrt(f^T N^-1 f), f = (+1 at X0'', -1 at X0'). Over 150 noise
    realisations of one pair the scatter of bx matches the reported value: the sample variance of
    n normal draws has relative std sqrt(2/(n-1)); allow 4 of them."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=2), points=sim.PointDesign(extra_ties_per_model=6),
                                 control=sim.ControlDesign(layout="mixed"))
    truth = sim.make_truth(design, np.random.default_rng(11))
    rng = np.random.default_rng(12)
    bx, reported = [], []
    for _ in range(150):
        p = sim.perturb(truth, sim.NoiseOptions(), rng)
        r = adjust(p)
        xyz = _positions(r)
        bx.append(xyz[1, 0] - xyz[0, 0])
        reported.append(r.base_component_mean_error(0, 1, 0) / r.sigma0)  # a-priori sigma0 = 1
    n = len(bx)
    ratio = np.var(bx, ddof=1) / np.mean(reported) ** 2
    assert abs(ratio - 1.0) < 4 * np.sqrt(2 / (n - 1))


def test_phi_omega_kappa_project_adjusts_as_omega_phi_kappa_and_writes_its_angles():
    """The same enforced attitudes given in phi-omega-kappa (primary axis Y) and in omega-phi-kappa
    give the same adjustment; photos.csv then carries pok_phi, pok_omega, pok_kappa whose mean errors
    equal those of the angles as functions of the unknowns (Schmid 81-84)."""

    p, truth = _pair(7)
    sig = np.full((2, 3), 2e-4)
    opk = _with_photo_sigmas(p, sigma_angles=sig, angles=angles_from_R(truth.R_ground_from_cam, "omega-phi-kappa"),
                             R_ground_from_cam=truth.R_ground_from_cam)
    # held angles (sigma 0): the same rotation in either convention must give the same adjustment
    a = adjust(replace(opk, photos=replace(opk.photos, sigma_angles=np.zeros((2, 3)))))
    pok_angles = angles_from_R(truth.R_ground_from_cam, "phi-omega-kappa")
    pok = replace(opk, settings=replace(opk.settings, rotation="phi-omega-kappa"),
                  photos=replace(opk.photos, angles=pok_angles, sigma_angles=np.zeros((2, 3))))
    b = adjust(pok)
    np.testing.assert_allclose(b.state.R_ground_from_cam, a.state.R_ground_from_cam, atol=1e-14)
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-10)
    free = adjust(replace(pok, photos=replace(pok.photos, sigma_angles=np.full((2, 3), np.nan))))
    table = photo_table(pok, free)
    unit = 180.0 / np.pi if pok.settings.angle_unit == "deg" else {"gon": 200.0 / np.pi, "rad": 1.0}[pok.settings.angle_unit]
    got = np.column_stack([table[n] for n in ("pok_phi", "pok_omega", "pok_kappa")]) / unit
    np.testing.assert_allclose(got, angles_from_R(free.state.R_ground_from_cam, "phi-omega-kappa"), atol=1e-13)
    sig_pok = np.column_stack([table[f"sigma_{n}"] for n in ("pok_phi", "pok_omega", "pok_kappa")]) / unit
    # second way: each angle as a function of the unknowns, its gradient J T on the photo's rotation
    # columns, through the general mean error of a function (Schmid 81-84)
    T = free.layout.rotation_maps(free.state)
    for k in range(2):
        G = angles_jacobian(free.state.R_ground_from_cam[k], "phi-omega-kappa") @ T[k]
        cols = free.layout.photo_cols[k, 3:]
        for row in range(3):
            f = np.zeros(free.n_unknowns)
            f[cols[cols >= 0]] = G[row, cols >= 0]
            assert sig_pok[k, row] == pytest.approx(free.mean_error(f), rel=1e-9)
    assert np.all(sig_pok > 0)
