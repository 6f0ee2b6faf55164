"""The full covariance of chosen parameter groups, for downstream work, and its S-transformation to
another datum (issue 17).

Groups (GROUPS): ``photos`` (per photo X0, Y0, Z0 and the three angles of the project's rotation
convention), ``camera`` (the estimated camera elements), ``points`` (X, Y, Z of every determined
object point). Their joint cofactor matrix, in units of the a-priori variances, is

    Q = [[T Qxx T^T, T Qxx G^T], [G Qxx T^T, G Qxx G^T + diag(Qm_i)]]

with Qxx = N^-1 of the unknowns (result.covariance), T the map from the unknowns to the photo and
camera elements (the angle Jacobian J T of rotations.angles_jacobian for the angles), and per point
``G_i = -Qm_i J_X^T P J_x`` the derivative of the point intersected from its adjusted rays with the
orientation held (Schmid 87-90, as striptri.equations.triangulation forms its blocks) and Qm_i its measurement
part (in the point datum plus the orientation's covariance with the datum points' own measurements,
point_datum.export_correction). The points share nothing through their own measurements, so the measurement parts are
block-diagonal (per point, or per joint group of points joined by distances: joint_groups); every other cross term
comes through Qxx. Multiplied by sigma0^2 a posteriori
(``sigma0_for_precision``) it is the covariance; its diagonal blocks are photos.csv's, cameras.csv's
and points.csv's mean errors squared (tested).

S-transformation (Baarda 1973): to the datum of chosen *datum points* D,
``Q' = S Q S^T``, ``S = I - H (H^T W H)^-1 H^T W``, H the columns of an infinitesimal similarity
transformation of the exported parameters (3 translations, 3 rotations, the scale: for a point or
a centre ``[I, [w]x X, X]`` about the centroid of D, for angles ``J R^T`` of the rotation, nothing
for the camera) and W selecting the coordinates of D. Afterwards the datum points carry inner
constraints (``H_D^T Q'_D = 0``): their mean errors are minimal and the others are relative to them.
Quantities invariant under the transformation keep their mean errors: under a similarity (7
columns) ratios of distances and angles, under a rigid motion (6, ``scale=False``: the scale is the
measurements', e.g. scale bars) distances too.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ..core.adjusted_points import triangulate_adjusted
from ..core.result import AdjustmentResult
from ..equations.joint_groups import has_distances, joint_intersections
from ..geometry.lens import CAMERA_ELEMENTS
from ..model import Project
from ..equations.point_datum import JointBlock, export_correction
from ..geometry.rotations import R_from_angles, angles_from_R, angles_jacobian, skew
from ..equations.triangulation import Triangulated, ray_terms
from ..equations import weights
from ..core.runs import GROUPS, CovarianceRequest

MAX_PARAMETERS = 20_000  # a dense matrix of this order is 3.2 GB: beyond it the export is refused


@dataclass(frozen=True)
class CovarianceExport:
    """labels: (n,) "<group>/<id>/<element>"; values: (n,) the adjusted values (ground frame, angles
    in radians in ``convention``); cov: (n, n) covariance (sigma0^2 Q); H: (n, 7) similarity
    columns (about ``centre``); datum: "adjustment" or the datum point ids after an S-transformation."""

    labels: list[str]
    values: np.ndarray
    cov: np.ndarray
    H: np.ndarray
    centre: np.ndarray
    sigma0: float
    convention: str
    datum: tuple[str, ...] | str = "adjustment"
    crs: str = ""

    def point_rows(self, point_id: str) -> list[int]:
        """The rows of point ``point_id``'s X, Y, Z (ValueError when it is not exported)."""
        return [self.labels.index(f"points/{point_id}/{axis}") for axis in "XYZ"]

    def distance(self, p1: str, p2: str) -> tuple[float, np.ndarray]:
        """|X_p1 - X_p2| (m) and its gradient f (n,) over the labels: the distance's mean error is
        ``sqrt(f^T cov f)``, the points' cross-covariance included."""
        i, j = self.point_rows(p1), self.point_rows(p2)
        d = self.values[i] - self.values[j]
        length = float(np.linalg.norm(d))
        f = np.zeros(len(self.labels))
        f[i], f[j] = d / length, -d / length
        return length, f

    def npz_bytes(self) -> bytes:
        """covariance.npz (docs/file-formats.md)."""
        buf = io.BytesIO()
        np.savez(buf, labels=np.array(self.labels), values=self.values, covariance=self.cov,
                 sigma0=np.float64(self.sigma0), convention=np.array(self.convention),
                 datum=np.array(self.datum if isinstance(self.datum, str) else ",".join(self.datum)),
                 crs=np.array(self.crs))
        return buf.getvalue()


def _joint_points(project: Project, result: AdjustmentResult, tri: Triangulated, points: np.ndarray, n: int) -> list:
    """Per joint group of points joined by distances (joint_groups.joint_intersections) whose
    members are all exported: (rows (3n_m,) of G among the exported points' rows, G (3n_m, n) over
    the unknowns, Qm (3n_m, 3n_m) the members' joint measurement part). Empty without distances."""
    if not has_distances(project) or not len(points):
        return []
    slot = np.full(len(project.points), -1)
    slot[points] = np.arange(len(points))
    out = []
    for js, inter in joint_intersections(project, result, tri.xyz):
        where = slot[js.point_index]
        if (where < 0).any():
            continue
        G = np.zeros((len(inter.G), n + 1))
        np.add.at(G, (slice(None), np.where(js.cols >= 0, js.cols, n)), inter.G)
        out.append(((3 * where[:, None] + np.arange(3)).ravel(), G[:, :n], inter.Qm))
    return out


def _point_gradients(project: Project, result: AdjustmentResult, tri: Triangulated, points: np.ndarray) -> np.ndarray:
    """G (len(points), 3, n_unknowns): d(point)/d(unknowns) with the adjusted rays held (module doc)."""
    s, layout, ip = result.state, result.layout, project.image_points
    n = result.n_unknowns
    slot = -np.ones(len(project.points), dtype=int)
    slot[points] = np.arange(len(points))
    rows = np.flatnonzero(slot[ip.point_index] >= 0)
    G = np.zeros((len(points), 3, n + 1))  # column n: the sink of held elements (index -1)
    if not len(rows):
        return G[:, :, :n]
    ph, pt = ip.photo_index[rows], ip.point_index[rows]
    params, conv = s.camera_terms(ph)
    _, dX, dO, drot, dint = ray_terms(s.R_ground_from_cam[ph][:, None], s.xyz0[ph][:, None], params[:, None],
                                      conv[:, None], tri.xyz[pt], result.plate_adjusted[rows][:, None],
                                      ip.xy[rows][:, None], with_lens=result.layout.lens_in_play(s))
    dX, dO, drot, dint = dX[:, 0], dO[:, 0], drot[:, 0], dint[:, 0]
    w = weights.weight(ip.sigma_xy[rows])  # (m, 2)
    A = -np.einsum("mij,mkj,mk->mik", tri.cov_measurement[pt], dX, w)  # (m, 3, 2): -Qm J_X^T P
    drot_u = np.einsum("mai,mij->maj", drot, layout.rotation_maps(s)[ph])
    cols = np.concatenate([layout.photo_cols[ph], layout.camera_cols[s.camera_of_photo[ph]]], 1)
    J = np.concatenate([dO, drot_u, dint], 2)  # (m, 2, 6 + NCP)
    contrib = A @ J  # (m, 3, 6 + NCP)
    cols = np.where(cols >= 0, cols, n)
    np.add.at(G, (slot[pt][:, None, None], np.arange(3)[None, :, None], cols[:, None, :]), contrib)
    return G[:, :, :n]


def joint_covariance(project: Project, result: AdjustmentResult, tri: Triangulated, groups=GROUPS,
                     convention: str | None = None) -> CovarianceExport:
    """The covariance of ``groups`` (module doc), in the adjustment's datum."""
    unknown = [g for g in groups if g not in GROUPS]
    if unknown:
        raise ValueError(f"unknown covariance group(s) {', '.join(unknown)}; choose from {', '.join(GROUPS)}")
    convention = convention or project.settings.rotation
    s, layout, n = result.state, result.layout, result.n_unknowns
    labels, values, maps, helmert = [], [], [], []
    xyz0 = s.xyz0 + result.offset
    if "photos" in groups:
        Jang = angles_jacobian(s.R_ground_from_cam, convention)  # (np, 3, 3) of the rotation vector
        T = layout.rotation_maps(s)
        from_rot = Jang @ T
        ang = angles_from_R(s.R_ground_from_cam, convention)
        for k, pid in enumerate(project.photos.ids):
            for a, name in enumerate(("X0", "Y0", "Z0")):
                labels.append(f"photos/{pid}/{name}")
                values.append(xyz0[k, a])
                row = np.zeros(n)
                c = layout.photo_cols[k, a]
                if c >= 0:
                    row[c] = 1.0
                maps.append(row)
                helmert.append(("xyz", xyz0[k], a))
            for a, name in enumerate(_angle_names(convention)):
                labels.append(f"photos/{pid}/{name}")
                values.append(ang[k, a])
                row = np.zeros(n)
                rc = layout.photo_cols[k, 3:]
                row[rc[rc >= 0]] = from_rot[k, a, rc >= 0]
                maps.append(row)
                helmert.append(("angle", Jang[k, a] @ s.R_ground_from_cam[k].T, a))
    if "camera" in groups:
        for j, cid in enumerate(project.cameras.ids):
            for e, name in enumerate(CAMERA_ELEMENTS):
                c = layout.camera_cols[j, e]
                if c < 0:
                    continue
                labels.append(f"camera/{cid}/{name}")
                values.append(s.interior[j, e])
                row = np.zeros(n)
                row[c] = 1.0
                maps.append(row)
                helmert.append(("none", None, 0))
    Tm = np.array(maps).reshape(-1, n)
    points = np.flatnonzero(tri.determined) if "points" in groups else np.zeros(0, dtype=int)
    n_total = len(Tm) + 3 * len(points)
    if n_total > MAX_PARAMETERS:
        raise ValueError(f"a covariance of {n_total} parameters is too large to export (limit {MAX_PARAMETERS}); "
                         "choose fewer groups")
    Qxx = result.covariance.dense() if n else np.zeros((0, 0))
    G = _point_gradients(project, result, tri, points).reshape(3 * len(points), n)
    joint = _joint_points(project, result, tri, points, n)
    for rows, Gj, _ in joint:  # the points joined by distances: intersected together (joint_groups)
        G[rows] = Gj
    F = np.vstack([Tm, G])
    Q = F @ Qxx @ F.T
    in_joint = np.zeros(len(points), dtype=bool)
    for rows, _, Qm in joint:
        in_joint[rows[::3] // 3] = True
        Q[np.ix_(len(Tm) + rows, len(Tm) + rows)] += Qm
    for i in np.flatnonzero(~in_joint):
        k = len(Tm) + 3 * i
        Q[k:k + 3, k:k + 3] += tri.cov_measurement[points[i]]
    fn = result.free_network
    if fn is not None and fn.points is not None and len(points):  # the point datum (point_datum)
        groups = [JointBlock(points[rows[::3] // 3], Qm) for rows, _, Qm in joint]
        Q += export_correction(fn.points, F @ fn.H, len(Tm) + 3 * np.arange(len(points)), tri.cov_measurement, points,
                               groups)
    xyz = tri.xyz[points] + result.offset
    for i, k in enumerate(points):
        for a, name in enumerate("XYZ"):
            labels.append(f"points/{project.points.ids[k]}/{name}")
            values.append(xyz[i, a])
            helmert.append(("xyz", xyz[i], a))
    s0 = result.sigma0_for_precision
    centre = xyz.mean(axis=0) if len(points) else xyz0.mean(axis=0)
    return CovarianceExport(labels=labels, values=np.array(values), cov=s0 * s0 * Q,
                            H=_similarity_columns(helmert, centre), centre=centre, sigma0=s0, convention=convention)


def _angle_names(convention: str) -> tuple[str, ...]:
    """The angles of a convention, in its order: "phi-omega-kappa" -> (phi, omega, kappa)."""
    return tuple(convention.split("-"))


def _similarity_columns(helmert: list, centre: np.ndarray) -> np.ndarray:
    """(n, 7) d(parameter)/d(tx, ty, tz, wx, wy, wz, scale) of an infinitesimal similarity
    transformation of the ground frame about ``centre`` (module doc)."""
    H = np.zeros((len(helmert), 7))
    for i, (kind, what, a) in enumerate(helmert):
        if kind == "xyz":
            v = np.asarray(what) - centre
            H[i, a] = 1.0
            H[i, 3:6] = -skew(v)[a]  # (w x v)_a = -([v]x w)_a
            H[i, 6] = v[a]
        elif kind == "angle":
            H[i, 3:6] = what  # row a of J R^T: Exp(w) R = R Exp(R^T w)
    return H


def s_transform(export: CovarianceExport, datum_points: list[str], scale: bool = True) -> CovarianceExport:
    """The covariance in the datum of ``datum_points`` (module doc): ``S Q S^T`` with
    ``S = I - H (H^T W H)^-1 H^T W``, W = 1 on the datum points' coordinates. scale: H with the
    scale column (a similarity, 7 parameters: the datum points also fix the scale; ratios of
    distances and angles keep their mean errors) or without (a rigid motion, 6: the scale stays the
    measurements', as with scale bars; distances keep their mean errors). ValueError when a datum
    point is not among the exported points or they cannot fix the transformation (fewer than three
    points, or all on a line)."""
    where = {}
    for i, label in enumerate(export.labels):
        group, pid, _ = label.rsplit("/", 2)
        if group == "points":
            where.setdefault(pid, []).append(i)
    missing = [p for p in datum_points if p not in where]
    if missing:
        raise ValueError(f"datum point(s) {', '.join(missing)} are not among the exported points "
                         "(a determined object point, with the group points exported)")
    rows = np.array([i for p in datum_points for i in where[p]], dtype=int)
    # the similarity about the datum points' centroid (better conditioned; S does not depend on it)
    xyz = export.values[rows].reshape(-1, 3)
    H = export.H.copy()
    shift = xyz.mean(axis=0) - export.centre
    xyz_rows = np.flatnonzero(np.abs(export.H[:, :3]).sum(axis=1) > 0)
    # moving the centre by `shift` changes v to v - shift: rotation and scale columns adjust
    for i in xyz_rows:
        a = int(np.argmax(export.H[i, :3]))
        H[i, 3:6] = export.H[i, 3:6] + skew(shift)[a]
        H[i, 6] = export.H[i, 6] - shift[a]
    H = H if scale else H[:, :6]
    HD = H[rows]
    M = HD.T @ HD
    if len(datum_points) < 3 or np.linalg.matrix_rank(M, tol=1e-10 * np.abs(M).max()) < H.shape[1]:
        raise ValueError("the datum points must be at least three points not on a line (they fix translation, "
                         "rotation and scale)")
    S = np.eye(len(H)) - H @ np.linalg.solve(M, HD.T) @ np.eye(len(H))[rows]
    cov = S @ export.cov @ S.T
    H_all = export.H.copy()
    H_all[:, :H.shape[1]] = H
    return CovarianceExport(labels=export.labels, values=export.values, cov=0.5 * (cov + cov.T), H=H_all,
                            centre=xyz.mean(axis=0), sigma0=export.sigma0, convention=export.convention,
                            datum=tuple(datum_points))


def in_grid(export: CovarianceExport, frame) -> CovarianceExport:
    """The export of a project in map coordinates (adjusted in the local frame ``frame``, a
    crs.frame.LocalFrame) in its CRS: ``values`` grid E, N, H and the angles of the grid frame,
    ``cov = F cov F^T`` with F the block-diagonal derivative of the grid values by the local ones
    (LocalFrame.point_jacobian_to_grid per point, photo_jacobian_to_grid per photo, the camera
    unchanged), ``H = F H`` (the local frame's similarity seen in grid values). An S-transformation
    belongs before this: the similarity is one of the Cartesian local frame."""
    group, ident, element = (np.array(x) for x in zip(*(label.rsplit("/", 2) for label in export.labels)))
    n = len(export.labels)
    rows, cols, vals = [np.arange(n)], [np.arange(n)], [np.ones(n)]
    values = export.values.copy()
    photo = np.flatnonzero((group == "photos") & (element == "X0"))  # X0, Y0, Z0, three angles
    point = np.flatnonzero((group == "points") & (element == "X"))  # X, Y, Z
    blocks = []
    if len(photo):
        at = photo[:, None] + np.arange(6)
        xyz, ang = values[at[:, :3]], values[at[:, 3:]]
        R = R_from_angles(ang, export.convention)
        blocks.append((at, frame.photo_jacobian_to_grid(xyz, R, export.convention)))
        values[at[:, 3:]] = angles_from_R(frame.rotations_to_grid(xyz, R), export.convention)
        values[at[:, :3]] = frame.from_local(xyz)
    if len(point):
        at = point[:, None] + np.arange(3)
        blocks.append((at, frame.point_jacobian_to_grid(values[at])))
        values[at] = frame.from_local(values[at])
    for at, J in blocks:
        rows[0][at.ravel()] = -1  # these rows come from the blocks
        k = at.shape[1]
        rows.append(np.repeat(at, k, axis=1).ravel())
        cols.append(np.tile(at, (1, k)).ravel())
        vals.append(J.ravel())
    keep = rows[0] >= 0
    rows[0], cols[0], vals[0] = rows[0][keep], cols[0][keep], vals[0][keep]
    F = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    cov = F @ (F @ export.cov).T
    return replace(export, values=values, cov=0.5 * (cov + cov.T), H=F @ export.H, crs=frame.settings.crs)


def covariance_file(project: Project, result: AdjustmentResult, request: CovarianceRequest, frame=None) -> bytes:
    """covariance.npz of ``request`` (docs/file-formats.md) for the adjusted ``project`` (the rows
    the adjustment kept). The points are intersected again for their measurement parts (points.csv's
    may hold the joint form (92) instead). frame: the crs.frame.LocalFrame of a project in map
    coordinates (``project`` then in that frame): S-transformed there, then written in the CRS
    (:func:`in_grid`). ValueError for what cannot be done."""
    export = joint_covariance(project, result, triangulate_adjusted(project, result), request.groups)
    if request.datum_points:
        export = s_transform(export, list(request.datum_points), request.scale)
    return (export if frame is None else in_grid(export, frame)).npz_bytes()
