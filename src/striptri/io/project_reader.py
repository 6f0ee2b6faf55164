"""Read a project folder into a :class:`striptri.model.Project` (DESIGN section 10, docs/file-formats.md).

The folder holds cameras.csv, photos.csv, image_points.csv and, optionally, control.csv,
bases.csv and project.toml. Every problem is an :class:`InputError` naming the file, the line and
the reason; the reader writes nothing.

Choices made here (also in docs/file-formats.md):

* photos keep the order of photos.csv (list them along the strip: the chain order and the band
  structure of the normal equations follow it); cameras keep the order of cameras.csv;
* object points: first the points of control.csv in its order, then the tie points in the order of
  their first measurement in image_points.csv; a control point measured on no photo is kept, a photo
  with no measurements is allowed;
* angles (and their sigmas) are in the unit of ``[units] angles`` and are converted to radians;
  the photos.csv angle columns are named after ``[units] rotation``: omega, phi, kappa or
  alpha, omega, chi;
* empty sigma: photos.csv -> free (nan), 0 -> held fixed, > 0 observed; cameras.csv and
  control.csv -> held fixed (nan; 0 also means held fixed), > 0 observed, and in cameras.csv the
  word ``free`` -> estimated without a prior (inf); image_points.csv -> ``[defaults] sigma_image``.
"""

from __future__ import annotations

import math
from dataclasses import replace
import re
from pathlib import Path

import numpy as np

from striptri import model, rotations
from striptri.errors import InputError
from striptri.lens import B1, CAMERA_ELEMENTS, CONVENTIONS, IMAGE, NCP
from striptri.adjustment import DATUMS, METHODS
from striptri.io.csvtable import CsvTable, read_csv
from striptri.solvers import SOLVERS

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the tomli backport
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None

# Radians per unit of [units] angles.
RADIANS_PER_UNIT = {"deg": math.pi / 180.0, "gon": math.pi / 200.0, "rad": 1.0}
# Names of the three angle columns of photos.csv for each rotation convention.
ANGLE_COLUMNS = {
    "omega-phi-kappa": ("omega", "phi", "kappa"),
    "alpha-omega-chi": ("alpha", "omega", "chi"),
}
# Base components of bases.csv (Schmid 17, 24): component -> ground axis.
BASE_AXES = {"bx": 0, "by": 1, "bz": 2}
# Keys project.toml may hold, per section.
TOML_KEYS = {
    "units": ("angles", "rotation"),
    "defaults": ("sigma_image",),
    "adjustment": ("method", "solver", "max_iterations", "cost_tolerance"),
    "datum": ("mode",),
}

FILE_NAMES = ("cameras.csv", "photos.csv", "image_points.csv", "control.csv", "bases.csv", "approx_points.csv",
              "project.toml")


def read_project(folder: str | Path) -> model.Project:
    """Read and validate the project folder ``folder``. Raises InputError; writes nothing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, None, "project folder not found" if not folder.exists() else "is not a folder")
    settings = read_settings(folder / "project.toml")
    cameras = _read_cameras(read_csv(folder / "cameras.csv"))
    photos = _read_photos(read_csv(folder / "photos.csv"), cameras, settings)
    control_path = folder / "control.csv"
    control = _read_control(read_csv(control_path)) if control_path.exists() else _Control.empty()
    image_points, points = _read_image_points(read_csv(folder / "image_points.csv"), photos, control, settings)
    bases_path = folder / "bases.csv"
    bases = _read_bases(read_csv(bases_path), photos) if bases_path.exists() else model.BaseComponents.empty()
    approx_path = folder / "approx_points.csv"
    if approx_path.exists():
        points = replace(points, xyz_approx=_read_approx_points(read_csv(approx_path), points))
    return model.Project(
        cameras=cameras,
        photos=photos,
        image_points=image_points,
        points=points,
        bases=bases,
        settings=settings,
        source=folder,
    )


# ---------------------------------------------------------------------------------------------
# project.toml


def read_settings(path: str | Path) -> model.ProjectSettings:
    """ProjectSettings from project.toml; defaults when the file is absent. Unknown sections, keys
    or values -> InputError naming project.toml and, where it can be found, the line."""
    path = Path(path)
    if not path.exists():
        return model.ProjectSettings()
    text = _read_toml_text(path)
    data = _parse_toml(path, text)
    defaults = model.ProjectSettings()
    _check_toml_keys(path, text, data)

    def get(section: str, key: str, default):
        return data.get(section, {}).get(key, default)

    def fail(section: str, key: str, reason: str) -> InputError:
        return InputError(path, _toml_line(text, section, key), f"[{section}] {key}: {reason}")

    def choice(section: str, key: str, allowed: tuple[str, ...], default: str) -> str:
        value = get(section, key, default)
        if not isinstance(value, str) or value not in allowed:
            raise fail(section, key, f"{value!r} is not one of {', '.join(repr(a) for a in allowed)}")
        return value

    sigma_image = get("defaults", "sigma_image", defaults.sigma_image)
    if isinstance(sigma_image, bool) or not isinstance(sigma_image, (int, float)) or not (
        math.isfinite(sigma_image) and sigma_image > 0
    ):
        raise fail("defaults", "sigma_image", f"{sigma_image!r} is not a positive number (plate units)")
    max_iterations = get("adjustment", "max_iterations", defaults.max_iterations)
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise fail("adjustment", "max_iterations", f"{max_iterations!r} is not a positive integer")
    cost_tolerance = get("adjustment", "cost_tolerance", defaults.cost_tolerance)
    if isinstance(cost_tolerance, bool) or not isinstance(cost_tolerance, (int, float)) or not (
        math.isfinite(cost_tolerance) and 0 <= cost_tolerance < 1
    ):
        raise fail("adjustment", "cost_tolerance", f"{cost_tolerance!r} is not a number in [0, 1)")
    return model.ProjectSettings(
        angle_unit=choice("units", "angles", model.ANGLE_UNITS, defaults.angle_unit),
        rotation=choice("units", "rotation", model.ROTATION_CONVENTIONS, defaults.rotation),
        sigma_image=float(sigma_image),
        method=choice("adjustment", "method", METHODS, defaults.method),
        solver=choice("adjustment", "solver", SOLVERS, defaults.solver),
        max_iterations=max_iterations,
        datum=choice("datum", "mode", DATUMS, defaults.datum),
        cost_tolerance=float(cost_tolerance),
    )


def _read_toml_text(path: Path) -> str:
    """The text of project.toml; undecodable bytes -> InputError with the line."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, raw[: exc.start].count(b"\n") + 1, "not valid UTF-8 text") from None


def _parse_toml(path: Path, text: str) -> dict:
    """tomllib.loads with its error turned into an InputError (line taken from the message)."""
    if tomllib is None:  # pragma: no cover
        raise InputError(path, None, "reading project.toml needs Python >= 3.11 or the 'tomli' package")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise InputError(path, int(match.group(1)) if match else None, f"not valid TOML: {exc}") from None


def _check_toml_keys(path: Path, text: str, data: dict) -> None:
    """Only the sections and keys of TOML_KEYS are allowed (a misspelt key must not be ignored)."""
    for section, table in data.items():
        if section not in TOML_KEYS:
            known = ", ".join(f"[{s}]" for s in TOML_KEYS)
            reason = f"unknown section [{section}] (known: {known})"
            raise InputError(path, _toml_section_line(text, section), reason)
        if not isinstance(table, dict):
            raise InputError(path, _toml_line(text, "", section), f"'{section}' must be a section [{section}]")
        for key in table:
            if key not in TOML_KEYS[section]:
                known = ", ".join(TOML_KEYS[section])
                raise InputError(
                    path, _toml_line(text, section, key), f"unknown key '{key}' in [{section}] (known: {known})"
                )


def _toml_section_line(text: str, section: str) -> int | None:
    """Line of the header [section], or None."""
    for number, line in enumerate(text.splitlines(), start=1):
        if re.match(rf"\s*\[\s*{re.escape(section)}\s*\]", line):
            return number
    return None


def _toml_line(text: str, section: str, key: str) -> int | None:
    """Line of ``key = ...`` inside [section] (section "" = top level), or None if not found."""
    current = ""
    for number, line in enumerate(text.splitlines(), start=1):
        header = re.match(r"\s*\[\s*([^\]]+?)\s*\]", line)
        if header:
            current = header.group(1)
        elif current == section and re.match(rf"\s*\"?{re.escape(key)}\"?\s*=", line):
            return number
    return None


# ---------------------------------------------------------------------------------------------
# cameras.csv


def _read_cameras(table: CsvTable) -> model.Cameras:
    """cameras.csv: camera_id, c, xp, yp[, k1, k2, k3, p1, p2, b1, b2][, distortion]
    [, sigma_<element> ...] (docs/camera-model.md). Additional parameters default to 0, held."""
    table.require("camera_id", "c", "xp", "yp")
    ids = table.strings("camera_id")
    _check_unique(table, "camera_id", ids)
    n = len(ids)
    interior = np.zeros((n, NCP))
    interior[:, :3] = np.column_stack([table.floats(name) for name in ("c", "xp", "yp")]).reshape(-1, 3)
    for i in np.flatnonzero(interior[:, 0] <= 0):
        raise table.error(i, f"principal distance c must be > 0 (got {table.rows[i][table.header.index('c')]})")
    for j, name in enumerate(CAMERA_ELEMENTS[3:], start=3):
        interior[:, j] = np.nan_to_num(table.optional_floats(name), nan=0.0)
    sigma = np.column_stack(
        [_sigma_column(table, f"sigma_{name}", zero_means_fixed=True, free_word=True) for name in CAMERA_ELEMENTS]
    ).reshape(-1, NCP)
    convention = np.zeros(n, dtype=int)
    for i, word in enumerate(table.optional_strings("distortion", "plate")):
        word = word.strip().lower() or "plate"
        if word not in CONVENTIONS:
            raise table.error(i, f"distortion must be 'plate' (the measured coordinates are corrected, "
                                 f"DBAT/photogrammetry) or 'image' (applied to the projected point, "
                                 f"BAL/COLMAP/OpenCV), not '{word}'")
        convention[i] = CONVENTIONS[word]
    affine = (interior[:, B1:] != 0) | ~np.isnan(sigma[:, B1:])
    for i in np.flatnonzero((convention == IMAGE) & affine.any(axis=1)):
        raise table.error(i, "b1, b2 (affinity, shear) belong to the plate convention; with distortion = image "
                             "they must be empty or 0 and held")
    return model.Cameras(ids=ids, interior=interior, sigma_interior=sigma, convention=convention)


# ---------------------------------------------------------------------------------------------
# photos.csv


def _read_photos(table: CsvTable, cameras: model.Cameras, settings: model.ProjectSettings) -> model.Photos:
    """photos.csv: photo_id, camera_id, strip_id, X0, Y0, Z0, three angles[, their sigmas].

    Angles in settings.angle_unit, named after settings.rotation; converted to radians and to
    R_ground_from_cam with rotations.R_from_angles. Sigma: empty = free (nan), 0 = fixed, > 0 observed.
    """
    angle_names = ANGLE_COLUMNS[settings.rotation]
    table.require("photo_id", "camera_id", "strip_id", "X0", "Y0", "Z0", *angle_names)
    ids = table.strings("photo_id")
    _check_unique(table, "photo_id", ids)
    camera_of = {cid: k for k, cid in enumerate(cameras.ids)}
    camera_index = np.zeros(len(ids), dtype=np.int64)
    for i, cid in enumerate(table.strings("camera_id")):
        if cid not in camera_of:
            raise table.error(i, f"unknown camera_id '{cid}' (not in cameras.csv)")
        camera_index[i] = camera_of[cid]
    to_rad = RADIANS_PER_UNIT[settings.angle_unit]
    xyz0 = np.column_stack([table.floats(n) for n in ("X0", "Y0", "Z0")]).reshape(-1, 3)
    angles = np.column_stack([table.floats(n) for n in angle_names]).reshape(-1, 3) * to_rad
    sigma_xyz0 = np.column_stack(
        [_sigma_column(table, f"sigma_{n}", zero_means_fixed=False) for n in ("X0", "Y0", "Z0")]
    ).reshape(-1, 3)
    sigma_angles = (
        np.column_stack([_sigma_column(table, f"sigma_{n}", zero_means_fixed=False) for n in angle_names]).reshape(
            -1, 3
        )
        * to_rad
    )
    return model.Photos(
        ids=ids,
        camera_index=camera_index,
        strip_ids=table.strings("strip_id", allow_empty=True),
        xyz0=xyz0,
        R_ground_from_cam=rotations.R_from_angles(angles, settings.rotation).reshape(-1, 3, 3),
        angles=angles,
        sigma_xyz0=sigma_xyz0,
        sigma_angles=sigma_angles,
    )


# ---------------------------------------------------------------------------------------------
# control.csv


class _Control:
    """The rows of control.csv: ids in file order, kind codes, given xyz and sigmas (nan = not given /
    held fixed)."""

    def __init__(self, ids: list[str], kind: np.ndarray, xyz: np.ndarray, sigma: np.ndarray):
        self.ids, self.kind, self.xyz, self.sigma = ids, kind, xyz, sigma

    @staticmethod
    def empty() -> "_Control":
        return _Control([], np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))


def _read_control(table: CsvTable) -> _Control:
    """control.csv: point_id, kind, X, Y, Z[, sigma_X, sigma_Y, sigma_Z].

    kind XYZ / XY / Z / check (case-insensitive). Coordinates the kind does not give are stored as
    nan (and ignored if present); check points keep their reference X, Y, Z and no sigma.
    Sigma: empty or 0 = held fixed (nan), > 0 = weighted control.
    """
    table.require("point_id", "kind", "X", "Y", "Z")
    ids = table.strings("point_id")
    _check_unique(table, "point_id", ids)
    kind = np.zeros(len(ids), dtype=np.int64)
    for i, text in enumerate(table.strings("kind", allow_empty=True)):
        if text.upper() not in model.KIND_CODES:
            raise table.error(i, f"unknown kind '{text}' (accepted: XYZ, XY, Z, check)")
        kind[i] = model.KIND_CODES[text.upper()]
    xyz_file = np.column_stack([table.optional_floats(n) for n in "XYZ"]).reshape(-1, 3)
    sigma_file = np.column_stack(
        [_sigma_column(table, f"sigma_{n}", zero_means_fixed=True) for n in "XYZ"]
    ).reshape(-1, 3)
    needed = np.array([_needed_axes(k) for k in kind], dtype=bool).reshape(-1, 3)
    for i, j in zip(*np.nonzero(needed & np.isnan(xyz_file))):
        name = model.KIND_NAMES[kind[i]]
        raise table.error(i, f"kind {name} needs {'XYZ'[j]} but it is empty (kind {name} needs "
                             f"{', '.join(a for a, n in zip('XYZ', needed[i]) if n)})")
    xyz = np.where(needed, xyz_file, np.nan)
    given = np.array([model.GIVEN_AXES[k] for k in kind], dtype=bool).reshape(-1, 3)
    sigma = np.where(given, sigma_file, np.nan)
    return _Control(ids, kind, xyz, sigma)


def _needed_axes(kind: int) -> tuple[bool, bool, bool]:
    """Which of X, Y, Z a control row of this kind must give (check points: all three, as reference)."""
    return (True, True, True) if kind == model.CHECK else model.GIVEN_AXES[kind]


# ---------------------------------------------------------------------------------------------
# image_points.csv and the object points


def _read_image_points(
    table: CsvTable, photos: model.Photos, control: _Control, settings: model.ProjectSettings
) -> tuple[model.ImagePoints, model.ObjectPoints]:
    """image_points.csv: photo_id, point_id, x, y[, sigma_x, sigma_y] (plate units).

    Empty sigma -> settings.sigma_image; a sigma must be > 0. Object points: control points in
    control.csv order, then tie points by first measurement.
    """
    table.require("photo_id", "point_id", "x", "y")
    photo_of = {pid: k for k, pid in enumerate(photos.ids)}
    point_of = {pid: k for k, pid in enumerate(control.ids)}
    point_ids = list(control.ids)
    photo_ids = table.strings("photo_id")
    measured_ids = table.strings("point_id")
    photo_index = np.zeros(len(table), dtype=np.int64)
    point_index = np.zeros(len(table), dtype=np.int64)
    first_line: dict[tuple[str, str], int] = {}
    for i, (photo_id, point_id) in enumerate(zip(photo_ids, measured_ids)):
        if photo_id not in photo_of:
            raise table.error(i, f"unknown photo_id '{photo_id}' (not in photos.csv)")
        key = (photo_id, point_id)
        if key in first_line:
            raise table.error(
                i, f"duplicate measurement of point '{point_id}' on photo '{photo_id}' (first on line {first_line[key]})"
            )
        first_line[key] = table.lines[i]
        if point_id not in point_of:
            point_of[point_id] = len(point_ids)
            point_ids.append(point_id)
        photo_index[i] = photo_of[photo_id]
        point_index[i] = point_of[point_id]
    xy = np.column_stack([table.floats("x"), table.floats("y")]).reshape(-1, 2)
    sigma_xy = np.column_stack(
        [_image_sigma(table, name, settings.sigma_image) for name in ("sigma_x", "sigma_y")]
    ).reshape(-1, 2)
    image_points = model.ImagePoints(photo_index=photo_index, point_index=point_index, xy=xy, sigma_xy=sigma_xy)
    return image_points, _object_points(point_ids, control)


def _image_sigma(table: CsvTable, name: str, default: float) -> np.ndarray:
    """An image sigma column: empty -> default; must be > 0."""
    values = table.optional_floats(name)
    for i in np.flatnonzero(values <= 0):
        raise table.error(i, f"column '{name}': a plate measurement sigma must be > 0 (got {values[i]!r})")
    return np.where(np.isnan(values), default, values)


def _object_points(point_ids: list[str], control: _Control) -> model.ObjectPoints:
    """ObjectPoints for point_ids, whose first len(control.ids) entries are the control points."""
    n, n_control = len(point_ids), len(control.ids)
    kind = np.full(n, model.TIE, dtype=np.int64)
    xyz_given = np.full((n, 3), np.nan)
    sigma_given = np.full((n, 3), np.nan)
    kind[:n_control] = control.kind
    xyz_given[:n_control] = control.xyz
    sigma_given[:n_control] = control.sigma
    return model.ObjectPoints(ids=point_ids, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given)


# ---------------------------------------------------------------------------------------------
# approx_points.csv


def _read_approx_points(table: CsvTable, points: model.ObjectPoints) -> np.ndarray:
    """approx_points.csv: point_id, X, Y, Z (empty = unknown): approximate coordinates of object
    points (starting values of the bundle method, written by striptri convert). Every id must be
    a point of the project. -> (n_points, 3), nan where not given."""
    table.require("point_id", "X", "Y", "Z")
    index = {pid: j for j, pid in enumerate(points.ids)}
    out = np.full((len(points), 3), np.nan)
    xyz = np.column_stack([table.optional_floats(a) for a in "XYZ"]).reshape(-1, 3)
    for i, pid in enumerate(table.strings("point_id")):
        if pid not in index:
            raise table.error(i, f"point_id '{pid}' is not measured in image_points.csv nor given in control.csv")
        out[index[pid]] = xyz[i]
    return out


# ---------------------------------------------------------------------------------------------
# bases.csv


def _read_bases(table: CsvTable, photos: model.Photos) -> model.BaseComponents:
    """bases.csv: photo_from, photo_to, component (bx|by|bz), value, sigma (our extension, Schmid 17, 24).

    value = O[photo_to, axis] - O[photo_from, axis] in metres. sigma: empty or 0 = enforced exactly,
    > 0 = observed (e.g. statoscope bz).
    """
    table.require("photo_from", "photo_to", "component", "value", "sigma")
    photo_of = {pid: k for k, pid in enumerate(photos.ids)}
    index = {}
    for name in ("photo_from", "photo_to"):
        index[name] = np.zeros(len(table), dtype=np.int64)
        for i, pid in enumerate(table.strings(name)):
            if pid not in photo_of:
                raise table.error(i, f"unknown {name} '{pid}' (not in photos.csv)")
            index[name][i] = photo_of[pid]
    axis = np.zeros(len(table), dtype=np.int64)
    first_line: dict[tuple[int, int, int], int] = {}
    for i, text in enumerate(table.strings("component")):
        if text.lower() not in BASE_AXES:
            raise table.error(i, f"unknown component '{text}' (accepted: bx, by, bz)")
        axis[i] = BASE_AXES[text.lower()]
        if index["photo_from"][i] == index["photo_to"][i]:
            raise table.error(i, "photo_from and photo_to are the same photo")
        key = (int(index["photo_from"][i]), int(index["photo_to"][i]), int(axis[i]))
        if key in first_line:
            raise table.error(i, f"duplicate base component {text.lower()} (first on line {first_line[key]})")
        first_line[key] = table.lines[i]
    return model.BaseComponents(
        photo_from=index["photo_from"],
        photo_to=index["photo_to"],
        axis=axis,
        value=table.floats("value"),
        sigma=_sigma_column(table, "sigma", zero_means_fixed=False),
    )


# ---------------------------------------------------------------------------------------------
# shared


def _check_unique(table: CsvTable, column: str, ids: list[str]) -> None:
    """InputError on the second occurrence of an id, naming the line of the first."""
    first_line: dict[str, int] = {}
    for i, value in enumerate(ids):
        if value in first_line:
            raise table.error(i, f"duplicate {column} '{value}' (first on line {first_line[value]})")
        first_line[value] = table.lines[i]


def _sigma_column(table: CsvTable, name: str, zero_means_fixed: bool, free_word: bool = False) -> np.ndarray:
    """An optional sigma column -> (n,): empty = nan, negative = InputError.

    zero_means_fixed: 0 -> nan (files where nan means "held fixed"). free_word: accept ``free`` -> inf.
    """
    values = table.optional_floats(name, keywords={"free": math.inf} if free_word else None)
    for i in np.flatnonzero(values < 0):
        raise table.error(i, f"column '{name}': a standard deviation cannot be negative (got {values[i]!r})")
    if zero_means_fixed:
        values = np.where(values == 0, np.nan, values)
    return values
