"""The GNSS/IMU model's part of the input files (io.gnss_reader's contract, written back):
cameras.csv's lever-arm and boresight columns, photos.csv's ``time`` and project.toml's ``[gnss]``."""

from __future__ import annotations

import math

import numpy as np

from .gnss_reader import BORESIGHT, LEVER


def _sigma(s: float):
    """nan -> empty (held), inf -> 'free'."""
    return "free" if math.isinf(s) else float(s)


def gnss_camera_columns(gnss, radians_per_unit: float) -> dict:
    columns = {}
    for a, name in enumerate(LEVER):
        columns[name] = gnss.lever[:, a]
    for a, name in enumerate(BORESIGHT):
        columns[name] = gnss.boresight[:, a] / radians_per_unit
    for a, name in enumerate(LEVER):
        columns[f"sigma_{name}"] = [_sigma(s) for s in gnss.sigma_lever[:, a]]
    for a, name in enumerate(BORESIGHT):
        columns[f"sigma_{name}"] = [_sigma(s / radians_per_unit) for s in gnss.sigma_boresight[:, a]]
    return columns


def gnss_photo_columns(gnss) -> dict:
    return {"time": np.asarray(gnss.time, dtype=float)} if np.isfinite(gnss.time).any() else {}


def gnss_toml(gnss) -> str:
    lines = ["", "[gnss]", f'shift = "{gnss.shift}"', f'drift = "{gnss.drift}"']
    if gnss.shift == "observed":
        lines.append(f"sigma_shift = {float(gnss.sigma_shift)!r}")
    if gnss.drift == "observed":
        lines.append(f"sigma_drift = {float(gnss.sigma_drift)!r}")
    return "\n".join(lines) + "\n"
