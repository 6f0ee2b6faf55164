"""The output tables of an adjustment: photos.csv, cameras.csv, the GNSS tables, points.csv and
residuals.csv as columns, and the check points' statistics (pipeline writes them, plan and
study reuse them; docs/file-formats.md)."""

from __future__ import annotations

import math

import numpy as np

from ..geometry import balanced
from . import gnss as gnss_output
from ..core.adjusted_points import UNDETERMINED, undetermined_points
from ..core.result import AdjustmentResult
from ..equations.groups import rays_per_point
from ..io.csvtable import format_csv
from ..geometry.rotations import RADIANS_PER_UNIT
from ..geometry.lens import CAMERA_ELEMENTS, CONVENTION_NAMES
from ..model import CHECK, KIND_NAMES, ROTATION_OUTPUT_NAMES, Project
from ..geometry.rotations import angles_from_R
from ..equations.triangulation import Triangulated


def _angle_scale(project: Project) -> float:
    return 1.0 / RADIANS_PER_UNIT[project.settings.angle_unit]


def photo_table(project: Project, result: AdjustmentResult) -> dict:
    """photos.csv: centres (ground frame) and omega, phi, kappa in the project's angle unit, with
    mean errors; for projects in another convention also its angles (ROTATION_OUTPUT_NAMES)."""
    s = result.state
    xyz = s.xyz0 + result.offset
    unit = _angle_scale(project)
    sig_xyz, sig_opk = result.photo_mean_errors("omega-phi-kappa")
    opk = angles_from_R(s.R_ground_from_cam, "omega-phi-kappa") * unit
    cols = {"photo_id": project.photos.ids}
    for a, name in enumerate(("X0", "Y0", "Z0")):
        cols[name] = xyz[:, a]
    for a, name in enumerate(("omega", "phi", "kappa")):
        cols[name] = opk[:, a]
    for a, name in enumerate(("X0", "Y0", "Z0")):
        cols[f"sigma_{name}"] = sig_xyz[:, a]
    for a, name in enumerate(("omega", "phi", "kappa")):
        cols[f"sigma_{name}"] = sig_opk[:, a] * unit
    convention = project.settings.rotation
    if convention in ROTATION_OUTPUT_NAMES:
        names = ROTATION_OUTPUT_NAMES[convention]
        _, sig_other = result.photo_mean_errors(convention)
        other = angles_from_R(s.R_ground_from_cam, convention) * unit
        for a, name in enumerate(names):
            cols[name] = other[:, a]
        for a, name in enumerate(names):
            cols[f"sigma_{name}"] = sig_other[:, a] * unit
    return cols


def camera_table(project: Project, result: AdjustmentResult) -> dict:
    cams = project.cameras
    sig = result.camera_mean_errors()
    estimated = result.layout.camera_cols >= 0
    cols = {"camera_id": cams.ids}
    # the contract's columns (c, xp, yp, k1, k2, their sigmas), then the other additional
    # parameters, the distortion convention and their sigmas (docs/camera-model.md)
    for first, last in ((0, 5), (5, len(CAMERA_ELEMENTS))):
        for e in range(first, last):
            cols[CAMERA_ELEMENTS[e]] = result.state.interior[:, e]
        if first:
            cols["distortion"] = [CONVENTION_NAMES[int(c)] for c in result.state.convention]
        for e in range(first, last):
            cols[f"sigma_{CAMERA_ELEMENTS[e]}"] = np.where(estimated[:, e], sig[:, e], np.nan)
    if cams.r0 is not None and np.isfinite(cams.r0).any():  # cameras given balanced (striptri.geometry.balanced)
        idx = result.layout.camera_cols[:, list(balanced.CHANGED)]
        Q = result.covariance.entries(idx[:, :, None], idx[:, None, :])
        cols.update(balanced.output_columns(cams.r0, result.state.interior, result.state.convention, Q,
                                            result.sigma0_for_precision))
    return cols


def gnss_tables(project: Project, result: AdjustmentResult) -> dict:
    """With the GNSS model (gnss_output): cameras.csv with the lever-arm and boresight columns
    after its others, and strips.csv when shift or drift are estimated."""
    prec = gnss_output.precision_of(project, result)
    if prec is None:
        return {}
    out = {"cameras.csv": format_csv({**camera_table(project, result),
                                      **gnss_output.camera_columns(prec, _angle_scale(project))})}
    strips = gnss_output.strip_table(project, prec)
    if strips is not None:
        out["strips.csv"] = format_csv(strips)
    return out


def point_covariances(result: AdjustmentResult, tri: Triangulated) -> np.ndarray:
    """(n, 3, 3) covariances of the triangulated points, m^2: sigma0^2 (measurement + orientation part)."""
    return (tri.cov_measurement + tri.cov_orientation) * result.sigma0_for_precision**2


def point_table(project: Project, result: AdjustmentResult, tri: Triangulated) -> dict:
    pts = project.points
    cov = point_covariances(result, tri)
    sig = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
    xyz = tri.xyz + result.offset
    sig = np.where(tri.determined[:, None], sig, np.nan)
    cols = {"point_id": pts.ids, "kind": [KIND_NAMES[int(k)] for k in pts.kind]}
    for a, name in enumerate("XYZ"):
        cols[name] = xyz[:, a]
    for a, name in enumerate("XYZ"):
        cols[f"sigma_{name}"] = sig[:, a]
    cols["rays"] = rays_per_point(project)
    cols["flag"] = np.where(undetermined_points(project, tri), UNDETERMINED, "").tolist()
    return cols


def residual_table(project: Project, det) -> dict:
    """residuals.csv over every original measurement: v (for a rejected one the residual it would
    have), the larger in magnitude of its normalised residuals w (x, y), the flag ("", "suspect":
    |w| above the critical value, "rejected", "dropped") and, after the contract's columns, the
    minimal detectable biases of x and y (plate units)."""
    ip = project.image_points
    return {
        "photo_id": [project.photos.ids[i] for i in ip.photo_index],
        "point_id": [project.points.ids[i] for i in ip.point_index],
        "vx": det.v[:, 0],
        "vy": det.v[:, 1],
        "w": det.row_w,
        "flag": list(det.flag),
        "mdb_x": det.mdb[:, 0],
        "mdb_y": det.mdb[:, 1],
    }


def check_point_statistics(project: Project, result: AdjustmentResult, tri: Triangulated) -> dict:
    """Differences adjusted - given at check points and their RMS per axis (None without any), over
    the check points the adjustment determines; ``n_left_out`` counts the undetermined ones
    (undetermined_points), which the report names."""
    check = project.points.kind == CHECK
    left_out = check & undetermined_points(project, tri)
    sel = check & ~left_out & tri.determined
    n = int(sel.sum())
    if n == 0:
        return {"n": 0, "rms_X": None, "rms_Y": None, "rms_Z": None, "n_left_out": int(left_out.sum())}
    diff = tri.xyz[sel] + result.offset - project.points.xyz_given[sel]
    rms = np.sqrt(np.mean(diff**2, axis=0))
    return {"n": n, "rms_X": float(rms[0]), "rms_Y": float(rms[1]), "rms_Z": float(rms[2]),
            "n_left_out": int(left_out.sum())}


def finite_or_none(x):
    return None if x is None or not math.isfinite(x) else float(x)
