"""Write a :class:`striptri.model.Project` as a project folder that read_project reads back.

The files follow docs/file-formats.md with the project's own settings: angles in
``settings.angle_unit`` and in the columns of ``settings.rotation``. Numbers are written with repr,
so ``read_project(write_project(folder, p))`` gives back p (angles to within an ulp of the unit
conversion), provided p's object points are in the reader's order (control points first, then tie
points by first measurement; :func:`reader_point_order` gives that order). Tie points measured on no
photo carry no information and cannot be written (there is no file for them): they are left out.
The folder is written atomically by write_output_folder.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from striptri import model
from striptri.geometry.lens import CAMERA_ELEMENTS, CONVENTION_NAMES, has_distortion
from striptri.io.csvtable import format_csv
from striptri.io.gnss_writer import gnss_camera_columns, gnss_photo_columns, gnss_toml
from striptri.io.output import write_output_folder
from striptri.geometry.balanced import balanced_from_gaussian
from striptri.geometry.rotations import RADIANS_PER_UNIT
from striptri.io.table_readers import ANGLE_COLUMNS, BASE_AXES

_AXIS_NAMES = {axis: name for name, axis in BASE_AXES.items()}


def write_project(
    folder: str | Path,
    project: model.Project,
    truth_tables: Mapping[str, Mapping[str, Sequence]] | None = None,
) -> Path:
    """Write project as the input files of folder (replacing folder whole); return its path.

    Files: cameras.csv, photos.csv, image_points.csv, control.csv (header only when there is no
    control), project.toml, bases.csv when there are base components. truth_tables: file name ->
    columns (as for format_csv), written as folder/truth/<file name>.
    """
    files = project_files(project)
    for name, columns in (truth_tables or {}).items():
        files[f"truth/{name}"] = format_csv(columns)
    return write_output_folder(folder, files)


def project_files(project: model.Project) -> dict[str, str]:
    """The text of every input file of project, by file name."""
    files = {
        "project.toml": settings_toml(project.settings),
        "cameras.csv": format_csv(_camera_columns(project.cameras)),
        "photos.csv": format_csv(_photo_columns(project.photos, project.cameras, project.settings)),
        "image_points.csv": format_csv(_image_point_columns(project)),
        "control.csv": format_csv(_control_columns(project.points)),
    }
    if len(project.bases):
        files["bases.csv"] = format_csv(_base_columns(project.bases, project.photos))
    if project.gnss is not None:  # io.gnss_writer: columns added at the end, a [gnss] section
        per_unit = RADIANS_PER_UNIT[project.settings.angle_unit]
        files["cameras.csv"] = format_csv({**_camera_columns(project.cameras),
                                           **gnss_camera_columns(project.gnss, per_unit)})
        files["photos.csv"] = format_csv({**_photo_columns(project.photos, project.cameras, project.settings),
                                          **gnss_photo_columns(project.gnss)})
        files["project.toml"] += gnss_toml(project.gnss)
    return files


def reader_point_order(project: model.Project) -> np.ndarray:
    """Indices of the object points in the order read_project gives them after write_project:
    control points (kind != TIE) in their order, then tie points by first measurement."""
    control = np.flatnonzero(project.points.kind != model.TIE)
    off = project.inactive_image_points
    point_index = project.image_points.point_index if off is None else np.concatenate(
        [project.image_points.point_index, off.point_index])  # the file's rows: active, then inactive
    _, first = np.unique(point_index, return_index=True)
    measured = point_index[np.sort(first)]
    ties = measured[project.points.kind[measured] == model.TIE]
    return np.concatenate([control, ties]).astype(np.int64)


def settings_toml(settings: model.ProjectSettings) -> str:
    """project.toml holding every setting explicitly ([datum] mode and [units] plate only when they
    are not the default, so that the simulator's projects in mm keep their files)."""
    defaults = model.ProjectSettings()
    datum = "" if settings.datum == defaults.datum else f'\n[datum]\nmode = "{settings.datum}"\n'
    if settings.datum_points:  # TOML basic strings: backslash and quote escaped
        quoted = ('"' + p.replace("\\", "\\\\").replace('"', '\\"') + '"' for p in settings.datum_points)
        datum += "points = [" + ", ".join(quoted) + "]\n"
    plate = "" if settings.plate_unit == defaults.plate_unit else f'plate = "{settings.plate_unit}"\n'
    return (
        "# striptri project settings (docs/file-formats.md)\n"
        "[units]\n"
        f'angles = "{settings.angle_unit}"\n'
        f'rotation = "{settings.rotation}"\n'
        + plate
        + "\n[defaults]\n"
        f"sigma_image = {float(settings.sigma_image)!r}\n"
        "\n[adjustment]\n"
        f'method = "{settings.method}"\n'
        f'solver = "{settings.solver}"\n'
        f"max_iterations = {int(settings.max_iterations)}\n"
        + (f"cost_tolerance = {float(settings.cost_tolerance)!r}\n" if settings.cost_tolerance else "")
        + datum
        + _corrections_toml(settings, defaults)
        + _coordinates_toml(settings.coordinates)
    )


def _corrections_toml(settings: model.ProjectSettings, defaults: model.ProjectSettings) -> str:
    """[corrections] only when a correction is on or the radius is not the default."""
    keys = ("earth_curvature", "refraction", "earth_radius")
    if all(getattr(settings, k) == getattr(defaults, k) for k in keys):
        return ""
    return ("\n[corrections]\n"
            f"earth_curvature = {'true' if settings.earth_curvature else 'false'}\n"
            f"refraction = {'true' if settings.refraction else 'false'}\n"
            f"earth_radius = {float(settings.earth_radius)!r}\n")


def _coordinates_toml(c: model.CoordinateSettings | None) -> str:
    """[coordinates] (striptri.crs.settings), or nothing for a project in a local frame."""
    if c is None:
        return ""
    crs = c.crs.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
    text = f'\n[coordinates]\ncrs = "{crs}"\nheights = "{c.heights}"\n'
    if c.geoid_undulation is not None:
        text += f"geoid_undulation = {float(c.geoid_undulation)!r}\n"
    if c.geoid_grid is not None:
        text += f'geoid_grid = "{c.geoid_grid.as_posix()}"\n'
    return text


def _camera_columns(cameras: model.Cameras) -> dict[str, Sequence]:
    """cameras.csv: sigma nan -> empty (held fixed), inf -> 'free'. The additional parameters and
    the distortion convention are written only when some camera uses them."""
    columns: dict[str, Sequence] = {"camera_id": cameras.ids}
    extended = has_distortion(cameras.interior, ~np.isnan(cameras.sigma_interior)) or bool(np.any(cameras.convention))
    names = CAMERA_ELEMENTS if extended else CAMERA_ELEMENTS[:3]
    r0 = cameras.r0 if cameras.r0 is not None and np.isfinite(cameras.r0).any() else None
    # cameras given balanced are written balanced (striptri.geometry.balanced), with their r0
    interior = cameras.interior if r0 is None else balanced_from_gaussian(cameras.interior, r0, cameras.convention)[0]
    for j, name in enumerate(names):
        columns[name] = interior[:, j]
    if extended:
        columns["distortion"] = [CONVENTION_NAMES[int(c)] for c in cameras.convention]
    if r0 is not None:
        columns["r0"] = r0
    if cameras.size_px is not None:  # a digital frame camera (striptri.geometry.pixels)
        columns["width_px"] = [int(v) if np.isfinite(v) else float("nan") for v in cameras.size_px[:, 0]]
        columns["height_px"] = [int(v) if np.isfinite(v) else float("nan") for v in cameras.size_px[:, 1]]
        columns["pixel_size"] = cameras.pixel_size
    for j, name in enumerate(names):
        columns[f"sigma_{name}"] = [_camera_sigma(s) for s in cameras.sigma_interior[:, j]]
    return columns


def _camera_sigma(sigma: float):
    return "free" if math.isinf(sigma) else float(sigma)


def _photo_columns(photos: model.Photos, cameras: model.Cameras, settings: model.ProjectSettings) -> dict:
    """photos.csv in settings.angle_unit and the angle columns of settings.rotation; sigma nan -> empty (free)."""
    per_rad = 1.0 / RADIANS_PER_UNIT[settings.angle_unit]
    names = ANGLE_COLUMNS[settings.rotation]
    columns: dict[str, Sequence] = {
        "photo_id": photos.ids,
        "camera_id": [cameras.ids[k] for k in photos.camera_index],
        "strip_id": photos.strip_ids,
    }
    for j, name in enumerate(("X0", "Y0", "Z0")):
        columns[name] = photos.xyz0[:, j]
    for j, name in enumerate(names):
        columns[name] = photos.angles[:, j] * per_rad
    for j, name in enumerate(("X0", "Y0", "Z0")):
        columns[f"sigma_{name}"] = photos.sigma_xyz0[:, j]
    for j, name in enumerate(names):
        columns[f"sigma_{name}"] = photos.sigma_angles[:, j] * per_rad
    return columns


def _image_point_columns(project: model.Project) -> dict[str, Sequence]:
    """image_points.csv with explicit sigmas, rows in the project's order; inactive rows last, with
    the column active (1/0) when there are any."""
    ip, off = project.image_points, project.inactive_image_points
    rows = [(ip, 1)] + ([(off, 0)] if off is not None and len(off) else [])
    columns = {
        "photo_id": [project.photos.ids[k] for t, _ in rows for k in t.photo_index],
        "point_id": [project.points.ids[k] for t, _ in rows for k in t.point_index],
        "x": np.concatenate([t.xy[:, 0] for t, _ in rows]),
        "y": np.concatenate([t.xy[:, 1] for t, _ in rows]),
        "sigma_x": np.concatenate([t.sigma_xy[:, 0] for t, _ in rows]),
        "sigma_y": np.concatenate([t.sigma_xy[:, 1] for t, _ in rows]),
    }
    if len(rows) > 1:  # the active rows, then the inactive ones (image_points.csv's active column)
        columns["active"] = np.concatenate([np.full(len(t), a, dtype=int) for t, a in rows])
    return columns


def _control_columns(points: model.ObjectPoints) -> dict[str, Sequence]:
    """control.csv: every point whose kind is not TIE; nan coordinate or sigma -> empty."""
    rows = np.flatnonzero(points.kind != model.TIE)
    columns: dict[str, Sequence] = {
        "point_id": [points.ids[k] for k in rows],
        "kind": [model.KIND_NAMES[int(points.kind[k])] for k in rows],
    }
    for j, name in enumerate("XYZ"):
        columns[name] = points.xyz_given[rows, j]
    for j, name in enumerate("XYZ"):
        columns[f"sigma_{name}"] = points.sigma_given[rows, j]
    return columns


def _base_columns(bases: model.BaseComponents, photos: model.Photos) -> dict[str, Sequence]:
    """bases.csv; sigma nan -> empty (enforced), 0 stays 0 (enforced)."""
    return {
        "photo_from": [photos.ids[k] for k in bases.photo_from],
        "photo_to": [photos.ids[k] for k in bases.photo_to],
        "component": [_AXIS_NAMES[int(a)] for a in bases.axis],
        "value": bases.value,
        "sigma": bases.sigma,
    }
