"""The plan as a noise-free project: planned ground points and the plate measurements they predict.

A plan is a project folder whose photos.csv gives the planned orientations (centres, attitudes),
control.csv the planned control (with its sigmas), image_points.csv which photo sees which point,
and approx_points.csv (optional) the planned ground points. The planned ground point of every
object point, per axis (DESIGN section 10, docs/plan.md):

1. the coordinates control.csv gives (the given axes of XYZ, XY, Z points; all three for a check
   point: its reference coordinates are the plan);
2. else approx_points.csv;
3. else the least-squares intersection of the point's rays, formed from image_points.csv's x, y
   through the planned orientations (a point on one photo: its ray at the given X, Y, or at the
   median height of the other points).

The predicted measurements are the collinearity images (Schmid 14, with the camera's distortion:
lens.observed_from_ideal) of the planned points in the planned photos; image_points.csv's x, y are
then only used for step 3, its sigma_x, sigma_y (or project.toml's sigma_image) are the plan's
plate sigmas.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..camera import ray_ground
from ..collinearity import plate_from_ground
from ..lens import observed_from_ideal, ideal_from_observed
from ..model import CHECK, FULL, HEIGHT, PLAN, Project

CONTROL_KINDS = {"XYZ": FULL, "XY": PLAN, "Z": HEIGHT}  # the kinds a control point has (what-ifs, ranking)
_STEEP = 1e-3  # a ray with a horizontal part below this (relative) is taken as vertical


def planned_points(project: Project) -> np.ndarray:
    """The planned ground coordinates of every object point (module doc), ground metres: (np, 3).
    nan where a point is on no photo and given by nothing."""
    pts, ip, ph = project.points, project.image_points, project.photos
    n = len(pts)
    given = np.where(pts.given_axes | (pts.kind == CHECK)[:, None], pts.xyz_given, np.nan)
    approx = np.full((n, 3), np.nan) if pts.xyz_approx is None else np.asarray(pts.xyz_approx, dtype=float)
    origin = np.mean(ph.xyz0, axis=0) if len(ph) else np.zeros(3)
    # rays of image_points.csv through the planned orientations, relative to origin
    cam = ph.camera_index[ip.photo_index]
    params, conv = project.cameras.interior[cam], project.cameras.convention[cam]
    xy = ideal_from_observed(ip.xy, params, conv).xy
    r = ray_ground(ph.R_ground_from_cam[ip.photo_index], xy, params[:, :3])
    r = r / np.linalg.norm(r, axis=1, keepdims=True)
    o = ph.xyz0[ip.photo_index] - origin
    # least-squares intersection: sum (I - r r^T) X = sum (I - r r^T) O, per point
    P = np.eye(3) - r[:, :, None] * r[:, None, :]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    np.add.at(A, ip.point_index, P)
    np.add.at(b, ip.point_index, np.einsum("mij,mj->mi", P, o))
    rays = np.bincount(ip.point_index, minlength=n)
    multi = rays >= 2
    inter = np.full((n, 3), np.nan)
    if multi.any():
        inter[multi] = np.linalg.solve(A[multi], b[multi][..., None])[..., 0] + origin
    xyz = np.where(np.isfinite(given), given, np.where(np.isfinite(approx), approx, inter))
    single = (rays == 1) & ~np.isfinite(xyz).all(axis=1)
    if single.any():
        xyz[single] = _on_single_ray(xyz, single, ip.point_index, o + origin, r)
    return xyz


def _on_single_ray(xyz: np.ndarray, single: np.ndarray, point_index: np.ndarray, centre: np.ndarray,
                   r: np.ndarray) -> np.ndarray:
    """The points ``single`` (on one photo): the point of the ray nearest the vertical through the
    known X, Y, else the ray at the known Z or the median height of the determined points."""
    row = np.full(len(single), -1)
    row[point_index] = np.arange(len(point_index))
    rows = row[single]
    O, d, known = centre[rows], r[rows], xyz[single]
    z_known = xyz[:, 2][np.isfinite(xyz[:, 2]) & ~single]
    z_fallback = float(np.median(z_known)) if len(z_known) else 0.0
    h2 = np.sum(d[:, :2] ** 2, axis=1)
    has_xy = np.isfinite(known[:, :2]).all(axis=1) & (h2 > _STEEP**2)
    t_xy = np.einsum("mi,mi->m", np.nan_to_num(known[:, :2]) - O[:, :2], d[:, :2]) / np.where(h2 > 0, h2, 1.0)
    z = np.where(np.isfinite(known[:, 2]), known[:, 2], z_fallback)
    t_z = (z - O[:, 2]) / np.where(d[:, 2] != 0, d[:, 2], np.nan)
    t = np.where(has_xy, t_xy, t_z)
    out = O + t[:, None] * d
    return np.where(np.isfinite(known), known, out)


def predicted_plates(project: Project, xyz_ground: np.ndarray) -> np.ndarray:
    """The plate coordinates the planned photos see the ground points at: (m, 2) over the rows of
    image_points (plate units), with the camera's distortion."""
    ip, ph = project.image_points, project.photos
    cam = ph.camera_index[ip.photo_index]
    params, conv = project.cameras.interior[cam], project.cameras.convention[cam]
    ideal = plate_from_ground(ph.R_ground_from_cam[ip.photo_index], ph.xyz0[ip.photo_index], params[:, :3],
                              xyz_ground[ip.point_index])
    return observed_from_ideal(ideal, params, conv)


def noise_free_project(project: Project, xyz_ground: np.ndarray | None = None) -> Project:
    """The plan with the measurements it predicts: plate coordinates from predicted_plates, every
    given control coordinate (and every coordinate of a check point) equal to the planned point, the planned points as approximate
    coordinates. Orientations, cameras, sigmas and kinds are the plan's."""
    xyz = planned_points(project) if xyz_ground is None else xyz_ground
    pts = project.points
    given = np.where(np.isfinite(pts.xyz_given) | (pts.kind == CHECK)[:, None], xyz, pts.xyz_given)
    return replace(project,
                   image_points=replace(project.image_points, xy=predicted_plates(project, xyz)),
                   points=replace(pts, xyz_given=given, xyz_approx=xyz.copy()))
