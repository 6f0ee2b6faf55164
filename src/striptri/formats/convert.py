"""The convert pipeline: read a BAL problem, a COLMAP text model, a DBAT script project or a
striptri project, write it as a COLMAP text model or a striptri project folder (atomically;
docs/formats.md).

Side files written next to the standard ones:

* COLMAP output: ``striptri_ids.csv`` (table, colmap_id, striptri_id, strip_id), the striptri ids of
  cameras and points and the strip of each image, read back when present (COLMAP ignores it);
* DBAT output: a folder with the script ``project.xml`` and the text files it names (formats.dbat.writer);
* BAL output: a folder with ``problem.txt`` (the BAL file) and ``striptri_ids.csv`` (BAL camera
  index -> photo id, BAL point index -> point id);
* project output: ``approx_points.csv`` (point_id, X, Y, Z), the approximate ground coordinates of
  the points (BAL, COLMAP, or given/intersected for a project), read by read_project as starting
  values.

A project is validated before it is written: io.parse_project reads the generated file texts with
exactly the rules of ``striptri adjust``'s reader, in memory, so that convert never writes a project
adjust would refuse (an InputError naming the source says why), and the reader's notes on the
converted project are passed on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from striptri import model
from striptri.errors import InputError
from striptri.formats.bal import bal_text, read_bal
from striptri.formats.colmap import colmap_files, read_colmap
from striptri.formats.conversions import (
    ColmapNames,
    approximate_points,
    bal_to_project,
    colmap_to_project,
    project_to_bal,
    project_to_colmap,
)
from striptri.formats.dbat import dbat_files, dbat_to_project, read_dbat, script_inputs
from striptri.formats.scene import Scene
from striptri.io.csvtable import format_csv, input_present, read_csv
from striptri.io.output import OutputReservation, check_output_location
from striptri.io.project_reader import FILE_NAMES as PROJECT_FILE_NAMES, parse_project, read_project
from striptri.io.project_writer import project_files

SOURCE_FORMATS = ("bal", "colmap", "dbat", "project")
TARGET_FORMATS = ("bal", "colmap", "dbat", "project")
BAL_FILE = "problem.txt"
IDS_FILE = "striptri_ids.csv"
APPROX_POINTS_FILE = "approx_points.csv"

@dataclass(frozen=True)
class ConvertResult:
    out_dir: Path
    source_format: str
    target_format: str
    n_cameras: int
    n_photos: int
    n_points: int
    n_image_points: int
    notes: list[str] = field(default_factory=list)

def detect_format(src: str | Path) -> str:
    """dbat for an .xml file (a DBAT script), bal for another file, colmap for a folder with
    cameras.txt or cameras.bin (a text or binary model), project for one with cameras.csv."""
    src = Path(src)
    if input_present(src) and not src.is_dir():  # a file (a FIFO or a device is refused by its reader)
        return "dbat" if src.suffix.lower() == ".xml" else "bal"
    if src.is_dir() and (input_present(src / "cameras.txt") or input_present(src / "cameras.bin")):
        return "colmap"  # its reader refuses a folder or a FIFO there
    if src.is_dir() and input_present(src / "cameras.csv"):
        return "project"
    raise InputError(src, None, "not found" if not src.exists() else
                     "cannot tell the format (a BAL file, a DBAT script .xml, a COLMAP folder with cameras.txt or .bin, "
                     "or a project folder with cameras.csv); give --from")

def read_scene(src: str | Path, source_format: str | None = None, pixel_size: float | None = None,
               drop_distortion: bool = False) -> tuple[str, Scene]:
    """Read src in source_format (detected when None) as a Scene. pixel_size: plate units per
    pixel for a COLMAP source (default 1)."""
    src = Path(src)
    fmt = source_format or detect_format(src)
    if fmt == "bal":
        return fmt, bal_to_project(read_bal(src), drop_distortion=drop_distortion)
    if fmt == "dbat":
        return fmt, dbat_to_project(read_dbat(src), drop_distortion=drop_distortion)
    if fmt == "colmap":
        model_ = read_colmap(src)
        return fmt, colmap_to_project(model_, 1.0 if pixel_size is None else pixel_size, _read_names(src), src)
    if fmt == "project":
        project = read_project(src)
        return fmt, Scene(project=project, xyz_ground=approximate_points(project),
                          notes=[str(note) for note in project.notes])
    raise ValueError(f"unknown source format {fmt!r}; one of {SOURCE_FORMATS}")

def source_inputs(src: str | Path, source_format: str | None = None) -> list[Path]:
    """Every file and folder converting src reads: the source itself and, for a DBAT script, each file
    its <input> names (they may lie anywhere base_dir points, the output folder included)."""
    src = Path(src)
    if input_present(src) and not src.is_dir() and (source_format or detect_format(src)) == "dbat":
        return script_inputs(src)
    if src.is_dir() and (source_format or "") in ("", "project") and input_present(src / "cameras.csv"):
        return [src, *(src / name for name in PROJECT_FILE_NAMES)]
    return [src]


def convert(src: str | Path, out_dir: str | Path, to: str, source_format: str | None = None,
            pixel_size: float | None = None, drop_distortion: bool = False,
            on_warning: Callable[[str], None] | None = None) -> ConvertResult:
    """Convert src to the format `to` in out_dir (written whole or not at all).

    pixel_size (plate units per pixel) applies to the COLMAP side: the plate unit of a COLMAP source,
    and for COLMAP output the pixel size of a project source (default 1; a BAL or COLMAP source
    keeps its own). The notes (what the conversion could not carry over, what the source does not
    use) are in the result and go to ``on_warning`` as soon as they are known, so that they reach
    the user even when the conversion then fails."""
    if to not in TARGET_FORMATS:
        raise ValueError(f"unknown target format {to!r}; one of {TARGET_FORMATS}")
    inputs = source_inputs(src, source_format)
    check_output_location(out_dir, inputs)  # before reading: never a file it reads, never around one
    notes = _Notes(on_warning)
    with OutputReservation(out_dir, inputs) as reservation:
        return _convert(reservation, src, to, source_format, pixel_size, drop_distortion, notes)


class _Notes(list):
    """The conversion's notes, each passed on to on_warning as it is added."""

    def __init__(self, on_warning):
        super().__init__()
        self.on_warning = on_warning

    def append(self, note) -> None:
        super().append(note)
        if self.on_warning is not None:
            self.on_warning(str(note))

    def __iadd__(self, notes):
        for note in notes:
            self.append(note)
        return self


def _convert(reservation: OutputReservation, src, to: str, source_format, pixel_size, drop_distortion,
             notes: "_Notes") -> ConvertResult:
    fmt, scene = read_scene(src, source_format, pixel_size, drop_distortion)
    project = scene.project
    notes += scene.notes
    notes += what_the_target_leaves_out(project, to)
    off = project.inactive_image_points
    n_off = 0 if off is None else len(off)
    if n_off and to != "project":
        notes.append(f"inactive measurements (image_points.csv active = 0) left out: {n_off}")
    if to == "project":
        files = project_files(project)
        # the points the project files hold: control points and measured tie points (a tie point
        # measured on no photo, e.g. a BAL point without observations, has no file to live in)
        measured = project.image_points.point_index if not n_off else np.concatenate(
            [project.image_points.point_index, off.point_index])
        kept = (project.points.kind != model.TIE) | np.isin(np.arange(len(project.points)), measured)
        if not kept.all():
            notes.append(f"points measured on no photo left out (a project has no file for them): {int((~kept).sum())}")
        files[APPROX_POINTS_FILE] = format_csv({
            "point_id": [pid for pid, k in zip(project.points.ids, kept) if k], "X": scene.xyz_ground[kept, 0],
            "Y": scene.xyz_ground[kept, 1], "Z": scene.xyz_ground[kept, 2],
        })
        known = {note.text for note in project.notes}  # a project source's own notes are said already
        notes += [f"converted project: {note}" for note in _validate_project(src, files) if note.text not in known]
    elif to == "dbat":
        files, more = dbat_files(project, 1.0 if pixel_size is None else pixel_size)
        notes += more
    elif to == "bal":
        problem, more = project_to_bal(project, scene.xyz_ground)
        notes += more
        names = ColmapNames(cameras={k: pid for k, pid in enumerate(project.photos.ids)},
                            points={k: project.points.ids[j] for k, j in
                                    enumerate(np.flatnonzero(np.isfinite(scene.xyz_ground).all(axis=1)))})
        files = {BAL_FILE: bal_text(problem), IDS_FILE: _names_csv(names)}
    else:
        s = scene.plate_units_per_pixel or (1.0 if pixel_size is None else pixel_size)
        colmap, names, more = project_to_colmap(project, scene.xyz_ground, s)
        notes += more
        files = colmap_files(colmap)
        files[IDS_FILE] = _names_csv(names)
    out = reservation.commit(files)
    return ConvertResult(out_dir=out, source_format=fmt, target_format=to, n_cameras=len(project.cameras),
                         n_photos=len(project.photos), n_points=len(project.points),
                         n_image_points=len(project.image_points), notes=list(notes))

def what_the_target_leaves_out(project: model.Project, to: str) -> list[str]:
    """Notes on what a project's settings mean for the numbers written to ``to``: map coordinates,
    plate corrections and GNSS models that the exchange formats cannot express (a project target
    keeps them), and scanned film, whose image points are written as plate coordinates."""
    target = {"bal": "BAL", "colmap": "COLMAP", "dbat": "DBAT", "project": "a project"}[to]
    notes = []
    settings = project.settings
    if to != "project":
        if settings.coordinates is not None:
            notes.append(f"map coordinates ([coordinates] crs = {settings.coordinates.crs!r}, {settings.coordinates.heights} "
                         f"heights): {target} has no coordinate reference system; centres and points are written as "
                         "grid E, N, H as they are, which is not a Cartesian frame (the projection's scale and the "
                         "Earth's curvature are in it)")
        corrected = [name for name, on in (("earth_curvature", settings.earth_curvature),
                                           ("refraction", settings.refraction)) if on]
        if corrected:
            notes.append(f"[corrections] {' and '.join(corrected)}: {target} gets the plate coordinates as measured, "
                         "without these corrections")
        if project.gnss is not None:
            notes.append(f"GNSS/IMU model ([gnss], lever arm, boresight, shifts, drifts): not written to {target}")
    if project.film is not None:
        notes.append("scanned film: the image points are written as plate coordinates (the scanner measurements "
                     "through each photo's fiducial transformation); the fiducial measurements and the film "
                     "calibration are not carried over")
    return notes


def _validate_project(src: Path, files: dict[str, str]) -> tuple:
    """Read the project files about to be written with the project reader's rules (in memory).
    -> the reader's notes (striptri.errors.Note); InputError naming src when adjust would refuse them."""
    try:
        return parse_project(files).notes
    except InputError as exc:
        raise InputError(src, None, f"the converted project would be invalid: {exc}") from None


def _names_csv(names: ColmapNames) -> str:
    table, colmap_id, striptri_id, strip = [], [], [], []
    for kind, mapping in (("camera", names.cameras), ("point", names.points)):
        for k, v in mapping.items():
            table.append(kind), colmap_id.append(k), striptri_id.append(v), strip.append("")
    for k, v in names.strips.items():
        table.append("image"), colmap_id.append(k), striptri_id.append(""), strip.append(v)
    return format_csv({"table": table, "colmap_id": colmap_id, "striptri_id": striptri_id, "strip_id": strip})

def _read_names(folder: Path) -> ColmapNames:
    """striptri ids from folder/striptri_ids.csv when it exists (else empty: COLMAP ids are used)."""
    path = folder / IDS_FILE
    if not input_present(path):
        return ColmapNames()
    table = read_csv(path)
    kinds = table.strings("table")
    ids = table.strings("colmap_id")
    names = table.strings("striptri_id", allow_empty=True)
    strips = table.optional_strings("strip_id")
    out = ColmapNames()
    first_of: dict[tuple, int] = {}  # (table, colmap_id) -> row; (table, striptri_id) -> row
    for i, (kind, cid, name, strip) in enumerate(zip(kinds, ids, names, strips)):
        try:
            key = int(cid)
        except ValueError:
            raise table.error(i, f"colmap_id '{cid}' is not an integer") from None
        if (kind, key) in first_of:
            raise table.error(i, f"{kind} {key} is listed twice (also on line {table.lines[first_of[kind, key]]}); "
                                 "one COLMAP id has one striptri id")
        first_of[kind, key] = i
        if name and kind in ("camera", "point"):
            if (kind, "name", name) in first_of:
                other = first_of[kind, "name", name]
                raise table.error(i, f"striptri_id '{name}' is given to {kind} {key} and to {kind} {ids[other]} "
                                     f"(line {table.lines[other]}): two {kind}s would become one")
            first_of[kind, "name", name] = i
        if kind == "camera":
            out.cameras[key] = name
        elif kind == "point":
            out.points[key] = name
        elif kind == "image":
            out.strips[key] = strip
        else:
            raise table.error(i, f"table '{kind}' is not camera, point or image")
    return out


__all__ = ["SOURCE_FORMATS", "TARGET_FORMATS", "ConvertResult", "convert", "detect_format", "read_scene"]
