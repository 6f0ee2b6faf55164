"""Interior orientation from fiducial marks (striptri.film.transform, striptri.film.fiducials; issue 16)."""

from __future__ import annotations

import numpy as np
import pytest

from striptri.film import fiducials, transform
from striptri.simulate.film import FIDUCIALS_MM

SIGMA_PX = 0.5


def true_params(kind: str, n: int, rng) -> np.ndarray:
    """Scan transformations of n photos: 50 px/mm, rotation up to 1 deg, shrinkage, shifts; for the
    projective kind a film not quite flat in the scanner (h6, h7 ~ 1e-5 / mm)."""
    s = 50.0 * (1 - rng.uniform(0, 2e-4, (n, 2)))
    a = np.radians(rng.uniform(-1, 1, n))
    t = np.column_stack([6000 + rng.uniform(-30, 30, n), -6000 + rng.uniform(-30, 30, n)])
    if kind == "similarity":
        return np.column_stack([s[:, 0] * np.cos(a), s[:, 0] * np.sin(a), t])
    affine = np.column_stack([t[:, 0], s[:, 0] * np.cos(a), -s[:, 1] * np.sin(a),
                              t[:, 1], s[:, 0] * np.sin(a), s[:, 1] * np.cos(a)])
    if kind == "affine":
        return affine
    return np.column_stack([affine[:, [1, 2, 0, 4, 5, 3]], rng.uniform(-1e-5, 1e-5, (n, 2))])


def measure(kind, p, rng, sigma=0.0):
    n = len(p)
    xy = np.broadcast_to(FIDUCIALS_MM, (n,) + FIDUCIALS_MM.shape)
    q, _, _ = transform.scan_from_plate(kind, p, xy)
    return xy, q + rng.normal(0.0, sigma, q.shape) if sigma else q


@pytest.mark.parametrize("kind", transform.KINDS)
def test_noise_free_plate_coordinates_equal_the_true_ones(kind):
    """Fiducials and image points without noise: the plate coordinates computed through the fitted
    transformation equal the true ones to 1e-9 mm; the fit's residuals vanish."""
    rng = np.random.default_rng(1)
    p = true_params(kind, 6, rng)
    xy, q = measure(kind, p, rng)
    fit = fiducials.fit_fiducials(kind, xy, q, np.full(xy.shape[:2], SIGMA_PX), np.ones(xy.shape[:2], bool))
    assert np.abs(np.nan_to_num(fit.v)).max() < 1e-7  # px
    assert not fit.flagged.any()
    xy_true = rng.uniform(-115, 115, (200, 2))
    photo = rng.integers(0, 6, 200)
    q_pts, _, _ = transform.scan_from_plate(kind, p[photo], xy_true[:, None])
    xy_plate, cov, sigma = fiducials.plate_points(fit, photo, q_pts[:, 0], np.full((200, 2), SIGMA_PX))
    assert np.abs(xy_plate - xy_true).max() < 1e-9
    assert np.all(sigma > 0.5 / 50 * 0.99)  # at least the measurement's own 0.5 px at 50 px/mm


@pytest.mark.parametrize("kind", transform.KINDS)
def test_jacobians_against_central_differences(kind):
    rng = np.random.default_rng(2)
    p = true_params(kind, 3, rng)
    xy = rng.uniform(-110, 110, (3, 5, 2))
    q, d_xy, d_p = transform.scan_from_plate(kind, p, xy)
    for j in range(2):
        h = np.zeros(2)
        h[j] = 1e-4
        num = (transform.scan_from_plate(kind, p, xy + h)[0] - transform.scan_from_plate(kind, p, xy - h)[0]) / 2e-4
        np.testing.assert_allclose(d_xy[..., j], num, rtol=1e-7, atol=1e-6)
    for j in range(p.shape[1]):
        h = np.zeros(p.shape[1])
        h[j] = 1e-7 * max(1.0, abs(p[0, j]))
        num = (transform.scan_from_plate(kind, p + h, xy)[0] - transform.scan_from_plate(kind, p - h, xy)[0]) / (2 * h[j])
        np.testing.assert_allclose(d_p[..., j], num, rtol=1e-6, atol=1e-4 * np.abs(d_p).max())
    # the inverse: xy = F^-1(q; p)
    pp, qq = p[[0, 1, 2]], q[:, 0]
    xy_back, J_q, J_p = transform.plate_from_scan(kind, pp, qq)
    for j in range(2):
        h = np.zeros(2)
        h[j] = 1e-3
        num = (transform.plate_from_scan(kind, pp, qq + h)[0] - transform.plate_from_scan(kind, pp, qq - h)[0]) / 2e-3
        np.testing.assert_allclose(J_q[..., j], num, rtol=1e-6, atol=1e-9)
    for j in range(p.shape[1]):
        h = np.zeros(p.shape[1])
        h[j] = 1e-7 * max(1.0, abs(p[0, j]))
        num = (transform.plate_from_scan(kind, pp + h, qq)[0] - transform.plate_from_scan(kind, pp - h, qq)[0]) / (2 * h[j])
        np.testing.assert_allclose(J_p[..., j], num, rtol=1e-5, atol=1e-6 * np.abs(J_p).max())


@pytest.mark.parametrize("kind", transform.KINDS)
def test_a_fiducial_with_a_20_pixel_error_is_flagged(kind):
    """One fiducial of photo 0 off by 20 px (40 sigma) in col: it, and only it, is flagged; the
    photo's sigma0 is reported, and without the bad mark is that of the noise (the other photos'
    sigma0 are unaffected)."""
    rng = np.random.default_rng(3)
    p = true_params(kind, 4, rng)
    xy, q = measure(kind, p, rng, SIGMA_PX)
    q[0, 2, 0] += 20.0
    ones = np.ones(xy.shape[:2], bool)
    fit = fiducials.fit_fiducials(kind, xy, q, np.full(xy.shape[:2], SIGMA_PX), ones)
    assert fit.flagged[0, 2] and fit.flagged.sum() == 1
    assert abs(fit.w[0, 2, 0]) > 20
    assert np.isfinite(fit.sigma0).all()
    # sigma0 without the mark: its redundancy is 2 less than the others'
    assert fit.redundancy[0] == fit.redundancy[1] - 2
    # after snooping the photo's sigma0 is a noise level (P(sigma0 > 3 | r >= 2) < 1e-3), not the blunder's
    assert fit.sigma0[0] < 3.0
    # the flagged mark's residual against the final fit is close to the 20 px put in
    assert abs(fit.v[0, 2, 0] + 20.0) < 3.0


def test_no_redundancy_no_test():
    """4 fiducials, projective: 8 observations for 8 parameters; sigma0 and w are nan, nothing flagged."""
    rng = np.random.default_rng(4)
    p = true_params("projective", 2, rng)
    xy, q = measure("projective", p, rng, SIGMA_PX)
    measured = np.zeros(xy.shape[:2], bool)
    measured[:, :4] = True
    fit = fiducials.fit_fiducials("projective", xy, q, np.full(xy.shape[:2], SIGMA_PX), measured)
    assert np.all(fit.redundancy == 0) and np.isnan(fit.sigma0).all()
    assert np.isnan(fit.w).all() and not fit.flagged.any()


@pytest.mark.parametrize("kind", transform.KINDS)
def test_sigma0_and_propagated_plate_covariance_match_the_noise(kind):
    """T = 2000 photos with fiducial noise, one image point each with point noise.

    * sigma0^2 r ~ chi^2(r) per photo: the pooled sum over T photos ~ chi^2(T r); its ratio to
      T r has standard deviation sqrt(2 / (T r)); allowed 4 of them.
    * the plate point's error e (2,) against the propagated covariance C (the transformation's
      parameters and the point's own noise): e^T C^-1 e ~ chi^2(2) to first order (the projective
      inverse is nonlinear: relative terms ~ 1e-5 here); its mean over T within 4 sqrt(4 / T) of 2.
    """
    T = 2000
    rng = np.random.default_rng(5)
    p = true_params(kind, T, rng)
    xy, q = measure(kind, p, rng, SIGMA_PX)
    fit = fiducials.fit_fiducials(kind, xy, q, np.full(xy.shape[:2], SIGMA_PX), np.ones(xy.shape[:2], bool))
    r = fit.redundancy.sum()
    # snooping removes ~0.1 % of good marks (alpha = 0.001 per coordinate): keep only photos with none
    ok = ~fit.flagged.any(1)
    ratio = np.nansum((fit.sigma0 ** 2 * fit.redundancy)[ok]) / fit.redundancy[ok].sum()
    assert abs(ratio - 1.0) < 4 * np.sqrt(2.0 / r)
    xy_true = rng.uniform(-110, 110, (T, 2))
    q_pts, _, _ = transform.scan_from_plate(kind, p, xy_true[:, None])
    q_meas = q_pts[:, 0] + rng.normal(0.0, SIGMA_PX, (T, 2))
    xy_plate, cov, _ = fiducials.plate_points(fit, np.arange(T), q_meas, np.full((T, 2), SIGMA_PX))
    e = (xy_plate - xy_true)[ok]
    m = np.einsum("ti,tij,tj->t", e, np.linalg.inv(cov[ok]), e)
    assert abs(m.mean() - 2.0) < 4 * np.sqrt(4.0 / ok.sum())
