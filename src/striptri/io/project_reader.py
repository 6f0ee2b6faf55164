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

import os
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from striptri import model
from striptri.errors import InputError
from striptri.geometry.rotations import RADIANS_PER_UNIT
from striptri.io.csvtable import CsvTable, decode_text, input_present, parse_csv, read_input_bytes
from striptri.io.distances_reader import FILE_NAME as DISTANCES_FILE, read_distances
from striptri.io.film_reader import FILE_NAMES as FILM_FILES, read_film
from striptri.io.gnss_reader import read_gnss
from striptri.io.project_notes import project_notes, unread_files_note
from striptri.io.settings_reader import (  # noqa: F401  (read_settings, parse_settings: this module's API)
    TOML_KEYS, _check_datum_points, _parse_toml, parse_settings, read_settings,
)
from striptri.io.table_readers import (  # noqa: F401  (ANGLE_COLUMNS, BASE_AXES: the writer's)
    ANGLE_COLUMNS, BASE_AXES, _active_column, _check_plate_geometry, _Control, _object_points, _read_approx_points,
    _read_bases, _read_cameras, _read_control, _read_image_points, _read_photos, _rows,
)
from striptri.io.toml_file import TomlFile


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
    project = _read(_FolderFiles(folder), plate_measurements_optional)
    project, ids = _without_ids(project)  # the parse's strings are all freed here ...
    return _with_ids(project, ids)  # ... before the ids are made again, together


def parse_project(files: Mapping[str, str | bytes], folder: str | Path | None = None,
                  plate_measurements_optional: bool = False) -> model.Project:
    """Read a project from the contents of its files (file name -> text or bytes, as written by
    project_files) with exactly the rules of read_project, in memory. folder: where the files would
    be, for messages (None: messages name the bare file names); plate_measurements_optional as
    read_project's. Raises InputError."""
    project = _read(_MemoryFiles(files, None if folder is None else Path(folder)), plate_measurements_optional)
    project, ids = _without_ids(project)  # as read_project
    return _with_ids(project, ids)


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


# The ids of photos, points and cameras are the only strings of the tables a project keeps. Each
# is one of the millions of short strings the parse made (a cell of a table), and Python's small-object
# allocator keeps a memory page as long as one object on it lives: the ids alone kept most of the
# pages of the parse resident for the whole run (240 MB of a 20,000-photo block's 600,000 plate
# measurements, 50 MB of a 5,000-photo block's). So they are copied out as one text per list, the
# project's strings freed with the parse's, and made again from those texts, on pages of their own
# (docs/decisions.md "Memory the parse and the formatting left behind").
_ID_LISTS = (("cameras", "ids"), ("photos", "ids"), ("photos", "strip_ids"), ("points", "ids"))
_ID_SEPARATOR = "\0"  # a list whose ids hold it (a NUL in the CSV file) is kept as it is


def _without_ids(project: model.Project) -> tuple[model.Project, list]:
    """The project with empty ids (as many) and its id lists, each as one joined text (a list
    itself when an id holds the separator); the caller drops the project it passed in."""
    texts, parts = [], {}
    for part, name in _ID_LISTS:
        ids = getattr(getattr(project, part), name)
        text = _ID_SEPARATOR.join(ids)
        texts.append(text if text.count(_ID_SEPARATOR) == max(len(ids) - 1, 0) else list(ids))
        parts.setdefault(part, {})[name] = [""] * len(ids)
    return replace(project, **{part: replace(getattr(project, part), **names) for part, names in parts.items()}), texts


def _with_ids(project: model.Project, texts: list) -> model.Project:
    """_without_ids undone: the id lists made again from their texts."""
    parts: dict = {}
    for (part, name), text in zip(_ID_LISTS, texts):
        n = len(getattr(getattr(project, part), name))
        parts.setdefault(part, {})[name] = text if isinstance(text, list) else (text.split(_ID_SEPARATOR) if n else [])
    return replace(project, **{part: replace(getattr(project, part), **names) for part, names in parts.items()})


def _project_toml(files) -> TomlFile:
    """project.toml as read (an empty TomlFile when the project has none)."""
    toml = "project.toml"
    if not files.present(toml):
        return TomlFile(None, {})
    path = files.path(toml)
    text = decode_text(path, files.content(toml))
    return TomlFile(path, _parse_toml(path, text), text)


def _read_gnss(files, tables: dict, cameras: model.Cameras, photos: model.Photos, settings: model.ProjectSettings):
    """The GNSS/IMU model (io.gnss_reader), with project.toml's [gnss] section."""
    return read_gnss(tables["cameras.csv"], tables["photos.csv"], cameras, photos,
                     RADIANS_PER_UNIT[settings.angle_unit], _project_toml(files))


def _read_film(files, tables: dict, cameras, photos, image_points):
    """Scanned film (striptri.film.data): fiducials to the plate, calibration.toml's cameras."""
    return read_film(files, _project_toml(files), tables["image_points.csv"], cameras, photos, image_points)


def _require_rows(table: CsvTable, what: str) -> None:
    """A required table must have data rows: InputError naming the file (and its header line)."""
    if table.header_line is None:
        raise InputError(table.path, None, f"the file is empty: no header row and no {what}")
    if not len(table):
        raise InputError(table.path, table.header_line, f"no {what}: the file has a header row but no data rows")


# ---------------------------------------------------------------------------------------------
# project.toml
