"""Estimates, mean errors and correlations of the GNSS/IMU unknowns (striptri.equations.gnss_unknowns) from
Qxx = N^-1 like every other element (covariance.Covariance): ``m = sigma0 sqrt(Qxx_ii)``.

The boresight's mean errors are those of its multiplicative correction (rotation vector, camera
frame), equal to those of the rotation vector itself to first order in the (small) boresight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..selected_inverse.covariance import strongest_correlations
from ..equations.gnss_unknowns import GROUPS
from ..geometry.rotations import log_so3

CENTRE_NAMES = ("X0", "Y0", "Z0")


@dataclass(frozen=True)
class GnssPrecision:
    """values, sigma: group name (gnss_unknowns.GROUPS) -> (n, 3) (lever m, boresight rad, shift m,
    drift m/s; sigma nan where held / not in the model); labels (k,) of the k estimated unknowns,
    correlation (k, k) among them, centre (k,) tuples (photo index, axis 0-2, correlation) of the
    projection-centre coordinate each is most correlated with ((-1, -1, nan) without one)."""

    values: dict
    sigma: dict
    labels: list
    correlation: np.ndarray
    centre: list

    def estimated(self, group: str) -> bool:
        return bool(np.isfinite(self.sigma[group]).any())


def gnss_values(state) -> dict:
    g = state.gnss
    return {"lever": g.lever, "boresight": log_so3(g.R_cam_from_imu), "shift": g.shift, "drift": g.drift}


def gnss_precision(result, camera_ids, strip_ids) -> GnssPrecision | None:
    """None when the result has no GNSS model. result: AdjustmentResult."""
    layout, state = result.layout, result.state
    if layout.gnss_cols is None or state.gnss is None:
        return None
    cov, s0 = result.covariance, result.sigma0_for_precision
    values = gnss_values(state)
    sigma, labels, cols = {}, [], []
    names = {"lever": camera_ids, "boresight": camera_ids, "shift": strip_ids, "drift": strip_ids}
    for group in GROUPS:
        c = layout.gnss_cols.group(group)
        q = cov.entries(c, c) if c.size else np.zeros(c.shape)
        sigma[group] = np.where(c >= 0, s0 * np.sqrt(np.maximum(q, 0.0)), np.nan)
        for k, row in enumerate(c):
            for a, col in enumerate(row):
                if col >= 0:
                    labels.append(f"{group} {names[group][k]} {_axis(group, a)}")
                    cols.append(int(col))
    cols = np.array(cols, dtype=int)
    if not len(cols):
        return GnssPrecision(values, sigma, labels, np.zeros((0, 0)), [])
    Q = cov.entries(cols[:, None], cols[None, :])
    s = np.sqrt(np.maximum(np.diag(Q), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = Q / np.outer(s, s)
    centre_cols = layout.photo_cols[:, :3].ravel()
    centre = [(-1, -1, float("nan"))] * len(cols)
    if (centre_cols >= 0).any():
        q_c = cov.entries(centre_cols, centre_cols)
        s_c = np.sqrt(np.maximum(np.where(centre_cols >= 0, q_c, np.nan), 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            ext = cov.entries(cols[:, None], centre_cols[None, :]) / (s[:, None] * s_c[None, :])
        centre = strongest_correlations(ext, 3)
    return GnssPrecision(values, sigma, labels, corr, centre)


def _axis(group: str, a: int) -> str:
    return ("x", "y", "z")[a] if group in ("lever", "boresight") else ("X", "Y", "Z")[a]
