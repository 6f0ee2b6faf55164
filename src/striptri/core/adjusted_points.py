"""Ground points of an adjusted result: the one entry to the triangulation for a finished adjustment.

The pipeline (points.csv with Schmid's (90) precision split) and the gross-error tests (coordinates
of points left with fewer rays) both call :func:`triangulate_adjusted`; it reads the rays, the
control and the orientation from the project and the result and hands them to
:func:`striptri.equations.triangulation.triangulate`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..equations.observations import observations_of
from .result import AdjustmentResult
from ..equations.joint_groups import joint_point_blocks
from ..equations.groups import rays_per_point
from ..model import CHECK, HELD, Project
from ..equations.point_datum import JointBlock, points_correction
from ..equations.triangulation import GivenCoordinates, RayObservations, Triangulated, triangulate



def triangulate_adjusted(project: Project, result: AdjustmentResult, *, orientation_part: bool = False) -> Triangulated:
    """The ground points (reduced frame: add ``result.offset``) from the adjusted plate coordinates
    of ``result`` (every row of ``project.image_points``, with the measurements for the camera
    model), the adjusted control coordinates (weighted ones as observations, held ones held) and
    the adjusted orientation, which is held.

    Returns triangulation.Triangulated: coordinates, which points are determined, and the
    measurement part of their cofactors; with ``orientation_part`` also the orientation part
    ``G Qxx G^T`` (Schmid 87-90), which reads ``result.covariance`` (a NumericalFailure where N is
    singular). Without it ``cov_orientation`` is zero. With the orientation part, the points joined
    by distances are intersected together (joint_groups.joint_point_precision: their blocks of the
    joint form), and in the point datum (point_datum) the orientation part carries also the
    orientation's covariance with the datum points' own measurements (point_datum.points_correction,
    with the joint groups' cross blocks).
    """
    ip = project.image_points
    rays = RayObservations(photo_index=ip.photo_index, point_index=ip.point_index, xy_plate=result.plate_adjusted,
                           sigma_xy=ip.sigma_xy, xy_measured=ip.xy)
    control = GivenCoordinates(xyz_ground=result.control_adjusted, given=project.points.given_axes,
                               q_given=observations_of(project, result.offset).q_control)
    tri = triangulate(rays, control, state=result.state, layout=result.layout,
                      Qxx=result.covariance if orientation_part else None)
    if not orientation_part:
        return tri
    tri, pairs = joint_point_blocks(project, result, tri)
    fn = result.free_network
    if fn is not None and fn.points is not None:
        H = np.vstack([fn.H, np.zeros((1, fn.H.shape[1]))])  # row -1: held elements do not move
        groups = [JointBlock(js.point_index, inter.Qm, inter.G @ H[js.cols]) for js, inter in pairs]
        tri = replace(tri, cov_orientation=tri.cov_orientation
                      + points_correction(fn.points, tri.cov_measurement, groups))
    return tri


UNDETERMINED = "undetermined"  # points.csv's flag (DESIGN, third wave)


def undetermined_points(project: Project, tri: Triangulated) -> np.ndarray:
    """(n_pt,) the points that have coordinates to determine and whose rays and given coordinates do
    not determine them at the adjusted values (triangulation.Triangulated.undetermined: a singular
    or nearly singular normal matrix): measured points, and check points even without rays. Held
    control has nothing to determine."""
    pts = project.points
    held = (pts.given_state == HELD).all(axis=1)
    measured = (rays_per_point(project) > 0) | (pts.kind == CHECK)
    return tri.undetermined & measured & ~held
