"""Observation equations of the bundle adjustment: collinearity (Schmid 14) per ray, batched.

``m = R^T (X - O)``, ``x = xp - c m_x / m_z``, ``y = yp - c m_y / m_z`` with ``R`` ground_from_cam.
Derivatives are taken in the parametrisation the adjustment updates (DESIGN section 1):
``dm/dX = R^T``, ``dm/dO = -R^T`` and, for ``R <- R Exp(d)``, ``m <- Exp(-d) m``, so
``dm/dd = [m]x``; ``dx/dc = -m_x/m_z``, ``dx/dxp = 1`` (and likewise for y).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import skew


@dataclass
class RayJacobians:
    """Plate coordinates xy (..., 2) of ground points and their derivatives (..., 2, 3) with
    respect to the point X, the projection centre O, the rotation vector d and the interior
    orientation (c, xp, yp)."""

    xy: np.ndarray
    d_point: np.ndarray
    d_centre: np.ndarray
    d_rot: np.ndarray
    d_interior: np.ndarray


def collinearity_jacobians(R_ground_from_cam, xyz0, interior, xyz_ground) -> RayJacobians:
    """Collinearity (Schmid 14) and its analytic Jacobians (module doc).

    R_ground_from_cam: (..., 3, 3); xyz0, interior (c, xp, yp), xyz_ground: (..., 3), batched alike.
    """
    m = np.einsum("...ji,...j->...i", R_ground_from_cam, xyz_ground - xyz0)
    c, mz = interior[..., 0], m[..., 2]
    xy = np.stack([interior[..., 1] - c * m[..., 0] / mz, interior[..., 2] - c * m[..., 1] / mz], -1)
    d_m = np.zeros(m.shape[:-1] + (2, 3))  # d xy / d m
    d_m[..., 0, 0] = -c / mz
    d_m[..., 1, 1] = -c / mz
    d_m[..., 0, 2] = c * m[..., 0] / mz**2
    d_m[..., 1, 2] = c * m[..., 1] / mz**2
    d_point = np.einsum("...aj,...ij->...ai", d_m, R_ground_from_cam)
    d_rot = d_m @ skew(m)
    d_interior = np.zeros_like(d_m)
    d_interior[..., 0, 0] = -m[..., 0] / mz
    d_interior[..., 1, 0] = -m[..., 1] / mz
    d_interior[..., 0, 1] = 1.0
    d_interior[..., 1, 2] = 1.0
    return RayJacobians(xy=xy, d_point=d_point, d_centre=-d_point, d_rot=d_rot, d_interior=d_interior)
