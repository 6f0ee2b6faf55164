"""The 2D transformations between the plate (fiducial system) and a scan (issue 16).

Frames: ``xy_plate`` in plate units (mm), x right, y up, diapositive (DESIGN section 1);
``q_scan`` = (col, -row) in scan pixels: the scan's column and its row *negated*, so that a scan
that is not mirrored maps to the plate by a proper (det > 0) transformation. The row of a scan
counts downwards; negating it is the only fixed convention, the rest is estimated.

Every transformation is written as a homography ``q = H (x, y, 1)`` (dehomogenised) with
parameters ``p`` per photo:

* similarity (4): ``q1 = a x - b y + t1``, ``q2 = b x + a y + t2``; p = (a, b, t1, t2)
* affine (6): ``q1 = a0 + a1 x + a2 y``, ``q2 = b0 + b1 x + b2 y``; p = (a0, a1, a2, b0, b1, b2)
* projective (8): ``q1 = (h0 x + h1 y + h2) / d``, ``q2 = (h3 x + h4 y + h5) / d``,
  ``d = h6 x + h7 y + 1``; p = (h0, ..., h7)

The fiducial fit estimates ``q = F(xy; p)`` with the measured pixels as the observations (the
calibrated fiducial coordinates are exact): a Gauss-Markov model with the residuals where the
errors are. Image points go the other way, ``xy = F^-1(q; p)``.
"""

from __future__ import annotations

import numpy as np

KINDS = ("similarity", "affine", "projective")
N_PARAMS = {"similarity": 4, "affine": 6, "projective": 8}
# fewest fiducials that determine the transformation (two coordinates each)
MIN_FIDUCIALS = {"similarity": 2, "affine": 3, "projective": 4}


def homography(kind: str, p: np.ndarray) -> np.ndarray:
    """The 3 x 3 matrix H of parameters p (..., N_PARAMS[kind]) -> (..., 3, 3)."""
    p = np.asarray(p, dtype=float)
    H = np.zeros(p.shape[:-1] + (3, 3))
    H[..., 2, 2] = 1.0
    if kind == "similarity":
        a, b, t1, t2 = (p[..., i] for i in range(4))
        H[..., 0, 0], H[..., 0, 1], H[..., 0, 2] = a, -b, t1
        H[..., 1, 0], H[..., 1, 1], H[..., 1, 2] = b, a, t2
    elif kind == "affine":
        H[..., 0, 2], H[..., 0, 0], H[..., 0, 1] = p[..., 0], p[..., 1], p[..., 2]
        H[..., 1, 2], H[..., 1, 0], H[..., 1, 1] = p[..., 3], p[..., 4], p[..., 5]
    elif kind == "projective":
        H[..., 0, :] = p[..., 0:3]
        H[..., 1, :] = p[..., 3:6]
        H[..., 2, 0:2] = p[..., 6:8]
    else:
        raise ValueError(f"unknown transformation {kind!r}")
    return H


def plate_per_pixel(kind: str, p: np.ndarray) -> np.ndarray:
    """(...,) plate units (mm) per scan pixel of parameters p (..., n): the root of the area factor
    of the inverse of the transformation's linear part (at the plate origin, for the projective)."""
    linear = homography(kind, p)[..., :2, :2]
    return np.sqrt(np.abs(np.linalg.det(np.linalg.inv(linear))))


def scan_from_plate(kind: str, p: np.ndarray, xy_plate: np.ndarray):
    """q_scan = F(xy_plate; p) and its derivatives.

    p: (P, n); xy_plate: (P, m, 2) (mm). Returns q (P, m, 2) px, dq/dxy (P, m, 2, 2) and
    dq/dp (P, m, 2, n).
    """
    xy_plate = np.asarray(xy_plate, dtype=float)
    H = homography(kind, p)
    x, y = xy_plate[..., 0], xy_plate[..., 1]
    h = H[:, None]  # (P, 1, 3, 3)
    num1 = h[..., 0, 0] * x + h[..., 0, 1] * y + h[..., 0, 2]
    num2 = h[..., 1, 0] * x + h[..., 1, 1] * y + h[..., 1, 2]
    d = h[..., 2, 0] * x + h[..., 2, 1] * y + 1.0
    q = np.stack([num1 / d, num2 / d], -1)
    # dq/dxy = (H[:2, :2] - q H[2, :2]) / d
    d_xy = (h[..., :2, :2] - q[..., :, None] * h[..., 2, None, :2]) / d[..., None, None]
    one, zero = np.ones_like(x), np.zeros_like(x)
    if kind == "similarity":
        d_p = np.stack([np.stack([x, -y, one, zero], -1), np.stack([y, x, zero, one], -1)], -2)
    elif kind == "affine":
        d_p = np.stack([np.stack([one, x, y, zero, zero, zero], -1),
                        np.stack([zero, zero, zero, one, x, y], -1)], -2)
    else:
        r1 = np.stack([x, y, one, zero, zero, zero, -q[..., 0] * x, -q[..., 0] * y], -1)
        r2 = np.stack([zero, zero, zero, x, y, one, -q[..., 1] * x, -q[..., 1] * y], -1)
        d_p = np.stack([r1, r2], -2) / d[..., None, None]
    return q, d_xy, d_p


def plate_from_scan(kind: str, p: np.ndarray, q_scan: np.ndarray):
    """xy_plate = F^-1(q_scan; p) and its derivatives, one photo per row of p.

    p: (m, n) the parameters of each point's photo; q_scan: (m, 2) px. Returns xy (m, 2) mm,
    dxy/dq (m, 2, 2) and dxy/dp (m, 2, n) (implicit function: dxy/dq = (dq/dxy)^-1,
    dxy/dp = -(dq/dxy)^-1 dq/dp).
    """
    q_scan = np.asarray(q_scan, dtype=float)
    Hinv = np.linalg.inv(homography(kind, p))
    qh = np.concatenate([q_scan, np.ones(q_scan.shape[:-1] + (1,))], -1)
    xyw = np.einsum("mij,mj->mi", Hinv, qh)
    xy = xyw[:, :2] / xyw[:, 2:3]
    # one Newton step on F(xy) = q polishes the round-off of the inverse
    q, d_xy, d_p = scan_from_plate(kind, p, xy[:, None])
    J_inv = np.linalg.inv(d_xy[:, 0])
    xy = xy - np.einsum("mij,mj->mi", J_inv, q[:, 0] - q_scan)
    q, d_xy, d_p = scan_from_plate(kind, p, xy[:, None])
    J_inv = np.linalg.inv(d_xy[:, 0])
    return xy, J_inv, -np.einsum("mij,mjk->mik", J_inv, d_p[:, 0])


def q_from_colrow(colrow: np.ndarray) -> np.ndarray:
    """(col, row) scan pixels (..., 2) -> q_scan = (col, -row)."""
    colrow = np.asarray(colrow, dtype=float)
    return np.stack([colrow[..., 0], -colrow[..., 1]], -1)


def colrow_from_q(q_scan: np.ndarray) -> np.ndarray:
    """q_scan (..., 2) -> (col, row) scan pixels."""
    return q_from_colrow(q_scan)
