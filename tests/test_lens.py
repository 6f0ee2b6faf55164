"""The camera model (striptri.geometry.lens): Brown's polynomial, both conventions, every Jacobian against
central differences (tolerance as in test_jacobians: h = 1e-6 of the scale, rtol 1e-6), and the
two conventions against each other (the image convention's undistortion inverts its distortion)."""

from __future__ import annotations

import numpy as np
import pytest
from test_jacobians import assert_jacobian, numeric_jacobian

from striptri.geometry import lens
from striptri.geometry.lens import IMAGE, NCP, PLATE, brown, ideal_from_observed, projection_terms


def plate_camera(rng, m):
    """DBAT-like camera in mm (c 24.5, 36 x 24 mm format) with strong distortion (~9 % at the corner)."""
    prm = np.zeros((m, NCP))
    prm[:, lens.C] = 24.5 + rng.normal(0, 0.1, m)
    prm[:, lens.XP] = 0.08 + rng.normal(0, 0.05, m)
    prm[:, lens.YP] = -0.05 + rng.normal(0, 0.05, m)
    prm[:, lens.K1] = 2.2e-4 * (1 + rng.normal(0, 0.1, m))
    prm[:, lens.K2] = -1.9e-7
    prm[:, lens.K3] = 3e-10
    prm[:, lens.P1] = -6e-5
    prm[:, lens.P2] = 4e-5
    prm[:, lens.B1] = 4e-4
    prm[:, lens.B2] = -2e-4
    xy = rng.uniform([-18, -12], [18, 12], (m, 2))
    return xy, prm


def image_camera(rng, m):
    """BAL-like camera in pixels: f 500 px, k1 -0.3, k2 0.1 (normalised), points within 0.6 of the axis."""
    prm = np.zeros((m, NCP))
    prm[:, lens.C] = 500.0 + rng.normal(0, 5, m)
    prm[:, lens.XP] = rng.normal(0, 2, m)
    prm[:, lens.YP] = rng.normal(0, 2, m)
    prm[:, lens.K1] = -0.3
    prm[:, lens.K2] = 0.1
    prm[:, lens.K3] = -0.01
    prm[:, lens.P1] = 1e-3
    prm[:, lens.P2] = -2e-3
    xy = rng.uniform(-280, 280, (m, 2))
    return xy, prm


def camera(convention, rng, m):
    """A camera of the convention (the image convention with affinity and shear too) and m measurements."""
    xy, prm = (plate_camera if convention == PLATE else image_camera)(rng, m)
    if convention == IMAGE:
        prm[:, lens.B1], prm[:, lens.B2] = 3e-3, -2e-3
    return xy, prm


SCALES = np.array([1.0, 0.1, 0.1, 1e-4, 1e-7, 1e-10, 1e-5, 1e-5, 1e-4, 1e-4])


def test_brown_derivatives():
    rng = np.random.default_rng(1)
    u = rng.normal(0, 0.5, (40, 2))
    prm = np.zeros((40, NCP))
    prm[:, lens.K1:lens.P2 + 1] = rng.normal(0, 0.2, (40, 5))
    _, d_u, d_k = brown(u, prm)
    assert_jacobian(d_u, numeric_jacobian(lambda v: brown(v, prm)[0], u, 1e-6), 1)

    def of_k(k):
        p = prm.copy()
        p[:, lens.K1:lens.P2 + 1] = k
        return brown(u, p)[0]
    assert_jacobian(d_k, numeric_jacobian(of_k, prm[:, lens.K1:lens.P2 + 1], 1e-6), 1)


def test_brown_is_browns_polynomial_written_out():
    """Hand-written terms for one point (Brown 1971; DBAT's brown_rad + tang_scale)."""
    x, y = 3.0, -2.0
    k1, k2, k3, p1, p2 = 1e-3, -2e-5, 3e-7, 4e-5, -5e-5
    r2 = x * x + y * y
    prm = np.zeros(NCP)
    prm[lens.K1:lens.P2 + 1] = k1, k2, k3, p1, p2
    want = (x + x * (k1 * r2 + k2 * r2**2 + k3 * r2**3) + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y,
            y + y * (k1 * r2 + k2 * r2**2 + k3 * r2**3) + 2 * p1 * x * y + p2 * (r2 + 2 * y * y))
    np.testing.assert_allclose(brown(np.array([x, y]), prm)[0], want, rtol=1e-15)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_ideal_points_derivatives(convention):
    rng = np.random.default_rng(2 + convention)
    xy, prm = camera(convention, rng, 60)
    ideal = ideal_from_observed(xy, prm, convention)
    assert ideal.converged.all()
    scale = SCALES if convention == PLATE else np.array([1.0, 0.1, 0.1, 1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-4, 1e-4])
    cam = numeric_jacobian(lambda p: ideal_from_observed(xy, p, convention).xy, prm, scale)
    assert_jacobian(ideal.d_camera, cam, 1)
    if convention == IMAGE:  # residuals in the measured coordinates: d ideal / d measured
        obs = numeric_jacobian(lambda v: ideal_from_observed(v, prm, convention).xy, xy, 1e-4)
        assert_jacobian(ideal.d_obs, obs, 1)
    else:  # residuals in the refined coordinates: the ideal point moves with them one to one
        np.testing.assert_array_equal(ideal.d_obs, np.broadcast_to(np.eye(2), ideal.d_obs.shape))


def test_plate_convention_is_dbat_model_3():
    """DBAT's backward model 3: skew(brown(aniscale(u) - u0)) with aniscale diag(1 + b1, 1)
    about the origin; ours scales about the principal point, so xp = xp_dbat / (1 + b1)."""
    rng = np.random.default_rng(4)
    xy, prm = plate_camera(rng, 20)
    a = 1 + prm[:, lens.B1]
    u0 = np.stack([prm[:, lens.XP] * a, prm[:, lens.YP]], -1)
    scaled = np.stack([a * xy[:, 0], xy[:, 1]], -1) - u0
    v = brown(scaled, prm)[0]
    dbat = np.stack([v[:, 0] + prm[:, lens.B2] * v[:, 1], v[:, 1]], -1)
    ideal = ideal_from_observed(xy, prm, PLATE)
    np.testing.assert_allclose(ideal.xy - prm[:, lens.XP:lens.YP + 1], dbat, rtol=0, atol=1e-13)


def test_undistortion_inverts_distortion():
    rng = np.random.default_rng(5)
    n = rng.uniform(-0.6, 0.6, (200, 2))
    _, prm = image_camera(rng, 200)
    prm[:, lens.B1:] = 0.0
    c, pp = prm[:, lens.C], prm[:, lens.XP:lens.YP + 1]
    measured = pp + c[:, None] * brown(n, prm)[0]
    ideal = ideal_from_observed(measured, prm, IMAGE)
    assert ideal.converged.all()
    np.testing.assert_allclose(ideal.xy, pp + c[:, None] * n, rtol=0, atol=1e-9)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_projection_terms_derivatives(convention):
    """The bundle's residual pred - obs: derivative with respect to the camera elements (the ideal
    projection xp - c m/m_z moves with c, xp, yp as collinearity says) and to the ideal projection."""
    rng = np.random.default_rng(6 + convention)
    xy, prm = camera(convention, rng, 50)
    n = rng.uniform(-0.5, 0.5, (50, 2)) * (0.7 if convention == PLATE else 1.0)

    def residual(p):
        pred_ideal = p[:, lens.XP:lens.YP + 1] + p[:, lens.C, None] * n
        t = projection_terms(pred_ideal, xy, p, convention)
        return t.pred - t.obs
    scale = SCALES if convention == PLATE else np.array([1.0, 0.1, 0.1, 1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-4, 1e-4])
    pred_ideal = prm[:, lens.XP:lens.YP + 1] + prm[:, lens.C, None] * n
    terms = projection_terms(pred_ideal, xy, prm, convention)
    assert_jacobian(terms.d_camera, numeric_jacobian(residual, prm, scale), 1)
    d_ideal = numeric_jacobian(lambda q: projection_terms(q, xy, prm, convention).pred, pred_ideal, 1e-4)
    assert_jacobian(terms.d_ideal, d_ideal, 1)


def test_conventions_agree_when_distortion_is_zero():
    rng = np.random.default_rng(7)
    xy, prm = plate_camera(rng, 10)
    prm[:, lens.K1:] = 0.0
    a = ideal_from_observed(xy, prm, PLATE)
    b = ideal_from_observed(xy, prm, IMAGE)
    np.testing.assert_allclose(a.xy, xy, atol=1e-14)
    np.testing.assert_allclose(b.xy, xy, atol=1e-12)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_observed_from_ideal_inverts_ideal_from_observed(convention):
    rng = np.random.default_rng(8 + convention)
    xy, prm = camera(convention, rng, 100)
    ideal = ideal_from_observed(xy, prm, convention).xy
    np.testing.assert_allclose(lens.observed_from_ideal(ideal, prm, convention), xy, rtol=0,
                               atol=1e-11 * np.abs(xy).max())


def test_image_convention_affinity_and_shear_is_the_calibration_matrix():
    """x = xp + c ((1 + b1) dx + b2 dy), y = yp + c dy with (dx, dy) = brown(n): the pinhole K with
    fx = c (1 + b1), fy = c, skew c b2 after the distortion, written out; the undistortion inverts it."""
    rng = np.random.default_rng(12)
    _, prm = image_camera(rng, 100)
    prm[:, lens.B1], prm[:, lens.B2] = 4e-3, -3e-3
    n = rng.uniform(-0.6, 0.6, (100, 2))
    c, xp, yp = prm[:, lens.C], prm[:, lens.XP], prm[:, lens.YP]
    d = brown(n, prm)[0]
    K = np.zeros((100, 2, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 0, 2] = c * (1 + prm[:, lens.B1]), c * prm[:, lens.B2], xp
    K[:, 1, 1], K[:, 1, 2] = c, yp
    by_hand = np.einsum("mij,mj->mi", K, np.column_stack([d, np.ones(100)]))
    ideal = prm[:, lens.XP:lens.YP + 1] + c[:, None] * n
    np.testing.assert_allclose(lens.observed_from_ideal(ideal, prm, IMAGE), by_hand, rtol=0, atol=1e-10)
    back = ideal_from_observed(by_hand, prm, IMAGE)
    assert back.converged.all()
    np.testing.assert_allclose(back.xy, ideal, rtol=0, atol=1e-9)
    t = projection_terms(ideal, by_hand, prm, IMAGE)
    np.testing.assert_allclose(t.pred, by_hand, rtol=0, atol=1e-10)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
@pytest.mark.parametrize("distorted", [False, True])
def test_ideal_xy_is_the_ideal_point_of_ideal_from_observed(convention, distorted):
    """ideal_xy (the rays' callers: no derivatives, and no polynomial for cameras without
    distortion, affinity or shear) gives ideal_from_observed's points to the last bit, for
    measurements and for adjusted observations beside their measurements."""
    rng = np.random.default_rng(17 + convention)
    xy, prm = camera(convention, rng, 500)
    if not distorted:
        prm[:, lens.DISTORTION_ELEMENTS] = 0.0
    measured = xy + rng.normal(0, 1e-3, xy.shape)
    for at, meas in ((xy, None), (xy, measured)):
        want = ideal_from_observed(at, prm, np.full(len(xy), convention), meas).xy
        got = lens.ideal_xy(at, prm, np.full(len(xy), convention), meas)
        assert np.array_equal(got, want)
    if not distorted:  # the points themselves, to round-off
        assert np.allclose(lens.ideal_xy(xy, prm, convention), xy, rtol=0, atol=1e-12)
