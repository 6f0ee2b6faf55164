"""GNSS-supported triangulation: what the project says about the GNSS antenna and the IMU
(docs/decisions.md "GNSS-supported triangulation").

Observation equations (parameter_observations, rows of the observed centres and angles):

* antenna position of photo i (camera c, strip s, time t_i), the photos.csv centre with a sigma:
  ``A_i = O_i + R_ground_from_cam_i e_c + s_s + d_s (t_i - t0_s)``: e_c the lever arm of camera c
  (metres, camera frame: x, y on the plate axes, z along the viewing direction's opposite, the
  frame of DESIGN section 1), s_s the shift and d_s the drift of the strip (ground frame, m and
  m/s), t0_s the earliest time of the strip's photos;
* IMU angles of photo i, the photos.csv angles with a sigma: ``angles(R_ground_from_cam_i Exp(b_c))``
  with b_c the boresight rotation vector of camera c (radians, camera frame):
  ``R_cam_from_imu = Exp(b_c)``, so ``R_ground_from_imu = R_ground_from_cam R_cam_from_imu``.

Every element is held (sigma nan, the default; a lever arm and boresight of 0 held is the model
without them), observed (sigma > 0, an observation of the element with the given value) or free
(sigma inf), as the camera elements (model.Cameras). Shift and drift are "none" (not in the
model), "free" or "observed" (an observation of 0 with the sigma of the project).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MODES = ("none", "free", "observed")


@dataclass(frozen=True)
class GnssModel:
    """lever (ncam, 3) m, sigma_lever (ncam, 3) (nan held, > 0 observed, inf free); boresight
    (ncam, 3) rotation vector in radians, sigma_boresight (ncam, 3) radians; time (n_photos,)
    seconds (nan: not given); strip (n_photos,) index of the photo's strip (-1: empty strip_id:
    no shift or drift), strip_ids (n_strips,); shift / drift modes (MODES) with their sigmas
    (m, m/s; used when "observed")."""

    lever: np.ndarray
    sigma_lever: np.ndarray
    boresight: np.ndarray
    sigma_boresight: np.ndarray
    time: np.ndarray
    strip: np.ndarray
    strip_ids: tuple
    shift: str = "none"
    drift: str = "none"
    sigma_shift: float = float("nan")
    sigma_drift: float = float("nan")

    @property
    def n_strips(self) -> int:
        return len(self.strip_ids)

    @property
    def t0(self) -> np.ndarray:
        """(n_strips,) the earliest time of each strip's photos (0 where no time is given)."""
        t0 = np.full(self.n_strips, np.inf)
        ok = (self.strip >= 0) & np.isfinite(self.time)
        np.minimum.at(t0, self.strip[ok], self.time[ok])
        return np.where(np.isfinite(t0), t0, 0.0)

    @property
    def dt(self) -> np.ndarray:
        """(n_photos,) t_i - t0 of the photo's strip (0 without a strip or a time)."""
        ok = (self.strip >= 0) & np.isfinite(self.time)
        out = np.zeros(len(self.time))
        out[ok] = self.time[ok] - self.t0[self.strip[ok]]
        return out

    @property
    def in_play(self) -> bool:
        """True when the model differs from plain observed centres and angles."""
        return bool(np.any(self.lever != 0) or np.any(self.boresight != 0) or np.any(~np.isnan(self.sigma_lever))
                    or np.any(~np.isnan(self.sigma_boresight)) or self.shift != "none" or self.drift != "none")


def default_gnss(n_cameras: int, strip_ids: list[str]) -> GnssModel:
    """The model of a project without GNSS columns: lever arm and boresight 0, held; no shift or
    drift (today's observed centres and angles)."""
    names = [s for s in dict.fromkeys(strip_ids) if s != ""]
    index = {s: k for k, s in enumerate(names)}
    strip = np.array([index.get(s, -1) for s in strip_ids], dtype=int)
    z = np.zeros((n_cameras, 3))
    nan = np.full((n_cameras, 3), np.nan)
    return GnssModel(lever=z, sigma_lever=nan, boresight=z.copy(), sigma_boresight=nan.copy(),
                     time=np.full(len(strip_ids), np.nan), strip=strip, strip_ids=tuple(names))
