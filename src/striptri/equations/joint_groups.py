"""Observed distances in the conditions form: the point groups joined by distances (issue 17).

A distance between the points a and b (distances.csv, bundle.distances.Distances) is the condition

    g = |X_a - X_b| - (d + v_d) = 0

on the points as their groups define them (DESIGN section 3): for a point of rays (tie, check,
height or plan point of k >= 2 rays) the closest approach of its first pair, ``O_1 + s r_1``
(conditions.first_pair_intersection, the intersection Schmid's height and plan point conditions 18-19
use); for a full control point its given coordinates plus their residuals (held: constants). The
condition shares observations with both groups, so the groups of the points that the distances
connect (a connected component of the distance graph) become one *joint group*: the conditions of
each member point plus one condition per distance, over the union of the members' observations and
the distances, with the full ``M = A Q A^T`` of the joint group. Count: two points of k_a and k_b
rays with 2 k_a + 2 k_b + 1 observations and 6 point unknowns give (2 k_a - 3) + (2 k_b - 3) + 1
conditions. At convergence every condition holds, so the adjustment is the bundle's with the
distances (tested).

Joint groups are few (scale bars): the member points are linearised by shape, vectorised, as the
other groups (linearise.linearise on sub-batches of their batches), and the joint groups are then
formed one component at a time (small dense matrices). Everything else keeps its batches: the
member points are taken out of them (:func:`JointGroups.of` returns the batches left).

Used by the method of conditions (conditions_method.adjust: assembly, back substitution, final
checks) and, for both methods, by precision (the residual cofactors: redundancy numbers and w-tests
of the distances and of the joined points' plate coordinates, and the points' precision).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .conditions import first_pair_intersection
from ..errors import InputError
from .groups import COLLINEARITY, GroupBatch
from .linearise import At, evaluate, linearise, unknown_blocks
from .observations import observations_of
from .groups import adjusted_kind, build_batches, rays_per_point
from ..model import FULL, Project
from .triangulation import ray_terms
from . import weights
from .point_precision import orientation_part

FILE_NAME = "distances.csv"


def has_distances(project: Project) -> bool:
    return project.distances is not None and len(project.distances) > 0


def check_distance_points(project: Project) -> None:
    """InputError (distances.csv, the line) for a distance to a point that does not define a point
    in the adjustment: a point measured on fewer than two photos unless it is a full control point
    measured on at least one (a single ray fixes no point; a full control point with no ray takes
    no part in the adjustment). The same rule for both methods."""
    if not has_distances(project):
        return
    dist = project.distances
    rays = rays_per_point(project)
    full = adjusted_kind(project.points.kind) == FULL
    ok = (rays >= 2) | (full & (rays >= 1))
    bad = np.flatnonzero(~ok[dist.point_from] | ~ok[dist.point_to])  # the first one is named
    for i in bad[:1]:
        for p in (dist.point_from[i], dist.point_to[i]):
            if ok[p]:
                continue
            pid = project.points.ids[p]
            what = (f"full control point {pid} is measured on no photo" if full[p] else
                    f"point {pid} is measured on {int(rays[p])} photo{'' if rays[p] == 1 else 's'}")
            line = None if dist.line is None else int(dist.line[i])
            raise InputError(FILE_NAME if project.source is None else Path(project.source) / FILE_NAME, line, f"{what}: a distance needs both its points in the adjustment "
                                              "(a tie, height or plan point on two photos or more, or a full "
                                              "control point on at least one)")


@dataclass(frozen=True)
class Component:
    """One joint group. members: (n,) global member numbers (JointGroups.member_*); distances: (r,)
    rows of Project.distances; ends: (r, 2) the member positions (0..n-1) of each distance's from
    and to point. Observation layout: each member's (2k plate, then 3 control for control points,
    as linearise) in member order, then the r distances; columns likewise each member's."""

    members: np.ndarray
    distances: np.ndarray
    ends: np.ndarray


@dataclass
class JointSystem:
    """The linearised joint group (DESIGN section 4, one group): A (nc, no), B (nc, nu), cols (nu,)
    global columns (-1 fixed), w, g (nc,), Q, l, l_hat (no,); photo_index (K,) the photos of the
    members' rays (each member's in chain order: B has 6 + camera_width columns per ray);
    plate_pos/plate_target: positions in the observation vector and flat indices into the (m_ip, 2)
    plate table; control_pos/control_target likewise into (n_pt, 3); distance_pos (r,) the
    distances' positions in it; point_index (n,) the member points; xyz (n, 3) the members as their
    groups define them, with dX_dl (n, 3, no) and dX_dx (n, 3, nu); member_rays: (n,) the image
    rows of each member in chain order. The last r rows of A, B, w, g are the distance conditions."""

    component: Component
    A: np.ndarray
    B: np.ndarray
    cols: np.ndarray
    w: np.ndarray
    g: np.ndarray
    Q: np.ndarray
    l: np.ndarray
    l_hat: np.ndarray
    photo_index: np.ndarray
    plate_pos: np.ndarray
    plate_target: np.ndarray
    control_pos: np.ndarray
    control_target: np.ndarray
    distance_pos: np.ndarray
    point_index: np.ndarray
    xyz: np.ndarray
    dX_dl: np.ndarray
    dX_dx: np.ndarray
    member_rays: list  # (n,) image rows of each member in chain order

    @property
    def n_conditions(self) -> int:
        return self.A.shape[0]


class JointGroups:
    """The joint groups of a project (module doc): ``JointGroups.of(project, batches)`` -> (the
    batches without the member points, JointGroups or None without distances)."""

    def __init__(self, project: Project, member_batches: list[GroupBatch], member_of: np.ndarray,
                 components: list[Component]):
        self.project = project
        self.member_batches = member_batches  # sub-batches of the member points, by shape
        self.member_of = member_of  # (n_members, 2): (sub-batch, row) of each member
        self.components = components
        self.member_point = np.array([member_batches[b].point_index[i] for b, i in member_of], dtype=int)
        self.n_conditions = int(sum(member_batches[b].n_conditions for b, _ in member_of) + len(project.distances))

    @staticmethod
    def of(project: Project, batches: list[GroupBatch]):
        if not has_distances(project):
            return batches, None
        check_distance_points(project)
        dist = project.distances
        ends = np.unique(np.concatenate([dist.point_from, dist.point_to]))
        is_end = np.zeros(len(project.points), dtype=bool)
        is_end[ends] = True
        rest, members, member_of = [], [], []
        for b in batches:
            pick = is_end[b.point_index]
            if not pick.any():
                rest.append(b)
                continue
            if not pick.all():
                rest.append(_sub(b, ~pick))
            members.append(_sub(b, pick))
            member_of += [(len(members) - 1, i) for i in range(int(pick.sum()))]
        member_of = np.array(member_of, dtype=int).reshape(-1, 2)
        member_point = np.array([members[b].point_index[i] for b, i in member_of], dtype=int)
        return rest, JointGroups(project, members, member_of, distance_components(project, member_point))

    def systems(self, at, distance_hat, scale_form: str = "3d", transform=None) -> list[JointSystem]:
        """The linearised joint groups at (l^, x^) (module doc; DESIGN section 4): the members'
        own conditions as linearise forms them (scaled to unit variance), then one row per
        distance ``g = |X_a - X_b| - d^`` scaled likewise; ``w = g + A (l - l^)``.
        at: linearise.At, where; distance_hat: (r,) the adjusted distances d + v_d (the observed ones
        at the start)."""
        state, layout, rotation_maps, obs, plate_hat, control_hat = at
        per_batch = []
        for sub in self.member_batches:
            s = linearise(sub, at, scale_form, transform)
            X, dXl, dXx = _points(sub, s, state, layout, rotation_maps, plate_hat, control_hat, obs.plate)
            per_batch.append((s, X, dXl, dXx))
        dist = self.project.distances
        return [self._system(c, per_batch, dist, distance_hat) for c in self.components]

    def _system(self, comp: Component, per_batch, dist, distance_hat) -> JointSystem:
        parts = []  # per member: (A, B, cols, g, Q, l, l_hat, X, dXl, dXx, batch)
        for m in comp.members:
            b, i = self.member_of[m]
            s, X, dXl, dXx = per_batch[b]
            parts.append((s.A[i], s.B[i], s.cols[i], s.g[i], s.Q[i], s.l[i], s.l_hat[i], X[i], dXl[i], dXx[i],
                          self.member_batches[b], i))
        n, r = len(parts), len(comp.distances)
        no_m = [p[0].shape[1] for p in parts]
        nu_m = [p[1].shape[1] for p in parts]
        nc_m = [p[0].shape[0] for p in parts]
        o_off = np.concatenate([[0], np.cumsum(no_m)])
        u_off = np.concatenate([[0], np.cumsum(nu_m)])
        c_off = np.concatenate([[0], np.cumsum(nc_m)])
        no, nu, nc = int(o_off[-1]) + r, int(u_off[-1]), int(c_off[-1]) + r
        A, B = np.zeros((nc, no)), np.zeros((nc, nu))
        g, Q, l, l_hat = np.zeros(nc), np.zeros(no), np.zeros(no), np.zeros(no)
        dX_dl, dX_dx, xyz = np.zeros((n, 3, no)), np.zeros((n, 3, nu)), np.zeros((n, 3))
        plate_pos, plate_target, control_pos, control_target, photos, rays, points = [], [], [], [], [], [], []
        for j, (Aj, Bj, cj, gj, Qj, lj, lhj, Xj, dXlj, dXxj, batch, i) in enumerate(parts):
            so, su, sc = slice(o_off[j], o_off[j + 1]), slice(u_off[j], u_off[j + 1]), slice(c_off[j], c_off[j + 1])
            A[sc, so], B[sc, su], g[sc] = Aj, Bj, gj
            Q[so], l[so], l_hat[so] = Qj, lj, lhj
            dX_dl[j, :, so], dX_dx[j, :, su], xyz[j] = dXlj, dXxj, Xj
            k = batch.k
            plate_pos.append(o_off[j] + np.arange(2 * k))
            plate_target.append((2 * batch.image_rows[i][:, None] + np.arange(2)).ravel())
            if batch.has_control:
                control_pos.append(o_off[j] + 2 * k + np.arange(3))
                control_target.append(3 * batch.point_index[i] + np.arange(3))
            photos.append(batch.photo_index[i])
            rays.append(batch.image_rows[i])
            points.append(batch.point_index[i])
        cols = np.concatenate([p[2] for p in parts])
        # the distance conditions
        ia, ib = comp.ends[:, 0], comp.ends[:, 1]
        delta = xyz[ia] - xyz[ib]
        length = np.linalg.norm(delta, axis=1)
        u = delta / length[:, None]
        rows = c_off[-1] + np.arange(r)
        dpos = o_off[-1] + np.arange(r)
        d_hat = distance_hat[comp.distances]
        A_d = np.einsum("ri,rio->ro", u, dX_dl[ia]) - np.einsum("ri,rio->ro", u, dX_dl[ib])
        A_d[np.arange(r), dpos] = -1.0
        B_d = np.einsum("ri,riu->ru", u, dX_dx[ia]) - np.einsum("ri,riu->ru", u, dX_dx[ib])
        Q[dpos], l[dpos], l_hat[dpos] = dist.sigma[comp.distances] ** 2, dist.distance[comp.distances], d_hat
        g_d = length - d_hat
        scale = weights.inverse_sigma((A_d * A_d) @ Q)
        A[rows], B[rows], g[rows] = A_d * scale[:, None], B_d * scale[:, None], g_d * scale
        w = g + A @ (l - l_hat)
        cat = lambda x: np.concatenate(x) if x else np.zeros(0, dtype=int)  # noqa: E731
        return JointSystem(comp, A, B, cols, w, g, Q, l, l_hat, np.concatenate(photos), cat(plate_pos),
                           cat(plate_target), cat(control_pos), cat(control_target), dpos, np.array(points),
                           xyz, dX_dl, dX_dx, rays)


def distance_components(project: Project, member_point: np.ndarray) -> list[Component]:
    """The joint groups of a project with distances: the connected components of the distance graph
    over ``member_point`` (n,), indices into project.points holding every end of a distance; the
    components' members are positions in member_point (Component). Used by JointGroups.of and by the
    point datum (point_datum), whose datum points are intersected jointly likewise."""
    dist = project.distances
    slot = np.full(len(project.points), -1)
    slot[member_point] = np.arange(len(member_point))
    a, c = slot[dist.point_from], slot[dist.point_to]
    if (a < 0).any() or (c < 0).any():  # check_distance_points lets no such point through
        raise ValueError("a distance point without a group")
    n = len(member_point)
    graph = coo_matrix((np.ones(len(a)), (a, c)), shape=(n, n))
    n_comp, label = connected_components(graph, directed=False)
    components = []
    for k in range(n_comp):
        mem = np.flatnonzero(label == k)
        pos = np.full(n, -1)
        pos[mem] = np.arange(len(mem))
        rows = np.flatnonzero(label[a] == k)
        components.append(Component(mem, rows, np.stack([pos[a[rows]], pos[c[rows]]], 1)))
    return components


def _sub(b: GroupBatch, pick: np.ndarray) -> GroupBatch:
    return GroupBatch(b.family, b.k, b.given_axes, b.point_index[pick], b.image_rows[pick], b.photo_index[pick],
                      b.n_conditions, b.star)


def _points(sub: GroupBatch, s, state, layout, rotation_maps, plate_hat, control_hat, plate_measured):
    """X (m, 3) of the member points of a sub-batch as their groups define them (module doc), with
    dX/dl (m, 3, no) over the group's observations (linearise's order) and dX/dx (m, 3, nu) over
    its columns (s.cols)."""
    m, no = s.Q.shape
    nu = s.B.shape[2]
    if sub.family == COLLINEARITY:  # full control: the given coordinates plus their residuals
        dXl = np.zeros((m, 3, no))
        dXl[:, :, 2 * sub.k:] = np.eye(3)
        return control_hat[sub.point_index], dXl, np.zeros((m, 3, nu))
    lin = evaluate(sub, state, plate_hat, control_hat, with_lens=layout.lens_in_play(state),
                   plate_measured=plate_measured, ray_function=first_pair_intersection)
    dXl = np.zeros((m, 3, no))
    dXl[:, :, : 2 * sub.k] = lin.d_plate.reshape(m, 3, 2 * sub.k)
    B, _ = unknown_blocks(lin, sub, state, layout, rotation_maps)
    return lin.g, dXl, B


def whiten_joint(js: JointSystem):
    """L^-1 B, L^-1 w, L^-1 g and L^-1 A Q of a joint group (normal_equations.whiten for one group)."""
    AQ = js.A * js.Q[None, :]
    M = AQ @ js.A.T
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    return Linv @ js.B, Linv @ js.w, Linv @ js.g, Linv @ AQ


def joint_point_precision(project: Project, result, tri):
    """Schmid's (90) precision of the points joined by distances, as one intersection per joint group
    (module doc): with the orientation held the member points are intersected together from their
    adjusted rays, their weighted given coordinates and the distances, ``Qm = (J^T P J + P_given +
    J_d^T P_d J_d)^-1`` over their free coordinates (3n at most), and the orientation part is
    ``G Qxx G^T`` with ``G = -Qm J^T P J_x`` (the same two parts triangulation.triangulate forms
    per point; the distance rows do not depend on the orientation). This is the bundle's point
    covariance with the distances (the block of the points in the inverse of its normals).

    tri: triangulation.Triangulated of the adjusted result with its orientation part
    (adjusted_points.triangulate_adjusted); returns it with the members' cov_measurement and
    cov_orientation replaced by the diagonal 3x3 blocks of the joint form (unchanged without distances)."""
    return joint_point_blocks(project, result, tri)[0]


def joint_point_blocks(project: Project, result, tri):
    """:func:`joint_point_precision` and the joint groups it formed: (tri, the (JointSystem,
    JointIntersection) pairs of joint_intersections; empty without distances). The point datum
    needs the cross blocks between the members (point_datum.points_correction)."""
    if not has_distances(project):
        return tri, []
    cov_m, cov_o = tri.cov_measurement.copy(), tri.cov_orientation.copy()
    lay, state = result.layout, result.state
    pairs = joint_intersections(project, result, tri.xyz)
    for js, inter in pairs:
        photo = js.photo_index[None]
        GQG = orientation_part(inter.G.reshape(1, len(inter.G), len(js.photo_index), -1), photo,
                               state.camera_of_photo[photo], lay.photo_cols, lay.camera_cols[:, lay.camera_elements],
                               result.covariance.group_forms)[0]
        for j, p in enumerate(js.point_index):
            sl = slice(3 * j, 3 * j + 3)
            cov_m[p], cov_o[p] = inter.Qm[sl, sl], GQG[sl, sl]
    return replace(tri, cov_measurement=cov_m, cov_orientation=cov_o), pairs


@dataclass(frozen=True)
class JointIntersection:
    """The member points of a joint group intersected together with the orientation held (module
    doc): Qm (3n, 3n) their measurement cofactors (zero rows and columns for held coordinates), F
    (3n, no) = dX/dl over the joint group's observations and G (3n, nu) = dX/dx over its columns
    (JointSystem's orders)."""

    Qm: np.ndarray
    F: np.ndarray
    G: np.ndarray


def joint_intersections(project: Project, result, xyz: np.ndarray, scale_form: str = "3d"):
    """(JointSystem at the result, JointIntersection) of every joint group; xyz (n_pt, 3) the
    adjusted points (reduced frame), where the distance rows are linearised. scale_form: the
    adjustment's (core.options.ConditionsOptions.scale_form)."""
    _, joint = JointGroups.of(project, build_batches(project))
    obs = observations_of(project, result.offset)
    lay, state, ip = result.layout, result.state, project.image_points
    at = At.of(state, lay, obs, result.plate_adjusted, result.control_adjusted)
    T_all = at.rotation_maps
    systems = joint.systems(at, project.distances.distance, scale_form)
    given, q_control, dist = project.points.given_axes, obs.q_control, project.distances
    out = []
    for js in systems:
        pts = js.point_index
        n, no, nu = len(pts), len(js.Q), len(js.cols)
        N = np.zeros((3 * n, 3 * n))
        R = np.zeros((3 * n, no))  # the right-hand side's map from the observations: X = Qm R l
        Nx = np.zeros((3 * n, nu))
        o_plate, u = 0, 0
        width = nu // len(js.photo_index)
        for j, (p, rows) in enumerate(zip(pts, js.member_rays)):
            k = len(rows)
            ph = ip.photo_index[rows]
            params, conv = state.camera_terms(ph[None])
            _, dX, dO, drot, dcam = ray_terms(state.R_ground_from_cam[ph][None], state.xyz0[ph][None], params, conv,
                                              xyz[p][None], result.plate_adjusted[rows][None], ip.xy[rows][None],
                                              lay.lens_in_play(state))
            J_parts = [dO[0], np.einsum("kai,kij->kaj", drot[0], T_all[ph])]
            if lay.camera_width:
                J_parts.append(dcam[0][..., lay.camera_elements])
            J_x = np.concatenate(J_parts, 2)  # (k, 2, width): the columns of js.cols, ray by ray
            sl = slice(3 * j, 3 * j + 3)
            JX = dX[0].reshape(2 * k, 3)
            PJ = weights.weigh(JX, ip.sigma_xy[rows].reshape(2 * k, 1))
            N[sl, sl] += JX.T @ PJ
            R[sl, js.plate_pos[o_plate:o_plate + 2 * k]] = PJ.T
            Nx[sl, u:u + k * width] = _ray_block(PJ, J_x)
            o_plate += 2 * k
            u += k * width
            here = js.control_target // 3 == p
            if here.any():
                qc = q_control[p]
                pc = weights.variance_weight(qc, given[p] & (qc > 0))
                N[sl, sl] += np.diag(pc)
                R[sl, js.control_pos[here]] = np.diag(pc)[:, js.control_target[here] % 3]
        for e, (a, b), o in zip(js.component.distances, js.component.ends, js.distance_pos):
            d = xyz[pts[a]] - xyz[pts[b]]
            d /= np.linalg.norm(d)
            Jd = np.zeros(3 * n)
            Jd[3 * a:3 * a + 3], Jd[3 * b:3 * b + 3] = d, -d
            N += weights.weigh(np.outer(Jd, Jd), dist.sigma[e])
            R[:, o] = weights.weigh(Jd, dist.sigma[e])
        free = ~(given[pts] & (q_control[pts] == 0)).ravel()
        Qm = np.zeros((3 * n, 3 * n))
        Qm[np.ix_(free, free)] = np.linalg.inv(N[np.ix_(free, free)])
        out.append((js, JointIntersection(Qm, Qm @ R, -Qm @ Nx)))
    return out


def _ray_block(PJ: np.ndarray, J_x: np.ndarray) -> np.ndarray:
    """(3, k width): J_X^T P J_x of one point's k rays, ray by ray in the columns (PJ (2k, 3) = P J_X,
    J_x (k, 2, width))."""
    k, _, width = J_x.shape
    return np.einsum("kai,kaw->ikw", PJ.reshape(k, 2, 3), J_x).reshape(3, k * width)
