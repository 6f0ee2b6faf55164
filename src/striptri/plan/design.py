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

from ..geometry.collinearity import plate_from_ground
from ..geometry.lens import observed_from_ideal
from ..equations.triangulation import planned_points  # noqa: F401  (the plan's ground points)
from ..model import CHECK, FULL, HEIGHT, PLAN, Project

CONTROL_KINDS = {"XYZ": FULL, "XY": PLAN, "Z": HEIGHT}  # the kinds a control point has (what-ifs, ranking)
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
