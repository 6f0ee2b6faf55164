"""Ray directions (Schmid 11) and collinearity (Schmid 14, from striptri.geometry.collinearity), batched
over a leading axis.

With ``m = R^T (X - O)`` (the ground vector in the camera frame):
``x = xp - c m_x / m_z``, ``y = yp - c m_y / m_z``. The ray of a plate point is
``r = R (x - xp, y - yp, -c)`` in the ground frame; its length is not normalised (it carries
the plate scale, like Schmid's u, v, w).
"""

from __future__ import annotations

import numpy as np

from .collinearity import camera_from_ground, plate_from_ground


def plate_vector(xy_plate: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """Camera-frame vector p = (x - xp, y - yp, -c). xy_plate: (..., 2); interior: (..., 3) c, xp, yp."""
    xy_plate, interior = np.asarray(xy_plate, dtype=float), np.asarray(interior, dtype=float)
    shape = np.broadcast_shapes(xy_plate.shape[:-1], interior.shape[:-1])
    return np.stack(
        np.broadcast_arrays(
            xy_plate[..., 0] - interior[..., 1], xy_plate[..., 1] - interior[..., 2], -interior[..., 0] + np.zeros(shape)
        ),
        -1,
    )


def ray_ground(R_ground_from_cam: np.ndarray, xy_plate: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """Ground direction of a plate point (Schmid 11: u, v, w). -> (..., 3)."""
    p = plate_vector(xy_plate, interior)
    return np.einsum("...ij,...j->...i", R_ground_from_cam, p)


def project(R_ground_from_cam: np.ndarray, xyz0: np.ndarray, interior: np.ndarray, xyz_ground: np.ndarray) -> np.ndarray:
    """Plate coordinates of ground points (Schmid 14; collinearity.plate_from_ground). All batched
    alike -> (..., 2)."""
    return plate_from_ground(R_ground_from_cam, xyz0, interior, xyz_ground)


def in_front(R_ground_from_cam: np.ndarray, xyz0: np.ndarray, xyz_ground: np.ndarray) -> np.ndarray:
    """True where the ground point lies in front of the camera (m_z < 0). -> (...,) bool."""
    return camera_from_ground(R_ground_from_cam, xyz0, xyz_ground)[..., 2] < 0
