"""Collinearity (Schmid 14) and its analytic Jacobians: the one place they are written.

Frames and units (DESIGN section 1): ``R_ground_from_cam`` maps a camera-frame vector to the
ground frame; ``xyz_centre`` (the projection centre O) and ``xyz_ground`` (the point X) are ground
coordinates in metres; ``interior`` is (c, xp, yp) and ``xy_plate`` (x, y), in plate units (mm).
With the point in the camera frame ``m = R_ground_from_cam^T (xyz_ground - xyz_centre)``::

    x = xp - c m_x / m_z,        y = yp - c m_y / m_z                        (Schmid 14)

Derivatives are taken in the parametrisation the adjustments update (DESIGN section 1): the
rotation vector d of ``R <- R Exp(d)``, under which ``m <- Exp(-d) m``::

    d(x, y)/dm  = (-c / m_z) [[1, 0, -m_x / m_z], [0, 1, -m_y / m_z]]
    dm/dX = R^T,   dm/dO = -R^T,   dm/dd = [m]x
    dx/dc = -m_x / m_z,  dx/dxp = 1;   dy/dc = -m_y / m_z,  dy/dyp = 1

Every function is batched over any leading axes (``...``), which broadcast against each other:
a point (m, 1, 3) against the k photos (m, k, 3, 3) that see it, for instance. Conditions
(conditions.collinearity), the bundle's observation equations (bundle.reduced), the triangulation
(triangulation.ray_terms) and the resection call these functions; tests/test_jacobians.py checks
the Jacobians against central differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def camera_from_ground(R_ground_from_cam: np.ndarray, xyz_centre: np.ndarray, xyz_ground: np.ndarray) -> np.ndarray:
    """The point in the camera frame, ``m = R^T (X - O)`` (ground metres, camera axes).

    R_ground_from_cam (..., 3, 3), xyz_centre (..., 3), xyz_ground (..., 3) -> (..., 3). The point
    lies in front of the camera where ``m_z < 0`` (the camera looks down its -z axis)."""
    return np.einsum("...ji,...j->...i", R_ground_from_cam, np.asarray(xyz_ground, dtype=float) - xyz_centre)


def plate_from_ground(R_ground_from_cam: np.ndarray, xyz_centre: np.ndarray, interior: np.ndarray,
                      xyz_ground: np.ndarray) -> np.ndarray:
    """Plate coordinates of ground points (Schmid 14), without derivatives.

    R_ground_from_cam (..., 3, 3), xyz_centre (..., 3), interior (..., 3) c, xp, yp, xyz_ground
    (..., 3) -> xy_plate (..., 2). A point in the plane of the camera (m_z = 0) gives inf or nan."""
    interior = np.asarray(interior, dtype=float)
    m = camera_from_ground(R_ground_from_cam, xyz_centre, xyz_ground)
    return interior[..., 1:3] - interior[..., :1] * m[..., :2] / m[..., 2:3]


@dataclass(frozen=True)
class CollinearityJacobians:
    """Plate coordinates and their derivatives (module doc), batched alike.

    xy_plate (..., 2); d_ground, d_centre, d_rotation, d_interior (..., 2, 3): d(x, y) with respect to
    xyz_ground, xyz_centre, the rotation vector d of ``R <- R Exp(d)`` (radians) and (c, xp, yp)."""

    xy_plate: np.ndarray
    d_ground: np.ndarray
    d_centre: np.ndarray
    d_rotation: np.ndarray
    d_interior: np.ndarray


def collinearity_jacobians(R_ground_from_cam: np.ndarray, xyz_centre: np.ndarray, interior: np.ndarray,
                           xyz_ground: np.ndarray) -> CollinearityJacobians:
    """Collinearity (Schmid 14) and its analytic Jacobians (module doc).

    R_ground_from_cam (..., 3, 3), xyz_centre (..., 3), interior (..., 3) c, xp, yp, xyz_ground
    (..., 3), broadcast against each other -> CollinearityJacobians of the broadcast shape.

    Written row by row instead of as ``d(x, y)/dm`` times ``dm/d...`` (no batched 2x3 by 3x3
    products): with ``f = -c / m_z`` and ``u = (m_x, m_y) / m_z``, row a of d(x, y)/dm is
    ``f (e_a - u_a e_z)``, so ``d/dX`` row a is ``f (R^T_a - u_a R^T_z)`` (rows of R^T) and
    ``d/dd`` row a is ``f (e_a x m - u_a e_z x m)`` (a row vector times [m]x is its cross product
    with m)."""
    interior = np.asarray(interior, dtype=float)
    m = camera_from_ground(R_ground_from_cam, xyz_centre, xyz_ground)
    c = interior[..., 0]
    mx, my, mz = m[..., 0], m[..., 1], m[..., 2]
    f = (-c / mz)[..., None, None]
    u = m[..., :2] / m[..., 2:3]  # (..., 2)
    xy_plate = interior[..., 1:3] - c[..., None] * m[..., :2] / m[..., 2:3]
    R_cam_from_ground = np.swapaxes(R_ground_from_cam, -1, -2)
    d_ground = f * (R_cam_from_ground[..., :2, :] - u[..., :, None] * R_cam_from_ground[..., 2:3, :])
    zero = np.zeros_like(mz)
    ea_cross_m = np.stack([np.stack([zero, -mz, my], -1), np.stack([mz, zero, -mx], -1)], -2)  # e_x x m, e_y x m
    ez_cross_m = np.stack([-my, mx, zero], -1)[..., None, :]
    d_rotation = f * (ea_cross_m - u[..., :, None] * ez_cross_m)
    d_interior = np.zeros(xy_plate.shape + (3,))
    d_interior[..., 0] = -u
    d_interior[..., 0, 1] = 1.0
    d_interior[..., 1, 2] = 1.0
    return CollinearityJacobians(xy_plate=xy_plate, d_ground=d_ground, d_centre=-d_ground, d_rotation=d_rotation,
                                 d_interior=d_interior)
