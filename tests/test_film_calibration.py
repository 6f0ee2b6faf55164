"""The calibration report turned into the camera model (striptri.film.calibration; issue 16).

Real reports: three USGS "Report of Calibration of Aerial Mapping Camera" (Wild RC30, Universal
Aviogon 153 mm), their printed values copied from the public copies at
https://docsbay.net/usgs-report-no (OSL/3030, May 11 2004),
https://studylib.net/doc/7485600/leica-rc-30-5368--lens-15-4-uag (OSL/2985, November 5 2003) and
https://docest.com/doc/367072/usgs-report-no (OSL/3221, 2006). Each prints the calibrated focal
length, the symmetric radial distortion in micrometres at field angles 7.5, 15, 22.7, 30, 35 and
40 deg (rounded to 1 um), the SMAC parameters K0, K1, K2 and the calibrated principal point (point
of symmetry).

Tolerances from the printed format: each printed value is the report's polynomial rounded to
1 um, so the report's own polynomial is within 0.5 um of every printed value (plus 0.05 um for the
4 significant digits of the printed K's); a least-squares fit of the same three terms has a sum of
squared residuals no larger than that polynomial's (it minimises it), so its rms is <= 0.5 um.
"""

from __future__ import annotations

import numpy as np
import pytest

from striptri.film import calibration as calib
from striptri.geometry.lens import PLATE, ideal_from_observed

ANGLES = np.array([7.5, 15.0, 22.7, 30.0, 35.0, 40.0])
# report: (CFL mm, printed distortion um, K0, K1, K2, (xp, yp) mm)
USGS = {
    "OSL/3030": (153.247, [-1, -1, -1, 0, 1, 1], 0.3285e-4, -0.5215e-8, 0.1642e-12, (0.006, -0.001)),
    "OSL/2985": (153.743, [-1, -1, -1, -1, 0, 1], 0.2616e-4, -0.2295e-8, 0.1454e-13, (-0.009, 0.002)),
    "OSL/3221": (153.527, [-1, -2, -3, -3, -1, 3], 0.6404e-4, -0.3587e-8, -0.9784e-13, (-0.013, 0.008)),
}


@pytest.mark.parametrize("report", sorted(USGS))
def test_the_printed_parameters_reproduce_the_printed_table(report):
    """The sign convention: a report's printed distortion is -(K0 r + K1 r^3 + K2 r^5), r = CFL tan(angle)."""
    cfl, dr, k0, k1, k2, _ = USGS[report]
    r = cfl * np.tan(np.radians(ANGLES))
    model = calib.model_distortion_mm(r, np.array([k1, k2, 0.0]), k0) * 1000
    assert np.abs(model - np.array(dr)).max() <= 0.5 + 0.05


@pytest.mark.parametrize("report", sorted(USGS))
def test_a_real_report_table_is_fitted_to_its_printed_precision(report):
    cfl, dr, k0, k1, k2, _ = USGS[report]
    r = cfl * np.tan(np.radians(ANGLES))
    fit = calib.fit_radial_distortion(r, dr, n_terms=2, linear_term=True)
    own = calib.model_distortion_mm(r, np.array([k1, k2, 0.0]), k0) * 1000 - np.array(dr)
    assert np.sum(fit.residual_um ** 2) <= np.sum(own ** 2) + 1e-12
    assert np.sqrt(np.mean(fit.residual_um ** 2)) <= 0.5
    # the fitted curve and the report's agree to the printing's precision over the whole table
    assert np.abs(fit.model_um - (own + np.array(dr))).max() <= 1.0


def test_noise_free_table_gives_the_coefficients():
    r = np.arange(10.0, 160.0, 10.0)
    k = np.array([-2e-8, 1.5e-12, -3e-17])
    dr = calib.model_distortion_mm(r, k, 4e-5) * 1000
    fit = calib.fit_radial_distortion(r, dr, n_terms=3, linear_term=True)
    np.testing.assert_allclose(fit.k, k, rtol=1e-7)
    assert abs(fit.k0 - 4e-5) < 1e-12 and np.abs(fit.residual_um).max() < 1e-9


def test_diagonals_are_averaged():
    r = np.arange(10.0, 110.0, 10.0)
    dr = calib.model_distortion_mm(r, np.array([-2e-8, 1e-12, 0.0])) * 1000
    rows = np.stack([dr + 1, dr - 1, dr + 0.5, dr - 0.5])
    rows[0, 3] = np.nan
    fit = calib.fit_radial_distortion(r, rows)
    expected = np.nanmean(rows, axis=0)
    np.testing.assert_allclose(fit.dr_um, expected)


def test_k0_folded_into_c_gives_the_same_rays():
    """x (1 + K0 + K1 r^2 + K2 r^4) + decentring with c gives the ray of the folded model
    (c / (1 + K0), k / (1 + K0)) through striptri.geometry.lens: the two directions are parallel."""
    rng = np.random.default_rng(7)
    k0, k, p1, p2, c, pp = 6e-5, np.array([-3.6e-9, -9.8e-14, 0.0]), -5.8e-8, 1.9e-8, 153.527, (-0.013, 0.008)
    fit = calib.RadialFit(np.zeros(0), np.zeros(0), k, np.zeros(0), np.zeros(0), 0.0, 2, k0)
    el = calib.camera_elements(c, pp, fit, p1, p2)
    xy = rng.uniform(-110, 110, (50, 2))
    u = xy - pp
    r2 = (u ** 2).sum(1)
    radial = k0 + k[0] * r2 + k[1] * r2 ** 2
    dec = np.column_stack([p1 * (r2 + 2 * u[:, 0] ** 2) + 2 * p2 * u[:, 0] * u[:, 1],
                           2 * p1 * u[:, 0] * u[:, 1] + p2 * (r2 + 2 * u[:, 1] ** 2)])
    ray_report = np.column_stack([u * (1 + radial[:, None]) + dec, np.full(50, -c)])
    ideal = ideal_from_observed(xy, el, np.full(50, PLATE)).xy
    ray_model = np.column_stack([ideal - pp, np.full(50, -el[0])])
    cross = np.cross(ray_report / np.linalg.norm(ray_report, axis=1)[:, None],
                     ray_model / np.linalg.norm(ray_model, axis=1)[:, None])
    assert np.abs(cross).max() < 1e-13
