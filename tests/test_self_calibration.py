"""Self-calibration with the camera model of striptri.geometry.lens, in both distortion conventions.

* the linearised conditions (B with respect to all ten camera elements, A with respect to the
  observations) against central differences, as test_jacobians does for the exterior elements;
* noise-free data: the adjustment recovers the true additional parameters and orientations;
* with noise: the method of conditions equals the bundle method (module doc of test_bundle:
  both minimise the same v^T P v; the plate convention's residuals live in the refined
  coordinates in both, the image convention's in the measured ones).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_jacobians import assert_jacobian

from striptri.geometry import lens
from striptri import model
from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust, observations_of
from striptri.equations.groups import build_batches
from striptri.geometry.lens import IMAGE, NCP, PLATE
from striptri.equations.linearise import At, evaluate, linearise
from striptri.equations.parameters import build_layout, initial_state, reduction_offset

H = 1500.0
FREE = ("k1", "k2", "p1", "p2")


def true_lens(convention: int) -> np.ndarray:
    """Additional parameters of a wide-angle aerial camera (c = 152 mm): radial distortion of
    about 40 um at 100 mm from the principal point, decentering of a few um, a small affinity."""
    prm = np.zeros(NCP)
    if convention == PLATE:
        prm[lens.K1], prm[lens.K2], prm[lens.P1], prm[lens.P2], prm[lens.B1] = 4e-8, -1e-12, 2e-7, -1.5e-7, 3e-5
    else:  # normalised coordinates: r_n = r / c
        prm[lens.K1], prm[lens.K2], prm[lens.P1], prm[lens.P2] = 9e-4, -5e-4, 3e-5, -2e-5
        prm[lens.B1], prm[lens.B2] = 2e-4, -1e-4  # affinity and shear after the distortion (K matrix)
    return prm


def calibration_project(convention: int, noise: sim.NoiseOptions, seed: int = 3, free=FREE):
    """A 3 x 5 block with 60 % sidelap over rough terrain, every-2 control; the measurements carry
    the true lens; the camera's chosen elements are free, starting from 0. -> (project, truth, prm)."""
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=5, n_strips=3, sidelap=0.6),
        terrain=sim.TerrainDesign(relief=150.0),
        points=sim.PointDesign(extra_ties_per_model=12),
        control=sim.ControlDesign(layout="every-k", every_k=2),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    project = sim.perturb(truth, noise, np.random.default_rng(seed + 1000))
    prm = np.concatenate([truth.interior, true_lens(convention)[3:]])
    ip = project.image_points
    measured = lens.observed_from_ideal(ip.xy, prm, convention)
    sigma = np.full((1, NCP), np.nan)
    start = prm.copy()  # held elements at their true values, free additional parameters from 0
    for name in free:
        e = lens.CAMERA_ELEMENTS.index(name)
        sigma[0, e] = np.inf
        start[e] = start[e] if e < 3 else 0.0
    cams = model.Cameras(project.cameras.ids, start[None, :], sigma, np.array([convention]))
    return replace(project, cameras=cams, image_points=replace(ip, xy=measured)), truth, prm


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_linearised_conditions_with_the_camera_model(convention):
    free = FREE + ("c", "xp", "yp", "k3", "b1", "b2")
    project, _, prm = calibration_project(convention, sim.NoiseOptions(), free=free)
    # evaluate away from zero: the true lens, slightly changed
    cams = replace(project.cameras, interior=(prm * (1 + 0.1 * np.arange(NCP) / NCP))[None, :])
    project = replace(project, cameras=cams)
    offset = reduction_offset(project)
    state = initial_state(project, offset)
    layout = build_layout(project)
    assert layout.camera_width == len(free) and (layout.camera_cols >= 0).sum() == len(free)
    position = {int(e): j for j, e in enumerate(layout.camera_elements)}  # element -> camera column of a ray
    T = layout.rotation_maps(state)
    obs = observations_of(project, offset)
    rng = np.random.default_rng(9)
    plate_hat = obs.plate + rng.normal(0, 1e-3, obs.plate.shape)
    control_hat = obs.control
    steps = {"c": 1e-3, "xp": 1e-3, "yp": 1e-3, "k1": 1e-10, "k2": 1e-14, "k3": 1e-19, "p1": 1e-9, "p2": 1e-9,
             "b1": 1e-6, "b2": 1e-6}
    if convention == IMAGE:
        steps.update(k1=1e-6, k2=1e-6, k3=1e-6, p1=1e-7, p2=1e-7)
    cam_cols = layout.camera_cols[0]
    for batch in build_batches(project)[:4]:
        system = linearise(batch, At(state, layout, T, obs, plate_hat, control_hat))
        m, nc = system.g.shape
        lin0 = evaluate(batch, state, plate_hat, control_hat, plate_measured=obs.plate)
        scale = system.g / lin0.g
        width = 6 + layout.camera_width
        B_cam = system.B.reshape(m, nc, batch.k, width)[..., 6:].sum(axis=2)  # one camera
        analytic, numeric = [], []
        for e, name in enumerate(lens.CAMERA_ELEMENTS):
            if cam_cols[e] < 0:
                continue
            d = np.zeros(layout.n_unknowns)
            d[cam_cols[e]] = steps[name]
            gp = evaluate(batch, state.updated(layout, d), plate_hat, control_hat, plate_measured=obs.plate).g
            gm = evaluate(batch, state.updated(layout, -d), plate_hat, control_hat, plate_measured=obs.plate).g
            # in units of the element's step, so that each column has the weight of a change in it
            numeric.append(scale * (gp - gm) / 2)
            analytic.append(B_cam[..., position[e]] * steps[name])
        assert_jacobian(np.stack(analytic, -1), np.stack(numeric, -1), 1)

        k = batch.k

        def g_of_plate(lvec):
            ph = plate_hat.copy()
            ph[batch.image_rows] = lvec.reshape(m, k, 2)
            return scale * evaluate(batch, state, ph, control_hat, plate_measured=obs.plate).g

        l0 = plate_hat[batch.image_rows].reshape(m, 2 * k)
        cols = []
        for j in range(2 * k):
            h = np.zeros_like(l0)
            h[:, j] = 1e-4
            cols.append((g_of_plate(l0 + h) - g_of_plate(l0 - h)) / 2e-4)
        assert_jacobian(system.A[:, :, : 2 * k], np.stack(cols, -1), 1)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_noise_free_self_calibration_recovers_the_lens(convention, method):
    project, truth, prm = calibration_project(convention, sim.NoiseOptions(sigma_image=0.0, stated_sigma_image=0.005, sigma_control_xy=0.0,
                                                                            sigma_control_z=0.0))
    result = adjust(project, AdjustmentOptions(method=method))
    assert result.converged
    got = result.state.interior[0]
    for name in FREE:
        e = lens.CAMERA_ELEMENTS.index(name)
        assert abs(got[e] - prm[e]) <= 1e-7 * abs(prm[e]), (name, got[e], prm[e])
    centres = result.state.xyz0 + result.offset
    assert np.abs(centres - truth.xyz0).max() < 1e-7 * H


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_conditions_equal_bundle_with_self_calibration(convention):
    project, _, _ = calibration_project(convention, sim.NoiseOptions(), seed=5)
    a = adjust(project, AdjustmentOptions(method="conditions"))
    b = adjust(project, AdjustmentOptions(method="bundle"))
    assert a.converged and b.converged
    assert a.redundancy == b.redundancy
    np.testing.assert_allclose(a.vtpv, b.vtpv, rtol=1e-7)
    np.testing.assert_allclose(a.state.xyz0, b.state.xyz0, rtol=0, atol=1e-6 * H)
    sig = a.camera_mean_errors()[0]
    cols = a.layout.camera_cols[0] >= 0
    diff = np.abs(a.state.interior[0] - b.state.interior[0])[cols] / sig[cols]
    assert diff.max() < 1e-5, diff
    np.testing.assert_allclose(a.plate_adjusted, b.plate_adjusted, rtol=0, atol=1e-6 * 0.005)


def test_camera_correlations_equal_the_dense_inverse():
    """precision.camera_correlations against Qxx = N^-1 formed densely: the correlations among the
    camera elements and, for each, its largest correlation with an exterior element."""
    from striptri.precision.residuals import camera_correlations

    project, _, _ = calibration_project(PLATE, sim.NoiseOptions(), seed=7)
    result = adjust(project)
    Q = np.linalg.inv(result.N.toarray())
    (block,) = camera_correlations(result)
    cols = result.layout.camera_cols[0][block["elements"]]
    s = np.sqrt(np.diag(Q)[cols])
    np.testing.assert_allclose(block["matrix"], Q[np.ix_(cols, cols)] / np.outer(s, s), atol=1e-9)
    photo_cols = result.layout.photo_cols.ravel()
    ok = photo_cols >= 0
    ext = Q[np.ix_(cols, photo_cols[ok])] / np.outer(s, np.sqrt(np.diag(Q)[photo_cols[ok]]))
    for i, (photo, element, rho) in enumerate(block["exterior"]):
        k = int(np.argmax(np.abs(ext[i])))
        assert photo_cols[ok][k] == result.layout.photo_cols[photo, element]
        assert rho == pytest.approx(ext[i, k], abs=1e-9)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_sequential_method_applies_a_held_lens(convention):
    """The sequential method holds the camera: with the true lens held, noise-free measurements
    give the true orientations (the lens applied once to the measurements); asked to estimate
    distortion it refuses in words."""
    from striptri.errors import InputError

    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=6), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=4))
    truth = sim.make_truth(design, np.random.default_rng(2))
    noise = sim.NoiseOptions(sigma_image=0.0, stated_sigma_image=0.005, sigma_control_xy=0.0, sigma_control_z=0.0)
    project = sim.perturb(truth, noise, np.random.default_rng(3))
    prm = np.concatenate([truth.interior, true_lens(convention)[3:]])
    ip = project.image_points
    measured = lens.observed_from_ideal(ip.xy, prm, convention)
    cams = model.Cameras(project.cameras.ids, prm[None, :], np.full((1, NCP), np.nan), np.array([convention]))
    project = replace(project, cameras=cams, image_points=replace(ip, xy=measured))
    result = adjust(project, AdjustmentOptions(method="sequential"))
    assert np.abs(result.state.xyz0 + result.offset - truth.xyz0).max() < 1e-6 * H
    sigma = cams.sigma_interior.copy()
    sigma[0, lens.K1] = np.inf
    with pytest.raises(InputError, match="cannot estimate lens distortion"):  # bad input for this method
        adjust(replace(project, cameras=replace(cams, sigma_interior=sigma)), AdjustmentOptions(method="sequential"))


def test_observed_distortion_element_is_a_weighted_observation():
    """k1 observed with a standard deviation: a tiny sigma holds it at the observed value, a huge
    one leaves it where the free estimate goes, and in between it lands between the two."""
    project, _, prm = calibration_project(PLATE, sim.NoiseOptions(), seed=11)
    free = adjust(project)
    k1_free = free.state.interior[0, lens.K1]
    sig_free = free.camera_mean_errors()[0, lens.K1] / free.sigma0_for_precision  # sqrt(Q_kk), a-priori units

    def with_k1_observed(value, sigma):
        cams = project.cameras
        interior, s = cams.interior.copy(), cams.sigma_interior.copy()
        interior[0, lens.K1], s[0, lens.K1] = value, sigma
        return adjust(replace(project, cameras=replace(cams, interior=interior, sigma_interior=s)))

    observed = k1_free + 10 * sig_free
    tight = with_k1_observed(observed, 1e-6 * sig_free)
    loose = with_k1_observed(observed, 1e6 * sig_free)
    equal = with_k1_observed(observed, sig_free)
    assert abs(tight.state.interior[0, lens.K1] - observed) < 1e-3 * sig_free
    assert abs(loose.state.interior[0, lens.K1] - k1_free) < 1e-3 * sig_free
    # equal weights of the prior and of the data: half-way (the update of a Gaussian estimate)
    assert equal.state.interior[0, lens.K1] == pytest.approx((k1_free + observed) / 2, abs=0.05 * sig_free)
    assert equal.redundancy == free.redundancy + 1


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_image_convention_affinity_and_shear_recovered_and_methods_agree(method):
    """Affinity and shear in the image convention (issue 17): noise-free, b1 and b2 free from 0 are
    recovered; with noise the method of conditions equals the bundle method."""
    free = FREE + ("b1", "b2")
    noise = sim.NoiseOptions(sigma_image=0.0, stated_sigma_image=0.005, sigma_control_xy=0.0, sigma_control_z=0.0)
    project, truth, prm = calibration_project(IMAGE, noise, free=free)
    result = adjust(project, AdjustmentOptions(method=method))
    got = result.state.interior[0]
    for name in free:
        e = lens.CAMERA_ELEMENTS.index(name)
        assert abs(got[e] - prm[e]) <= 1e-7 * abs(prm[e]), (name, got[e], prm[e])
    if method == "bundle":
        project, _, _ = calibration_project(IMAGE, sim.NoiseOptions(), seed=5, free=free)
        a = adjust(project, AdjustmentOptions(method="conditions"))
        b = adjust(project, AdjustmentOptions(method="bundle"))
        assert a.redundancy == b.redundancy
        np.testing.assert_allclose(a.vtpv, b.vtpv, rtol=1e-7)
        sig = a.camera_mean_errors()[0]
        cols = a.layout.camera_cols[0] >= 0
        diff = np.abs(a.state.interior[0] - b.state.interior[0])[cols] / sig[cols]
        assert diff.max() < 1e-5, diff


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_the_sweeps_lens_table_gives_each_chunks_ideal_points(convention, monkeypatch):
    """linearise.lens_table (the ideal plate points of every image row, once per sweep) gives the
    chunks the systems they compute for themselves: the same to round-off (the image convention's
    Newton iterations stop when all rows of a call have converged, so a row may take one more step
    below its tolerance); where the model is not in play, or there are more than LENS_TABLE_ROWS
    rows, there is no table; and the adjustment is the same with and without it."""
    from striptri.equations import linearise as lin_module
    from striptri.equations.linearise import lens_table

    project, _, prm = calibration_project(convention, sim.NoiseOptions(), free=FREE + ("c", "xp", "yp"))
    cams = replace(project.cameras, interior=(prm * (1 + 0.1 * np.arange(NCP) / NCP))[None, :])
    project = replace(project, cameras=cams)
    offset = reduction_offset(project)
    state, layout = initial_state(project, offset), build_layout(project)
    obs = observations_of(project, offset)
    plate_hat = obs.plate + np.random.default_rng(9).normal(0, 1e-3, obs.plate.shape)
    at = At.of(state, layout, obs, plate_hat, obs.control)
    batches = build_batches(project)
    table = lens_table(batches, at)
    assert table is not None
    rows = np.concatenate([b.image_rows.ravel() for b in batches])
    assert np.all(table.converged[rows]) and np.all(table.xy[rows] != plate_hat[rows])  # undistorted
    for batch in batches:
        for chunk in batch.chunks(7):
            own, read = linearise(chunk, at), linearise(chunk, at, lens=table)
            for name in ("A", "B", "w", "g"):
                a, b = getattr(own, name), getattr(read, name)
                np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * max(np.abs(a).max(), 1.0), err_msg=name)
    held = replace(project, cameras=model.Cameras(project.cameras.ids, np.concatenate([prm[:3], np.zeros(NCP - 3)])[None, :],
                                                  np.full((1, NCP), np.nan), project.cameras.convention))
    held_state, held_layout = initial_state(held, offset), build_layout(held)
    assert lens_table(batches, At.of(held_state, held_layout, obs, plate_hat, obs.control)) is None
    monkeypatch.setattr(lin_module, "LENS_TABLE_ROWS", len(rows) - 1)
    assert lens_table(batches, at) is None
    options = AdjustmentOptions(method="conditions")
    per_chunk = adjust(project, options)
    monkeypatch.setattr(lin_module, "LENS_TABLE_ROWS", len(rows))
    with_table = adjust(project, options)
    assert per_chunk.iterations == with_table.iterations
    np.testing.assert_allclose(with_table.state.xyz0, per_chunk.state.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(with_table.state.interior, per_chunk.state.interior, rtol=1e-10, atol=0)
    assert with_table.vtpv == pytest.approx(per_chunk.vtpv, rel=1e-10)
