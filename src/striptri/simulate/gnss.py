"""A GNSS-supported block (striptri.model (GnssModel)): the antenna positions of the true flight with a
lever arm, per-strip shift and drift and noise; time stamps; optionally IMU angles with a
boresight misalignment.

``add_gnss(project, truth, options, rng)`` replaces the photos' centres by the observed antenna
positions (sigma ``sigma_gnss``), adds the time of each exposure (``interval`` seconds apart along
each strip, strips ``strip_gap`` seconds apart) and the GNSS model with the modes of ``options``;
with ``sigma_imu`` the angles become IMU observations ``angles(R Exp(b))`` + noise. Draws from rng
in a fixed order: shifts, drifts, antenna noise, IMU noise, observed lever arm, observed boresight.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.model import default_gnss
from striptri.geometry.rotations import R_from_opk, exp_so3, opk_from_R
from striptri.simulate.truth import Truth


@dataclass(frozen=True)
class GnssOptions:
    """lever_arm: (3,) m, camera frame; shift_std: m, drift_std: m/s, the standard deviations of
    the true per-strip shifts and drifts (normal, per axis); sigma_gnss: m, antenna noise;
    interval: s between exposures; strip_gap: s between strips; boresight: (3,) rotation vector
    in degrees (camera frame); sigma_imu: deg, None = no IMU angles. lever_mode, boresight_mode:
    how the project states them ("held" at the true value, "free", or "observed" with
    sigma_lever m / sigma_boresight deg about the true value); shift_mode, drift_mode:
    model.GNSS_MODES."""

    lever_arm: tuple = (0.1, -0.2, 1.5)
    shift_std: float = 0.3
    drift_std: float = 0.002
    sigma_gnss: float = 0.05
    interval: float = 3.0
    strip_gap: float = 120.0
    boresight: tuple = (0.0, 0.0, 0.0)
    sigma_imu: float | None = None
    lever_mode: str = "free"
    boresight_mode: str = "held"
    shift_mode: str = "free"
    drift_mode: str = "free"
    sigma_lever: float = 0.05
    sigma_boresight: float = 0.01
    sigma_shift: float = 0.5
    sigma_drift: float = 0.01


@dataclass(frozen=True)
class GnssTruth:
    """The true lever arm (3,), boresight (3,) rad, shifts and drifts (n_strips, 3), times (n,)."""

    lever_arm: np.ndarray
    boresight: np.ndarray
    shift: np.ndarray
    drift: np.ndarray
    time: np.ndarray
    strip_ids: tuple


def add_gnss(project: model.Project, truth: Truth, options: GnssOptions, rng: np.random.Generator):
    """(project with GNSS antenna positions, times, model; GnssTruth). Module doc."""
    photos = project.photos
    n = len(photos)
    base = default_gnss(len(project.cameras), photos.strip_ids)
    ns = base.n_strips
    time = _times(base.strip, options)
    shift = rng.normal(0.0, options.shift_std, (ns, 3))
    drift = rng.normal(0.0, options.drift_std, (ns, 3))
    g = replace(base, time=time)
    dt = g.dt
    lever = np.asarray(options.lever_arm, dtype=float)
    strip = g.strip
    sd = np.where(strip[:, None] >= 0, shift[strip] + drift[strip] * dt[:, None], 0.0)
    antenna = truth.xyz0 + truth.R_ground_from_cam @ lever + sd
    antenna = antenna + rng.normal(0.0, options.sigma_gnss, (n, 3))
    b = np.radians(np.asarray(options.boresight, dtype=float))
    new_photos = replace(photos, xyz0=antenna, sigma_xyz0=np.full((n, 3), options.sigma_gnss))
    if options.sigma_imu is not None:
        imu = opk_from_R(truth.R_ground_from_cam @ exp_so3(b)) + rng.normal(0.0, np.radians(options.sigma_imu), (n, 3))
        new_photos = replace(new_photos, angles=imu, R_ground_from_cam=R_from_opk(imu),
                             sigma_angles=np.full((n, 3), np.radians(options.sigma_imu)))
    ncam = len(project.cameras)
    gnss = replace(g, lever=_given(options.lever_mode, lever, options.sigma_lever, ncam, rng),
                   sigma_lever=_sigma(options.lever_mode, options.sigma_lever, len(project.cameras)),
                   boresight=_given(options.boresight_mode, b, np.radians(options.sigma_boresight), ncam, rng),
                   sigma_boresight=_sigma(options.boresight_mode, np.radians(options.sigma_boresight),
                                          len(project.cameras)),
                   shift=options.shift_mode, drift=options.drift_mode,
                   sigma_shift=options.sigma_shift if options.shift_mode == "observed" else float("nan"),
                   sigma_drift=options.sigma_drift if options.drift_mode == "observed" else float("nan"))
    truth_g = GnssTruth(lever_arm=lever, boresight=b, shift=shift, drift=drift, time=time, strip_ids=g.strip_ids)
    return replace(project, photos=new_photos, gnss=gnss), truth_g


def _times(strip: np.ndarray, options: GnssOptions) -> np.ndarray:
    """Exposure times: photo k of strip s at s * (strip length + gap) + k * interval."""
    t = np.zeros(len(strip))
    start = 0.0
    for s in range(int(strip.max()) + 1 if len(strip) else 0):
        idx = np.flatnonzero(strip == s)
        t[idx] = start + options.interval * np.arange(len(idx))
        start = t[idx].max() + options.strip_gap if len(idx) else start
    return t


def _given(mode: str, true: np.ndarray, sigma: float, ncam: int, rng) -> np.ndarray:
    """What the project states: held, the true value; observed, true + noise; free, 0."""
    if mode == "free":
        return np.zeros((ncam, 3))
    if mode == "observed":
        return true + rng.normal(0.0, sigma, (ncam, 3))
    return np.tile(true, (ncam, 1))


def _sigma(mode: str, sigma: float, ncam: int) -> np.ndarray:
    value = {"held": np.nan, "free": np.inf, "observed": sigma}
    if mode not in value:
        raise ValueError(f"gnss: mode {mode!r} is not one of held, free, observed")
    return np.full((ncam, 3), value[mode])


def gnss_truth_tables(t: GnssTruth, camera_ids: list[str]) -> dict[str, dict]:
    """truth/cameras_gnss.csv (camera_id, lever_x.., boresight_x.. in degrees) and truth/strips.csv
    (strip_id, shift_X.., drift_X..)."""
    cams = {"camera_id": list(camera_ids)}
    for a, name in enumerate("xyz"):
        cams[f"lever_{name}"] = [float(t.lever_arm[a])] * len(camera_ids)
    for a, name in enumerate("xyz"):
        cams[f"boresight_{name}"] = [float(np.degrees(t.boresight[a]))] * len(camera_ids)
    strips = {"strip_id": list(t.strip_ids)}
    for a, name in enumerate("XYZ"):
        strips[f"shift_{name}"] = t.shift[:, a]
    for a, name in enumerate("XYZ"):
        strips[f"drift_{name}"] = t.drift[:, a]
    return {"cameras_gnss.csv": cams, "strips.csv": strips}
