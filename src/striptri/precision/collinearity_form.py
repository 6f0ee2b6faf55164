"""The residual cofactors and the points' cofactors of a bundle result in the collinearity form
(points as unknowns), O(k^2) per point of k rays instead of the conditions form's O(k^3) (issue 11).

The conditions form (precision.residual_cofactors) forms per point group ``M = A Q A^T`` (2k - 3
conditions, dense) and ``B Qxx B^T`` over all k photos of the point: O(k^3) per point, which on
close-range tracks of 60-90 rays dominates the command. With the point among the unknowns the same
numbers follow from small blocks. Per point, linearised at the adjusted orientation x^ and the
point X^ intersected from the adjusted rays, ray a has the collinearity derivatives ``Jc_a`` (2, 6 + e:
its photo's six unknowns, then its camera's e estimated elements, the columns of the conditions
form's B) and ``Jp_a`` (2, 3: the point), weights ``P_a = Q_a^-1``. With

    N_pp = sum_a Jp_a^T P_a Jp_a + P_given            (3x3; held axes: unit rows, zero inverse)
    G    = -N_pp^-1 sum_a Jp_a^T P_a Jc_a             (3 x the point's unknown sets)
    Qcc  = result.covariance                          (the reduced system's inverse: the Qxx of both forms)

the joint cofactors of the point and its orientation unknowns are ``Q_pc = G Qcc``,
``Q_pp = N_pp^-1 + G Qcc G^T`` (Schmid 90: the measurement part plus the orientation part), and the
residual cofactors of the point's rays are

    Qvv_ab = delta_ab Q_a - (Jc_a Qcc Jc_b^T + Jc_a Qcc G^T Jp_b^T + Jp_a G Qcc Jc_b^T + Jp_a Q_pp Jp_b^T),

of weighted control coordinates ``q_given - (Q_pp)_ii``. ``Jc_a`` touches only ray a's photo and
camera, so everything is formed from Qcc among the point's unknown sets (``Covariance.set_blocks``,
D = 6k + e columns when the point's rays share one camera): ``Qcc G^T`` is (D, 3), ``Jc Qcc`` is
(2k, D), the diagonal of Qvv O(k) more and the whole 2k x 2k block (reliability.separability)
O(k^2). Batched over the points of k rays (struct of arrays), chunked so that a chunk's blocks stay
within MAX_ENTRIES. A small system (at most DENSE_UNKNOWNS unknowns, Qcc read whole) with long tracks
forms ``Qcc G^T`` instead as one product with the whole Qcc (:func:`_by_products`, O(n^2) a point
but in BLAS, where the gather reads D^2 entries one by one): the diagonal of Qvv then needs Qcc only
among each ray's own columns. At close range (66 rays a point, 695 unknowns) that route is 2.3 times
faster; a 100-photo block's tracks of 3 or 4 rays gather 1.7 times faster (PRODUCT_RATIO).

At convergence (adjusted rays that meet in X^) both forms are the same linear model: the
conditions are the collinearity equations with the point eliminated (A Jp = 0, B = -A Jc), so the
numbers agree to rounding (tests/test_bundle_precision.py), except that the subtraction ``q - J Qxx J^T``
loses digits where the redundancy number is tiny: such points are marked ``imprecise``
(R_SUBTRACTION) and precision.residual_cofactors takes them from the conditions form. Used by
precision.residual_cofactors for a bundle result without distances (their observations couple
points) and without a free network (its Qxx is not the reduced system's inverse), and for such a
result of the conditions method when the system is small (its adjusted rays meet in X^ as well,
and its N is the same reduced normal matrix): :func:`applies`.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..core.adjusted_points import triangulate_adjusted
from ..equations.observations import observations_of
from ..core.result import AdjustmentResult
from ..equations.point_precision import orientation_part
from ..equations.groups import points_with_conditions
from ..model import Project
from ..equations.triangulation import Triangulated, ray_terms
from ..equations import padding, weights

METHOD = "bundle"
CONDITIONS = "conditions"  # its results too, where Qcc is read whole (applies)
MAX_ENTRIES = 1 << 21  # entries of the gathered Qcc blocks (m D^2) of one chunk of points (16 MB)
DENSE_UNKNOWNS = 2048  # up to this many unknowns Qcc is read once whole (32 MB) and gathered from
# _Qcc.by_products: multiply-adds of the whole product that cost as much as one entry gathered. Measured:
# the product wins 2.3x at 3 n^2 / width^2 = 2.8 (close range), the gather 1.7x at 2,400 (a 100-photo
# block); by the costs of one entry gathered (~7 ns) and one multiply-add in BLAS (~0.1 ns) they cross
# near 60. Taken lower: where they are close the gather needs no scratch of n x 3m.
PRODUCT_RATIO = 32
# qvv = q - J Qxx J^T is exact to a few eps of q: a redundancy number r keeps ~ -log10(r / 1e-15)
# digits. Points with a coordinate below this r are marked imprecise (at worst ~1e-11 relative here);
# precision.residual_cofactors takes them from the conditions form, which has no subtraction.
R_SUBTRACTION = 1e-4


def applies(project: Project, result: AdjustmentResult) -> bool:
    """Whether the collinearity form gives the residual cofactors of ``result`` (module doc), without
    distances and without a free-network datum: a bundle result, and a result of the conditions
    method whose Qcc is read whole (at most DENSE_UNKNOWNS unknowns). At convergence both are the same
    linear model; for a small system the collinearity form is the faster (close range: 0.04-0.12 s
    against 0.50 s; tracks of 7 rays on 12 photos: 0.008 against 0.029 s), for a large block's short
    tracks the conditions form (5,000 photos: 0.31 against 0.36 s)."""
    return applies_to(project, result.method, result.layout.n_unknowns, result.free_network is not None)


def applies_to(project: Project, method: str, n_unknowns: int, free_network: bool) -> bool:
    """applies() before the result: for a ``method`` with ``n_unknowns`` unknowns, in a free network or not."""
    if getattr(project, "distances", None) is not None or free_network:
        return False
    return method == METHOD or (method == CONDITIONS and n_unknowns <= DENSE_UNKNOWNS)


@dataclass
class CollinearityCofactors:
    """plate (m_ip, 2): qvv of the plate coordinates (0 for the rows of points without conditions);
    control (n_pt, 3): qvv of the weighted given coordinates (0 elsewhere); plate_blocks: when asked,
    per chunk (image_rows (m, k), Qvv (m, 2k, 2k)) with (x, y) per ray in the order of image_rows
    (precision.ResidualCofactors.plate_blocks); imprecise: the points whose qvv lost digits to the
    subtraction (R_SUBTRACTION); points: triangulation.Triangulated, the points with
    Schmid's (90) cofactors (measurement part N_pp^-1, orientation part G Qcc G^T), as
    adjusted_points.triangulate_adjusted(..., orientation_part=True) gives them."""

    plate: np.ndarray
    control: np.ndarray
    plate_blocks: list | None
    points: Triangulated
    # (n_pt,) bool: points with a plate or weighted control r below R_SUBTRACTION, and points with
    # conditions that their rays do not determine, or only weakly (Triangulated.undetermined)
    imprecise: np.ndarray


# the last pass over a project and a result: weak references to both, and what a second pass over them
# (the blocks of data snooping's suspects, reliability.snooping) or points_of reads again: "points",
# the Triangulated with the (90) cofactors (a pass over every point), "adjusted" (X^ with N_pp^-1)
# and "qcc" (_Qcc: Qcc read whole for a small system)
_last: dict = {}


def _is_last(project: Project, result: AdjustmentResult) -> bool:
    return bool(_last) and _last["project"]() is project and _last["result"]() is result


def residual_cofactors(project: Project, result: AdjustmentResult, plate_blocks: bool = False,
                       residuals: bool = True, points: np.ndarray | None = None) -> CollinearityCofactors:
    """Residual cofactors of the plate and control observations and the points' cofactors of a
    bundle result by the collinearity form (module doc). Points with conditions whose rays do not
    determine them at the adjusted values, or only weakly (triangulation.Triangulated.undetermined),
    are left to the conditions form (``imprecise``), which needs no N_pp^-1 (docs/decisions.md
    "Undetermined points"). The points are kept
    for :func:`points_of` (weakly: the last pass only). residuals=False: the points only (plate
    and control zero). points: (n_pt,) bool, only these points (the others' qvv, blocks and
    orientation parts zero; such a pass is not kept)."""
    global _last
    ip = project.image_points
    n_points = len(project.points)
    obs = observations_of(project, result.offset)
    state, layout = result.state, result.layout
    if not _is_last(project, result):
        _last = {"project": weakref.ref(project), "result": weakref.ref(result), "qcc": _Qcc(result),
                 "adjusted": triangulate_adjusted(project, result)}  # X^: the adjusted rays' intersection, N_pp^-1
    qcc, tri = _last["qcc"], _last["adjusted"]
    given = project.points.given_axes
    weighted = given & (obs.q_control > 0)
    counts = np.bincount(ip.point_index, minlength=n_points)
    with_conditions = points_with_conditions(project)
    order = np.lexsort((ip.photo_index, ip.point_index))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    T = layout.rotation_maps(state)
    elements = layout.camera_elements
    camera_cols = layout.camera_cols[:, elements]
    lens = layout.lens_in_play(state)
    q_plate = np.zeros_like(obs.plate)
    q_control = np.zeros_like(obs.control)
    cov_orientation = np.zeros((n_points, 3, 3))
    blocks = [] if plate_blocks else None
    # points whose rays do not determine them (or only weakly) at the adjusted values: N_pp^-1 does
    # not exist or loses digits, so their qvv come from the conditions form, which does not need it
    # (nan there only where their conditions degenerate); their (90) cofactors as they are
    undetermined = with_conditions & tri.undetermined
    wanted = tri.determined  # with the points with conditions; one without: its (90) only
    if points is not None:
        wanted = wanted & points
        undetermined = undetermined & points
    # by ray count, neighbouring counts of few points joined, the shorter tracks padded with rays of
    # weight zero (equations.padding: their G is zero, their rows of Qvv are not read)
    for k, sel_k in padding.count_groups(counts, np.flatnonzero(wanted)):
        width = 6 * k + camera_cols.shape[1] * k
        step = qcc.points_per_chunk(k, width, camera_cols.shape[1])
        for first in range(0, len(sel_k), step):
            sel = sel_k[first: first + step]
            rows, real = padding.padded_rows(order, starts, counts, sel, k)
            ph = ip.photo_index[rows]
            params, conv = state.camera_terms(ph)
            with np.errstate(all="ignore"):
                _, dX, dO, drot, dcam = ray_terms(state.R_ground_from_cam[ph], state.xyz0[ph], params, conv,
                                                  tri.xyz[sel], result.plate_adjusted[rows], obs.plate[rows], lens)
            Jc = np.concatenate([dO, drot @ T[ph], dcam[..., elements]], 3)  # (m, k, 2, 6 + e)
            p = weights.inverse_variance(obs.q_plate[rows]) * real[..., None]
            Qm, pJX = tri.cov_measurement[sel], dX * p[..., None]
            rays = _Rays(Jc, dX, Qm, pJX, ph, state.camera_of_photo[ph], obs.q_plate[rows])
            chunk = _ray_cofactors(qcc, rays, layout.photo_cols, camera_cols, full=blocks is not None,
                                   residuals=residuals)
            cov_orientation[sel] = chunk.orientation
            if not residuals:
                continue
            cond = with_conditions[sel] & ~undetermined[sel]
            q_plate[rows[cond[:, None] & real]] = chunk.diagonal[cond[:, None] & real]
            q_control[sel] = np.where(weighted[sel] & cond[:, None],
                                      obs.q_control[sel] - np.diagonal(chunk.Q_pp, axis1=1, axis2=2), 0.0)
            if blocks is not None and cond.any():  # per real ray count: the blocks of its real rays
                for n in np.unique(counts[sel[cond]]):
                    of_n = cond & (counts[sel] == n)
                    blocks.append((rows[of_n, :n], chunk.block[of_n, : 2 * n, : 2 * n]))
    triangulated = Triangulated(xyz=tri.xyz, cov_measurement=tri.cov_measurement,
                                cov_orientation=np.where(tri.determined[:, None, None], cov_orientation, 0.0),
                                determined=tri.determined, weak=tri.weak)
    if points is None:  # a pass over every point
        _last["points"] = triangulated
    small = np.zeros(n_points, dtype=bool)
    if residuals:
        np.logical_or.at(small, ip.point_index, (q_plate < R_SUBTRACTION * obs.q_plate).any(axis=1))
        small |= (weighted & (q_control < R_SUBTRACTION * obs.q_control)).any(axis=1)
    imprecise = (small & with_conditions) | undetermined
    return CollinearityCofactors(q_plate, q_control, blocks, triangulated,
                                 imprecise if points is None else imprecise & points)


def points_of(project: Project, result: AdjustmentResult) -> Triangulated:
    """The points of a bundle result with Schmid's (90) cofactors, as
    ``adjusted_points.triangulate_adjusted(project, result, orientation_part=True)`` (equal to
    rounding, tested), by the collinearity form: those of the last :func:`residual_cofactors` pass
    when it was over the same project and result (the pipeline's reliability measures), else a pass."""
    if _is_last(project, result) and "points" in _last:
        return _last["points"]
    return residual_cofactors(project, result, residuals=False).points


@dataclass
class _RayChunk:
    diagonal: np.ndarray | None  # (m, k, 2) qvv of the plate coordinates (None: not asked)
    Q_pp: np.ndarray  # (m, 3, 3)
    orientation: np.ndarray  # (m, 3, 3) its orientation part G Qcc G^T
    block: np.ndarray | None  # (m, 2k, 2k) the plate block of Qvv, (x, y) per ray


class _Qcc:
    """Qcc among the points' unknown sets. ``gather(parts)``: covariance.Slots -> Qcc among their
    sets (m, D, D) (Covariance.set_blocks' contract). Small systems (at most DENSE_UNKNOWNS
    unknowns, e.g. close range) read Qcc whole once (``dense``, (n + 1, n + 1) with a zero last row
    and column for the fixed elements, -1) and gather from it, several times faster than reading
    it by blocks of set pairs; long tracks there take the product route (:meth:`by_products`)."""

    def __init__(self, result: AdjustmentResult):
        n = result.layout.n_unknowns
        # weakly: kept in _last, this must not keep a result's selected inverse alive (data snooping
        # adjusts again beside it)
        self._result = weakref.ref(result)
        self.dense = None
        if n <= DENSE_UNKNOWNS:
            self.dense = np.zeros((n + 1, n + 1))  # row and column -1 (a fixed element) read zero
            self.dense[:n, :n] = result.covariance.dense_solved()

    def gather(self, parts):
        if self.dense is None:
            return self._result().covariance.set_blocks(parts)
        m = len(parts[0].sets)
        idx = np.concatenate([P.columns[P.sets].reshape(m, -1) for P in parts], 1)  # (m, D)
        return self.dense[idx[:, :, None], idx[:, None, :]]

    def by_products(self, width: int) -> bool:
        """Whether points whose unknown sets have ``width`` columns take the product route:
        ``Qcc G^T`` as one product with the whole Qcc (3 n^2 multiply-adds a point) instead of
        Qcc gathered among the point's sets (width^2 entries read, then multiplied). The gather's
        entries cost about PRODUCT_RATIO multiply-adds each (close range, one BLAS thread)."""
        n = 0 if self.dense is None else len(self.dense)
        return self.dense is not None and 3 * n * n <= PRODUCT_RATIO * width * width

    def points_per_chunk(self, k: int, width: int, e: int) -> int:
        """Points of k rays (their sets ``width`` columns, e camera elements a ray) in one chunk."""
        if self.by_products(width):
            return max(1, MAX_ENTRIES // max(3 * len(self.dense), k * (6 + e) ** 2))
        return max(1, MAX_ENTRIES // (width * width))


class _Rays(NamedTuple):
    """The rays of m points of k rays each: Jc (m, k, 2, 6 + e) their derivatives by the photo and
    camera unknowns; dX, pJX (m, k, 2, 3) by the point, and those times the plate weights; Qm (m,
    3, 3) N_pp^-1; ph, camera (m, k) the photo and camera of each ray; q (m, k, 2) plate cofactors."""

    Jc: np.ndarray
    dX: np.ndarray
    Qm: np.ndarray
    pJX: np.ndarray
    ph: np.ndarray
    camera: np.ndarray
    q: np.ndarray


def _ray_cofactors(qcc: _Qcc, rays: _Rays, photo_cols, camera_cols, full: bool, residuals: bool = True) -> _RayChunk:
    """Qvv of the rays (m points of k rays each) and their Q_pp (module doc). qcc: the result's
    Qcc; photo_cols (n_photos, 6), camera_cols (n_cameras, e): its columns. full: also the whole
    plate block of Qvv; residuals=False: Q_pp and its orientation part only."""
    Jc, dX, Qm, pJX, ph, camera, q = rays
    m, k = ph.shape
    # G per ray: -N_pp^-1 Jp_a^T P_a Jc_a, (m, 3, k, 6 + e); ray_slots (in orientation_part) makes the
    # point's unknown sets (its k photos, then its camera once when its rays share one, else one
    # camera set per ray)
    G = -np.einsum("mij,mkaj,mkac->mikc", Qm, pJX, Jc, optimize=True)
    if not full and qcc.by_products(Jc.shape[3] * k):
        return _by_products(qcc.dense, rays, G, photo_cols, camera_cols, residuals)
    gather = qcc.gather
    read: dict = {}

    def forms(parts):  # Qcc gathered once per chunk: the residual cofactors below read it again
        Q = gather(parts)  # (m, D, D)
        Gf = np.concatenate([P.G.reshape(m, 3, -1) for P in parts], 2)  # (m, 3, D)
        read.update(parts=parts, Q=Q, Gf=Gf)
        return Gf @ (Q @ np.swapaxes(Gf, 1, 2))  # Gf (Qcc G^T)

    GQG = orientation_part(G, ph, camera, photo_cols, camera_cols, forms)  # Schmid's (90)
    parts, Q, Gf = read["parts"], read["Q"], read["Gf"]
    Q_pp = Qm + GQG
    if not residuals:
        return _RayChunk(None, Q_pp, GQG, None)
    # Jc Qcc (m, 2k, D): the photo part of ray a reads the rows of its photo set a, the camera part
    # the rows of its camera set
    D = Q.shape[1]
    JQ = (Jc[..., :6] @ Q[:, : 6 * k].reshape(m, k, 6, D)).reshape(m, 2 * k, D)
    summed = len(parts) > 1 and parts[1].sets.shape[1] == 1
    e = Jc.shape[3] - 6
    if len(parts) > 1:
        Jcam = Jc[..., 6:]
        if summed:
            JQ += Jcam.reshape(m, 2 * k, e) @ Q[:, 6 * k:]
        else:
            JQ += (Jcam @ Q[:, 6 * k:].reshape(m, k, e, D)).reshape(m, 2 * k, D)
    JX = dX.reshape(m, 2 * k, 3)
    JcT = JQ @ np.swapaxes(Gf, 1, 2)  # (m, 2k, 3): Jc Qcc G^T
    W = JcT + JX @ Q_pp  # the part multiplied by Jp^T from the right
    Jph = Jc[..., :6]
    if full:
        # Jc Qcc Jc^T: column block b of the photo part is JQ[:, :, photo b] Jph_b^T
        JQph = np.moveaxis(JQ[:, :, : 6 * k].reshape(m, 2 * k, k, 6), 2, 1)  # (m, k, 2k, 6)
        F = np.moveaxis(JQph @ np.swapaxes(Jph, 2, 3), 1, 2).reshape(m, 2 * k, 2 * k)
        if len(parts) > 1:
            if summed:
                F += JQ[:, :, 6 * k:] @ np.swapaxes(Jcam.reshape(m, 2 * k, e), 1, 2)
            else:
                JQc = np.moveaxis(JQ[:, :, 6 * k:].reshape(m, 2 * k, k, e), 2, 1)
                F += np.moveaxis(JQc @ np.swapaxes(Jcam, 2, 3), 1, 2).reshape(m, 2 * k, 2 * k)
        F += W @ np.swapaxes(JX, 1, 2) + JX @ np.swapaxes(JcT, 1, 2)
        block = -F
        idx = np.arange(2 * k)
        block[:, idx, idx] += q.reshape(m, 2 * k)
        return _RayChunk(np.diagonal(block, axis1=1, axis2=2).reshape(m, k, 2).copy(), Q_pp, GQG, block)
    a = np.arange(k)
    # diagonal only: ray a's rows of JQ against its own photo (and camera) columns
    own = JQ.reshape(m, k, 2, D)
    d = np.einsum("mkac,mkac->mka", own[..., : 6 * k].reshape(m, k, 2, k, 6)[:, a, :, a, :].transpose(1, 0, 2, 3),
                  Jph)
    if len(parts) > 1:
        cam = own[..., 6 * k:]
        if not summed:
            cam = cam.reshape(m, k, 2, k, e)[:, a, :, a, :].transpose(1, 0, 2, 3)
        d += np.einsum("mkac,mkac->mka", cam, Jcam)
    d += np.einsum("mri,mri->mr", W + JcT, JX).reshape(m, k, 2)  # 2 Jc Qcc G^T Jp^T + Jp Q_pp Jp^T
    return _RayChunk(q - d, Q_pp, GQG, None)


def _by_products(Q: np.ndarray, rays: _Rays, G: np.ndarray, photo_cols, camera_cols, residuals: bool) -> _RayChunk:
    """_ray_cofactors' diagonal of Qvv and Q_pp by products with the whole Qcc (Q: (n + 1, n + 1),
    its last row and column zero for the fixed elements): long tracks of a small system (close
    range), where a point's sets cover much of Qcc. ``Y = Qcc Gs`` (n + 1, 3m), Gs every point's G
    placed in its columns, is one product; then ``G Qcc G^T`` of a point is its G against its rows of
    Y, ``Jc Qcc G^T`` of a ray its Jc against its own rows of Y, and ``Jc_a Qcc Jc_a^T`` (the
    diagonal) needs Qcc only among the ray's own 6 + e columns: no point's D x D block of Qcc is
    formed."""
    Jc, dX, Qm, pJX, ph, camera, q = rays
    m, k = ph.shape
    n1 = len(Q)
    point = np.arange(m)[:, None, None]
    kept: list[np.ndarray] = []  # Y, for the rays' Jc Qcc G^T below

    def forms(parts):
        gs = np.zeros(n1 * 3 * m)
        for P in parts:  # Gs[column, 3 point + i] += G_i at that column (a camera shared by rays: summed)
            cols = np.where(P.columns[P.sets] < 0, n1 - 1, P.columns[P.sets])  # (m, s, w)
            at = (cols[:, None] * (3 * m) + 3 * point[..., None] + np.arange(3)[None, :, None, None])
            gs += np.bincount(at.ravel(), weights=P.G.ravel(), minlength=len(gs))
        Y = (Q @ gs.reshape(n1, 3 * m)).reshape(n1, m, 3)
        kept.append(Y)
        GQG = np.zeros((m, 3, 3))
        for P in parts:  # column -1 reads Y's last row, zero
            GQG += np.einsum("mrsw,mswj->mrj", P.G, Y[P.columns[P.sets], point], optimize=True)
        return GQG

    GQG = orientation_part(G, ph, camera, photo_cols, camera_cols, forms)  # Schmid's (90)
    Q_pp = Qm + GQG
    if not residuals:
        return _RayChunk(None, Q_pp, GQG, None)
    # each ray's own columns: its photo's six, then its camera's e
    own = np.concatenate([photo_cols[ph], camera_cols[camera]], 2)  # (m, k, 6 + e); -1: Q's zero last row
    Y = kept[0]
    JcT = (Jc @ Y[own, point]).reshape(m, 2 * k, 3)  # Jc Qcc G^T
    d = np.einsum("mkac,mkac->mka", Jc @ Q[own[..., :, None], own[..., None, :]], Jc)  # Jc_a Qcc Jc_a^T
    JX = dX.reshape(m, 2 * k, 3)
    d += np.einsum("mri,mri->mr", 2.0 * JcT + JX @ Q_pp, JX).reshape(m, k, 2)  # 2 Jc Qcc G^T Jp^T + Jp Q_pp Jp^T
    return _RayChunk(q - d, Q_pp, GQG, None)
