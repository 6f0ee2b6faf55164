"""A free network whose inner constraints act on object points (issue 17): ``[datum] mode =
"inner-points"``, ``striptri adjust --datum inner-points [--datum-points P1,P2,...]``.

Datum points D (all object points of the adjustment, or a chosen subset of at least three). With
``H_p`` (3, d) the change of point p under the similarity directions the control leaves free
(datum.FreeDirections: the same coefficients as the photos' H, about the centroid of the
projection centres), the datum is

    sum_{p in D} H_p^T (X_p - X0_p) = 0                                   (d equations)

with X0 the approximations of the points (approx_points.csv, given coordinates, else the
intersection of the measured rays at the approximate orientations) and H at the adjusted points:
the adjusted datum points have no similarity with respect to their approximations (the linearised
Helmert fit of X onto X0 is the identity). The condition is on the final coordinates, not on each
increment, so the datum does not depend on the iteration's path, and the conditions and the bundle
method reach the same one (docs/decisions.md).

The points are eliminated in both methods: ``dX_p = N_pp^-1 (b_p - N_pc dx)`` (the collinearity
blocks of the point's rays, whitened, at the current orientation and point), so the constraint on
the step is one on the orientation unknowns,

    C^T dx = t,   C = -sum_p N_cp N_pp^-1 H_p,   t = -sum_p H_p^T (X_p - X0_p + N_pp^-1 b_p),

which datum.FreeNetwork carries with the minimum constraints and the S-transformation of the
photo datum (``C^T H = sum_p H_p^T H_p``, H being a null vector of the full normal matrix). The
method of conditions has the same N (the bundle's reduced camera system), so both use this C,
formed here from the datum points' rays only (a derived quantity that defines the datum, not part
of the adjustment).

Precision. The orientation estimate now depends on the datum points' own measurements (through
``sum H_p^T N_pp^-1 b_p``), which is uncorrelated with the reduced system: with
``K = (C^T H)^-1`` and ``V = sum_p H_p^T N_pp^-1 H_p``,

    Qxx = S Q_min S^T + H K V K^T H^T                                     (FreeNetwork.extra = V)

and a point's covariance gets, beside Schmid's (90) parts, the cross term of the orientation with
its own measurements, ``-(H_p K H_q^T Qm_q + Qm_p H_p K H_q^T)`` for q, p in D
(:func:`points_correction`, :func:`export_correction`). With these, the covariance equals the
S-transformation (covariance_export.s_transform, W = I on D) of any other datum's (tested).

With distances (distances.csv) the points a distance joins are intersected together (joint_groups),
and so are the datum points: ``dX_D = Qm_D (b_D - N_Dc dx)`` with Qm_D block-diagonal over groups (a
lone point's 3x3 ``N_pp^-1``; a joint group's ``(sum N_pp + J_d^T P_d J_d)^-1``, whose members that are
no datum points are linearised too, with H_p = 0), b_D with the distances' misclosures. Then
``C = -N_cD Qm_D H_D``, ``t = -(sum H_p^T (X_p - X0_p) + H_D^T Qm_D b_D)``, ``V = H_D^T Qm_D H_D``
(DatumJoint) and the cross term is ``-(H_p K B_q + B_p^T K^T H_q^T)`` with ``B_q = H_D^T Qm_{D,q}``
(:func:`own_blocks`, from the joint groups' Qm of joint_groups.joint_intersections). Without distances
every path is the per-point one above, unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import ray_ground
from .datum import FreeDirections, FreeNetwork, similarity_matrix
from ..errors import NumericalFailure
from .joint_groups import distance_components, has_distances
from ..geometry.lens import ideal_xy
from ..model import Project
from .parameters import State, UnknownLayout
from .triangulation import ray_terms
from . import weights

MIN_POINTS = 3


@dataclass(frozen=True)
class PointTerms:
    """What the point datum's precision needs beyond Qxx: index (n_D,) the datum points;
    H (n_D, 3, d) their similarity columns at the adjusted points (zero on held coordinates);
    K (d, d) = (C^T H)^-1."""

    index: np.ndarray
    H: np.ndarray
    K: np.ndarray


@dataclass(frozen=True)
class JointBlock:
    """A joint group of points (points joined by distances, joint_groups) at the adjusted result:
    point_index (k,) its members (indices into project.points), Qm (3k, 3k) their joint measurement
    part (joint_groups.JointIntersection.Qm) and GH (3k, d) their change along the free directions
    (G H; None where the caller has it otherwise, export_correction)."""

    point_index: np.ndarray
    Qm: np.ndarray
    GH: np.ndarray | None = None


@dataclass(frozen=True)
class DatumJoint:
    """The joint groups of the datum points (points joined by distances): with the orientation held
    their members are intersected together, ``dX_J = Qm_J (b_J - N_Jc dx)`` with ``Qm_J = (sum of the
    members' N_pp + J_d^T P_d J_d)^-1``, so the datum's C, t and V take these blocks (module doc).
    datum: (n,) the PointDatum's slot is a datum point (False: a member of a joint group with a datum
    point, linearised for the coupling only); groups: per joint group with a datum point, (slots (k,)
    its members' positions in PointDatum.index, rows (r,) its rows of Project.distances, ends (r, 2)
    each distance's from and to as positions in slots); distance, sigma: (r_all,) Project.distances'."""

    datum: np.ndarray
    groups: tuple
    distance: np.ndarray
    sigma: np.ndarray

    @staticmethod
    def of(project: Project, index: np.ndarray):
        """(index extended by the other members of the joint groups of the datum points ``index``,
        DatumJoint; None when no datum point is joined by a distance)."""
        dist = project.distances
        ends = np.unique(np.concatenate([dist.point_from, dist.point_to]))
        is_datum = np.zeros(len(project.points), dtype=bool)
        is_datum[index] = True
        touched = [c for c in distance_components(project, ends) if is_datum[ends[c.members]].any()]
        if not touched:
            return index, None
        members = np.concatenate([ends[c.members] for c in touched])
        index = np.concatenate([index, members[~is_datum[members]]])
        slot_of = np.full(len(project.points), -1)
        slot_of[index] = np.arange(len(index))
        groups = tuple((slot_of[ends[c.members]], c.distances, c.ends) for c in touched)
        return index, DatumJoint(is_datum[index], groups, dist.distance, dist.sigma)

    def coupled(self, N_pp: np.ndarray, b_p: np.ndarray, Y: np.ndarray, Hp: np.ndarray, xyz: np.ndarray,
                free: np.ndarray):
        """(Y, b) with the joint groups' members replaced by their joint form: Y = Qm_J H_J (k, 3, d)
        and b_J = b_p + J_d^T P_d (d - |X_a - X_b|) (k, 3); N_pp (n, 3, 3), b_p (n, 3), Y (n, 3, d) =
        N_pp^-1 H_p, Hp (n, 3, d), xyz (n, 3) at the PointDatum's slots; free (n, 3) the unknown
        coordinates (the distance rows have no columns on held ones)."""
        Y, b = Y.copy(), b_p.copy()
        d = Hp.shape[2]
        for slots, rows, ends in self.groups:
            k = len(slots)
            N = np.zeros((3 * k, 3 * k))
            for j, s in enumerate(slots):
                N[3 * j:3 * j + 3, 3 * j:3 * j + 3] = N_pp[s]
            bJ = b_p[slots].ravel()
            for e, (a, c) in zip(rows, ends):
                delta = xyz[slots[a]] - xyz[slots[c]]
                length = np.linalg.norm(delta)
                Jd = np.zeros(3 * k)
                Jd[3 * a:3 * a + 3] = delta / length * free[slots[a]]
                Jd[3 * c:3 * c + 3] = -delta / length * free[slots[c]]
                N += weights.weigh(np.outer(Jd, Jd), self.sigma[e])
                bJ += weights.weigh(Jd * (self.distance[e] - length), self.sigma[e])
            Y[slots] = np.linalg.solve(N, Hp[slots].reshape(3 * k, d)).reshape(k, 3, d)
            b[slots] = bJ.reshape(k, 3)
        return Y, b


@dataclass(frozen=True)
class PointDatum:
    """The datum points and their rays (struct of arrays).

    index: (n_D,) indices into project.points; ids: their ids; xyz_approx: (n_D, 3) X0, reduced
    frame; rows: (r,) the image-point rows of their rays (those the adjustment uses); slot: (r,)
    each row's datum point (position in index); photo: (r,) its photo; free: (n_D, 3) the
    coordinate is not held; weight: (n_D, 3) 1/sigma^2 of weighted control coordinates (0
    elsewhere); given: (n_D, 3) given coordinates (reduced frame; 0 where not given); centroid:
    (3,) the centroid of the approximate projection centres, about which the similarity turns;
    joint: the datum points' joint groups (DatumJoint; None without distances between them), whose
    other members follow the datum points in index (ids names the datum points only)."""

    index: np.ndarray
    ids: tuple
    xyz_approx: np.ndarray
    rows: np.ndarray
    slot: np.ndarray
    photo: np.ndarray
    free: np.ndarray
    weight: np.ndarray
    given: np.ndarray
    centroid: np.ndarray
    joint: DatumJoint | None = None

    @staticmethod
    def of(project: Project, ids, batches, state: State, obs, offset: np.ndarray) -> "PointDatum":
        """The datum points ``ids`` (empty: every point of the adjustment with two or more rays) of a
        project whose point groups are ``batches`` (groups.GroupBatch). ValueError for an unknown id; NumericalFailure
        (explained) for datum points that take no part in the adjustment or fewer than three."""
        pts = project.points
        included = np.zeros(len(pts), dtype=bool)
        for b in batches:  # of the adjustment, with two or more rays (a plan point may have one)
            if b.k >= 2:
                included[b.point_index] = True
        if ids:
            where = {str(p): i for i, p in enumerate(pts.ids)}
            unknown = [p for p in ids if p not in where]
            if unknown:
                raise ValueError(f"datum point(s) {', '.join(unknown)} are not object points of the project")
            index = np.array([where[p] for p in ids], dtype=int)
            out = [str(pts.ids[i]) for i in index if not included[i]]
            if out:
                raise NumericalFailure(
                    f"the datum point(s) {', '.join(out)} take no part in the adjustment with two or more rays: "
                    "they cannot carry the inner constraints. Choose others ([datum] points in project.toml, "
                    "--datum-points).", reason="datum_defect")
        else:
            index = np.flatnonzero(included)
        if len(index) < MIN_POINTS:
            raise NumericalFailure(
                f"the point datum (inner-points) needs at least {MIN_POINTS} datum points; the adjustment has "
                f"{len(index)}", reason="datum_defect")
        ids = tuple(str(pts.ids[i]) for i in index)
        joint = None
        if has_distances(project):  # the datum points joined by distances: their joint groups' members
            index, joint = DatumJoint.of(project, index)
        slot_of = -np.ones(len(pts), dtype=int)
        slot_of[index] = np.arange(len(index))
        rows = np.concatenate([b.image_rows[slot_of[b.point_index] >= 0].ravel() for b in batches])
        slot = slot_of[project.image_points.point_index[rows]]
        order = np.argsort(slot, kind="stable")
        rows, slot = rows[order], slot[order]
        given = pts.given_axes[index] & np.isfinite(pts.xyz_given[index])
        weighted = given & (obs.q_control[index] > 0)
        held = given & ~weighted
        weight = weights.variance_weight(obs.q_control[index], weighted)
        given_xyz = np.where(given, obs.control[index], 0.0)
        centroid = state.xyz0.mean(axis=0)
        datum = PointDatum(index, ids, np.zeros((len(index), 3)), rows, slot,
                           project.image_points.photo_index[rows], ~held, weight, given_xyz, centroid, joint)
        x0 = datum.intersection(state, obs.plate, obs)
        if pts.xyz_approx is not None:
            approx = pts.xyz_approx[index] - offset
            x0 = np.where(np.isfinite(approx).all(axis=1)[:, None], approx, x0)
        x0 = np.where(given, given_xyz, x0)
        return PointDatum(index, ids, x0, rows, slot, datum.photo, datum.free, weight, given_xyz, centroid, joint)

    def intersection(self, state: State, plate: np.ndarray, obs) -> np.ndarray:
        """(n_D, 3) least-squares intersection of the datum points' rays through the plate
        coordinates ``plate`` (all image rows; measured or adjusted, with obs.plate the measurements
        for the camera model) at ``state`` (triangulation.intersect_rays, flat over the rays);
        held coordinates at their given values."""
        ph = self.photo
        params, conv = state.camera_terms(ph)
        xy = ideal_xy(plate[self.rows], params, conv, obs.plate[self.rows])
        r = ray_ground(state.R_ground_from_cam[ph], xy, params[..., :3])
        rh = r / np.linalg.norm(r, axis=-1, keepdims=True)
        P = np.eye(3) - rh[:, :, None] * rh[:, None, :]
        n = len(self.index)
        lhs = _sum_by(self.slot, P, n)
        rhs = _sum_by(self.slot, np.einsum("rij,rj->ri", P, state.xyz0[ph]), n)
        if self.joint is not None:  # a joint group's member may be a control point of one ray
            other = ~self.joint.datum[:, None]
            w = (self.weight + ~self.free) * other
            lhs += w[:, :, None] * np.eye(3)
            rhs += w * self.given
        xyz = np.linalg.solve(lhs, rhs[..., None])[..., 0]
        return np.where(self.free, xyz, self.given)

    def similarity(self, free: FreeDirections, xyz: np.ndarray | None = None) -> np.ndarray:
        """H_p (n_D, 3, d) of the datum points at ``xyz`` (n_D, 3; default: at their approximations,
        the datum's definition) (point_similarity about ``centroid``); zero on held coordinates."""
        xyz = self.xyz_approx if xyz is None else xyz
        H = point_similarity(xyz, self.centroid, free) * self.free[:, :, None]
        return H if self.joint is None else H * self.joint.datum[:, None, None]  # the others: no H

    def photo_similarity(self, state: State, layout: UnknownLayout, free: FreeDirections) -> np.ndarray:
        """H (n_unknowns, d) of the photos at ``state`` under the same similarities as
        :meth:`similarity` (about ``centroid``): the pair (H, H_p) is a null vector of the normals."""
        return similarity_matrix(state, layout, free.extent, self.centroid)[0] @ free.coefficients

    def linearise(self, state: State, layout: UnknownLayout, obs, xyz: np.ndarray):
        """The whitened collinearity blocks of the datum points at (state, xyz) (as
        bundle.reduced.linearise_points, flat over the rays): N_pp (n_D, 3, 3), b_p (n_D, 3),
        N_cp (r, w, 3) of each ray and its columns (r, w) (-1 held)."""
        ph, rows = self.photo, self.rows
        params, conv = state.camera_terms(ph)
        e, d_point, d_centre, d_rot, d_camera = ray_terms(
            state.R_ground_from_cam[ph][:, None], state.xyz0[ph][:, None], params[:, None], conv[:, None],
            xyz[self.slot], obs.plate[rows][:, None], with_lens=layout.lens_in_play(state))
        e, d_point, d_centre, d_rot, d_camera = e[:, 0], d_point[:, 0], d_centre[:, 0], d_rot[:, 0], d_camera[:, 0]
        d_rot = d_rot @ layout.rotation_maps(state)[ph]
        sigma, s = weights.whitening(obs.q_plate[rows])
        elements = layout.camera_elements
        Jc = np.concatenate([d_centre, d_rot, d_camera[..., elements]], -1) * s
        cols = np.concatenate([layout.photo_cols[ph], layout.camera_cols[state.camera_of_photo[ph]][:, elements]], -1)
        Jp = d_point * s * self.free[self.slot][:, None, :]
        e = weights.whiten(e, sigma)
        n = len(self.index)
        N_pp = _sum_by(self.slot, np.einsum("rai,raj->rij", Jp, Jp), n)
        b_p = _sum_by(self.slot, np.einsum("rai,ra->ri", Jp, e), n)
        N_pp += (self.weight + ~self.free)[:, :, None] * np.eye(3)
        b_p += self.weight * np.where(self.weight > 0, self.given - xyz, 0.0)
        return N_pp, b_p, np.einsum("rai,raj->rij", Jc, Jp), cols

    def free_network(self, base: FreeNetwork, state: State, layout: UnknownLayout, obs, xyz: np.ndarray,
                     at_solution: bool = False) -> FreeNetwork:
        """The FreeNetwork of the point datum at (state, xyz) (module doc): base gives the free
        directions and the held unknowns of the minimum constraints; xyz (n_D, 3) the current datum
        points (reduced frame). The iteration's constraint has H_p at the approximations (the
        datum's definition: linear in X, met in one step); at_solution: H_p at ``xyz`` instead, the
        inner constraints at the adjusted points that define the precision (the S-transformation's)."""
        free = base.free
        H = self.photo_similarity(state, layout, free)
        Hp = self.similarity(free, xyz if at_solution else None)
        N_pp, b_p, N_cp, cols = self.linearise(state, layout, obs, xyz)
        Y = np.linalg.solve(N_pp, Hp)  # (n_D, 3, d): N_pp^-1 H_p
        if self.joint is not None:  # the joint groups: Qm_J H_J and b_J with the distances
            Y, b_p = self.joint.coupled(N_pp, b_p, Y, Hp, xyz, self.free)
        n = layout.n_unknowns
        C = _sum_by(np.where(cols >= 0, cols, n).ravel(), -(N_cp @ Y[self.slot]).reshape(cols.size, -1), n + 1)[:n]
        target = -(np.einsum("pia,pi->a", Hp, xyz - self.xyz_approx) + np.einsum("pia,pi->a", Y, b_p))
        V = np.einsum("pia,pib->ab", Hp, Y)
        V = 0.5 * (V + V.T)
        K = np.linalg.inv(C.T @ H)
        misclosure = self.misclosure(xyz, free)
        terms = (PointTerms(self.index, Hp, K) if self.joint is None else
                 PointTerms(self.index[self.joint.datum], Hp[self.joint.datum], K))
        return FreeNetwork(H, C, base.held, FreeDirections(H, free.coefficients, free.extent), target, V,
                           "inner-points", terms, misclosure, self.centroid)

    def misclosure(self, xyz: np.ndarray, free: FreeDirections) -> np.ndarray:
        """sum_p H_p^T (X_p - X0_p) (d,) of the datum points xyz (n_D, 3), H_p at the approximations:
        zero in the point datum."""
        return np.einsum("pia,pi->a", self.similarity(free), xyz - self.xyz_approx)


def _sum_by(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sums of the rows of ``values`` (r, ...) by ``index`` (r,) into (n, ...) (a bincount per entry:
    much faster than np.add.at)."""
    flat = values.reshape(len(index), -1)
    w = flat.shape[1]
    out = np.bincount((index[:, None] * w + np.arange(w)).ravel(), weights=flat.ravel(), minlength=n * w)
    return out.reshape((n,) + values.shape[1:])


def point_similarity(xyz: np.ndarray, centroid: np.ndarray, free: FreeDirections) -> np.ndarray:
    """(n, 3, d): the change of points at ``xyz`` (n, 3) under the free directions (the
    coefficients of datum.similarity_changes: about ``centroid``, rotations and scale in units of
    the extent)."""
    v = (xyz - centroid) / free.extent
    H7 = np.zeros((len(xyz), 3, 7))
    H7[:, :, :3] = np.eye(3)
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        H7[:, :, 3 + a] = np.cross(e, v)
    H7[:, :, 6] = v
    return H7 @ free.coefficients


def check_directions(datum: PointDatum, base: FreeNetwork, state: State) -> None:
    """NumericalFailure when the datum points cannot fix the free directions (all on a line, or
    a subset that leaves a direction without any datum point moving): sum H_p^T H_p singular."""
    Hp = datum.similarity(base.free)
    G = np.einsum("pia,pib->ab", Hp, Hp)
    w = np.linalg.eigvalsh(G) if len(G) else np.ones(1)
    if w.min() <= 1e-10 * max(w.max(), 1e-300):
        raise NumericalFailure(
            f"the {len(datum.index)} datum points cannot fix the {len(base)} free similarity direction(s) of the "
            "network (they lie on a line, or none of them moves along a free direction): choose datum points "
            "spread over the object ([datum] points in project.toml, --datum-points).", reason="datum_defect")


def points_correction(terms: PointTerms, cov_measurement: np.ndarray, groups=()) -> np.ndarray:
    """(n_pt, 3, 3) to add to the points' covariance (the orientation part of Schmid 90) in the point
    datum: ``-(H_p K B_p + B_p^T K^T H_p^T)`` with ``B_p = H_D^T Qm_{D,p}`` (:func:`own_blocks`; module
    doc), zero for the points whose measurements the datum points share nothing with.
    cov_measurement: (n_pt, 3, 3) the measurement parts Qm; groups: the JointBlock of every joint
    group (points joined by distances, with GH), whose members' H_p are their rows of GH (empty:
    no distances, the per-point form ``-(H_p K H_p^T Qm_p + ...)`` of the datum points)."""
    out = np.zeros_like(cov_measurement)
    if not groups:
        Hp = terms.H
        Qm = cov_measurement[terms.index]
        A = Hp @ terms.K @ np.swapaxes(Hp, 1, 2) @ Qm
        out[terms.index] = -(A + np.swapaxes(A, 1, 2))
        return out
    points, B = own_blocks(terms, cov_measurement, groups)
    H = np.zeros(B.shape[:1] + (3, B.shape[1]))
    where = {int(p): k for k, p in enumerate(points)}
    slot = {int(p): k for k, p in enumerate(terms.index)}
    for p, k in where.items():  # the datum points alone: their H
        if p in slot:
            H[k] = terms.H[slot[p]]
    for g in groups:  # the members of joint groups: G H
        for j, p in enumerate(g.point_index):
            if int(p) in where:
                H[where[int(p)]] = g.GH[3 * j:3 * j + 3]
    A = H @ terms.K @ B
    out[points] = -(A + np.swapaxes(A, 1, 2))
    return out


def own_blocks(terms: PointTerms, cov_measurement: np.ndarray, groups=()):
    """The covariance of the datum's right-hand side with the points' own measurements: (points
    (m,), B (m, d, 3)) with ``B_q = H_D^T Qm_{D,q} = sum_{p in D} H_p^T Qm_{p,q}`` for every point q
    where it is not zero: a datum point alone (Qm_{D,q} its own block, cov_measurement[q]), and every
    member of a joint group (groups: JointBlock) with a datum point (Qm_{D,q} from the group's joint
    Qm: the datum members' rows)."""
    slot = np.full(max(len(cov_measurement), int(terms.index.max(initial=-1)) + 1), -1)
    slot[terms.index] = np.arange(len(terms.index))
    in_group = np.zeros(len(slot), dtype=bool)
    for g in groups:
        in_group[g.point_index] = True
    lone = terms.index[~in_group[terms.index]]
    points = [lone]
    blocks = [np.swapaxes(terms.H[slot[lone]], 1, 2) @ cov_measurement[lone]]
    d = terms.H.shape[2]
    for g in groups:
        s = slot[g.point_index]
        if not (s >= 0).any():
            continue
        k = len(g.point_index)
        HJ = np.zeros((k, 3, d))
        HJ[s >= 0] = terms.H[s[s >= 0]]
        B = HJ.reshape(3 * k, d).T @ g.Qm  # (d, 3k)
        points.append(np.asarray(g.point_index))
        blocks.append(np.moveaxis(B.reshape(d, k, 3), 1, 0))
    return np.concatenate(points), np.concatenate(blocks)


def export_correction(terms: PointTerms, FH: np.ndarray, point_rows: np.ndarray, cov_measurement: np.ndarray,
                      exported: np.ndarray, groups=()) -> np.ndarray:
    """(n, n) to add to an exported joint covariance (covariance_export) in the point datum:
    ``-(FH K Hq + (FH K Hq)^T)`` with FH (n, d) the change of the exported parameters along the free
    directions and Hq (d, n) the blocks ``B_q = H_D^T Qm_{D,q}`` (:func:`own_blocks`; without distances
    ``H_q^T Qm_q`` of the datum points) at the rows of the exported points. point_rows:
    (n_exported_points,) the first row of each exported point; exported: (n_exported_points,) their
    indices in project.points; groups: the JointBlock of every joint group (points joined by
    distances; GH unused), empty without distances."""
    if groups:
        points, B = own_blocks(terms, cov_measurement, groups)
        where = np.full(max(int(exported.max(initial=-1)), int(points.max(initial=-1))) + 1, -1)
        where[exported] = np.arange(len(exported))
        at = where[points]
        Hq = np.zeros((FH.shape[1], len(FH)))
        rows = point_rows[at[at >= 0]][:, None] + np.arange(3)
        Hq[:, rows.ravel()] = np.moveaxis(B[at >= 0], 1, 0).reshape(FH.shape[1], -1)
        A = FH @ terms.K @ Hq
        return -(A + A.T)
    slot = -np.ones(int(max(exported.max(initial=-1), terms.index.max(initial=-1))) + 1, dtype=int)
    slot[terms.index] = np.arange(len(terms.index))
    s = slot[exported]
    sel = s >= 0
    Hq = np.zeros((FH.shape[1], len(FH)))
    blocks = np.swapaxes(terms.H[s[sel]], 1, 2) @ cov_measurement[exported[sel]]  # (m, d, 3): H_p^T Qm_p
    rows = point_rows[sel][:, None] + np.arange(3)
    Hq[:, rows.ravel()] = np.moveaxis(blocks, 1, 0).reshape(FH.shape[1], -1)
    A = FH @ terms.K @ Hq
    return -(A + A.T)
