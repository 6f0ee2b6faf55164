"""The input files of scanned film (issue 16; docs/file-formats.md "Scanned film"): project.toml's
[film] section, fiducials.csv, fiducial_measurements.csv and calibration.toml.

:func:`read_film` is called by the project reader (striptri.io.project_reader) after the image
points are read: with ``[film] image_points = "scan_px"`` it fits the fiducial transformation of
every photo and replaces the image points' x, y (scan pixels: col, row) and sigmas by plate
coordinates (mm) with propagated sigmas (striptri.film.fiducials); with a calibration.toml it
replaces the calibrated cameras' c, xp, yp, k1, k2, k3, p1, p2 (striptri.film.calibration). Every
problem is an InputError naming file, line and reason.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np

from striptri import model
from striptri.errors import InputError, Note
from striptri.io import plausibility as limits
from striptri.film import calibration as calib
from striptri.film import fiducials as fid
from striptri.film import transform
from striptri.film.data import CameraCalibration, FilmData
from striptri.io.csvtable import CsvTable, decode_text, parse_csv
from striptri.io.toml_file import TomlFile
from striptri.geometry.lens import PLATE

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the tomli backport
    import tomli as tomllib

TOML_SECTION = "film"
TOML_KEYS = ("image_points", "transformation", "sigma_px")
IMAGE_POINT_UNITS = ("plate", "scan_px")
DEFAULT_TRANSFORMATION = "affine"
DEFAULT_SIGMA_PX = 0.5
FIDUCIALS, MEASUREMENTS, CALIBRATION = "fiducials.csv", "fiducial_measurements.csv", "calibration.toml"
FILE_NAMES = (FIDUCIALS, MEASUREMENTS, CALIBRATION)
CALIBRATION_KEYS = ("focal_length_mm", "pbs_mm", "ppa_mm", "radius_mm", "field_angle_deg", "radial_distortion_um",
                    "radial_terms", "linear_term", "decentering_p1", "decentering_p2")


def read_film(files, toml: TomlFile, image_table: CsvTable, cameras: model.Cameras, photos: model.Photos,
              image_points: model.ImagePoints):
    """Apply the film inputs (module doc). files: the reader's file access (present, content, path);
    toml: project.toml as read. Returns (film or None, cameras, image_points, notes)."""
    section = toml.data.get(TOML_SECTION, {})
    has_calibration = files.present(CALIBRATION)
    if not section and not has_calibration:
        return None, cameras, image_points, []

    def fail(key: str, reason: str) -> InputError:
        return InputError(toml.path, toml.line(TOML_SECTION, key), f"[{TOML_SECTION}] {key}: {reason}")

    units = section.get("image_points", "plate")
    if units not in IMAGE_POINT_UNITS:
        raise fail("image_points", f"{units!r} is not one of 'plate' (mm of the plate, reduced already) or "
                                   "'scan_px' (col, row pixels of the scans, with fiducials)")
    kind = section.get("transformation", DEFAULT_TRANSFORMATION)
    if kind not in transform.KINDS:
        raise fail("transformation", f"{kind!r} is not one of {', '.join(map(repr, transform.KINDS))}")
    sigma_px = section.get("sigma_px", DEFAULT_SIGMA_PX)
    if isinstance(sigma_px, bool) or not isinstance(sigma_px, (int, float)) or not (
            math.isfinite(sigma_px) and sigma_px > 0):
        raise fail("sigma_px", f"{sigma_px!r} is not a positive number (scan pixels)")
    if not limits.SIGMA_MIN <= sigma_px <= limits.SIGMA_MAX:
        raise fail("sigma_px", f"{sigma_px!r} is outside the plausible range [{limits.number_text(limits.SIGMA_MIN)}, "
                               f"{limits.number_text(limits.SIGMA_MAX)}] scan pixels (docs/file-formats.md, Limits)")
    notes = []
    calibrations = ()
    if has_calibration:
        calibrations = _read_calibration(files, cameras)
        cameras = _apply_calibration(cameras, calibrations)
        notes.append(Note(str(files.path(CALIBRATION)), None,
                          "c, xp, yp, k1, k2, k3, p1, p2 of camera(s) " + ", ".join(c.camera_id for c in calibrations)
                          + " taken from calibration.toml (cameras.csv's values of these elements replaced)"))
    photo_ids, names, fit = [], [], None
    if units == "scan_px":
        for name in (FIDUCIALS, MEASUREMENTS):
            if not files.present(name):
                raise InputError(files.path(name), None, f"not found: [film] image_points = 'scan_px' needs {name}")
        fid_table = parse_csv(files.path(FIDUCIALS), files.content(FIDUCIALS))
        fiducial_xy = read_fiducials(fid_table, cameras)
        meas_table = parse_csv(files.path(MEASUREMENTS), files.content(MEASUREMENTS))
        photo_rows, names, xy_plate, q, sigma, measured = read_measurements(meas_table, photos, fiducial_xy, sigma_px)
        _check_enough(files.path(MEASUREMENTS), kind, photos, photo_rows, measured, image_points)
        for k in np.flatnonzero(fid.undetermined(kind, xy_plate, measured))[:1]:
            raise InputError(files.path(MEASUREMENTS), None,
                             f"the measured fiducials of photo '{photos.ids[photo_rows[k]]}' "
                             f"({', '.join(n for n, m in zip(names[k], measured[k]) if m)}) lie on a line or "
                             f"coincide: they cannot determine a {kind} transformation")
        try:
            fit = fid.fit_fiducials(kind, xy_plate, q, sigma, measured)
        except np.linalg.LinAlgError as exc:
            raise InputError(files.path(MEASUREMENTS), None,
                             f"the {kind} fiducial transformation could not be fitted ({exc}); check the "
                             "measured fiducials against fiducials.csv") from None
        notes += [_unused_note(t) for t in (fid_table, meas_table) if t.unused_columns()]
        photo_ids = [photos.ids[p] for p in photo_rows]
        row_of = np.full(len(photos.ids), -1)
        row_of[photo_rows] = np.arange(len(photo_rows))
        sigma_q = np.column_stack([_px_sigma(image_table, n, sigma_px) for n in ("sigma_x", "sigma_y")]).reshape(-1, 2)
        xy, _, sigma_xy = fid.plate_points(fit, row_of[image_points.photo_index],
                                           transform.q_from_colrow(image_points.xy), sigma_q)
        image_points = replace(image_points, xy=xy, sigma_xy=sigma_xy)
    film = FilmData(kind, float(sigma_px), photo_ids, names, fit, calibrations)
    return film, cameras, image_points, notes


def _unused_note(table: CsvTable) -> Note:
    """Columns of a film table that nothing reads (never ignored silently)."""
    return Note(str(table.path), table.header_line, "columns not used (ignored): "
                + ", ".join(f"'{c}'" for c in table.unused_columns()))


def _px_sigma(table: CsvTable, name: str, default: float) -> np.ndarray:
    """image_points.csv's sigma column in scan pixels (checked > 0 by the reader); empty -> default."""
    values = table.optional_floats(name)
    return np.where(np.isnan(values), default, values)


def read_fiducials(table: CsvTable, cameras: model.Cameras) -> dict:
    """fiducials.csv: camera_id, fiducial_id, x, y (calibrated, plate mm) -> {camera_index: {fid: (x, y)}}."""
    table.require("camera_id", "fiducial_id", "x", "y")
    if not len(table):
        raise InputError(table.path, table.header_line, "no fiducials: the file has a header row but no data rows")
    cam_of = {c: k for k, c in enumerate(cameras.ids)}
    cams, ids = table.strings("camera_id"), table.strings("fiducial_id")
    xy = np.column_stack([table.floats("x"), table.floats("y")]).reshape(-1, 2)
    out: dict = {}
    for i, (cam, f) in enumerate(zip(cams, ids)):
        if cam not in cam_of:
            raise table.error(i, f"unknown camera_id '{cam}' (not in cameras.csv)")
        marks = out.setdefault(cam_of[cam], {})
        if f in marks:
            raise table.error(i, f"fiducial '{f}' of camera '{cam}' is given twice")
        if np.abs(xy[i]).max() > 1e4:
            raise table.error(i, f"fiducial ({table.text(i, 'x')}, {table.text(i, 'y')}) is not a plate coordinate "
                                 "in mm (|x|, |y| <= 10000)")
        marks[f] = xy[i]
    return out


def read_measurements(table: CsvTable, photos: model.Photos, fiducial_xy: dict, sigma_px: float):
    """fiducial_measurements.csv: photo_id, fiducial_id, col, row[, sigma] (scan px) -> the fit's arrays
    for the photos that have measurements (photos.csv order)."""
    table.require("photo_id", "fiducial_id", "col", "row")
    if not len(table):
        raise InputError(table.path, table.header_line, "no fiducial measurements: the file has a header row "
                                                        "but no data rows")
    photo_of = {p: k for k, p in enumerate(photos.ids)}
    pids, fids = table.strings("photo_id"), table.strings("fiducial_id")
    colrow = np.column_stack([table.floats("col"), table.floats("row")]).reshape(-1, 2)
    sig = table.optional_floats("sigma")
    for i in np.flatnonzero(sig <= 0):
        raise table.error(i, f"column 'sigma': must be > 0 (got {table.text(i, 'sigma')})")
    i = limits.first_sigma_out_of_range(sig)
    if i is not None:
        raise table.error(i, f"column 'sigma': {table.text(i, 'sigma')} scan pixels is outside the plausible range "
                             f"[{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}]")
    sig = np.where(np.isnan(sig), sigma_px, sig)
    seen: dict = {}
    for i, (p, f) in enumerate(zip(pids, fids)):
        if p not in photo_of:
            raise table.error(i, f"unknown photo_id '{p}' (not in photos.csv)")
        cam = int(photos.camera_index[photo_of[p]])
        if f not in fiducial_xy.get(cam, {}):
            raise table.error(i, f"fiducial '{f}' is not in fiducials.csv for camera of photo '{p}'")
        if (p, f) in seen:
            raise table.error(i, f"fiducial '{f}' of photo '{p}' is measured twice (first on line "
                                 f"{table.lines[seen[(p, f)]]})")
        if np.abs(colrow[i]).max() > 1e7:
            raise table.error(i, "col, row are not scan pixels (|value| <= 1e7)")
        seen[(p, f)] = i
    photo_rows = sorted({photo_of[p] for p in pids})
    row_of = {p: k for k, p in enumerate(photo_rows)}
    n_fid = max(len(fiducial_xy[int(photos.camera_index[p])]) for p in photo_rows)
    P = len(photo_rows)
    names = [[""] * n_fid for _ in range(P)]
    xy_plate = np.zeros((P, n_fid, 2))
    for k, p in enumerate(photo_rows):
        marks = fiducial_xy[int(photos.camera_index[p])]
        names[k][:len(marks)] = list(marks)
        xy_plate[k, :len(marks)] = np.array(list(marks.values()))
    q = np.zeros((P, n_fid, 2))
    sigma = np.ones((P, n_fid))
    measured = np.zeros((P, n_fid), dtype=bool)
    for (p, f), i in seen.items():
        k = row_of[photo_of[p]]
        j = names[k].index(f)
        q[k, j] = transform.q_from_colrow(colrow[i])
        sigma[k, j], measured[k, j] = sig[i], True
    return photo_rows, names, xy_plate, q, sigma, measured


def _check_enough(path, kind: str, photos: model.Photos, photo_rows: list, measured: np.ndarray,
                  image_points: model.ImagePoints) -> None:
    """Every photo with image points needs MIN_FIDUCIALS[kind] measured fiducials."""
    count = np.zeros(len(photos.ids), dtype=int)
    count[photo_rows] = measured.sum(1)
    need = transform.MIN_FIDUCIALS[kind]
    with_points = np.zeros(len(photos.ids), dtype=bool)
    with_points[image_points.photo_index] = True
    for p in np.flatnonzero(with_points & (count < need))[:1]:
        raise InputError(path, None, f"photo '{photos.ids[p]}' has {count[p]} measured fiducials; the {kind} "
                                     f"transformation needs at least {need}")


def _read_calibration(files, cameras: model.Cameras) -> tuple:
    """calibration.toml: one table [camera.<camera_id>] per calibrated camera (docs/file-formats.md)."""
    path = files.path(CALIBRATION)
    text = decode_text(path, files.content(CALIBRATION))
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise InputError(path, int(match.group(1)) if match else None, f"not valid TOML: {exc}") from None

    def line(cam: str, key: str | None = None):
        head = None
        for number, row in enumerate(text.splitlines(), start=1):
            if re.match(rf"\s*\[\s*camera\.\"?{re.escape(cam)}\"?\s*\]", row):
                head = number
            elif head is not None and key and re.match(rf"\s*{re.escape(key)}\s*=", row):
                return number
        return head

    cams = data.get("camera")
    if not isinstance(cams, dict) or not cams or set(data) != {"camera"}:
        raise InputError(path, None, "expected one or more tables [camera.<camera_id>] and nothing else")
    out = []
    for cam, table in cams.items():
        def fail(key, reason, cam=cam):
            return InputError(path, line(cam, key), f"[camera.{cam}] {key + ': ' if key else ''}{reason}")
        if cam not in cameras.ids:
            raise fail(None, f"unknown camera '{cam}' (not in cameras.csv)")
        for key in table:
            if key not in CALIBRATION_KEYS:
                raise fail(key, f"unknown key (known: {', '.join(CALIBRATION_KEYS)})")

        def number(key, positive=False, default=None):
            value = table.get(key, default)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or (
                    positive and value <= 0):
                raise fail(key, f"{value!r} is not a {'positive ' if positive else ''}number")
            if abs(value) > limits.PLATE_LIMIT:  # named here, not later against cameras.csv
                raise fail(key, f"{value!r} exceeds the plausibility limit of "
                                f"{limits.number_text(limits.PLATE_LIMIT)} mm (docs/file-formats.md, Limits)")
            return float(value)

        def vector(key, length=None):
            value = table.get(key)
            ok = isinstance(value, list) and value and all(
                not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
                and abs(v) <= limits.PLATE_LIMIT for v in value)
            if not ok or (length is not None and len(value) != length):
                raise fail(key, f"{value!r} is not a list of {length or 'some'} numbers")
            return np.array(value, dtype=float)

        c = number("focal_length_mm", positive=True)
        pbs = vector("pbs_mm", 2)
        ppa = vector("ppa_mm", 2) if "ppa_mm" in table else np.full(2, np.nan)
        if ("radius_mm" in table) == ("field_angle_deg" in table):
            raise fail(None, "give the table's radial distances as radius_mm or as field_angle_deg (one of them)")
        if "radius_mm" in table:
            radius, angle = vector("radius_mm"), None
        else:
            angle = vector("field_angle_deg")
            if np.any((angle <= 0) | (angle >= 89)):
                raise fail("field_angle_deg", "angles must lie in (0, 89) degrees")
            radius = c * np.tan(np.radians(angle))
        raw = table.get("radial_distortion_um")
        rows = raw if isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw) else [raw]
        dr = np.array([_distortion_row(r, len(radius), fail) for r in rows])
        terms = table.get("radial_terms", 2)
        if terms not in (2, 3) or isinstance(terms, bool):
            raise fail("radial_terms", f"{terms!r} is not 2 (k1, k2) or 3 (k1, k2, k3)")
        linear = table.get("linear_term", True)
        if not isinstance(linear, bool):
            raise fail("linear_term", f"{linear!r} is not true or false")
        if len(radius) < terms + int(linear):
            raise fail("radial_distortion_um", f"{len(radius)} radial distances cannot determine "
                                               f"{terms + int(linear)} terms")
        fit = calib.fit_radial_distortion(radius, dr, terms, linear)
        p1, p2 = number("decentering_p1", default=0.0), number("decentering_p2", default=0.0)
        out.append(CameraCalibration(cam, c, pbs, ppa, np.full(len(radius), np.nan) if angle is None else angle,
                                     fit, calib.camera_elements(c, pbs, fit, p1, p2)))
    return tuple(out)


def _distortion_row(row, n: int, fail) -> np.ndarray:
    """One row of radial_distortion_um: n numbers (micrometres)."""
    ok = isinstance(row, list) and len(row) == n and all(
        not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in row)
    if not ok:
        raise fail("radial_distortion_um", f"expected {n} numbers (micrometres, one per radial distance) or a list "
                                           f"of such rows (one per semi-diagonal), got {row!r}")
    return np.array(row, dtype=float)


def _apply_calibration(cameras: model.Cameras, calibrations: tuple) -> model.Cameras:
    """cameras with the calibrated elements c .. p2 replaced and the plate convention."""
    interior = cameras.interior.copy()
    convention = (np.zeros(len(cameras.ids), dtype=int) if cameras.convention is None
                  else np.asarray(cameras.convention).copy())
    for cal in calibrations:
        j = cameras.ids.index(cal.camera_id)
        interior[j, :8] = cal.elements[:8]
        convention[j] = PLATE
    return replace(cameras, interior=interior, convention=convention)
