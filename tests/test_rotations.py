"""Rotations: both angle conventions, their exact conversions both ways, Schmid's auxiliaries (9)
and rays (11), and the rotation vector."""

import numpy as np
import pytest

from striptri.geometry.camera import project, ray_ground
from striptri.geometry.rotations import (
    R_from_aoc,
    R_from_opk,
    R_from_pok,
    angles_from_R,
    aoc_from_R,
    exp_so3,
    log_so3,
    opk_from_R,
    pok_from_R,
    schmid_auxiliaries,
    skew,
    wrap_angle,
)


def _random_rotations(rng, n):
    return exp_so3(rng.normal(size=(n, 3)) * rng.uniform(0, 3, (n, 1)))


def test_opk_is_rx_ry_rz():
    omega, phi, kappa = 0.3, -0.2, 1.1
    rx = np.array([[1, 0, 0], [0, np.cos(omega), -np.sin(omega)], [0, np.sin(omega), np.cos(omega)]])
    ry = np.array([[np.cos(phi), 0, np.sin(phi)], [0, 1, 0], [-np.sin(phi), 0, np.cos(phi)]])
    rz = np.array([[np.cos(kappa), -np.sin(kappa), 0], [np.sin(kappa), np.cos(kappa), 0], [0, 0, 1]])
    np.testing.assert_allclose(R_from_opk([omega, phi, kappa]), rx @ ry @ rz, atol=1e-15)


@pytest.mark.parametrize("convention", ["omega-phi-kappa", "alpha-omega-chi", "phi-omega-kappa"])
def test_conversions_both_ways_for_any_rotation(convention):
    rng = np.random.default_rng(0)
    R = _random_rotations(rng, 500)
    angles = angles_from_R(R, convention)
    from striptri.geometry.rotations import R_from_angles

    np.testing.assert_allclose(R_from_angles(angles, convention), R, atol=1e-13)
    np.testing.assert_allclose(angles_from_R(R_from_angles(angles, convention), convention), angles, atol=1e-12)


def test_opk_and_aoc_describe_the_same_rotation():
    rng = np.random.default_rng(1)
    R = _random_rotations(rng, 200)
    np.testing.assert_allclose(R_from_opk(opk_from_R(R)), R_from_aoc(aoc_from_R(R)), atol=1e-13)


def test_schmid_matrix_is_a_proper_rotation_and_normal_case_is_identity():
    rng = np.random.default_rng(2)
    R = R_from_aoc(rng.uniform(-np.pi, np.pi, (100, 3)))
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    np.testing.assert_allclose(R_from_aoc([np.pi, 0.0, 0.0]), np.eye(3), atol=1e-15)


def test_ray_is_schmid_11():
    """u = (x-xp) A1 + (y-yp) A2 + c D1, v = ... B, E, w = ... C, F (Schmid 11)."""
    rng = np.random.default_rng(3)
    angles = rng.uniform(-1, 1, (50, 3))
    xy = rng.uniform(-100, 100, (50, 2))
    interior = np.column_stack([rng.uniform(80, 200, 50), rng.normal(0, 0.1, (50, 2))])
    s = schmid_auxiliaries(angles)
    dx, dy, c = xy[:, 0] - interior[:, 1], xy[:, 1] - interior[:, 2], interior[:, 0]
    uvw = np.column_stack([dx * s["A1"] + dy * s["A2"] + c * s["D1"],
                           dx * s["B1"] + dy * s["B2"] + c * s["E1"],
                           dx * s["C1"] + dy * s["C2"] + c * s["F1"]])
    np.testing.assert_allclose(ray_ground(R_from_aoc(angles), xy, interior), uvw, atol=1e-11)


def test_collinearity_is_schmid_14_and_inverts_the_ray():
    """x = c [(X)A1 + (Y)B1 + (Z)C1] / q + xp, q = (X)D1 + (Y)E1 + (Z)F1 (Schmid 14)."""
    rng = np.random.default_rng(4)
    n = 50
    angles = rng.uniform(-0.5, 0.5, (n, 3)) + [np.pi, 0, 0]
    O = rng.normal(0, 100, (n, 3)) + [0, 0, 1500]
    X = rng.normal(0, 300, (n, 3))
    interior = np.column_stack([np.full(n, 152.0), rng.normal(0, 0.1, (n, 2))])
    s = schmid_auxiliaries(angles)
    d = X - O
    q = d[:, 0] * s["D1"] + d[:, 1] * s["E1"] + d[:, 2] * s["F1"]
    x = interior[:, 0] * (d[:, 0] * s["A1"] + d[:, 1] * s["B1"] + d[:, 2] * s["C1"]) / q + interior[:, 1]
    y = interior[:, 0] * (d[:, 0] * s["A2"] + d[:, 1] * s["B2"] + d[:, 2] * s["C2"]) / q + interior[:, 2]
    R = R_from_aoc(angles)
    xy = project(R, O, interior, X)
    np.testing.assert_allclose(xy, np.column_stack([x, y]), atol=1e-10)
    r = ray_ground(R, xy, interior)
    np.testing.assert_allclose(np.cross(r, d), 0.0, atol=1e-8 * np.abs(r).max() * np.abs(d).max())


def test_exp_log_and_skew():
    rng = np.random.default_rng(5)
    u = rng.normal(size=(100, 3))
    d = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0, 3.1, (100, 1))  # angles < pi
    np.testing.assert_allclose(log_so3(exp_so3(d)), d, atol=1e-10)
    np.testing.assert_allclose(exp_so3(1e-10 * d), np.eye(3) + skew(1e-10 * d), atol=1e-18)
    a, b = rng.normal(size=(2, 100, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), atol=1e-14)


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle(np.array([0.1, 2 * np.pi + 0.1, -2 * np.pi - 0.1])), [0.1, 0.1, -0.1])


def test_pok_is_ry_rx_rz_with_phi_first():
    phi, omega, kappa = 0.3, -0.2, 1.1
    rx = np.array([[1, 0, 0], [0, np.cos(omega), -np.sin(omega)], [0, np.sin(omega), np.cos(omega)]])
    ry = np.array([[np.cos(phi), 0, np.sin(phi)], [0, 1, 0], [-np.sin(phi), 0, np.cos(phi)]])
    rz = np.array([[np.cos(kappa), -np.sin(kappa), 0], [np.sin(kappa), np.cos(kappa), 0], [0, 0, 1]])
    np.testing.assert_allclose(R_from_pok([phi, omega, kappa]), ry @ rx @ rz, atol=1e-15)


def test_pok_round_trips_to_1e12_rad_and_describes_the_same_rotation_as_opk():
    """Angles in the convention's range (phi, kappa in (-pi, pi], omega in [-pi/2, pi/2]) -> R ->
    angles to 1e-12 rad; opk and pok of one R give the same R."""
    rng = np.random.default_rng(11)
    angles = np.column_stack([rng.uniform(-np.pi, np.pi, 1000), rng.uniform(-1.55, 1.55, 1000),
                              rng.uniform(-np.pi, np.pi, 1000)])
    np.testing.assert_allclose(pok_from_R(R_from_pok(angles)), angles, rtol=0, atol=1e-12)
    R = _random_rotations(rng, 300)
    np.testing.assert_allclose(R_from_pok(pok_from_R(R)), R_from_opk(opk_from_R(R)), atol=1e-13)
    # a small rotation about Y alone is phi in pok and phi in opk
    np.testing.assert_allclose(pok_from_R(R_from_opk([0.0, 0.2, 0.0])), [0.2, 0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("convention", ["omega-phi-kappa", "alpha-omega-chi", "phi-omega-kappa"])
def test_gimbal_lock_angles_reproduce_the_matrix(convention):
    """At the lock of the middle angle (+-90 deg) the angles are not unique; the conversion must
    still give angles whose matrix is the given one (the same behaviour for every convention)."""
    from striptri.geometry.rotations import R_from_angles

    for first in (0.3, -1.2, 2.9):
        for middle in (np.pi / 2, -np.pi / 2):
            angles = np.array([first + (np.pi if convention == "alpha-omega-chi" else 0.0), middle, 0.7])
            R = R_from_angles(angles, convention)
            back = angles_from_R(R, convention)
            np.testing.assert_allclose(R_from_angles(back, convention), R, atol=1e-15)
            assert abs(abs(back[1]) - np.pi / 2) < 1e-7
