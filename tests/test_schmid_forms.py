"""Schmid's special forms reproduced by the general machinery: the normal case of the coplanarity
observation equation (70)/(71), the pair intersection (72-74), the independent triangulation
(75-80) and the mean error of a base component (85-86)."""

import numpy as np
import pytest

from striptri.geometry.camera import plate_vector
from striptri.equations.conditions import RayConditions, coplanarity, closest_scales, ray_chain
from striptri.geometry.rotations import R_from_aoc, angles_jacobian
from striptri.equations.triangulation import independent_pair_triangulation, intersect_rays, schmid_pair_intersection


def _normal_case_coefficients(xy1, xy2, c):
    """Our coplanarity linearised in the normal case (alpha = 180 deg, omega = chi = 0, base along X
    of unit length): coefficients of the plate residuals and of (d alpha, d omega, d chi) per photo."""
    R = np.broadcast_to(R_from_aoc(np.array([np.pi, 0.0, 0.0])), (1, 2, 3, 3))
    interior = np.array([[[c, 0.0, 0.0], [c, 0.0, 0.0]]])
    xy = np.array([[xy1, xy2]])
    p = plate_vector(xy, interior)
    r = np.einsum("mkij,mkj->mki", R, p)
    b = np.array([[1.0, 0.0, 0.0]])
    g, dg_b, dg_r1, dg_r2 = coplanarity(b, r[:, 0], r[:, 1])
    d_r = np.stack([dg_r1, dg_r2], 1)[:, None]
    lin = ray_chain(RayConditions(g[:, None], d_r, np.zeros_like(d_r), np.zeros((1, 1, 3))), R, p)
    # rotation vector -> Schmid's angles: d = J^-1 d(alpha, omega, chi)
    Jinv = np.linalg.inv(angles_jacobian(R[0], "alpha-omega-chi"))
    d_angles = np.einsum("ki,kij->kj", lin.d_rot[0, 0], Jinv)
    return g[0], lin.d_plate[0, 0], d_angles


@pytest.mark.parametrize("seed", range(5))
def test_normal_case_reduces_to_schmid_70(seed):
    rng = np.random.default_rng(seed)
    c = 152.0
    x1, y1, x2, y2 = rng.uniform(-100, 100, 4)
    g, d_plate, d_angles = _normal_case_coefficients((x1, y1), (x2, y2), c)
    # Schmid (70): c (v_y'' - v_y') = -y''x' da' + (c^2 + y'y'') dw' - c x' dchi'
    #              + y'x'' da'' - (c^2 + y'y'') dw'' + c x'' dchi'' - c (y'' - y')
    # ours: A v + B dx + w = 0, so Schmid's coefficients of the unknowns are -B and his
    # absolute term is -w.
    assert g == pytest.approx(c * (y2 - y1), rel=1e-12)
    np.testing.assert_allclose(d_plate, [[0.0, -c], [0.0, c]], atol=1e-9)
    expected = np.array([[-y2 * x1, c**2 + y1 * y2, -c * x1], [y1 * x2, -(c**2 + y1 * y2), c * x2]])
    np.testing.assert_allclose(-d_angles, expected, rtol=1e-10, atol=1e-9)


def test_schmid_71_is_70_divided_by_c_for_equal_y():
    """(71) follows from (70) with y' = y'' = y: v_p = (y x''/c) da'' - (y x'/c) da' + ... """
    c, y = 152.0, 37.0
    x1, x2 = 60.0, -30.0
    _, _, d_angles = _normal_case_coefficients((x1, y), (x2, y), c)
    coeff = -d_angles / c
    np.testing.assert_allclose(coeff[1, 0], y * x2 / c, rtol=1e-10)
    np.testing.assert_allclose(coeff[0, 0], -y * x1 / c, rtol=1e-10)
    np.testing.assert_allclose(coeff[1, 2], x2, rtol=1e-10)
    np.testing.assert_allclose(coeff[0, 2], -x1, rtol=1e-10)
    np.testing.assert_allclose(coeff[1, 1], -c * (1 + y**2 / c**2), rtol=1e-10)


def _intersecting_pair(rng, m=20):
    O1 = rng.normal(0, 5, (m, 3)) + [0, 0, 1500]
    O2 = O1 + [600, 0, 0] + rng.normal(0, 10, (m, 3))
    X = np.column_stack([rng.uniform(-200, 800, m), rng.uniform(-500, 500, m), rng.normal(100, 30, m)])
    return O1, X - O1, O2, (X - O2) * rng.uniform(0.001, 0.01, (m, 1)), X


def test_schmid_pair_intersection_matches_closest_approach():
    rng = np.random.default_rng(3)
    O1, r1, O2, r2, X = _intersecting_pair(rng)
    Xs, mu1, mu2 = schmid_pair_intersection(O1, r1, O2, r2)
    np.testing.assert_allclose(Xs, X, atol=1e-8)
    s, t, _, _ = closest_scales(O2 - O1, r1, r2)
    np.testing.assert_allclose(mu1, s, rtol=1e-10)
    np.testing.assert_allclose(mu2, t, rtol=1e-10)
    Xm = intersect_rays(np.stack([O1, O2], 1), np.stack([r1, r2], 1))
    np.testing.assert_allclose(Xm, X, atol=1e-8)


def test_independent_triangulation_75_80():
    """Rays made not to intersect by plate noise: one condition, one normal equation; the adjusted
    observations satisfy (20), the check (80) v^T P v = -w k holds, and the residuals are the
    least-squares ones (no smaller vtpv on the condition's manifold, checked by perturbation)."""
    rng = np.random.default_rng(4)
    m = 30
    c = 152.0
    from striptri.geometry.camera import project
    from striptri.geometry.rotations import R_from_opk

    R1 = R_from_opk(rng.normal(0, 0.03, (m, 3)))
    R2 = R_from_opk(rng.normal(0, 0.03, (m, 3)))
    O1 = np.tile([0.0, 0.0, 1500.0], (m, 1))
    O2 = np.tile([600.0, 0.0, 1510.0], (m, 1))
    X = np.column_stack([rng.uniform(0, 600, m), rng.uniform(-400, 400, m), rng.normal(100, 30, m)])
    interior = np.tile([c, 0.0, 0.0], (m, 1))
    xy1 = project(R1, O1, interior, X) + rng.normal(0, 0.005, (m, 2))
    xy2 = project(R2, O2, interior, X) + rng.normal(0, 0.005, (m, 2))
    sig = np.full((m, 4), 0.005)
    res = independent_pair_triangulation(np.stack([R1, R2], 1), np.stack([O1, O2], 1), np.stack([interior] * 2, 1),
                                         np.concatenate([xy1, xy2], 1), sig)
    g0, *_ = coplanarity(O2 - O1, *(np.einsum("mij,mj->mi", R, plate_vector(xy, interior)) for R, xy in ((R1, xy1), (R2, xy2))))
    assert np.abs(res.misclosure).max() < 1e-9 * np.abs(g0).max()
    # (80): v^T P v = -w k, with w the absolute term of the last linearisation
    np.testing.assert_allclose(res.vtpv, -res.w * res.k, rtol=1e-9)
    # a point's coordinates are ~ the true ones (precision of a 0.005 mm plate at 1:10000: dm)
    assert np.abs(res.xyz - X).max() < 1.0
    # v^T P v is chi-square with one degree of freedom: the mean of 30 has std sqrt(2/30)
    assert abs(np.mean(res.vtpv) - 1.0) < 4 * np.sqrt(2 / m)
    # least squares: an independent constrained minimisation finds the same residuals
    from scipy.optimize import minimize

    for j in range(3):
        l0 = np.concatenate([xy1[j], xy2[j]])

        def cond(l):
            r1 = R1[j] @ plate_vector(l[:2], interior[j])
            r2 = R2[j] @ plate_vector(l[2:], interior[j])
            return coplanarity((O2 - O1)[j][None], r1[None], r2[None])[0][0] / 1e6

        sol = minimize(lambda l: np.sum((l - l0) ** 2) / 0.005**2, l0, constraints=[{"type": "eq", "fun": cond}],
                       method="SLSQP", options={"ftol": 1e-14, "maxiter": 200})
        np.testing.assert_allclose(sol.x - l0, res.v[j], atol=1e-7)
