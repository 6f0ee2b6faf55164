"""The reduced camera system: object points eliminated point by point (Schur complement).

For a chunk of m points seen by k photos each, the whitened observation equations are
``Jc dx + Jp dX = e + v~`` (plate coordinates, ``e = (l - f(x^, X^)) / sigma``) plus
``dX = (given - X^) + v~`` times ``1/sigma`` for weighted control coordinates. Per point, with
its orientation unknowns ``c`` (the columns of each of its rays: centre, rotation unknowns and,
when cameras are estimated, the camera elements estimated in some camera; -1 = held) and its coordinates ``p``:

    N_pp = Jp^T Jp + P_control          b_p = Jp^T e + P_control (given - X^)
    N_cp = Jc^T Jp                      b_c = Jc^T e
    N_rcs += N_cc - N_cp N_pp^-1 N_pc   b_rcs += b_c - N_cp N_pp^-1 b_p

Coordinates held fixed have zero columns in Jp and the identity in N_pp, so every point uses a
3x3 block. After ``N_rcs dx = b_rcs``, each point follows by back-substitution
``dX = N_pp^-1 (b_p - N_pc dx)`` from the point chunks the assembly keeps (``ReducedNormals.kept``),
so an iteration linearises the observation equations once: about 22 numbers per plate
measurement are held from the assembly to the back substitution.

Three ways to sum the points' share, the same numbers to round-off (ReducedNormals.add_points):
dense in the full space for small blocks with long tracks (bundle.dense: close range); with each
point's camera columns summed over its rays first where all its rays are of one camera
(reduce_points_one_camera: 6k + w columns per point instead of k (6 + w)); and in general
(reduce_points), each scattered ray pair by ray pair into the block pattern of N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..geometry.collinearity import plate_from_ground
from ..equations.groups import GroupBatch
from ..geometry.lens import NCP, projection_terms
from ..equations.linearise import Observations
from ..equations.block_pattern import BlockPattern, ray_columns, selection_matrix
from ..equations.parameters import State, UnknownLayout
from ..equations.triangulation import ray_terms
from .dense import DenseSchur, dense_pays
from .points import PointUnknowns
from ..equations import weights

@dataclass
class PointChunk:
    """A chunk of m points with k rays each, linearised and whitened (module doc).

    cols: (m, k, w) global columns (-1 = held); Jc: (m, k, 2, w) (w = 6 + layout.camera_width); Jp: (m, k, 2, 3); e: (m, k, 2);
    sigma: (m, k, 2) plate standard deviations; N_pp: (m, 3, 3); b_p: (m, 3); free: (m, 3);
    weight: (m, 3) control weights; control_misclosure: (m, 3) given - X^ (0 where not weighted).
    """

    batch: GroupBatch
    cols: np.ndarray
    Jc: np.ndarray
    Jp: np.ndarray
    e: np.ndarray
    sigma: np.ndarray
    N_pp: np.ndarray
    b_p: np.ndarray
    free: np.ndarray
    weight: np.ndarray
    control_misclosure: np.ndarray

    @property
    def N_cp(self) -> np.ndarray:
        """(m, 9k, 3), rows in the order of ``cols.reshape(m, 9k)``."""
        # a batched matrix product per ray: a quarter of einsum's time for these 6 x 2 by 2 x 3 products
        return (np.swapaxes(self.Jc, -1, -2) @ self.Jp).reshape(len(self.e), -1, 3)

    def sum_of_squares(self) -> float:
        """e^T e of the plate and control observations at the linearisation point."""
        return float(np.sum(self.e**2) + np.sum(self.weight * self.control_misclosure**2))


def linearise_points(batch: GroupBatch, state: State, layout: UnknownLayout, rotation_maps: np.ndarray,
                     obs: Observations, unknowns: PointUnknowns, xyz: np.ndarray, damping: float = 0.0) -> PointChunk:
    """Whitened observation equations of a chunk of points at (x^, X^).

    rotation_maps: (n_photos, 3, 3) of UnknownLayout.rotation_maps; xyz: (n_pt, 3) current points.
    damping: Levenberg-Marquardt factor, ``N_pp + damping diag(N_pp)`` (0: Gauss-Newton).
    """
    ph, rows, pt = batch.photo_index, batch.image_rows, batch.point_index
    cam = state.camera_of_photo[ph]
    params, conv = state.camera_terms(ph)
    xyz_ground = xyz[pt]
    # residual space and derivatives through the camera model (lens.py), as triangulation does
    e, d_point, d_centre, d_rot, d_camera = ray_terms(state.R_ground_from_cam[ph], state.xyz0[ph], params, conv, xyz_ground,
                                                      obs.plate[rows], with_lens=layout.lens_in_play(state))
    d_rot = d_rot @ rotation_maps[ph]
    sigma, s = weights.whitening(obs.q_plate[rows])
    real = getattr(batch, "real", None)  # bundle.padding: padded rays get weight zero
    if real is not None:
        s = s * real[:, :, None, None]
    parts, col_parts = [d_centre, d_rot], [layout.photo_cols[ph]]
    if layout.camera_width:
        elements = layout.camera_elements
        parts.append(d_camera[..., elements])
        col_parts.append(layout.camera_cols[cam][..., elements])
    Jc = np.concatenate(parts, -1) * s
    free = unknowns.free[pt]
    Jp = d_point * s * free[:, None, None, :]
    e = weights.whiten(e, sigma) if real is None else weights.whiten(e, sigma) * real[..., None]
    cols = np.concatenate(col_parts, -1)
    weight = unknowns.weight[pt]
    control_misclosure = np.where(weight > 0, unknowns.given[pt] - xyz_ground, 0.0)
    N_pp = np.einsum("mkai,mkaj->mij", Jp, Jp)
    N_pp += (weight + ~free)[:, :, None] * np.eye(3)
    if damping:
        N_pp += damping * np.einsum("mii->mi", N_pp)[:, :, None] * (free[:, :, None] * np.eye(3))
    b_p = np.einsum("mkai,mka->mi", Jp, e) + weight * control_misclosure
    return PointChunk(batch, cols, Jc, Jp, e, sigma, N_pp, b_p, free, weight, control_misclosure)


def residual_sum_of_squares(batch: GroupBatch, state: State, layout: UnknownLayout, obs: Observations,
                            unknowns: PointUnknowns, xyz: np.ndarray) -> float:
    """Sum of the squared whitened residuals (plate and weighted control) of a chunk at (x^, X^),
    without derivatives (the trial steps of the damped iteration); inf where a point lies in the
    plane of a camera."""
    ph, rows, pt = batch.photo_index, batch.image_rows, batch.point_index
    params, conv = state.camera_terms(ph)
    xyz_ground = xyz[pt]
    with np.errstate(divide="ignore", invalid="ignore"):
        pred = plate_from_ground(state.R_ground_from_cam[ph], state.xyz0[ph], params[..., :3], xyz_ground[:, None, :])
        xy_obs = obs.plate[rows]
        if layout.lens_in_play(state):
            terms = projection_terms(pred, xy_obs, params, conv)
            e = terms.obs - terms.pred
        else:
            e = xy_obs - pred
        total = float(np.sum(weights.whiten(e, np.sqrt(obs.q_plate[rows])) ** 2))
    weight = unknowns.weight[pt]
    total += float(np.sum(weight * np.where(weight > 0, unknowns.given[pt] - xyz_ground, 0.0) ** 2))
    return total if np.isfinite(total) else np.inf


def reduce_points(chunk: PointChunk):
    """Each point's contribution to the reduced camera system: (m, 9k, 9k), (m, 9k) and
    b_p^T N_pp^-1 b_p (m,) (the points' share of the reduced sum of squares)."""
    m, k = chunk.e.shape[:2]
    N_cp = chunk.N_cp
    N_pp_inv = np.linalg.inv(chunk.N_pp)
    Y = N_cp @ N_pp_inv
    N_loc = -(Y @ np.swapaxes(N_cp, 1, 2))
    N_cc = np.swapaxes(chunk.Jc, -1, -2) @ chunk.Jc  # (m, k, w, w): rays of a point, block diagonal
    width = chunk.Jc.shape[-1]
    # the ray-diagonal blocks as a view of N_loc (einsum's repeated index): a fancy-indexed += over
    # the rays took twice as long
    np.einsum("maiaj->maij", N_loc.reshape(m, k, width, k, width))[...] += N_cc
    b_c = np.einsum("mkai,mka->mki", chunk.Jc, chunk.e).reshape(m, width * k)
    b_loc = b_c - np.einsum("mci,mi->mc", Y, chunk.b_p)
    reduced = np.einsum("mi,mij,mj->m", chunk.b_p, N_pp_inv, chunk.b_p)
    return N_loc, b_loc, reduced


# From this many rays per point on, a chunk whose points each see one camera sums each point's
# camera columns over its rays before the reduction (reduce_points_one_camera); the decision is the
# chunk's, made once per adjustment (block_pattern) with its scatters. It pays from two rays on
# (measured, one thread: a 1,000-photo block with 2 to 9 rays and c, xp, yp, k1, k2 free 0.064 s
# an assembly against 0.126 s; the benchmark's close range 0.11 s against 0.22 s).
CAMERA_SUM_RAYS = 2


def sums_camera_columns(pattern: BlockPattern, cam: np.ndarray) -> bool:
    """Whether a chunk with cameras cam (m, k) takes reduce_points_one_camera: the cameras are
    estimated, its points have CAMERA_SUM_RAYS rays or more and all rays of each point are of one
    camera."""
    return bool(pattern.with_cameras and cam.shape[1] >= CAMERA_SUM_RAYS and np.all(cam == cam[:, :1]))


@dataclass
class OneCameraReduction:
    """reduce_points for points whose rays are all of one camera, in the point's own columns: the
    6 photo elements of each ray, then the w camera elements once (their sum over the rays: the
    same unknowns), instead of k (6 + w).

    pp: (m, k, k, 6, 6) ray-pair blocks in pattern order (block (a, b) is pp[:, a, b]);
    pc: (m, k, 6, w) ray a's photo with the camera; cc: (m, w, w); b_photo: (m, k, 6);
    b_camera: (m, w); reduced: (m,) b_p^T N_pp^-1 b_p.
    """

    pp: np.ndarray
    pc: np.ndarray
    cc: np.ndarray
    b_photo: np.ndarray
    b_camera: np.ndarray
    reduced: np.ndarray


def reduce_points_one_camera(chunk: PointChunk) -> OneCameraReduction:
    """The reduction of reduce_points for a chunk whose points each see one camera
    (sums_camera_columns): with ``Y = N_cp N_pp^-1``, ``N_cc - Y N_pc`` and ``b_c - Y b_p`` in the
    summed columns (OneCameraReduction). N_cc is block diagonal over the rays (added to the
    ray-diagonal blocks pp[:, a, a] only) but for the camera, which every ray shares; the ray
    pairs come from broadcast 6x3 by 3x6 products straight in pattern order (no transposed copy
    of a (m, 6k, 6k) product)."""
    m, k = chunk.e.shape[:2]
    Jc = chunk.Jc
    N_pp_inv = np.linalg.inv(chunk.N_pp)
    Jc_T = np.swapaxes(Jc, -1, -2)
    N_cp = Jc_T @ chunk.Jp  # (m, k, 6 + w, 3), per ray
    N_cp_photo = N_cp[:, :, :6]  # (m, k, 6, 3)
    N_cp_camera = N_cp[:, :, 6:].sum(axis=1)  # (m, w, 3)
    Y_photo = N_cp_photo @ N_pp_inv[:, None]  # (m, k, 6, 3)
    Y_camera = N_cp_camera @ N_pp_inv  # (m, w, 3)
    N_pc_camera = np.swapaxes(N_cp_camera, 1, 2)  # (m, 3, w)
    pp = -np.matmul(Y_photo[:, :, None], np.swapaxes(N_cp_photo, 2, 3)[:, None])  # (m, k, k, 6, 6)
    N_cc = Jc_T @ Jc  # (m, k, 6 + w, 6 + w), per ray
    ray = np.arange(k)
    pp[:, ray, ray] += N_cc[:, :, :6, :6]
    pc = N_cc[:, :, :6, 6:] - Y_photo @ N_pc_camera[:, None]
    cc = N_cc[:, :, 6:, 6:].sum(axis=1) - Y_camera @ N_pc_camera
    b_c = np.einsum("mkai,mka->mki", Jc, chunk.e)  # (m, k, 6 + w)
    b_photo = b_c[..., :6] - np.einsum("mkir,mr->mki", Y_photo, chunk.b_p)
    b_camera = b_c[..., 6:].sum(axis=1) - np.einsum("mir,mr->mi", Y_camera, chunk.b_p)
    reduced = np.einsum("mi,mij,mj->m", chunk.b_p, N_pp_inv, chunk.b_p)
    return OneCameraReduction(pp, pc, cc, b_photo, b_camera, reduced)


def point_corrections(chunk: PointChunk, dx: np.ndarray, shift: np.ndarray | None = None):
    """Back-substitution ``dX = N_pp^-1 (b_p - N_pc dx)`` (m, 3) and the linearised whitened
    residuals after the step: plate (m, k, 2) ``Jc dx + Jp dX - e`` and control (m, 3).
    shift: (m, 3) added to dX (the distances' coupling, bundle.distances), or None."""
    dxp = np.concatenate([dx, [0.0]])
    dx_loc = dxp[chunk.cols]  # (m, k, 9); column -1 reads 0
    # N_pc dx = Jp^T (Jc dx) ray by ray: Jc dx serves the residuals too, and N_cp (m, 9k, 3) is not
    # formed (at 5,000 photos 0.054 -> 0.030 s a back substitution)
    Jc_dx = np.einsum("mkai,mki->mka", chunk.Jc, dx_loc)
    rhs = chunk.b_p - np.einsum("mkai,mka->mi", chunk.Jp, Jc_dx)
    dX = np.linalg.solve(chunk.N_pp, rhs[..., None])[..., 0]
    if shift is not None:
        dX = dX + shift
    v_plate = Jc_dx + np.einsum("mkai,mi->mka", chunk.Jp, dX) - chunk.e
    v_control = np.sqrt(chunk.weight) * (dX - chunk.control_misclosure)
    return dX, v_plate, v_control


@dataclass
class PointProducts:
    """A chunk's share of the reduced camera system in the block pattern (ReducedNormals.products),
    formed in the chunk's thread and added up in order by ReducedNormals.add_products.

    scatters: the chunk's BlockPattern.scatters (None in a lean assembly); sums: its ray-pair blocks
    summed by position for each of them (ChunkScatter.sums; None where not formed: the cameras held,
    no N); b, d: (full-space columns, numbers) added in turn to b_full and to d_full; reduced:
    sum b_p^T N_pp^-1 b_p; ee: the chunk's e^T e.
    """

    chunk: PointChunk
    scatters: tuple | None
    sums: tuple
    b: list
    d: list
    reduced: float
    ee: float


class ReducedNormals:
    """Sums the reduced camera system ``N_rcs dx = b_rcs`` of point chunks and parameter
    observations.

    The point contributions are scattered into the block pattern of N computed once per adjustment
    (block_pattern.BlockPattern: 6x6 photo, 6x3 and 3x3 camera blocks in the full element
    space); :meth:`finish` reduces it to the unknowns with the selection ``S`` (fixed elements
    dropped, tied elements summed), ``N_rcs = S^T N_full S``. The reduced camera system has the
    pattern of the conditions method's N: two photos are coupled when they see a common point.

    ``ug`` and ``gPg`` are zero: the collinearity equations are exactly invariant under a
    similarity of photos and points together (scale included), so the datum diagnosis
    (datum.diagnose) needs no misclosure term for the bundle. ``ee`` is the sum of squares of all
    whitened misclosures, ``reduced`` the part of it that the point elimination removes
    (sum b_p^T N_pp^-1 b_p); ``ee - reduced - b_rcs^T N_rcs^-1 b_rcs`` is the minimum of the
    linearised problem (Schmid 59's [LL.u]).
    """

    def __init__(self, pattern: BlockPattern, S: sp.csr_matrix, dense: DenseSchur | None = None):
        """dense: sum the points' share dense (bundle.dense; block_pattern decides), else into the
        block pattern chunk by chunk."""
        self.pattern, self.S, self.dense = pattern, S, dense
        self.n = S.shape[1]
        self.kept: list[PointChunk] = []  # the linearised chunks, for the back substitution
        if dense is None:  # the block numbers of the pattern, summed chunk by chunk
            self.pp = np.zeros(len(pattern.pp) * 36)
            self.pc = np.zeros(len(pattern.pc) * 6 * pattern.camera_width)
            self.cc = np.zeros(len(pattern.cc) * pattern.camera_width**2)
        self.b_full = np.zeros(pattern.n_full)
        self.d_full = np.zeros(pattern.n_full)  # diag of the camera normals before the points' reduction
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.ug = np.zeros(self.n)
        self.gPg = 0.0
        self.ee = 0.0
        self.reduced = 0.0
        self.N: sp.csr_matrix | None = None
        self.b: np.ndarray | None = None
        self.damped = False  # the points' blocks carry Levenberg-Marquardt damping
        # b, ee and the kept chunks only, no N (a chord step's normals, bundle.adjust; block pattern only)
        self.lean = False

    @property
    def datum_metric(self) -> np.ndarray:
        """The diagonal of the camera normals before the points' reduction, in the unknowns
        (datum.free_directions measures the free directions against it)."""
        return self.d

    def add_points(self, chunk: PointChunk, camera_of_photo: np.ndarray, scatters=None, keep: bool = True) -> None:
        """Add a linearised chunk; scatters: its BlockPattern.scatters (or, summed dense, its
        bundle.dense.DenseScatter) when worked out before; keep: hold the chunk for the back
        substitution (``kept``)."""
        if self.lean or self.dense is None:
            self.add_products(self.products(chunk, camera_of_photo, scatters), keep)
            return
        if keep:
            self.kept.append(chunk)
        photo = chunk.batch.photo_index
        self._add_dense(chunk, photo, camera_of_photo[photo], scatters)
        self.ee += chunk.sum_of_squares()

    def products(self, chunk: PointChunk, camera_of_photo: np.ndarray, scatters=None) -> PointProducts:
        """What a chunk adds to the normals in the block pattern (not summed dense): changes nothing
        shared, so that the chunk threads form it (bundle.adjust._Problem.assemble) and this
        process only adds it up (:meth:`add_products`, in the chunks' order: the same numbers as
        :meth:`add_points`). scatters: the chunk's BlockPattern.scatters when worked out before."""
        photo = chunk.batch.photo_index
        cam = camera_of_photo[photo]
        pat = self.pattern
        if self.lean:
            scatters, parts = None, self._lean_parts(chunk, photo, cam)
        elif sums_camera_columns(pat, cam):
            scatters = scatters if scatters is not None else pat.scatters(photo, cam, camera_summed=True)
            parts = self._one_camera_parts(chunk, photo, cam, scatters)
        else:
            scatters = scatters if scatters is not None else pat.scatters(photo, cam)
            parts = self._general_parts(chunk, photo, cam, scatters)
        return PointProducts(chunk, scatters, *parts, chunk.sum_of_squares())

    def add_products(self, made: PointProducts, keep: bool = True) -> None:
        """Add a chunk's :meth:`products`; keep: hold its chunk for the back substitution."""
        if keep:
            self.kept.append(made.chunk)
        for target, sums, scatter in zip((self.pp, self.pc, self.cc), made.sums, made.scatters or (None,) * 3):
            if sums is not None:
                scatter.add_sums(target, sums)
        n_full = self.pattern.n_full
        for cols, numbers in made.b:
            self.b_full += np.bincount(cols, weights=numbers, minlength=n_full)
        for cols, numbers in made.d:
            self.d_full += np.bincount(cols, weights=numbers, minlength=n_full)
        self.reduced += made.reduced
        self.ee += made.ee

    def _lean_parts(self, chunk: PointChunk, photo: np.ndarray, cam: np.ndarray):
        """products without N: ``b_c - Y b_p`` (Y = N_cp N_pp^-1, as reduce_points) and the
        diagonal of N_cc, and the points' share of the reduced sum."""
        pat = self.pattern
        m, k = photo.shape
        width = chunk.Jc.shape[-1]
        N_pp_inv = np.linalg.inv(chunk.N_pp)
        Y = chunk.N_cp @ N_pp_inv
        b_c = np.einsum("mkai,mka->mki", chunk.Jc, chunk.e).reshape(m, width * k)
        b3 = (b_c - np.einsum("mci,mi->mc", Y, chunk.b_p)).reshape(m, k, width)
        d3 = np.einsum("mkai,mkai->mki", chunk.Jc, chunk.Jc)  # diagonal of N_cc before the reduction
        full_cols = ray_columns(pat, photo, cam)  # (m, k, 6 + pattern width)
        if not pat.with_cameras:
            full_cols, b3, d3 = full_cols[..., :6], b3[..., :6], d3[..., :6]
        cols = full_cols.ravel()
        reduced = float(np.sum(np.einsum("mi,mij,mj->m", chunk.b_p, N_pp_inv, chunk.b_p)))
        return (None, None, None), [(cols, b3.ravel())], [(cols, d3.ravel())], reduced

    def _add_dense(self, chunk: PointChunk, photo: np.ndarray, cam: np.ndarray, scatter=None) -> None:
        """add_points summed dense (bundle.dense): the points' share into the DenseSchur, ``Jc^T e``
        and the diagonal of N_cc into b_full and d_full; scatter: the chunk's bundle.dense.DenseScatter
        when worked out before."""
        pat = self.pattern
        if scatter is not None:
            full_cols = scatter.full_cols
        else:
            full_cols = ray_columns(pat, photo, cam)  # (m, k, 6 + pattern width)
            full_cols = full_cols if pat.with_cameras else full_cols[..., :6]
        Jc = chunk.Jc if pat.with_cameras else chunk.Jc[..., :6]
        self.reduced += self.dense.add(Jc, chunk.Jp, chunk.N_pp, chunk.b_p, full_cols, scatter)
        b_c = np.einsum("mkai,mka->mki", Jc, chunk.e)
        d3 = np.einsum("mkai,mkai->mki", Jc, Jc)  # diagonal of N_cc before the reduction
        self.b_full += np.bincount(full_cols.ravel(), weights=b_c.ravel(), minlength=pat.n_full)
        self.d_full += np.bincount(full_cols.ravel(), weights=d3.ravel(), minlength=pat.n_full)

    def _one_camera_parts(self, chunk: PointChunk, photo: np.ndarray, cam: np.ndarray, scatters):
        """products for points that each see one camera (reduce_points_one_camera): the
        photo-camera scatter gets one block per ray, the camera-camera scatter one per point
        (BlockPattern.scatters with camera_summed)."""
        red = reduce_points_one_camera(chunk)
        pat = self.pattern
        scatter_pp, scatter_pc, scatter_cc = scatters
        sums = (scatter_pp.sums(red.pp), scatter_pc.sums(red.pc[:, :, None]), scatter_cc.sums(red.cc[:, None, None]))
        photo_cols = 6 * photo[..., None] + np.arange(6)  # (m, k, 6) full-space columns
        camera_cols = 6 * pat.n_photos + NCP * cam[:, :1] + pat.camera_elements  # (m, w)
        d3 = np.einsum("mkai,mkai->mki", chunk.Jc, chunk.Jc)  # diagonal of N_cc before the reduction
        b = [(photo_cols.ravel(), red.b_photo.ravel()), (camera_cols.ravel(), red.b_camera.ravel())]
        return sums, b, [(ray_columns(pat, photo, cam).ravel(), d3.ravel())], float(np.sum(red.reduced))

    def _general_parts(self, chunk: PointChunk, photo: np.ndarray, cam: np.ndarray, scatters):
        """products for any chunk: the (k (6 + w))^2 blocks of reduce_points, ray pair by ray pair."""
        N_loc, b_loc, reduced = reduce_points(chunk)
        m, k = photo.shape
        pat = self.pattern
        width = chunk.Jc.shape[-1]
        N5 = N_loc.reshape(m, k, width, k, width).transpose(0, 1, 3, 2, 4)  # (m, k, k, w, w): pattern order
        scatter_pp, scatter_pc, scatter_cc = scatters
        sums = (scatter_pp.sums(N5[..., :6, :6]), None, None)
        if pat.with_cameras:
            sums = (sums[0], scatter_pc.sums(N5[..., :6, 6:]), scatter_cc.sums(N5[..., 6:, 6:]))
        del N_loc, N5  # the chunk's largest array, before the thread takes its next chunk
        full_cols = ray_columns(pat, photo, cam)  # (m, k, 6 + pattern width)
        b3 = b_loc.reshape(m, k, width)
        d3 = np.einsum("mkai,mkai->mki", chunk.Jc, chunk.Jc)  # diagonal of N_cc before the reduction
        if not pat.with_cameras:
            full_cols, b3, d3 = full_cols[..., :6], b3[..., :6], d3[..., :6]
        cols = full_cols.ravel()
        return sums, [(cols, b3.ravel())], [(cols, d3.ravel())], float(np.sum(reduced))

    def add_rows(self, J: np.ndarray, cols: np.ndarray, e: np.ndarray) -> None:
        """Whitened observation equations of parameters, one row each: J (p, w), cols (p, w) in the
        columns of the unknowns (-1 = none), e (p,)."""
        self.rows.append((J, cols, e))
        self.ee += float(np.sum(e**2))

    def finish(self) -> "ReducedNormals":
        pat, S = self.pattern, self.S
        w = pat.camera_width
        if self.lean:  # b and d alone
            self.N, self.b, self.d = None, S.T @ self.b_full, S.T @ self.d_full
            for J, cols, e in self.rows:
                valid = cols >= 0
                self.b += np.bincount(cols[valid], weights=(J * e[:, None])[valid], minlength=self.n)
                self.d += np.bincount(cols[valid], weights=(J * J)[valid], minlength=self.n)
            return self
        if self.dense is not None:
            N_full, b_points = self.dense.finish()
            self.b_full += b_points
            N = pat.reduced_matrix_of_dense(S, N_full)
            self.dense = None  # the dense arrays are not needed beyond here
        else:
            N = pat.reduced_matrix(S, self.pp.reshape(-1, 6, 6), self.pc.reshape(len(pat.pc), 6, w),
                                   self.cc.reshape(len(pat.cc), w, w))
        b = S.T @ self.b_full
        for J, cols, e in self.rows:
            valid = cols >= 0
            b += np.bincount(cols[valid], weights=(J * e[:, None])[valid], minlength=self.n)
            pair = valid[:, :, None] & valid[:, None, :]
            JJ = J[:, :, None] * J[:, None, :]
            r = np.broadcast_to(cols[:, :, None], JJ.shape)[pair]
            c = np.broadcast_to(cols[:, None, :], JJ.shape)[pair]
            N = N + sp.coo_matrix((JJ[pair], (r, c)), shape=(self.n, self.n)).tocsr()
        N.sum_duplicates()
        self.N, self.b = N, b
        # Levenberg-Marquardt scaling: the diagonal of J^T J of the orientation unknowns (points not
        # yet eliminated), with the parameter observations' share
        self.d = S.T @ self.d_full
        for J, cols, _ in self.rows:
            valid = cols >= 0
            self.d += np.bincount(cols[valid], weights=(J * J)[valid], minlength=self.n)
        return self


def block_pattern(batches, state: State, layout: UnknownLayout, chunk_size: int):
    """The block pattern of the reduced camera system, the selection S, whether the points' share
    is summed dense (bundle.dense.dense_pays) and, when it is not, each chunk's scatter (in the
    order of the chunks; None each when dense), computed once: (pattern, S, dense, scatters)."""
    chunks = [(c.photo_index, state.camera_of_photo[c.photo_index]) for b in batches for c in b.chunks(chunk_size)]
    pattern = BlockPattern(len(state.xyz0), len(state.interior), bool((layout.camera_cols >= 0).any()), chunks,
                           layout.camera_elements)
    dense = dense_pays(pattern, [photo for photo, _ in chunks])
    scatters = [None if dense else pattern.scatters(photo, cam, sums_camera_columns(pattern, cam))
                for photo, cam in chunks]
    S = selection_matrix(layout.photo_cols, layout.camera_cols, layout.n_unknowns)
    pattern.reduction(S)
    return pattern, S, dense, scatters
