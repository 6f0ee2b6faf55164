"""The object points among the unknowns of the bundle adjustment, and their starting values.

Per object point, the coordinates that are not held fixed are unknowns: X, Y, Z of a tie or check
point; X, Y of a height point with its Z held; Z of a plan point with X, Y held; none of a full
point held fixed (its rays are then collinearity equations on the orientation alone, like Schmid's
full control). A weighted control coordinate is an unknown with the extra observation
``given - X`` and the given standard deviation.

A point takes part when its observations outnumber its unknown coordinates,
``2k + (weighted coordinates) - (unknown coordinates) = 2k - (3 - d) > 0`` for k rays and d given
coordinates: exactly the points for which the method of conditions forms conditions
(``groups.build_batches``), so both methods adjust the same observations with the same
redundancy. A tie point on one photo is ignored, a height point on one photo gives nothing, a plan
point on one photo has its Z determined by its one ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import ray_ground
from ..geometry.lens import ideal_xy
from ..equations.groups import GroupBatch
from ..equations.linearise import Observations
from ..model import Project
from ..equations.parameters import State
from ..equations.triangulation import intersect_rays
from ..equations import weights

# A single ray closer to the vertical than this (|r_xy| / |r|) cannot place a plan point's height.
_STEEP_RAY = 1e-3


@dataclass(frozen=True)
class PointUnknowns:
    """free (n_pt, 3): the coordinate is an unknown; weight (n_pt, 3): 1/sigma^2 of a weighted
    control coordinate, 0 elsewhere; given (n_pt, 3): given coordinates in the reduced frame (0 where
    not given); held (n_pt, 3): given and held fixed; included (n_pt,): the point takes part."""

    free: np.ndarray
    weight: np.ndarray
    given: np.ndarray
    held: np.ndarray
    included: np.ndarray

    @property
    def n_unknowns(self) -> int:
        return int(self.free[self.included].sum())

    @property
    def n_control_observations(self) -> int:
        return int(np.count_nonzero(self.weight[self.included] > 0))


def point_unknowns(project: Project, batches: list[GroupBatch], obs: Observations) -> PointUnknowns:
    """Which coordinates are unknowns (module doc). obs: core.observations.observations_of(project, offset)."""
    pts = project.points
    given = pts.given_axes & np.isfinite(pts.xyz_given)
    weighted = given & (obs.q_control > 0)
    held = given & ~weighted
    included = np.zeros(len(pts), dtype=bool)
    for batch in batches:
        included[batch.point_index] = True
    weight = weights.variance_weight(obs.q_control, weighted)
    return PointUnknowns(free=~held, weight=weight, given=np.where(given, obs.control, 0.0), held=held,
                         included=included)


def initial_points(batches: list[GroupBatch], state: State, obs: Observations, unknowns: PointUnknowns,
                   chunk_size: int, approx: np.ndarray | None = None) -> np.ndarray:
    """Starting coordinates (n_pt, 3), reduced frame, nan for points that take no part.

    Given coordinates (held or weighted) start at their given values; then approximate
    coordinates (approx, reduced frame, nan = none: ObjectPoints.xyz_approx). The others: the
    least-squares intersection of the point's rays from the approximate orientations
    (triangulation.intersect_rays) when it has two or more; for a plan point on one photo, the
    point of its ray nearest the vertical through the given X, Y (or, for a ray too close to the
    vertical, the ray at the median height of the other points).
    """
    n_pt = len(unknowns.free)
    xyz = np.full((n_pt, 3), np.nan)
    given_any = unknowns.held | (unknowns.weight > 0)
    single = []
    for batch in batches:
        for chunk in batch.chunks(chunk_size):
            xyz_centre, r = _rays(chunk, state, obs)
            pt = chunk.point_index
            if chunk.k >= 2:  # a padded batch (bundle.padding): its real rays only
                xyz_ground = intersect_rays(xyz_centre, r, mask=getattr(chunk, "real", None))
            else:
                xyz_ground = np.full((len(pt), 3), np.nan)
                single.append((chunk, xyz_centre[:, 0], r[:, 0]))
            if approx is not None:
                xyz_ground = np.where(np.isfinite(approx[pt]).all(axis=1)[:, None], approx[pt], xyz_ground)
            xyz[pt] = np.where(given_any[pt], unknowns.given[pt], xyz_ground)
    if single:
        z_known = xyz[:, 2][np.isfinite(xyz[:, 2])]
        z_fallback = float(np.median(z_known)) if len(z_known) else 0.0
        for chunk, xyz_centre0, r0 in single:
            pt = chunk.point_index
            xyz[pt, 2] = np.where(np.isfinite(xyz[pt, 2]), xyz[pt, 2],
                                  _height_on_ray(xyz_centre0, r0, xyz[pt, :2], z_fallback))
    return xyz


def _rays(chunk: GroupBatch, state: State, obs: Observations):
    """Projection centres and ground rays (Schmid 11) of a chunk's measurements: (m, k, 3) each."""
    ph = chunk.photo_index
    params, conv = state.camera_terms(ph)
    xy = ideal_xy(obs.plate[chunk.image_rows], params, conv)
    return state.xyz0[ph], ray_ground(state.R_ground_from_cam[ph], xy, params[..., :3])


def _height_on_ray(xyz_centre, r0, xy_given, z_fallback: float) -> np.ndarray:
    """Z of the point of the ray O + t r0 nearest the vertical through xy_given; the ray's height
    at z_fallback where the ray is too steep for that. xyz_centre (O), r0: (m, 3); xy_given: (m, 2)
    -> (m,)."""
    d2 = np.sum(r0[:, :2] ** 2, axis=1)
    steep = d2 < (_STEEP_RAY**2) * np.sum(r0**2, axis=1)
    t = np.einsum("mi,mi->m", xy_given - xyz_centre[:, :2], r0[:, :2]) / np.where(steep, 1.0, d2)
    z = xyz_centre[:, 2] + t * r0[:, 2]
    return np.where(steep | ~(t > 0), z_fallback, z)
