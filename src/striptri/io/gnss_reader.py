"""The GNSS/IMU model of a project (striptri.model (GnssModel)) from its optional inputs
(docs/file-formats.md):

* cameras.csv: ``lever_x, lever_y, lever_z`` (m, camera frame; empty = 0), ``boresight_x,
  boresight_y, boresight_z`` (the rotation vector ``R_cam_from_imu = Exp(b)``, camera frame, in
  the unit of ``[units] angles``; empty = 0) and their ``sigma_<name>``: empty, absent or 0 =
  held, > 0 = observed, ``free`` = estimated without a prior (the camera elements' rule);
* photos.csv: ``time`` (seconds, any origin), needed for the drift;
* project.toml ``[gnss]``: ``shift``, ``drift`` = "none" (default) | "free" | "observed",
  ``sigma_shift`` (m), ``sigma_drift`` (m/s) for "observed" (an observation of 0).

A project with none of these has no GNSS model (``Project.gnss`` None): today's behaviour.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import InputError
from ..model import GNSS_MODES, default_gnss
from . import plausibility as limits
from .csvtable import CsvTable
from .toml_file import TomlFile

TOML_SECTION = "gnss"
TOML_KEYS = ("shift", "drift", "sigma_shift", "sigma_drift")
LEVER = ("lever_x", "lever_y", "lever_z")
BORESIGHT = ("boresight_x", "boresight_y", "boresight_z")
LEVER_LIMIT_M = 100.0  # a lever arm beyond this is a unit error (mm for m)


def read_gnss(cameras_table: CsvTable, photos_table: CsvTable, cameras, photos, radians_per_unit: float,
              toml: TomlFile):
    """GnssModel or None (module doc); toml: project.toml as read. Raises InputError naming the
    file, line and reason."""
    toml_path, toml_line = toml.path, toml.line
    section = toml.data.get(TOML_SECTION, {}) if toml.data else {}
    names = LEVER + BORESIGHT + tuple(f"sigma_{n}" for n in LEVER + BORESIGHT)
    has_camera_columns = any(cameras_table.has(n) for n in names)
    has_time = photos_table.has("time")
    if not (has_camera_columns or has_time or section):
        return None
    g = default_gnss(len(cameras), photos.strip_ids)
    lever = np.column_stack([np.nan_to_num(cameras_table.optional_floats(n), nan=0.0) for n in LEVER]).reshape(-1, 3)
    _check_limit(cameras_table, LEVER, lever, LEVER_LIMIT_M, "m")
    boresight = np.column_stack([np.nan_to_num(cameras_table.optional_floats(n), nan=0.0)
                                 for n in BORESIGHT]).reshape(-1, 3) * radians_per_unit
    for i, row in enumerate(np.linalg.norm(boresight, axis=1)):
        if row >= math.pi:
            raise cameras_table.error(i, "the boresight rotation vector must be shorter than 180 degrees")
    sigma_lever = np.column_stack([_sigma(cameras_table, f"sigma_{n}") for n in LEVER]).reshape(-1, 3)
    sigma_boresight = np.column_stack([_sigma(cameras_table, f"sigma_{n}") for n in BORESIGHT]).reshape(-1, 3)
    sigma_boresight = sigma_boresight * radians_per_unit
    time = photos_table.optional_floats("time") if has_time else np.full(len(photos), np.nan)
    modes = {}
    for key in ("shift", "drift"):
        value = section.get(key, "none")
        if not isinstance(value, str) or value not in GNSS_MODES:
            raise InputError(toml_path, toml_line(TOML_SECTION, key),
                             f"[gnss] {key}: {value!r} is not one of {', '.join(repr(m) for m in GNSS_MODES)}")
        modes[key] = value
    sigmas = {}
    for key, unit in (("shift", "m"), ("drift", "m/s")):
        name = f"sigma_{key}"
        value = section.get(name)
        where = InputError(toml_path, toml_line(TOML_SECTION, name), "")
        if modes[key] == "observed":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
                raise InputError(where.path, where.line or toml_line(TOML_SECTION, key),
                                 f"[gnss] {key} = \"observed\" needs {name} = a positive number ({unit}), got {value!r}")
            if not limits.SIGMA_MIN <= value <= limits.SIGMA_MAX:
                raise InputError(where.path, where.line, f"[gnss] {name} = {value!r} is outside the plausible range "
                                 f"[{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}] "
                                 f"{unit} (docs/file-formats.md, Limits); for a {key} that is not observed use "
                                 f"{key} = \"free\"")
            sigmas[key] = float(value)
        elif value is not None:
            raise InputError(where.path, where.line, f"[gnss] {name} is only used with {key} = \"observed\" "
                                                     f"(it is {modes[key]!r})")
        else:
            sigmas[key] = float("nan")
    model = replace(g, lever=lever, sigma_lever=sigma_lever, boresight=boresight, sigma_boresight=sigma_boresight,
                    time=time, shift=modes["shift"], drift=modes["drift"], sigma_shift=sigmas["shift"],
                    sigma_drift=sigmas["drift"])
    _check_consistency(model, cameras_table, photos_table, photos, toml)
    return model


def _sigma(table: CsvTable, name: str) -> np.ndarray:
    """Camera-element sigma rule: empty / 0 = held (nan), > 0 observed, ``free`` = inf."""
    values = table.optional_floats(name, keywords={"free": math.inf})
    for i in np.flatnonzero(values < 0):
        raise table.error(i, f"column '{name}': a standard deviation cannot be negative (got {table.text(i, name)})")
    i = limits.first_sigma_out_of_range(values)
    if i is not None:
        raise table.error(i, f"column '{name}': a standard deviation of {table.text(i, name)} is outside the plausible "
                             f"range [{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}]")
    return np.where(values == 0, np.nan, values)


def _check_limit(table: CsvTable, names, values: np.ndarray, limit: float, unit: str) -> None:
    hit = limits.first_beyond(values, limit)
    if hit is not None:
        i, j = hit
        raise table.error(i, f"column '{names[j]}': {table.text(i, names[j])} exceeds the plausibility limit of "
                             f"{limits.number_text(limit)} {unit} for a lever arm, in magnitude")


def _check_consistency(g, cameras_table: CsvTable, photos_table: CsvTable, photos, toml: TomlFile) -> None:
    """What the model needs: observed centres for a lever arm, shift or drift; observed angles for
    a boresight; times for a drift."""
    observed_centre = (photos.sigma_xyz0 > 0).any(axis=1)
    observed_angles = (photos.sigma_angles > 0).any(axis=1)
    for j in range(len(g.lever)):
        mine = photos.camera_index == j
        if (~np.isnan(g.sigma_lever[j])).any() and not observed_centre[mine].any():
            raise cameras_table.error(j, "a lever arm is estimated (sigma_lever_* observed or free) but no photo of this "
                                         "camera has an observed (GNSS) centre in photos.csv")
        if (~np.isnan(g.sigma_boresight[j])).any() and not observed_angles[mine].any():
            raise cameras_table.error(j, "a boresight is estimated (sigma_boresight_* observed or free) but no photo of "
                                         "this camera has observed (IMU) angles in photos.csv")
    for key, mode in (("shift", g.shift), ("drift", g.drift)):
        if mode != "none" and not (observed_centre & (g.strip >= 0)).any():
            raise InputError(toml.path, toml.line(TOML_SECTION, key),
                             f"[gnss] {key} = {mode!r} but no photo with a strip_id has an observed (GNSS) centre "
                             "in photos.csv")
    if g.drift != "none":
        need = observed_centre & (g.strip >= 0) & ~np.isfinite(g.time)
        if not photos_table.has("time"):
            raise InputError(photos_table.path, photos_table.header_line,
                             "[gnss] drift needs the time of each exposure: add a column 'time' (seconds)")
        for i in np.flatnonzero(need)[:1]:
            raise photos_table.error(i, "[gnss] drift needs the time of this exposure (column 'time', seconds): "
                                        "it has an observed centre and a strip")
