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
* the plate quantities (c, xp, yp, x, y and their sigmas) are in the unit ``[units] plate`` names
  (mm, the default, or px); it labels the report and converts nothing;
* empty sigma: photos.csv -> free (nan), 0 -> held fixed, > 0 observed; cameras.csv and
  control.csv -> held fixed (nan; 0 also means held fixed), > 0 observed, and in cameras.csv the
  word ``free`` -> estimated without a prior (inf); image_points.csv -> ``[defaults] sigma_image``;
* the three required tables must have data rows; numbers must lie within the plausibility limits
  of :mod:`striptri.io.plausibility`;
* nothing is ignored silently: what the reader does not use (a column, a file of the folder, a
  control point no photo measures, a tie point on one photo, ...) becomes a
  :class:`striptri.errors.Note` in ``Project.notes`` (:mod:`striptri.io.project_notes`).

The same rules read a project from a mapping file name -> text (:func:`parse_project`):
``striptri convert`` validates the project it is about to write that way, without a temporary file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import replace
from itertools import repeat
from pathlib import Path

import numpy as np

from striptri.geometry import balanced, rotations
from striptri import model
from striptri.errors import InputError
from striptri.geometry.lens import CAMERA_ELEMENTS, CONVENTIONS, NCP
from striptri.geometry.rotations import RADIANS_PER_UNIT
from striptri.core.options import DATUMS, METHODS
from striptri.crs.settings import KEYS, parse_coordinates
from striptri.io import plausibility as limits
from striptri.io.csvtable import CsvTable, decode_text, input_present, parse_csv, read_input_bytes
from striptri.io.distances_reader import FILE_NAME as DISTANCES_FILE, read_distances
from striptri.io.film_reader import FILE_NAMES as FILM_FILES, TOML_KEYS as FILM_TOML_KEYS, read_film
from striptri.io.gnss_reader import TOML_KEYS as GNSS_TOML_KEYS, TOML_SECTION as GNSS_SECTION, read_gnss
from striptri.io.project_notes import project_notes, unread_files_note
from striptri.equations.plate_corrections import EARTH_RADIUS_RANGE_M
from striptri.solvers import SOLVERS

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the tomli backport
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None

# Names of the three angle columns of photos.csv for each rotation convention.
ANGLE_COLUMNS = {
    "omega-phi-kappa": ("omega", "phi", "kappa"),
    "alpha-omega-chi": ("alpha", "omega", "chi"),
    "phi-omega-kappa": ("phi", "omega", "kappa"),
}
# Base components of bases.csv (Schmid 17, 24): component -> ground axis.
BASE_AXES = {"bx": 0, "by": 1, "bz": 2}
# Keys project.toml may hold, per section.
TOML_KEYS = {
    "units": ("angles", "rotation", "plate"),
    "defaults": ("sigma_image",),
    "adjustment": ("method", "solver", "max_iterations", "cost_tolerance"),
    "datum": ("mode", "points"),
    "corrections": ("earth_curvature", "refraction", "earth_radius"),
    GNSS_SECTION: GNSS_TOML_KEYS,  # GNSS shift and drift (io.gnss_reader)
    "coordinates": KEYS,  # striptri.crs.settings
    "plan": ("format", "terrain_height"),  # striptri plan only (striptri.plan.vongruber)
    "film": FILM_TOML_KEYS,  # scanned film (striptri.film.data)
}

FILE_NAMES = ("cameras.csv", "photos.csv", "image_points.csv", "control.csv", "bases.csv", "approx_points.csv",
              "project.toml", DISTANCES_FILE) + FILM_FILES
# the required tables and what their rows are (for "no cameras ..." messages)
REQUIRED_TABLES = {"cameras.csv": "cameras", "photos.csv": "photos", "image_points.csv": "plate measurements"}


def read_project(folder: str | Path, plate_measurements_optional: bool = False) -> model.Project:
    """Read and validate the project folder ``folder``. Raises InputError; writes nothing.
    plate_measurements_optional: a folder without image_points.csv reads as a project with no plate
    measurements and the control points as its points (a plan, striptri.plan.vongruber)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, None, "project folder not found" if not folder.exists() else "is not a folder")
    return _read(_FolderFiles(folder), plate_measurements_optional)


def parse_project(files: Mapping[str, str | bytes], folder: str | Path | None = None) -> model.Project:
    """Read a project from the contents of its files (file name -> text or bytes, as written by
    project_files) with exactly the rules of read_project, in memory. folder: where the files would
    be, for messages (None: messages name the bare file names). Raises InputError."""
    return _read(_MemoryFiles(files, None if folder is None else Path(folder)))


class _FolderFiles:
    """The input files of a project folder on disk."""

    def __init__(self, folder: Path):
        self.folder = folder

    def path(self, name: str) -> Path:
        return self.folder / name

    def present(self, name: str) -> bool:
        return input_present(self.path(name))

    def content(self, name: str) -> bytes:
        return read_input_bytes(self.path(name))

    def source(self) -> Path:
        return self.folder

    def unread_notes(self) -> list:
        note = unread_files_note(self.folder, os.listdir(self.folder), FILE_NAMES)
        return [] if note is None else [note]


class _MemoryFiles:
    """The input files of a project held in memory (file name -> text)."""

    def __init__(self, files: Mapping[str, str | bytes], folder: Path | None):
        self.files, self.folder = files, folder

    def path(self, name: str) -> Path:
        return Path(name) if self.folder is None else self.folder / name

    def present(self, name: str) -> bool:
        return name in self.files

    def content(self, name: str) -> str | bytes:
        if name not in self.files:
            raise InputError(self.path(name), None, "file not found")
        return self.files[name]

    def source(self) -> Path | None:
        return self.folder

    def unread_notes(self) -> list:
        return []


def _read(files, plate_measurements_optional: bool = False) -> model.Project:
    """The project of ``files`` (_FolderFiles or _MemoryFiles): every rule of the module doc;
    plate_measurements_optional as read_project's."""
    toml = "project.toml"
    settings = parse_settings(files.path(toml), files.content(toml)) if files.present(toml) else model.ProjectSettings()
    tables: dict[str, CsvTable] = {}

    def table(name: str) -> CsvTable:
        tables[name] = parse_csv(files.path(name), files.content(name))
        if name in REQUIRED_TABLES:
            _require_rows(tables[name], REQUIRED_TABLES[name])
        return tables[name]

    cameras = _read_cameras(table("cameras.csv"))
    photos = _read_photos(table("photos.csv"), cameras, settings)
    control = _read_control(table("control.csv")) if files.present("control.csv") else _Control.empty()
    film, film_notes = None, []
    if plate_measurements_optional and not files.present("image_points.csv"):
        image_points = model.ImagePoints(photo_index=np.zeros(0, dtype=np.int64), point_index=np.zeros(0, dtype=np.int64),
                                         xy=np.zeros((0, 2)), sigma_xy=np.zeros((0, 2)))
        points = _object_points(list(control.ids), control)
        active = np.ones(0, dtype=bool)
    else:
        active = _active_column(table("image_points.csv"))
        image_points, points = _read_image_points(tables["image_points.csv"], photos, control, settings, active)
        film, cameras, image_points, film_notes = _read_film(files, tables, cameras, photos, image_points)
        _check_plate_geometry(tables["image_points.csv"], tables["cameras.csv"], image_points, photos, cameras)
    bases = _read_bases(table("bases.csv"), photos) if files.present("bases.csv") else model.BaseComponents.empty()
    if files.present("approx_points.csv"):
        points = replace(points, xyz_approx=_read_approx_points(table("approx_points.csv"), points))
    gnss = _read_gnss(files, tables, cameras, photos, settings)
    distances = read_distances(table(DISTANCES_FILE), points) if files.present(DISTANCES_FILE) else None
    if distances is not None and not len(distances):
        distances = None  # a header without rows: no distances (as every other optional file)
    notes = (project_notes(tables, cameras, photos, image_points, points, len(control.ids), active)
             if "image_points.csv" in tables else []) + film_notes + files.unread_notes()
    inactive = None if active.all() else _rows(image_points, ~active)
    _check_datum_points(files, settings, points)
    return model.Project(
        cameras=cameras,
        photos=photos,
        image_points=image_points if inactive is None else _rows(image_points, active),
        inactive_image_points=inactive,
        distances=distances,
        points=points,
        bases=bases,
        settings=settings,
        source=files.source(),
        notes=tuple(notes),
        gnss=gnss,
        film=film,
    )


def _read_gnss(files, tables: dict, cameras: model.Cameras, photos: model.Photos, settings: model.ProjectSettings):
    """The GNSS/IMU model (io.gnss_reader), with project.toml's [gnss] section."""
    toml = "project.toml"
    path, text, data = None, "", {}
    if files.present(toml):
        path = files.path(toml)
        text = decode_text(path, files.content(toml))
        data = _parse_toml(path, text)
    return read_gnss(tables["cameras.csv"], tables["photos.csv"], cameras, photos,
                     RADIANS_PER_UNIT[settings.angle_unit], path, text, data,
                     lambda section, key: _toml_line(text, section, key))


def _read_film(files, tables: dict, cameras, photos, image_points):
    """Scanned film (striptri.film.data): fiducials to the plate, calibration.toml's cameras."""
    toml = "project.toml"
    path, text, data = files.path(toml), "", {}
    if files.present(toml):
        text = decode_text(path, files.content(toml))
        data = _parse_toml(path, text)
    return read_film(files, path, text, data, lambda section, key: _toml_line(text, section, key),
                     tables["image_points.csv"], cameras, photos, image_points)


def _require_rows(table: CsvTable, what: str) -> None:
    """A required table must have data rows: InputError naming the file (and its header line)."""
    if table.header_line is None:
        raise InputError(table.path, None, f"the file is empty: no header row and no {what}")
    if not len(table):
        raise InputError(table.path, table.header_line, f"no {what}: the file has a header row but no data rows")


# ---------------------------------------------------------------------------------------------
# project.toml


def read_settings(path: str | Path) -> model.ProjectSettings:
    """ProjectSettings from project.toml; defaults when the file is absent (a link to nothing, a
    folder or a FIFO is an InputError). Unknown sections, keys or values -> InputError naming
    project.toml and, where it can be found, the line."""
    path = Path(path)
    if not input_present(path):
        return model.ProjectSettings()
    return parse_settings(path, read_input_bytes(path))


def parse_settings(path: str | Path, content: str | bytes) -> model.ProjectSettings:
    """ProjectSettings from the content of project.toml (UTF-8, a byte-order mark accepted); path
    names it in messages. Rules of read_settings."""
    path = Path(path)
    text = decode_text(path, content)
    data = _parse_toml(path, text)
    defaults = model.ProjectSettings()
    _check_toml_keys(path, text, data)

    def get(section: str, key: str, default):
        return data.get(section, {}).get(key, default)

    def fail(section: str, key: str, reason: str) -> InputError:
        return InputError(path, _toml_line(text, section, key), f"[{section}] {key}: {reason}")

    def choice(section: str, key: str, allowed: tuple[str, ...], default: str, meaning: str = "") -> str:
        value = get(section, key, default)
        if not isinstance(value, str) or value not in allowed:
            raise fail(section, key, f"{value!r} is not one of {', '.join(repr(a) for a in allowed)}{meaning}")
        return value

    sigma_image = get("defaults", "sigma_image", defaults.sigma_image)
    if isinstance(sigma_image, bool) or not isinstance(sigma_image, (int, float)) or not (
        math.isfinite(sigma_image) and sigma_image > 0
    ):
        raise fail("defaults", "sigma_image", f"{sigma_image!r} is not a positive number (plate units)")
    if not limits.SIGMA_MIN <= sigma_image <= limits.SIGMA_MAX:
        raise fail("defaults", "sigma_image", f"{sigma_image!r} is outside the plausible range "
                                              f"[{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}] of a standard deviation")
    max_iterations = get("adjustment", "max_iterations", defaults.max_iterations)
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise fail("adjustment", "max_iterations", f"{max_iterations!r} is not a positive integer")
    cost_tolerance = get("adjustment", "cost_tolerance", defaults.cost_tolerance)
    if isinstance(cost_tolerance, bool) or not isinstance(cost_tolerance, (int, float)) or not (
        math.isfinite(cost_tolerance) and 0 <= cost_tolerance < 1
    ):
        raise fail("adjustment", "cost_tolerance", f"{cost_tolerance!r} is not a number in [0, 1)")
    switches = {key: get("corrections", key, getattr(defaults, key)) for key in ("earth_curvature", "refraction")}
    for key, value in switches.items():
        if not isinstance(value, bool):
            raise fail("corrections", key, f"{value!r} is not true or false")
    earth_radius = get("corrections", "earth_radius", defaults.earth_radius)
    low, high = EARTH_RADIUS_RANGE_M
    if isinstance(earth_radius, bool) or not isinstance(earth_radius, (int, float)) or not low <= earth_radius <= high:
        raise fail("corrections", "earth_radius", f"{earth_radius!r} is not a radius of the Earth in metres "
                                                  f"(accepted: {low:.0f} to {high:.0f})")
    datum = choice("datum", "mode", DATUMS, defaults.datum)
    datum_points = get("datum", "points", [])
    if not isinstance(datum_points, list) or not all(isinstance(p, str) for p in datum_points):
        raise fail("datum", "points", f"{datum_points!r} is not a list of point ids (strings)")
    if datum_points and datum != "inner-points":
        raise fail("datum", "points", "datum points are for mode = \"inner-points\" (the point datum)")
    if datum_points and len(datum_points) < 3:
        raise fail("datum", "points", f"{len(datum_points)} datum point(s): the point datum needs at least three")
    if len(set(datum_points)) != len(datum_points):
        raise fail("datum", "points", "a point is given twice")
    coordinates = None
    if "coordinates" in data:
        coordinates = parse_coordinates(data["coordinates"], path.parent, lambda key, reason: fail("coordinates", key, reason),
                                        _toml_section_line(text, "coordinates"))
    if coordinates is not None and switches["earth_curvature"]:
        raise fail("corrections", "earth_curvature", "true with [coordinates] crs: the project is adjusted in a local "
                   "Cartesian frame, where the Earth's curvature is in the coordinates themselves; the correction "
                   "would count it twice (docs/decisions.md)")
    return model.ProjectSettings(
        earth_curvature=switches["earth_curvature"],
        refraction=switches["refraction"],
        earth_radius=float(earth_radius),
        coordinates=coordinates,
        angle_unit=choice("units", "angles", model.ANGLE_UNITS, defaults.angle_unit),
        rotation=choice("units", "rotation", model.ROTATION_CONVENTIONS, defaults.rotation),
        sigma_image=float(sigma_image),
        method=choice("adjustment", "method", METHODS, defaults.method),
        solver=choice("adjustment", "solver", SOLVERS, defaults.solver),
        max_iterations=max_iterations,
        datum=datum,
        datum_points=tuple(datum_points),
        cost_tolerance=float(cost_tolerance),
        plate_unit=choice("units", "plate", model.PLATE_UNITS, defaults.plate_unit,
                          " (the unit of c and of the plate coordinates: mm of the film or sensor, px for the "
                          "pixels of the image)"),
    )


def _check_datum_points(files, settings: model.ProjectSettings, points: model.ObjectPoints) -> None:
    """[datum] points must name object points of the project (InputError at the key's line)."""
    known = set(map(str, points.ids))
    unknown = [p for p in settings.datum_points if p not in known]
    if unknown:
        path = files.path("project.toml")
        text = decode_text(path, files.content("project.toml"))
        raise InputError(path, _toml_line(text, "datum", "points"),
                         f"[datum] points: {', '.join(unknown)} not among the object points of the project")


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


AFFINITY_LIMIT = 0.5  # |b1|, |b2| at or beyond this: no camera's affinity or shear (b1 = -1 makes x vanish)


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
        raise table.error(i, f"principal distance c must be > 0 (got {table.text(i, 'c')})")
    _check_limit(table, ("c", "xp", "yp"), interior[:, :3], limits.PLATE_LIMIT, "plate units")
    for j, name in enumerate(CAMERA_ELEMENTS[3:], start=3):
        interior[:, j] = np.nan_to_num(table.optional_floats(name), nan=0.0)
    for name in ("b1", "b2"):  # affinity and shear: c (1 + b1) is the x scale, c b2 the shear
        j = CAMERA_ELEMENTS.index(name)
        for i in np.flatnonzero(~(np.abs(interior[:, j]) < AFFINITY_LIMIT))[:1]:
            raise table.error(i, f"column '{name}': {table.text(i, name)} is no affinity or shear of a camera "
                                 f"(|{name}| must be below {AFFINITY_LIMIT:g}; a real camera's is below 1e-3): "
                                 f"{'c (1 + b1) is the scale of x' if name == 'b1' else 'c b2 shears x by y'}")
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
    r0 = _balanced_radius(table, sigma) if table.has("r0") else None
    if r0 is not None:
        interior = balanced.gaussian_from_balanced(interior, r0, convention)
        for i in np.flatnonzero(np.isfinite(r0) & ~(interior[:, 0] > 0)):
            raise table.error(i, f"with r0 = {table.text(i, 'r0')} the balanced radial distortion gives a principal "
                                 f"distance {interior[i, 0]:.6g} <= 0: check k1, k2, k3 and r0")
    return model.Cameras(ids=ids, interior=interior, sigma_interior=sigma, convention=convention, r0=r0)


def _balanced_radius(table: CsvTable, sigma: np.ndarray) -> np.ndarray:
    """cameras.csv's optional r0 (striptri.geometry.balanced): empty = Gaussian; otherwise > 0 (plate units,
    or normalised for distortion = image), and c, k1-k3, p1, p2 held or free, not observed (their
    weights would not carry over exactly)."""
    r0 = table.optional_floats("r0")
    for i in np.flatnonzero(r0 <= 0):
        raise table.error(i, f"column 'r0': the zero-crossing radius must be > 0 (got {table.text(i, 'r0')})")
    observed = np.isfinite(sigma[:, list(balanced.CHANGED)]) & np.isfinite(r0)[:, None]
    for i in np.flatnonzero(observed.any(axis=1))[:1]:
        names = [CAMERA_ELEMENTS[e] for e, o in zip(balanced.CHANGED, observed[i]) if o]
        raise table.error(i, f"with r0 (balanced radial distortion) {', '.join(names)} may be held (empty sigma) or "
                             "'free', not observed with a standard deviation: the balanced elements' weights do not "
                             "carry over to the Gaussian form the adjustment uses")
    return r0


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
    camera_ids = table.strings("camera_id")
    camera_index = np.fromiter(map(camera_of.get, camera_ids, repeat(-1)), dtype=np.int64, count=len(ids))
    for i in np.flatnonzero(camera_index < 0)[:1]:
        raise table.error(i, f"unknown camera_id '{camera_ids[i]}' (not in cameras.csv)")
    to_rad = RADIANS_PER_UNIT[settings.angle_unit]
    xyz0 = np.column_stack([table.floats(n) for n in ("X0", "Y0", "Z0")]).reshape(-1, 3)
    _check_limit(table, ("X0", "Y0", "Z0"), xyz0, limits.GROUND_LIMIT_M, "m for ground coordinates")
    angles_file = np.column_stack([table.floats(n) for n in angle_names]).reshape(-1, 3)
    _check_limit(table, angle_names, angles_file, limits.angle_limit(to_rad),
                 f"{settings.angle_unit} ({limits.ANGLE_LIMIT_TURNS} full turns) for an angle")
    angles = angles_file * to_rad
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
    texts = table.strings("kind", allow_empty=True)
    kind = np.fromiter(map(model.KIND_CODES.get, map(str.upper, texts), repeat(-1)), dtype=np.int64, count=len(ids))
    for i in np.flatnonzero(kind < 0)[:1]:
        raise table.error(i, f"unknown kind '{texts[i]}' (accepted: XYZ, XY, Z, check)")
    xyz_file = np.column_stack([table.optional_floats(n) for n in "XYZ"]).reshape(-1, 3)
    _check_limit(table, tuple("XYZ"), xyz_file, limits.GROUND_LIMIT_M, "m for ground coordinates")
    sigma_file = np.column_stack(
        [_sigma_column(table, f"sigma_{n}", zero_means_fixed=True) for n in "XYZ"]
    ).reshape(-1, 3)
    needed = model.needed_axes(kind).reshape(-1, 3)
    for i, j in zip(*np.nonzero(needed & np.isnan(xyz_file))):
        name = model.KIND_NAMES[kind[i]]
        raise table.error(i, f"kind {name} needs {'XYZ'[j]} but it is empty (kind {name} needs "
                             f"{', '.join(a for a, n in zip('XYZ', needed[i]) if n)})")
    xyz = np.where(needed, xyz_file, np.nan)
    given = model.given_axes(kind).reshape(-1, 3)
    sigma = np.where(given, sigma_file, np.nan)
    return _Control(ids, kind, xyz, sigma)


# ---------------------------------------------------------------------------------------------
# image_points.csv and the object points


def _read_image_points(
    table: CsvTable, photos: model.Photos, control: _Control, settings: model.ProjectSettings, active: np.ndarray
) -> tuple[model.ImagePoints, model.ObjectPoints]:
    """image_points.csv: photo_id, point_id, x, y[, sigma_x, sigma_y] (plate units).

    Empty sigma -> settings.sigma_image; a sigma must be > 0. Object points: control points in
    control.csv order, then tie points by first measurement. active (m,) bool (the ``active``
    column): a point may be measured on a photo once among the active rows; inactive rows of the same
    photo and point beside it (a rejected measurement kept with its re-measurement) are allowed.
    """
    table.require("photo_id", "point_id", "x", "y")
    photo_of = {pid: k for k, pid in enumerate(photos.ids)}
    photo_ids = table.strings("photo_id")
    measured_ids = table.strings("point_id")
    photo_index = np.fromiter(map(photo_of.get, photo_ids, repeat(-1)), dtype=np.int64, count=len(table))
    # points: the control points in their order, then the others by first measurement
    point_of = {pid: k for k, pid in enumerate(control.ids)}
    for pid in dict.fromkeys(measured_ids):
        point_of.setdefault(pid, len(point_of))
    point_ids = list(point_of)
    point_index = np.fromiter(map(point_of.__getitem__, measured_ids), dtype=np.int64, count=len(table))
    # the first row that is an error: an unknown photo, or a point measured twice on one photo
    unknown = np.flatnonzero(photo_index < 0)
    key = photo_index * max(len(point_ids), 1) + point_index
    key = np.where(active, key, -1 - np.arange(len(key)))  # inactive rows never repeat a key
    order = np.argsort(key, kind="stable")
    repeated = np.flatnonzero(key[order][1:] == key[order][:-1]) + 1  # in order: a later row of the same key
    first_unknown = int(unknown[0]) if len(unknown) else len(table)
    first_repeat = int(order[repeated].min()) if len(repeated) else len(table)
    if first_unknown < len(table) and first_unknown <= first_repeat:
        raise table.error(first_unknown, f"unknown photo_id '{photo_ids[first_unknown]}' (not in photos.csv)")
    if first_repeat < len(table):
        i = first_repeat
        first = int(np.flatnonzero(key == key[i])[0])
        also = "" if active.all() else "; an inactive row (active = 0) may repeat it"
        raise table.error(i, f"duplicate measurement of point '{measured_ids[i]}' on photo '{photo_ids[i]}' "
                             f"(first on line {table.lines[first]}{also})")
    xy = np.column_stack([table.floats("x"), table.floats("y")]).reshape(-1, 2)
    _check_limit(table, ("x", "y"), xy, limits.PLATE_LIMIT, "plate units")
    sigma_xy = np.column_stack(
        [_image_sigma(table, name, settings.sigma_image) for name in ("sigma_x", "sigma_y")]
    ).reshape(-1, 2)
    image_points = model.ImagePoints(photo_index=photo_index, point_index=point_index, xy=xy, sigma_xy=sigma_xy)
    return image_points, _object_points(point_ids, control)


ACTIVE_WORDS = {"1": True, "true": True, "0": False, "false": False}  # image_points.csv's active, any case


def _active_column(table: CsvTable) -> np.ndarray:
    """image_points.csv's optional ``active`` column -> (m,) bool: 1/true (or empty) = adjusted,
    0/false = kept and reported but not adjusted (striptri.report.inactive). Anything else: InputError."""
    words = [w.lower() or "1" for w in table.optional_strings("active", "1")]
    for i, w in enumerate(words):
        if w not in ACTIVE_WORDS:
            raise table.error(i, f"column 'active': '{table.text(i, 'active')}' is not 1, 0, true or false")
    return np.array([ACTIVE_WORDS[w] for w in words], dtype=bool).reshape(len(words))


def _rows(ip: model.ImagePoints, keep: np.ndarray) -> model.ImagePoints:
    return model.ImagePoints(photo_index=ip.photo_index[keep], point_index=ip.point_index[keep], xy=ip.xy[keep],
                             sigma_xy=ip.sigma_xy[keep])


def _image_sigma(table: CsvTable, name: str, default: float) -> np.ndarray:
    """An image sigma column: empty -> default; must be > 0 and within the plausible range."""
    values = table.optional_floats(name)
    for i in np.flatnonzero(values <= 0):
        raise table.error(i, f"column '{name}': a plate measurement sigma must be > 0 (got {table.text(i, name)})")
    _check_sigma_range(table, name, values)
    return np.where(np.isnan(values), default, values)


def _check_plate_geometry(table: CsvTable, camera_table: CsvTable, image_points: model.ImagePoints,
                          photos: model.Photos, cameras: model.Cameras) -> None:
    """Plate coordinates against their camera (striptri.io.plausibility): a ray at most
    MAX_OFF_AXIS_DEG off the axis, r = |(x - xp, y - yp)| <= c tan(89 deg); and per camera the
    measured points not all within MIN_FIELD c of the principal point (numerically parallel rays)."""
    cam = photos.camera_index[image_points.photo_index]
    c = cameras.interior[cam, 0]
    r = np.hypot(*(image_points.xy - cameras.interior[cam, 1:3]).T)
    for i in np.flatnonzero(r > limits.MAX_RADIUS_PER_C * c)[:1]:
        off = math.degrees(math.atan2(float(r[i]), float(c[i])))
        raise table.error(i, f"plate point ({table.text(i, 'x')}, {table.text(i, 'y')}) lies "
                             f"{float(r[i]):.6g} plate units from the principal point of camera "
                             f"'{cameras.ids[cam[i]]}' (c = {float(c[i]):.6g}): a ray {off:.2f} deg off the "
                             f"camera axis, which a frame camera cannot image (limit {limits.MAX_OFF_AXIS_DEG:g} "
                             "deg); check the plate coordinates, their units and c")
    r_max = np.full(len(cameras), -1.0)
    np.maximum.at(r_max, cam, r)
    narrow = (r_max >= 0) & (r_max < limits.MIN_FIELD * cameras.interior[:, 0])
    for j in np.flatnonzero(narrow)[:1]:
        cj = float(cameras.interior[j, 0])
        raise camera_table.error(j, f"camera '{cameras.ids[j]}': c = {camera_table.text(j, 'c')} but every point "
                                    f"measured with it lies within {float(r_max[j]):.6g} plate units of the principal "
                                    f"point ({float(r_max[j]) / cj:.3g} c: every ray within "
                                    f"{math.degrees(math.atan2(float(r_max[j]), cj)) * 3600:.3g} arc seconds of the "
                                    f"camera axis), so its rays are numerically parallel (limit "
                                    f"{limits.number_text(limits.MIN_FIELD)} c); check c and the units of the plate "
                                    "coordinates")


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
    ids = table.strings("point_id")
    _check_unique(table, "point_id", ids)
    xyz = np.column_stack([table.optional_floats(a) for a in "XYZ"]).reshape(-1, 3)
    _check_limit(table, tuple("XYZ"), xyz, limits.GROUND_LIMIT_M, "m for ground coordinates")
    for i, pid in enumerate(ids):
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
    index = table.id_indices(("photo_from", "photo_to"), photo_of, "photos.csv")
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
    value = table.floats("value")
    _check_limit(table, ("value",), value, limits.GROUND_LIMIT_M, "m for a base component")
    return model.BaseComponents(
        photo_from=index["photo_from"],
        photo_to=index["photo_to"],
        axis=axis,
        value=value,
        sigma=_sigma_column(table, "sigma", zero_means_fixed=False),
    )


# ---------------------------------------------------------------------------------------------
# shared


def _check_unique(table: CsvTable, column: str, ids: list[str]) -> None:
    """InputError on the second occurrence of an id, naming the line of the first."""
    if len(set(ids)) == len(ids):
        return
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
        raise table.error(i, f"column '{name}': a standard deviation cannot be negative (got {table.text(i, name)})")
    _check_sigma_range(table, name, values)
    if zero_means_fixed:
        values = np.where(values == 0, np.nan, values)
    return values


def _check_sigma_range(table: CsvTable, name: str, values: np.ndarray) -> None:
    """A sigma that is an observation (finite, > 0) must lie in [SIGMA_MIN, SIGMA_MAX]."""
    i = limits.first_sigma_out_of_range(values)
    if i is not None:
        raise table.error(i, f"column '{name}': a standard deviation of {table.text(i, name)} is outside the plausible "
                             f"range [{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}]: its weight 1/sigma^2 is not a "
                             "meaningful number")


def _check_limit(table: CsvTable, names: tuple[str, ...], values: np.ndarray, limit: float, what: str) -> None:
    """InputError at the first value of the columns ``names`` (values (n, len(names))) beyond +-limit."""
    hit = limits.first_beyond(values, limit)
    if hit is not None:
        i, j = hit
        raise table.error(i, f"column '{names[j]}': {table.text(i, names[j])} exceeds the plausibility limit of "
                             f"{limits.number_text(limit)} {what}, in magnitude (docs/file-formats.md, Limits)")
