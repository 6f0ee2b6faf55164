"""Spatial resection: the orientation of one photograph from known ground points (approximations
for close-range projects that come without them, e.g. DBAT's camera calibration).

A closed-form start, then Gauss-Newton on the collinearity equations (Schmid 14):

* coplanar points (a calibration sheet): the plane-to-plate homography ``H ~ R^T [e1 e2 X0 - O]``
  from the direct linear transformation, split into the rotation and the centre (Zhang 2000);
* points in general position (six or more): the 3 x 4 direct linear transformation
  ``P ~ R^T [I | -O]``, its left 3 x 3 block made a rotation by the polar decomposition.

Plate coordinates are ideal (striptri.geometry.lens.ideal_from_observed) and reduced to the principal
point; the camera looks down its -z axis (DESIGN section 1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry.camera import ray_ground
from ..geometry.collinearity import camera_from_ground, collinearity_jacobians, plate_from_ground
from ..errors import NumericalFailure
from ..geometry.lens import ideal_xy
from ..model import FULL
from ..geometry.rotations import angles_from_R, exp_so3
from .triangulation import intersect_rays


@dataclass(frozen=True)
class Resection:
    """R_ground_from_cam (3, 3), centre (3,), rms: plate residual RMS after refinement, iterations."""

    R: np.ndarray
    centre: np.ndarray
    rms: float
    iterations: int


def _dlt_rows(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rows of the DLT ``dst x (P src) = 0`` for homogeneous src (n, a) and dst (n, 3)."""
    n, a = src.shape
    rows = np.zeros((2 * n, 3 * a))
    rows[0::2, 0:a] = dst[:, 2:3] * src
    rows[0::2, 2 * a:3 * a] = -dst[:, 0:1] * src
    rows[1::2, a:2 * a] = dst[:, 2:3] * src
    rows[1::2, 2 * a:3 * a] = -dst[:, 1:2] * src
    return rows


def _nearest_rotation(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _closed_form(xy: np.ndarray, X: np.ndarray, c: float):
    """(R_ground_from_cam, centre) from the linear solution (module doc)."""
    rays = np.column_stack([xy / c, -np.ones(len(xy))])  # camera-frame directions, z = -1
    centroid = X.mean(axis=0)
    _, s, Vt = np.linalg.svd(X - centroid)
    planar = s[2] <= 1e-3 * s[0]
    if planar:
        e1, e2 = Vt[0], Vt[1]
        e3 = np.cross(e1, e2)
        uv = (X - centroid) @ np.column_stack([e1, e2])
        scale = np.abs(uv).max()
        src = np.column_stack([uv / scale, np.ones(len(X))])
        H = np.linalg.svd(_dlt_rows(src, rays))[2][-1].reshape(3, 3)
        H = H @ np.diag([1 / scale, 1 / scale, 1.0])
        m = src @ np.diag([scale, scale, 1.0]) @ H.T
        if np.median(m[:, 2]) > 0:  # points in front: m_z < 0
            H = -H
        lam = 2.0 / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
        r1, r2, t = lam * H[:, 0], lam * H[:, 1], lam * H[:, 2]
        Rt = _nearest_rotation(np.column_stack([r1, r2, np.cross(r1, r2)]) @ np.vstack([e1, e2, e3]))
        return Rt.T, centroid - Rt.T @ t
    if len(X) < 6:
        raise ValueError("a resection from points in general position needs six of them (four if coplanar)")
    scale = np.abs(X - centroid).max()
    src = np.column_stack([(X - centroid) / scale, np.ones(len(X))])
    P = np.linalg.svd(_dlt_rows(src, rays))[2][-1].reshape(3, 4)
    m = src @ P.T
    if np.median(m[:, 2]) > 0:
        P = -P
    M = P[:, :3] / scale
    Rt = _nearest_rotation(M)
    s = np.trace(Rt.T @ M) / 3.0
    centre = centroid - np.linalg.solve(M, P[:, 3]) if abs(s) > 0 else centroid
    return Rt.T, centre


def resect(xy: np.ndarray, X: np.ndarray, c: float, iterations: int = 20) -> Resection:
    """Orientation of a photo from n >= 4 (coplanar) or >= 6 ground points X (n, 3) measured at ideal
    plate coordinates xy (n, 2) reduced to the principal point, principal distance c.
    Raises ValueError when the points do not determine the orientation."""
    xy, X = np.asarray(xy, dtype=float), np.asarray(X, dtype=float)
    if len(X) < 4:
        raise ValueError(f"a resection needs at least four known points, this photo has {len(X)}")
    R_ground_from_cam, xyz_centre = _closed_form(xy, X, c)
    interior = np.array([c, 0.0, 0.0])
    rms = np.inf
    for it in range(1, iterations + 1):
        jac = collinearity_jacobians(R_ground_from_cam, xyz_centre, interior, X)
        e = (xy - jac.xy_plate).ravel()
        J = np.concatenate([jac.d_centre, jac.d_rotation], -1).reshape(-1, 6)
        dx = np.linalg.lstsq(J, e, rcond=None)[0]
        xyz_centre = xyz_centre + dx[:3]
        R_ground_from_cam = R_ground_from_cam @ exp_so3(dx[3:])
        rms = float(np.sqrt(np.mean(e**2)))
        if np.abs(dx[:3]).max() <= 1e-12 * (1 + np.abs(xyz_centre).max()) and np.abs(dx[3:]).max() <= 1e-12:
            break
    rms = float(np.sqrt(np.mean((xy - plate_from_ground(R_ground_from_cam, xyz_centre, interior, X)) ** 2)))
    if not np.all(np.isfinite(R_ground_from_cam)) or np.any(camera_from_ground(R_ground_from_cam, xyz_centre, X)[:, 2] >= 0):
        raise ValueError("the resection puts some known points behind the camera")
    return Resection(R=R_ground_from_cam, centre=xyz_centre, rms=rms, iterations=it)


def resect_missing(project, max_rounds: int = 50):
    """The project with approximate orientations for the photos that have none (nan centre):
    photos are resected, in rounds, from the full control points and the tie points intersected
    from photos already oriented (two rays or more), as DBAT's spatial_resection and
    forward_intersection do. Measurements are taken through the camera model at the cameras'
    current values. -> (project, notes). Raises NumericalFailure naming the photos left over."""
    ph, ip, pts, cams = project.photos, project.image_points, project.points, project.cameras
    todo = ~np.isfinite(ph.xyz0).all(axis=1)
    if not todo.any():
        return project, []
    cam = ph.camera_index[ip.photo_index]
    params = cams.interior[cam]
    xy = ideal_xy(ip.xy, params, cams.convention[cam]) - params[:, 1:3]
    known = np.where(((pts.kind == FULL) & np.isfinite(pts.xyz_given).all(axis=1))[:, None], pts.xyz_given, np.nan)
    xyz0, R = ph.xyz0.copy(), ph.R_ground_from_cam.copy()
    oriented = ~todo
    done_by_resection = 0
    for _ in range(max_rounds):
        progress = False
        for i in np.flatnonzero(~oriented):
            rows = np.flatnonzero((ip.photo_index == i) & np.isfinite(known[ip.point_index]).all(axis=1))
            try:
                res = resect(xy[rows], known[ip.point_index[rows]], float(cams.interior[ph.camera_index[i], 0]))
            except (ValueError, np.linalg.LinAlgError):
                continue
            xyz0[i], R[i], oriented[i] = res.centre, res.R, True
            done_by_resection += 1
            progress = True
        # intersect the points seen by two or more oriented photos
        use = oriented[ip.photo_index] & ~np.isfinite(known[ip.point_index]).all(axis=1)
        counts = np.bincount(ip.point_index[use], minlength=len(pts))
        for k in np.unique(counts[counts >= 2]):
            sel = np.flatnonzero(counts == k)
            order = np.lexsort((ip.photo_index[use], ip.point_index[use]))
            rows_all = np.flatnonzero(use)[order]
            pt_sorted = ip.point_index[rows_all]
            rows = rows_all[np.isin(pt_sorted, sel)].reshape(len(sel), k)
            p = ip.photo_index[rows]
            c = cams.interior[ph.camera_index[p], 0]
            r = ray_ground(R[p], xy[rows], np.stack([c, np.zeros_like(c), np.zeros_like(c)], -1))
            known[sel] = intersect_rays(xyz0[p], r)
            progress = True
        if oriented.all() or not progress:
            break
    if not oriented.all():
        left = [ph.ids[i] for i in np.flatnonzero(~oriented)]
        raise NumericalFailure(f"no approximate orientation for {len(left)} photos ({', '.join(left[:5])}"
                               f"{', ...' if len(left) > 5 else ''}): they see fewer than four known points "
                               "(coplanar) or six (in general position); give approximate orientations")
    angles = np.where(todo[:, None], angles_from_R(R, project.settings.rotation), ph.angles)
    photos = replace(ph, xyz0=xyz0, R_ground_from_cam=R, angles=angles)
    return replace(project, photos=photos), [f"approximate orientations of {done_by_resection} photos by spatial "
                                             "resection from control and intersected points"]
