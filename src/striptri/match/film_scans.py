"""Scanned film in ``striptri match`` (issue 28; docs/matching.md "Scanned film").

A project is one of scanned film when its project.toml says ``[film] image_points = "scan_px"``:
its image points, the user's and the automatic ones, are scan pixels (col, row), carried to the
plate through each photo's fiducial transformation by the project reader. The matcher needs that
transformation too (to pair the photos, check the tracks and thin them in plate coordinates), so
it takes the fiducial marks from fiducial_measurements.csv when the project has one, and otherwise
finds them in the scans (match.fiducials.find_marks_turned) and writes fiducial_measurements.csv
into OUT. A mark that was not found is reported with the reason and left out of the file, never
guessed; a photo with fewer marks than its transformation needs stops the run (exit status 2),
naming the scan and the marks.

Finding needs the scan's pixel size (``--scan-pixel-size``, micrometres: where on the scan a
calibrated fiducial should lie) and a template of the mark: a synthetic cross or dot of the given
size and line width (mm on the film), or an example mark cut from a scan (an image file whose
centre is the mark's centre).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..film import fiducials as fid
from ..film import transform
from ..io.csvtable import parse_csv, read_input_bytes
from ..io.film_reader import (DEFAULT_SIGMA_PX, DEFAULT_TRANSFORMATION, FIDUCIALS, MEASUREMENTS, TOML_SECTION,
                              read_fiducials, read_measurements)
from ..io.project_reader import FILE_NAMES, parse_project
from ..model import Project
from .features import cv2_module
from .fiducials import FoundMark, find_marks_turned, synthetic_mark
from .frames import FiducialMeasurements

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the tomli backport
    import tomli as tomllib

MARK_KINDS = ("cross", "dot")


@dataclass(frozen=True)
class FiducialOptions:
    """pixel_size_um: the scans' pixel size (micrometres; needed to find the marks); mark: 'cross',
    'dot' or the path of an example mark's image; mark_size_mm: the synthetic mark's extent (a
    cross's arms tip to tip, a dot's diameter is mark_line_mm); mark_line_mm: its line width."""

    pixel_size_um: float | None = None
    mark: str = "cross"
    mark_size_mm: float = 5.0
    mark_line_mm: float = 0.5


@dataclass(frozen=True)
class FilmSetting:
    """What project.toml says of the scans: the transformation's kind and the default sigma (px)."""

    kind: str
    sigma_px: float


def film_setting(project_dir: Path) -> FilmSetting | None:
    """The film setting of a project whose image points are scan pixels, else None. project.toml is
    checked fully by the project reader; here only what the matcher needs is taken."""
    path = project_dir / "project.toml"
    if not path.is_file():
        return None
    try:
        section = tomllib.loads(read_input_bytes(path).decode("utf-8-sig")).get(TOML_SECTION, {})
    except (tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None  # the project reader names the problem
    if not isinstance(section, dict) or section.get("image_points") != "scan_px":
        return None
    sigma = section.get("sigma_px", DEFAULT_SIGMA_PX)
    return FilmSetting(str(section.get("transformation", DEFAULT_TRANSFORMATION)),
                       float(sigma) if isinstance(sigma, (int, float)) else DEFAULT_SIGMA_PX)


def read_film_project(project_dir: Path, photos: str | None = None) -> tuple[Project, dict[str, bytes]]:
    """The project of scans as the matcher needs it: everything but its image points (which the
    full read carries through the fiducial transformation), and the input files read (name ->
    bytes). The whole project, with the fiducials, is read again from OUT's files before they are
    written (pipeline.run_match). photos: photos.csv to read instead of the user's (photos without
    orientations, match.unoriented)."""
    files = {name: read_input_bytes(project_dir / name) for name in FILE_NAMES if (project_dir / name).is_file()}
    bare = {k: v for k, v in files.items() if k not in ("image_points.csv", MEASUREMENTS)}
    if photos is not None:
        bare["photos.csv"] = photos
    if FIDUCIALS not in files:
        raise InputError(project_dir / FIDUCIALS, None, "not found: the scans' fiducial marks need the calibrated "
                                                        "fiducial coordinates (camera_id, fiducial_id, x, y)")
    return parse_project(bare, project_dir, plate_measurements_optional=True), files


def calibrated_fiducials(project_dir: Path, files: dict, project: Project) -> dict:
    """fiducials.csv: {camera_index: {fiducial_id: (x, y) mm}} (io.film_reader.read_fiducials), with
    the fiducials of every camera a photo uses."""
    fiducials = read_fiducials(parse_csv(project_dir / FIDUCIALS, files[FIDUCIALS]), project.cameras)
    for cam in sorted(set(project.photos.camera_index.tolist()) - set(fiducials)):
        raise InputError(project_dir / FIDUCIALS, None, f"no fiducials of camera '{project.cameras.ids[cam]}', "
                                                        "which photos.csv names")
    return fiducials


def given_measurements(project_dir: Path, files: dict, project: Project, fiducials: dict,
                       setting: FilmSetting) -> FiducialMeasurements:
    """fiducial_measurements.csv of the project, for every photo."""
    table = parse_csv(project_dir / MEASUREMENTS, files[MEASUREMENTS])
    rows, names, xy, q, sigma, measured = read_measurements(table, project.photos, fiducials, setting.sigma_px)
    marks = _empty(project, fiducials, setting)
    for k, p in enumerate(rows):
        marks.q[p], marks.sigma[p], marks.measured[p] = q[k], sigma[k], measured[k]
        marks.names[p][:] = names[k]
        marks.xy_plate[p] = xy[k]
    _check_enough(project, marks, lambda p: project_dir / MEASUREMENTS)
    return marks


def found_measurements(project: Project, fiducials: dict, setting: FilmSetting, found: list[list[FoundMark]],
                       images: list[Path]) -> FiducialMeasurements:
    """The marks found in the scans (found: per photo, one FoundMark per fiducial of its camera)."""
    marks = _empty(project, fiducials, setting)
    for p, row in enumerate(found):
        for m in row:
            if m.found:
                j = marks.names[p].index(m.fiducial_id)
                marks.q[p, j] = transform.q_from_colrow(np.array([m.col, m.row]))
                marks.measured[p, j] = True
    for p in np.flatnonzero(marks.measured.sum(1) < transform.MIN_FIDUCIALS[setting.kind])[:1]:
        missing = "; ".join(f"{m.fiducial_id}: {m.reason}" for m in found[p] if not m.found)
        raise InputError(images[p], None, f"{int(marks.measured[p].sum())} of {len(found[p])} fiducial marks found "
                                          f"(the {setting.kind} transformation needs "
                                          f"{transform.MIN_FIDUCIALS[setting.kind]}): {missing}. Check "
                                          "--scan-pixel-size and --fiducial-mark, or measure the marks in "
                                          "fiducial_measurements.csv")
    _check_enough(project, marks, lambda p: images[p])
    return marks


def _empty(project: Project, fiducials: dict, setting: FilmSetting) -> FiducialMeasurements:
    n = len(project.photos.ids)
    F = max((len(v) for v in fiducials.values()), default=0)
    names = [[""] * F for _ in range(n)]
    xy = np.zeros((n, F, 2))
    for p, cam in enumerate(project.photos.camera_index):
        marks = fiducials.get(int(cam), {})
        names[p][:len(marks)] = list(marks)
        if marks:
            xy[p, :len(marks)] = np.array(list(marks.values()))
    return FiducialMeasurements(setting.kind, xy, np.zeros((n, F, 2)), np.full((n, F), setting.sigma_px),
                                np.zeros((n, F), dtype=bool), names)


def _check_enough(project: Project, marks: FiducialMeasurements, path_of) -> None:
    """Every photo needs MIN_FIDUCIALS[kind] marks that are not on a line (path_of(photo): the file
    to name)."""
    need = transform.MIN_FIDUCIALS[marks.kind]
    count = marks.measured.sum(1)
    for p in np.flatnonzero(count < need)[:1]:
        raise InputError(path_of(p), None, f"photo '{project.photos.ids[p]}' has {int(count[p])} fiducial marks; "
                                           f"the {marks.kind} transformation needs {need}")
    for p in np.flatnonzero(fid.undetermined(marks.kind, marks.xy_plate, marks.measured))[:1]:
        raise InputError(path_of(p), None, f"the fiducial marks of photo '{project.photos.ids[p]}' lie on a line "
                                           f"or coincide; they cannot determine a {marks.kind} transformation")


def template(options: FiducialOptions, px_per_mm: float) -> np.ndarray:
    """The template of a mark in scan pixels (module doc). InputError for an unreadable example."""
    if options.mark in MARK_KINDS:
        line = options.mark_line_mm * px_per_mm
        size = options.mark_size_mm if options.mark == "cross" else 2.0 * options.mark_line_mm
        side = int(np.ceil(size * px_per_mm)) | 1  # odd: the centre on a pixel
        return synthetic_mark(options.mark, max(side, 5), line_px=max(line, 1.0))
    cv2 = cv2_module()
    image = cv2.imread(str(options.mark), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(Path(options.mark), None, "--fiducial-mark: not 'cross', 'dot' or an image OpenCV can read")
    return image.astype(np.float32)


def find_in_scan(scan: np.ndarray, fiducials: dict, options: FiducialOptions) -> list[FoundMark]:
    """The fiducial marks of one scan (fiducials: {fiducial_id: (x, y) mm} of its camera), with the
    template of options at the scan's resolution."""
    px_per_mm = 1000.0 / float(options.pixel_size_um)
    return find_marks_turned(scan, {f: tuple(xy) for f, xy in fiducials.items()}, template(options, px_per_mm),
                             px_per_mm)


def measurements_csv(project: Project, found: list[list[FoundMark]]) -> str:
    """fiducial_measurements.csv of the marks found (docs/file-formats.md): photo_id, fiducial_id,
    col, row; the marks not found are left out (the report and the terminal list them)."""
    lines = ["photo_id,fiducial_id,col,row"]
    for pid, row in zip(project.photos.ids, found):
        lines += [f"{pid},{m.fiducial_id},{m.col:.4f},{m.row:.4f}" for m in row if m.found]
    return "\n".join(lines) + "\n"
