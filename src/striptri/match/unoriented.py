"""Photographs without approximate orientations (docs/matching.md, "Photos without orientations").

photos.csv may leave out X0, Y0, Z0 and the three angles (or leave every one of their cells
empty). Then ``striptri match``:

* reads the project with parallel photographs at one place in their stead (:func:`placeholder`),
  used for nothing but the reading;
* takes its candidate pairs from the strips (match.pairs.strip_pairs, both directions of flight);
* skips the ground check of the tracks (there are no orientations to check them with);
* checks the tracks with the two-view geometry of each matched pair instead
  (match.tracks.two_view_consistent): a chain of false matches can join two points into one track;
* after the tie points are chosen (:func:`orient`): leaves out the points that do not fit the
  relative orientation of two successive photos of a strip (the essential matrix by RANSAC, which
  is not misled by a flat scene), builds each strip by the sequential method and places the
  strips on the full control and on one another (striptri.sequential.block), then checks every
  tie point with these orientations as with the user's (match.ground_check) and leaves out those
  that do not meet on the ground;
* writes photos.csv into OUT with those approximate orientations (:func:`with_orientations`), so
  that ``striptri adjust OUT`` can start; the chips of the control points are cut with them.

Before any image is read, :func:`check_control` asks for what the placing needs at least: one
strip with three full control points measured in it.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError, NumericalFailure
from ..geometry.rotations import RADIANS_PER_UNIT, angles_from_R
from ..io.csvtable import decode_text, format_csv, input_present, parse_csv, read_input_bytes
from ..io.project_reader import FILE_NAMES, parse_project
from ..io.settings_reader import parse_settings
from ..io.table_readers import ANGLE_COLUMNS
from ..model import FULL, Project, ProjectSettings
from ..reliability.outcome import subset
from ..sequential.block import BlockFromStrips, block_from_strips
from .ground_check import ground_consistent

PHOTOS = "photos.csv"
CENTRE_COLUMNS = ("X0", "Y0", "Z0")


def settings_of(project_dir: Path) -> ProjectSettings:
    """project.toml's settings (the defaults when there is none)."""
    toml = project_dir / "project.toml"
    return parse_settings(toml, read_input_bytes(toml)) if toml.is_file() else ProjectSettings()


def placeholder(project_dir: Path, photos: bytes) -> str | None:
    """photos.csv with every orientation element 0 when the user's gives none (module doc), else
    None (the file is read as it is, and the reader names any problem with it). Line for line as
    the user's, so that the reader's messages name the user's lines."""
    table = parse_csv(project_dir / PHOTOS, photos)
    columns = (*CENTRE_COLUMNS, *ANGLE_COLUMNS[settings_of(project_dir).rotation])
    if table.header_line is None or any(table.has(c) and any(table.columns[table.header.index(c)]) for c in columns):
        return None
    lines = decode_text(project_dir / PHOTOS, photos).splitlines()
    at = [table.header.index(c) if table.has(c) else None for c in columns]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    for number, line in enumerate(lines, start=1):
        if number < table.header_line or not line.strip() or line.lstrip().startswith("#"):
            out.write(line + "\n")
            continue
        fields = next(csv.reader([line]))
        for c, k in zip(columns, at):
            value = c if number == table.header_line else "0"
            if k is None:
                fields.append(value)
            elif number != table.header_line and k < len(fields):
                fields[k] = value
        writer.writerow(fields)
    return out.getvalue()


def read_with(project_dir: Path, photos: str) -> Project:
    """The project of project_dir read with ``photos`` as its photos.csv (image_points.csv optional)."""
    files = {name: read_input_bytes(project_dir / name) for name in FILE_NAMES if input_present(project_dir / name)}
    files[PHOTOS] = photos
    return parse_project(files, project_dir, plate_measurements_optional=True)


def with_orientations(project_dir: Path, photos: bytes, R_ground_from_cam: np.ndarray, xyz0: np.ndarray) -> str:
    """The user's photos.csv (its columns and rows, comments dropped) with X0, Y0, Z0 (m, 3
    decimals) and the angles (project.toml's rotation and unit, 6 decimals) filled in."""
    settings = settings_of(project_dir)
    table = parse_csv(project_dir / PHOTOS, photos)
    cells: dict = {name: list(values) for name, values in zip(table.header, table.columns)}
    angles = angles_from_R(R_ground_from_cam, settings.rotation) / RADIANS_PER_UNIT[settings.angle_unit]
    for j, c in enumerate(CENTRE_COLUMNS):
        cells[c] = [f"{v:.3f}" for v in xyz0[:, j]]
    for j, c in enumerate(ANGLE_COLUMNS[settings.rotation]):
        cells[c] = [f"{v:.6f}" for v in angles[:, j]]
    return format_csv(cells)


@dataclass(frozen=True)
class Oriented:
    """What :func:`orient` found: the block's approximate orientations, OUT's photos.csv with them,
    and the ids of the automatic points left out as false."""

    block: BlockFromStrips
    photos_csv: str
    false_points: frozenset


def orient(project_dir: Path, files: dict, stand_in: str, tolerance: float, ground_tolerance: float,
           height: float) -> Oriented:
    """The approximate orientations of OUT's project (files, its photos.csv as ``stand_in``) from
    its tie points and control (module doc). tolerance: a ray's distance from the epipolar line
    of two successive photos beyond which its point is false (plate units); ground_tolerance,
    height: the ground check's (match.ground_check). NumericalFailure, in words, when the strips
    cannot be built or placed."""
    whole = parse_project({**{k: v for k, v in files.items() if k in FILE_NAMES}, PHOTOS: stand_in}, project_dir)
    auto = np.array([pid.startswith("auto_") for pid in whole.points.ids], dtype=bool)
    off = _off_the_relative_orientations(whole, tolerance) & auto
    rows = ~off[whole.image_points.point_index]
    try:
        block = block_from_strips(subset(whole, rows))
    except NumericalFailure as exc:
        raise NumericalFailure("approximate orientations from the strips (photos.csv has none): " + str(exc),
                               exc.reason) from exc
    oriented = replace(whole, photos=replace(whole.photos, xyz0=block.xyz0, R_ground_from_cam=block.R_ground_from_cam))
    ip = whole.image_points
    mine = auto[ip.point_index]
    uniq, track = np.unique(ip.point_index[mine], return_inverse=True)
    met = ground_consistent(oriented, track, ip.photo_index[mine], ip.xy[mine], height, ground_tolerance, len(uniq))
    off[uniq[~met]] = True
    photos_csv = with_orientations(project_dir, read_input_bytes(project_dir / PHOTOS), block.R_ground_from_cam,
                                   block.xyz0)
    return Oriented(block, photos_csv, frozenset(whole.points.ids[k] for k in np.flatnonzero(off)))


def _off_the_relative_orientations(project: Project, tolerance: float) -> np.ndarray:
    """(n_pt,) bool: the points one of whose rays in two successive photos of a strip (photos.csv's
    order) lies further than ``tolerance`` (plate units) from the epipolar line of the essential
    matrix fitted to all their common points by RANSAC."""
    from .features import cv2_module

    cv2 = cv2_module()
    ph, ip, cams = project.photos, project.image_points, project.cameras
    interior = cams.interior[ph.camera_index[ip.photo_index], :3]
    normal = (ip.xy - interior[:, 1:3]) / interior[:, :1]  # normalised image coordinates
    off = np.zeros(len(project.points), dtype=bool)
    row = {(int(i), int(q)): k for k, (i, q) in enumerate(zip(ip.photo_index, ip.point_index))}
    strips = np.asarray(ph.strip_ids)
    for s in dict.fromkeys(strips.tolist()):
        members = np.flatnonzero(strips == s)
        for i, j in zip(members[:-1], members[1:]):
            common = np.intersect1d(ip.point_index[ip.photo_index == i], ip.point_index[ip.photo_index == j])
            if len(common) < 8:
                continue
            a = normal[[row[int(i), int(q)] for q in common]]
            b = normal[[row[int(j), int(q)] for q in common]]
            c = float(np.median(cams.interior[ph.camera_index[[i, j]], 0]))
            E, inlier = cv2.findEssentialMat(a, b, np.eye(3), cv2.RANSAC, 0.9999, tolerance / c)
            if E is None or inlier is None:
                continue
            off[common[~inlier.ravel().astype(bool)]] = True
    return off


def check_control(project: Project, project_dir: Path) -> None:
    """InputError unless some strip has three full control points measured in two of its photos
    (the least sequential.block needs to place the first strip)."""
    ph, ip, pts = project.photos, project.image_points, project.points
    full = (pts.kind == FULL) & np.isfinite(pts.xyz_given).all(1)
    strip = np.asarray(ph.strip_ids)[ip.photo_index]
    rows = full[ip.point_index]
    best = 0
    for s in np.unique(strip):
        seen = np.bincount(ip.point_index[rows & (strip == s)], minlength=len(pts))
        best = max(best, int((seen >= 2).sum()))
    if best < 3:
        raise InputError(project_dir / PHOTOS, None,
                         "the photos have no approximate orientations (X0, Y0, Z0 and the angles), so striptri match "
                         "orients the strips from the tie points and places them on the control: that needs a strip "
                         f"with three full control points (kind XYZ) each measured in two of its photos "
                         f"(image_points.csv), and the best strip has {best}. Give approximate orientations "
                         "(GNSS/IMU or the flight plan), or measure the control in the photos.")
