"""The GNSS/IMU unknowns (striptri.model (GnssModel)): their current values, their columns in the normal
matrix (after the camera columns: lever arms, boresights per camera, then shifts, drifts per
strip, 3 each) and their update.

Update: lever arm, shift and drift additively; the boresight multiplicatively,
``R_cam_from_imu <- R_cam_from_imu Exp(db)`` (db the 3 boresight unknowns, camera frame), as the
photos' rotations (DESIGN section 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import HELD, GnssModel
from ..geometry.rotations import exp_so3

GROUPS = ("lever", "boresight", "shift", "drift")


@dataclass(frozen=True)
class GnssState:
    """lever (ncam, 3) m camera frame; R_cam_from_imu (ncam, 3, 3); shift (n_strips, 3) m and
    drift (n_strips, 3) m/s ground frame (reduced frame: the offset is in the centres); dt
    (n_photos,) t_i - t0 of each photo's strip, strip (n_photos,) its strip (-1 none)."""

    lever: np.ndarray
    R_cam_from_imu: np.ndarray
    shift: np.ndarray
    drift: np.ndarray
    dt: np.ndarray
    strip: np.ndarray

    def updated(self, cols: "GnssColumns", dxp: np.ndarray) -> "GnssState":
        """dxp: the correction vector with a trailing 0 (column -1 reads it)."""
        return GnssState(lever=self.lever + dxp[cols.lever], R_cam_from_imu=self.R_cam_from_imu @ exp_so3(dxp[cols.boresight]),
                         shift=self.shift + dxp[cols.shift], drift=self.drift + dxp[cols.drift], dt=self.dt,
                         strip=self.strip)


@dataclass(frozen=True)
class GnssColumns:
    """Columns (-1 held or not in the model): lever, boresight (ncam, 3); shift, drift (n_strips, 3)."""

    lever: np.ndarray
    boresight: np.ndarray
    shift: np.ndarray
    drift: np.ndarray

    def blocks(self) -> list[np.ndarray]:
        """Every camera's lever arm and boresight, every strip's shift and drift: rows of 3 columns."""
        return [*self.lever, *self.boresight, *self.shift, *self.drift]

    def group(self, name: str) -> np.ndarray:
        return getattr(self, name)


def initial_gnss_state(gnss: GnssModel) -> GnssState:
    z = np.zeros((gnss.n_strips, 3))
    return GnssState(lever=gnss.lever.copy(), R_cam_from_imu=exp_so3(gnss.boresight), shift=z, drift=z.copy(),
                     dt=gnss.dt, strip=gnss.strip.copy())


def gnss_columns(gnss: GnssModel, first: int) -> tuple[GnssColumns, int]:
    """Columns from ``first`` on: an element gets one when observed or free (sigma not nan; shift
    and drift when their mode is not "none"). Returns (columns, next free column)."""
    col = first

    def take(estimated: np.ndarray) -> np.ndarray:
        nonlocal col
        out = -np.ones(estimated.shape, dtype=int)
        k = int(estimated.sum())
        out[estimated] = np.arange(col, col + k)
        col += k
        return out

    ns = gnss.n_strips
    lever = take(gnss.lever_state != HELD)
    boresight = take(gnss.boresight_state != HELD)
    shift = take(np.full((ns, 3), gnss.shift != "none"))
    drift = take(np.full((ns, 3), gnss.drift != "none"))
    return GnssColumns(lever=lever, boresight=boresight, shift=shift, drift=drift), col
