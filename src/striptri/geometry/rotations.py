"""Rotations, batched over a leading axis (DESIGN section 1).

Three angle conventions for ``R_ground_from_cam``:

* omega-phi-kappa: ``R = Rx(omega) Ry(phi) Rz(kappa)`` (primary axis X);
* phi-omega-kappa: ``R = Ry(phi) Rx(omega) Rz(kappa)`` (primary axis Y; the order of many European
  and Chinese textbooks and programs); the angles are stored in the order (phi, omega, kappa);
* Schmid's alpha-omega-chi (Schmid 9): the columns of R are (A1, B1, C1), (A2, B2, C2) and
  -(D1, E1, F1), so that the ray of Schmid (11), ``u = (x-xp) A1 + (y-yp) A2 + c D1`` etc., is
  ``R p`` with the diapositive vector ``p = (x - xp, y - yp, -c)``. His normal case
  alpha = 180 deg, omega = chi = 0 is ``R = I``.

Unknown corrections are a rotation vector applied on the right: ``R <- R Exp(d)``.
"""

from __future__ import annotations

import numpy as np


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def R_from_opk(angles: np.ndarray) -> np.ndarray:
    """R_ground_from_cam = Rx(omega) Ry(phi) Rz(kappa). angles: (..., 3) radians -> (..., 3, 3)."""
    angles = np.asarray(angles, dtype=float)
    return _rx(angles[..., 0]) @ _ry(angles[..., 1]) @ _rz(angles[..., 2])


def opk_from_R(R: np.ndarray) -> np.ndarray:
    """Inverse of R_from_opk, phi in [-90, 90] deg. R: (..., 3, 3) -> (..., 3) radians."""
    R = np.asarray(R, dtype=float)
    omega = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    phi = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    kappa = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    return np.stack([omega, phi, kappa], -1)


def R_from_pok(angles: np.ndarray) -> np.ndarray:
    """R_ground_from_cam = Ry(phi) Rx(omega) Rz(kappa). angles: (..., 3) radians, order (phi, omega,
    kappa) -> (..., 3, 3)."""
    angles = np.asarray(angles, dtype=float)
    return _ry(angles[..., 0]) @ _rx(angles[..., 1]) @ _rz(angles[..., 2])


def pok_from_R(R: np.ndarray) -> np.ndarray:
    """Inverse of R_from_pok, omega in [-90, 90] deg. R: (..., 3, 3) -> (..., 3) radians (phi, omega,
    kappa).

    R[1, 2] = -sin(omega); R[0, 2] = sin(phi) cos(omega); R[2, 2] = cos(phi) cos(omega);
    R[1, 0] = cos(omega) sin(kappa); R[1, 1] = cos(omega) cos(kappa). At gimbal lock (omega = +-90
    deg) phi and kappa are not separable; as in opk_from_R and aoc_from_R nothing special is done:
    atan2 of the entries that carry the factor cos(omega) (rounded, not zero, for a matrix made from
    angles) recovers the angles; the Jacobian is singular there (the adjustment never uses angles,
    only the rotation vector).
    """
    R = np.asarray(R, dtype=float)
    phi = np.arctan2(R[..., 0, 2], R[..., 2, 2])
    omega = np.arcsin(np.clip(-R[..., 1, 2], -1.0, 1.0))
    kappa = np.arctan2(R[..., 1, 0], R[..., 1, 1])
    return np.stack([phi, omega, kappa], -1)


def schmid_auxiliaries(angles: np.ndarray) -> dict[str, np.ndarray]:
    """Schmid's rotational auxiliaries A1..H2 (formula 9) from alpha, omega, chi (radians), batched."""
    a, w, x = (np.asarray(angles, dtype=float)[..., i] for i in range(3))
    sa, ca, sw, cw, sx, cx = np.sin(a), np.cos(a), np.sin(w), np.cos(w), np.sin(x), np.cos(x)
    return {
        "A1": -ca * cx + sa * sw * sx, "A2": -ca * sx - sa * sw * cx,
        "B1": -cw * sx, "B2": cw * cx,
        "C1": sa * cx + ca * sw * sx, "C2": sa * sx - ca * sw * cx,
        "D1": sa * cw, "D2": sa * sw,
        "E1": sw, "E2": cw,
        "F1": ca * cw, "F2": ca * sw,
        "G1": sa, "G2": ca,
        "H1": sx, "H2": cx,
    }


def R_from_aoc(angles: np.ndarray) -> np.ndarray:
    """R_ground_from_cam from Schmid's alpha, omega, chi (formula 9). (..., 3) rad -> (..., 3, 3)."""
    s = schmid_auxiliaries(angles)
    col1 = np.stack([s["A1"], s["B1"], s["C1"]], -1)
    col2 = np.stack([s["A2"], s["B2"], s["C2"]], -1)
    col3 = -np.stack([s["D1"], s["E1"], s["F1"]], -1)
    return np.stack([col1, col2, col3], -1)


def aoc_from_R(R: np.ndarray) -> np.ndarray:
    """Inverse of R_from_aoc, omega in [-90, 90] deg. R: (..., 3, 3) -> (..., 3) radians.

    From (9): R[1, 2] = -E1 = -sin(omega); R[0, 2] = -sin(alpha) cos(omega);
    R[2, 2] = -cos(alpha) cos(omega); R[1, 0] = -cos(omega) sin(chi); R[1, 1] = cos(omega) cos(chi).
    """
    R = np.asarray(R, dtype=float)
    omega = np.arcsin(np.clip(-R[..., 1, 2], -1.0, 1.0))
    alpha = np.arctan2(-R[..., 0, 2], -R[..., 2, 2])
    chi = np.arctan2(-R[..., 1, 0], R[..., 1, 1])
    return np.stack([alpha, omega, chi], -1)


# Radians per unit of the angles of photos.csv ([units] angles in project.toml).
RADIANS_PER_UNIT = {"deg": np.pi / 180.0, "gon": np.pi / 200.0, "rad": 1.0}
CONVENTIONS = {
    "omega-phi-kappa": (R_from_opk, opk_from_R),
    "alpha-omega-chi": (R_from_aoc, aoc_from_R),
    "phi-omega-kappa": (R_from_pok, pok_from_R),
}


def R_from_angles(angles: np.ndarray, convention: str) -> np.ndarray:
    return CONVENTIONS[convention][0](angles)


def angles_from_R(R: np.ndarray, convention: str) -> np.ndarray:
    return CONVENTIONS[convention][1](R)


def skew(v: np.ndarray) -> np.ndarray:
    """[v]_x with [v]_x w = v x w. (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def exp_so3(d: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector d (Rodrigues). (..., 3) -> (..., 3, 3)."""
    d = np.asarray(d, dtype=float)
    theta2 = np.sum(d * d, axis=-1)[..., None, None]
    theta = np.sqrt(theta2)
    small = theta2 < 1e-16
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = skew(d)
    return np.eye(3) + a * K + b * (K @ K)


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (angle in [0, pi)). (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_t)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin_t = np.sin(theta)
    small = sin_t < 1e-8
    factor = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, sin_t)))
    return factor[..., None] * v


def _d_atan2(y, x, dy, dx):
    return (x[..., None] * dy - y[..., None] * dx) / (x * x + y * y)[..., None]


def _d_asin(s, ds):
    return ds / np.sqrt(np.maximum(1.0 - s * s, 1e-300))[..., None]


def angles_jacobian(R: np.ndarray, convention: str) -> np.ndarray:
    """d angles(R Exp(d)) / dd at d = 0: (..., 3, 3), rows the angles, columns the rotation vector.

    dR/dd_k = R [e_k]x; the angles are atan2/asin of entries of R (see opk_from_R, aoc_from_R).
    """
    R = np.asarray(R, dtype=float)
    E = skew(np.eye(3))  # [e_k]x for k = 0, 1, 2: (3, 3, 3)
    dR = np.einsum("...ij,kjl->...ilk", R, E)  # dR[..., i, l, k] = d R_il / d d_k

    def e(i, j):
        return R[..., i, j], dR[..., i, j, :]

    if convention == "omega-phi-kappa":
        (r12, d12), (r22, d22), (r02, d02), (r01, d01), (r00, d00) = e(1, 2), e(2, 2), e(0, 2), e(0, 1), e(0, 0)
        rows = [_d_atan2(-r12, r22, -d12, d22), _d_asin(r02, d02), _d_atan2(-r01, r00, -d01, d00)]
    elif convention == "alpha-omega-chi":
        (r12, d12), (r02, d02), (r22, d22), (r10, d10), (r11, d11) = e(1, 2), e(0, 2), e(2, 2), e(1, 0), e(1, 1)
        rows = [_d_atan2(-r02, -r22, -d02, -d22), _d_asin(-r12, -d12), _d_atan2(-r10, r11, -d10, d11)]
    elif convention == "phi-omega-kappa":
        (r02, d02), (r22, d22), (r12, d12), (r10, d10), (r11, d11) = e(0, 2), e(2, 2), e(1, 2), e(1, 0), e(1, 1)
        rows = [_d_atan2(r02, r22, d02, d22), _d_asin(-r12, -d12), _d_atan2(r10, r11, d10, d11)]
    else:
        raise ValueError(f"unknown rotation convention {convention!r}")
    return np.stack(rows, -2)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angle differences into (-pi, pi]."""
    return -((-np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)
