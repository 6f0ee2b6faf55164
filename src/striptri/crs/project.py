"""A project in map coordinates, adjusted in its local frame (docs/decisions.md, "Map coordinates").

:func:`in_local_frame` converts everything of a project that is a ground coordinate or direction
(photo centres and rotations with their standard deviations, control, check points, approximate
points) from the project's CRS to the local frame of :mod:`striptri.crs.frame`, centred at the
block's centre; the adjustment then runs unchanged. :func:`photo_columns_to_grid` and
:func:`point_columns_to_grid` turn the output tables back.

Partial control (kind XY or Z) lacks one part of the position its local coordinates depend on
(the local Z of a point changes by d/R per metre of horizontal position, d its distance from the
centre; the local X, Y by as much per metre of height): it is converted at the missing coordinates
of an approximate position (approx_points.csv, else the intersection of the approximate rays), and
:func:`refine_partial_control` converts it again at the adjusted position (the pipeline re-adjusts
until that changes the given coordinates by less than REFINE_TOLERANCE_M).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.geometry.camera import ray_ground
from striptri.crs.frame import LocalFrame, angle_sigmas
from striptri.errors import InputError
from striptri.geometry.rotations import RADIANS_PER_UNIT
from striptri.geometry.rotations import R_from_angles, angles_from_R
from striptri.equations.triangulation import intersect_rays

REFINE_TOLERANCE_M = 1e-4


@dataclass(frozen=True)
class FramedProject:
    """grid: the project as read (map coordinates); local: the same in the local frame; frame."""

    grid: model.Project
    local: model.Project
    frame: LocalFrame


def block_centre(project: model.Project) -> np.ndarray:
    """Grid E, N of the block's centre: the mean of the photo centres and of the given plan
    positions of the control and check points. -> (3,) (height 0: the origin is on the ellipsoid)."""
    pts = project.points
    plan = pts.xyz_given[np.all(np.isfinite(pts.xyz_given[:, :2]), axis=1), :2]
    xy = np.concatenate([project.photos.xyz0[:, :2], plan])
    return np.array([*xy.mean(axis=0), 0.0])


def in_local_frame(project: model.Project) -> FramedProject:
    """The project in the local frame of its [coordinates] (module doc). InputError for what cannot
    be converted (bases.csv: base components are differences along grid axes, not converted)."""
    toml = project.source / "project.toml" if project.source is not None else "project.toml"
    if len(project.bases):
        raise InputError(toml, project.settings.coordinates.line,
                         "[coordinates] with bases.csv: base components are differences of grid coordinates, which "
                         "the local frame does not keep; adjust such a project without [coordinates]")
    frame = LocalFrame(project.settings.coordinates, block_centre(project), toml)
    photos = _photos_to_local(project.photos, project.settings.rotation, frame)
    points = _points_to_local(project, frame, _approximate_positions(project))
    _require_converted(project, photos, points, toml)
    return FramedProject(project, replace(project, photos=photos, points=points), frame)


def _require_converted(project: model.Project, photos: model.Photos, points: model.ObjectPoints, toml) -> None:
    """InputError for a photo centre or given point PROJ could not convert (outside the projection's
    domain: coordinates that are not in this CRS)."""
    crs = project.settings.coordinates.crs
    for name, ids, given, local in (("photos.csv", project.photos.ids, project.photos.xyz0, photos.xyz0),
                                    ("control.csv", project.points.ids, project.points.xyz_given, points.xyz_given)):
        bad = np.flatnonzero(np.any(np.isfinite(given) & ~np.isfinite(local), axis=1))
        if len(bad):
            k = int(bad[0])
            raise InputError(toml, project.settings.coordinates.line,
                             f"[coordinates] crs = {crs!r}: '{ids[k]}' of {name} at {given[k].tolist()} cannot be "
                             f"converted (outside the domain of the projection); are the coordinates in this CRS?")


def _photos_to_local(photos: model.Photos, convention: str, frame: LocalFrame) -> model.Photos:
    R = frame.rotations_to_local(photos.xyz0, photos.R_ground_from_cam)
    return replace(
        photos,
        xyz0=frame.to_local(photos.xyz0),
        R_ground_from_cam=R,
        angles=angles_from_R(R, convention),
        sigma_xyz0=frame.sigmas_to_local(photos.xyz0, photos.sigma_xyz0),
        sigma_angles=angle_sigmas(photos.R_ground_from_cam, R, photos.sigma_angles, convention),
    )


def _points_to_local(project: model.Project, frame: LocalFrame, xyz_approx_grid: np.ndarray) -> model.ObjectPoints:
    pts = project.points
    xyz_grid = np.where(np.isnan(pts.xyz_given), xyz_approx_grid, pts.xyz_given)
    has_given = np.any(np.isfinite(pts.xyz_given), axis=1)
    xyz_local = frame.to_local(xyz_grid)
    missing = has_given & ~np.all(np.isfinite(xyz_local), axis=1)
    if missing.any():
        k = int(np.flatnonzero(missing)[0])
        raise InputError(frame.toml, None, f"[coordinates]: control point '{pts.ids[k]}' (kind "
                                           f"{model.KIND_NAMES[int(pts.kind[k])]}) has no approximate position for "
                                           "its missing coordinates (give it in approx_points.csv or measure it on "
                                           "two photos)")
    sigma = frame.sigmas_to_local(np.where(np.isfinite(xyz_grid), xyz_grid, 0.0), pts.sigma_given)
    approx = None
    if pts.xyz_approx is not None:
        approx = frame.to_local(pts.xyz_approx)
    return replace(pts, xyz_given=np.where(np.isnan(pts.xyz_given), np.nan, xyz_local), sigma_given=sigma,
                   xyz_approx=approx)


def _approximate_positions(project: model.Project) -> np.ndarray:
    """Grid positions of the points from approx_points.csv, else from the least-squares intersection
    of their approximate rays (photos as given, no distortion), nan where neither exists. -> (np, 3)."""
    pts, ip, photos = project.points, project.image_points, project.photos
    out = np.full((len(pts), 3), np.nan) if pts.xyz_approx is None else pts.xyz_approx.copy()
    need = np.flatnonzero(np.any(np.isnan(pts.xyz_given), axis=1) & np.any(np.isfinite(pts.xyz_given), axis=1)
                          & np.any(np.isnan(out), axis=1))
    if len(need) == 0:
        return out
    rows = np.flatnonzero(np.isin(ip.point_index, need))
    rows = rows[np.argsort(ip.point_index[rows], kind="stable")]
    point, start, counts = np.unique(ip.point_index[rows], return_index=True, return_counts=True)
    two = counts >= 2
    if not two.any():
        return out
    slot = np.arange(len(rows)) - np.repeat(start, counts)  # the ray's place among its point's rays
    group = np.repeat(np.arange(len(point)), counts)
    centre = np.zeros((len(point), int(counts.max()), 3))
    r = np.tile(np.array([0.0, 0.0, -1.0]), (len(point), int(counts.max()), 1))
    mask = np.zeros(centre.shape[:2])
    ph = ip.photo_index[rows]
    centre[group, slot] = photos.xyz0[ph]
    r[group, slot] = ray_ground(photos.R_ground_from_cam[ph], ip.xy[rows],
                                project.cameras.interior[photos.camera_index[ph], :3])
    mask[group, slot] = 1.0
    point, centre, r, mask = point[two], centre[two], r[two], mask[two]
    out[point] = np.where(np.isnan(out[point]), intersect_rays(centre, r, mask, safe=True), out[point])
    return out


def refine_partial_control(framed: FramedProject, xyz_local_adjusted: np.ndarray) -> tuple[FramedProject, float]:
    """Convert the partial control again with its missing coordinates taken from the adjusted points
    (local (np, 3)). -> (the new FramedProject, the largest change of a given local coordinate, m)."""
    pts = framed.grid.points
    partial = np.any(np.isnan(pts.xyz_given), axis=1) & np.any(np.isfinite(pts.xyz_given), axis=1)
    adjusted_grid = framed.frame.from_local(np.where(partial[:, None], xyz_local_adjusted, np.nan))
    approx = np.where(partial[:, None] & np.all(np.isfinite(adjusted_grid), axis=1)[:, None], adjusted_grid,
                      _approximate_positions(framed.grid))
    points = _points_to_local(framed.grid, framed.frame, approx)
    points = replace(points, xyz_approx=framed.local.points.xyz_approx)
    old = framed.local.points.xyz_given
    change = np.abs(np.where(np.isfinite(old), points.xyz_given - old, 0.0))
    return replace(framed, local=replace(framed.local, points=points)), float(change.max(initial=0.0))


def has_partial_control(project: model.Project) -> bool:
    g = np.isfinite(project.points.xyz_given)
    return bool(np.any(np.any(g, axis=1) & ~np.all(g, axis=1)))


# ------------------------------------------------------------------------------------- outputs


def photo_columns_to_grid(cols: dict, project: model.Project, frame: LocalFrame, covariances=None) -> dict:
    """photos.csv's columns (pipeline.photo_table, in the local frame) in the project's CRS: centres,
    omega, phi, kappa (and the project's own convention's angles) and their standard deviations.
    covariances(convention) -> (n, 6, 6) the local frame's covariance of centre (m) and angles (rad)
    (AdjustmentResult.photo_covariances): the standard deviations are then propagated with all
    correlations through LocalFrame.photo_jacobian_to_grid; without it from the local standard
    deviations alone (diagonal)."""
    out = dict(cols)
    xyz_local = np.column_stack([np.asarray(cols[n], dtype=float) for n in ("X0", "Y0", "Z0")])
    xyz_grid = frame.from_local(xyz_local)
    per_unit = RADIANS_PER_UNIT[project.settings.angle_unit]
    for convention, names in (("omega-phi-kappa", ("omega", "phi", "kappa")),
                              *model.ROTATION_OUTPUT_NAMES.items()):
        if names[0] not in cols:
            continue
        angles = np.column_stack([np.asarray(cols[n], dtype=float) for n in names]) * per_unit
        R_local = R_from_angles(angles, convention)
        R_grid = frame.rotations_to_grid(xyz_local, R_local)
        grid_angles = angles_from_R(R_grid, convention) / per_unit
        if covariances is None:
            sig = np.column_stack([np.asarray(cols[f"sigma_{n}"], dtype=float) for n in names]) * per_unit
            sig_xyz = frame.sigmas_to_grid(xyz_local, np.column_stack(
                [np.asarray(cols[f"sigma_{n}"], dtype=float) for n in ("X0", "Y0", "Z0")]))
            grid_sig = angle_sigmas(R_local, R_grid, sig, convention) / per_unit
        else:
            F = frame.photo_jacobian_to_grid(xyz_local, R_local, convention)
            sig6 = _sigmas(F @ covariances(convention) @ np.swapaxes(F, -1, -2))
            sig_xyz, grid_sig = sig6[:, :3], sig6[:, 3:] / per_unit
        for a, name in enumerate(names):
            out[name], out[f"sigma_{name}"] = grid_angles[:, a], grid_sig[:, a]
    for a, name in enumerate(("X0", "Y0", "Z0")):  # the same in every convention: the last one's
        out[name], out[f"sigma_{name}"] = xyz_grid[:, a], sig_xyz[:, a]
    return out


def point_columns_to_grid(cols: dict, frame: LocalFrame, cov_local: np.ndarray | None = None) -> dict:
    """points.csv's columns (pipeline.point_table, local frame) in the project's CRS. cov_local:
    the points' (n, 3, 3) covariances in the local frame (m^2): the standard deviations are then
    propagated with the correlations; without it from the local standard deviations alone."""
    out = dict(cols)
    xyz_local = np.column_stack([np.asarray(cols[n], dtype=float) for n in "XYZ"])
    xyz_grid = frame.from_local(xyz_local)
    if cov_local is None:
        sig_local = np.column_stack([np.asarray(cols[f"sigma_{n}"], dtype=float) for n in "XYZ"])
        sig_grid = frame.sigmas_to_grid(np.where(np.isfinite(xyz_local), xyz_local, 0.0), sig_local)
    else:
        given = np.column_stack([np.asarray(cols[f"sigma_{n}"], dtype=float) for n in "XYZ"])
        J = frame.point_jacobian_to_grid(xyz_local)
        sig_grid = np.where(np.isfinite(given), _sigmas(J @ cov_local @ np.swapaxes(J, -1, -2)), np.nan)
    for a, name in enumerate("XYZ"):
        out[name], out[f"sigma_{name}"] = xyz_grid[:, a], sig_grid[:, a]
    return out


def _sigmas(cov: np.ndarray) -> np.ndarray:
    """Square roots of the diagonals of (n, k, k) covariances (nan stays nan)."""
    return np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
