"""Step-by-step formation of the normal equations (Schmid 36-38, 46-50; DESIGN section 4).

Each group is whitened with the Cholesky factor of ``M = A Q A^T`` (``M = L L^T``):
``B~ = L^-1 B``, ``w~ = L^-1 w`` are Schmid's pseudo-observations with their cross-weights folded
in, and the group adds ``B~^T B~`` to N and ``B~^T w~`` to u. Contributions are scattered into the
global matrix chunk by chunk, so memory does not grow with the number of points.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .block_pattern import BlockPattern, ChunkScatter, ray_columns
from .linearise import GroupSystem
from .ray_columns import RayColumns, of_system as by_ray_of
from . import weights


class Whitened(NamedTuple):
    """A chunk of whitened groups (whiten): Bw = L^-1 B (m, nc, nu), ww = L^-1 w and gw = L^-1 g
    (m, nc), L^-1 (m, nc, nc) (M = A Q A^T = L L^T), Gt = L^-1 A Q (m, nc, no) or None, B by
    ray (ray_columns.RayColumns) for the chunks of long tracks, else None, and clear (m,) bool,
    whether each M is clearly regular (:func:`clearly_regular`), or None."""

    Bw: np.ndarray
    ww: np.ndarray
    gw: np.ndarray
    Linv: np.ndarray
    Gt: np.ndarray | None
    by_ray: RayColumns | None
    clear: np.ndarray | None = None


CLEARLY_REGULAR = 1e-8  # clearly_regular: eigenvalues that span less than 1e8


def clearly_regular(M: np.ndarray, Minv: np.ndarray) -> np.ndarray:
    """Whether each positive definite M (m, n, n), with its inverse Minv, is clearly regular:
    ``1 / (|M|_F |M^-1|_F)``, a lower bound of its smallest over its largest eigenvalue, above
    CLEARLY_REGULAR (triangulation.safe_inverse keeps such an inverse without computing eigenvalues)."""
    bound = 1.0 / (np.sqrt(np.einsum("mij,mij->m", M, M)) * np.sqrt(np.einsum("mij,mij->m", Minv, Minv)))
    return bound > CLEARLY_REGULAR


def whiten(system: GroupSystem, residual_map: bool = False, regularity: bool = False) -> Whitened:
    """L^-1 B, L^-1 w, L^-1 g and L^-1 for each group (M = A Q A^T = L L^T), and with residual_map
    also ``L^-1 A Q`` (m, nc, no): the map from the whitened ``t = L^-1 (w + B dx)`` to the
    residuals, ``v = Q A^T k = -(L^-1 A Q)^T t``, so that the back substitution needs no second
    linearisation; with regularity also whether each M is clearly regular (clearly_regular).
    Batched: one triangular factorisation and one solve with all right-hand sides.
    For long tracks L^-1 B is formed ray by ray from B's compact form (ray_columns)."""
    AQ = system.A * system.Q[:, None, :]
    M = np.matmul(AQ, np.swapaxes(system.A, 1, 2))
    L = np.linalg.cholesky(M)
    m, nc = system.g.shape
    nu, no = system.cols.shape[-1], AQ.shape[-1]
    by_ray = by_ray_of(system)
    rhs = [system.w[..., None], system.g[..., None]] + ([AQ] if residual_map else [])
    # L^-1 times all right-hand sides: the inverse of the small triangular L and one batched
    # product is three times faster than a batched LU solve (the conditions are scaled to unit
    # variance, so L is well conditioned)
    Linv = lower_inverse(L)
    solved = np.matmul(Linv, np.concatenate(rhs, axis=-1))
    ww, gw = solved[..., 0], solved[..., 1]
    Gt = solved[..., 2 : 2 + no] if residual_map else None
    Bw = np.matmul(Linv, system.B) if by_ray is None else by_ray.left(Linv).reshape(m, nc, nu)
    clear = clearly_regular(M, np.matmul(np.swapaxes(Linv, 1, 2), Linv)) if regularity else None
    return Whitened(Bw, ww, gw, Linv, Gt, by_ray, clear)


TRIANGULAR_BLOCK = 16  # lower_inverse: row by row up to this size


def lower_inverse(L: np.ndarray) -> np.ndarray:
    """L^-1 of lower-triangular matrices L (..., n, n), by halves:
    ``[[A, 0], [C, D]]^-1 = [[A^-1, 0], [-D^-1 C A^-1, D^-1]]``, the halves in turn, and row by
    row (_lower_inverse_rows) from TRIANGULAR_BLOCK rows down. np.linalg.inv treats L as a general
    matrix (an LU factorisation, then n solves: eight times the arithmetic of a triangular
    inverse), which for the 129 conditions of a 66-ray close-range target was the largest part
    of the whitening; measured on one core, 3 groups of 129 conditions 5.0 -> 1.3 ms, 10 of 60
    3.0 -> 1.2 ms; the aerial groups (9 conditions and fewer) are not split."""
    n = L.shape[-1]
    if n <= TRIANGULAR_BLOCK:
        return _lower_inverse_rows(L)
    h = n // 2
    A_inv, D_inv = lower_inverse(L[..., :h, :h]), lower_inverse(L[..., h:, h:])
    out = np.zeros_like(L)
    out[..., :h, :h] = A_inv
    out[..., h:, h:] = D_inv
    out[..., h:, :h] = -D_inv @ (L[..., h:, :h] @ A_inv)
    return out


def _lower_inverse_rows(L: np.ndarray) -> np.ndarray:
    """L^-1 of lower-triangular matrices L (..., n, n) by forward substitution of the identity,
    one row at a time for all matrices at once: row i of X = L^-1 is ``(e_i - L[i, :i] X[:i]) /
    L[i, i]``, whose columns beyond i are zero. A third of np.linalg.inv's time for the aerial
    groups' 3 to 9 conditions (1,024 groups of 9: 1.52 -> 0.51 ms), half for 16."""
    n = L.shape[-1]
    X = np.zeros_like(L)
    d = 1.0 / np.diagonal(L, axis1=-2, axis2=-1)  # (..., n)
    for i in range(n):
        if i:
            X[..., i, :i] = -(L[..., i : i + 1, :i] @ X[..., :i, :i])[..., 0, :] * d[..., i : i + 1]
        X[..., i, i] = d[..., i]
    return X


class NormalAccumulator:
    """Sums ``B~^T B~`` and ``B~^T w~`` of group chunks into a sparse N and a dense u."""

    def __init__(self, n_unknowns: int):
        self.n = n_unknowns
        self.N = sp.csr_matrix((n_unknowns, n_unknowns))
        self.u = np.zeros(n_unknowns)
        self.wPw = 0.0  # sum of w~^T w~ (Schmid 59: [LL])
        # sum B~^T g~ and g~^T g~ of the misclosures at l^ (used by the datum diagnosis: the tie
        # conditions are homogeneous of degree one in the scale of the block, so B h_scale = g)
        self.ug = np.zeros(n_unknowns)
        self.gPg = 0.0

    def add(self, Bw: np.ndarray, ww: np.ndarray, cols: np.ndarray, gw: np.ndarray | None = None) -> None:
        """Bw: (m, nc, nu) whitened B; ww, gw: (m, nc) whitened w and g; cols: (m, nu) global
        columns, -1 = fixed."""
        self.wPw += float(np.sum(ww * ww))
        gw = ww if gw is None else gw
        self.gPg += float(np.sum(gw * gw))
        if Bw.shape[-1] == 0 or self.n == 0:
            return
        if Bw.shape[0] == 1:  # one large group (a joint group of points joined by distances)
            Bw, cols = _columns_summed(Bw, cols)
        Nloc = np.swapaxes(Bw, 1, 2) @ Bw  # batched BLAS products
        uloc = np.einsum("mca,mc->ma", Bw, ww)
        valid = cols >= 0
        self.u += np.bincount(cols[valid], weights=uloc[valid], minlength=self.n)
        uglo = np.einsum("mca,mc->ma", Bw, gw)
        self.ug += np.bincount(cols[valid], weights=uglo[valid], minlength=self.n)
        pair = valid[:, :, None] & valid[:, None, :]
        rows = np.broadcast_to(cols[:, :, None], Nloc.shape)[pair]
        cc = np.broadcast_to(cols[:, None, :], Nloc.shape)[pair]
        chunk = sp.coo_matrix((Nloc[pair], (rows, cc)), shape=(self.n, self.n)).tocsr()
        self.N = self.N + chunk

    def add_rows(self, grad: np.ndarray, cols: np.ndarray, misclosure: np.ndarray, sigma: np.ndarray) -> None:
        """Parameter observations: one condition each, B = -grad, w = misclosure, M = sigma^2."""
        Bw = weights.whiten(-grad, sigma[:, None])[:, None, :]
        ww = weights.whiten(misclosure, sigma)[:, None]
        self.add(Bw, ww, cols, np.zeros_like(ww))


def _columns_summed(Bw: np.ndarray, cols: np.ndarray):
    """One group's Bw (1, nc, nu) with the columns of the same unknown summed (they are one unknown:
    the rays of a joint group share their photos, 573 rays of 24 photos in a close range with a
    distance between every pair of targets), so that its product is over the distinct unknowns.
    -> (Bw (1, nc, nu'), cols (1, nu')); fixed columns (-1) stay one column, dropped as before."""
    unique, inverse = np.unique(cols[0], return_inverse=True)
    if len(unique) == cols.shape[1]:
        return Bw, cols
    S = sp.csr_matrix((np.ones(len(inverse)), (np.arange(len(inverse)), inverse)), shape=(len(inverse), len(unique)))
    return (S.T @ Bw[0].T).T[None], unique[None]


# From this many rays per point on, the ray-pair blocks come from the whole product Bw^T Bw of a
# group (BLAS) instead of batched products of its rays' column groups (faster for short tracks):
# measured on 2 cores, 8 rays 2.5 ms vs 2.8 ms per chunk, 20 rays 3.4 ms vs 2.6 ms, 67 rays 5.1 vs 1.4 ms.
FULL_PRODUCT_RAYS = 12


def sums_camera_columns(pattern: BlockPattern, cam: np.ndarray) -> bool:
    """Whether PatternAccumulator.add_groups sums the camera columns of a chunk with cameras
    cam (m, k) over each group's rays: the cameras are estimated, its groups have FULL_PRODUCT_RAYS
    rays or more and all rays of each group are of one camera. Such a chunk's scatters are
    BlockPattern.scatters with camera_summed."""
    return bool(pattern.with_cameras and cam.shape[1] >= FULL_PRODUCT_RAYS and np.all(cam == cam[:, :1]))


class GroupProducts(NamedTuple):
    """What a chunk of whitened groups adds to N and u (group_products), before it is summed into
    the block pattern (PatternAccumulator.add_products): the ray-pair blocks B~_a^T B~_b of the
    photos (pp, (m, k, k, 6, 6)), of photos and cameras (pc) and of cameras (cc) (None when the
    cameras are held), B~^T [w~ g~] per full column (ug, (m, k width, 2)) with those columns
    (full_cols), the sums w~^T w~ and g~^T g~, and the chunk's photos and cameras (m, k).
    summed: pp, pc and cc are already summed by pattern position (ChunkScatter.sums of the
    chunk's scatters, given to group_products)."""

    pp: np.ndarray
    pc: np.ndarray | None
    cc: np.ndarray | None
    ug: np.ndarray
    full_cols: np.ndarray
    wPw: float
    gPg: float
    photo: np.ndarray
    cam: np.ndarray
    one_camera: bool
    summed: bool = False


def group_products(pat: BlockPattern, Bw, ww, gw, photo, cam, white: Whitened | None = None,
                   scatters=None) -> GroupProducts:
    """The products of a chunk of whitened groups (GroupProducts; arguments as
    PatternAccumulator.add_groups). Changes nothing shared: the chunk threads of an assembly
    (parallel.map_ordered) form them while the caller sums the chunks before. white: the chunk's
    Whitened (whiten), whose B by ray, where it has one, gives the blocks of long one-camera
    tracks as ``B^T (M^-1 B)`` ray by ray (ray_columns) instead of the dense ``B~^T B~``.
    scatters: the chunk's BlockPattern.scatters; the blocks are then summed by position here
    (ChunkScatter.sums), in the chunk's thread, leaving the caller only their addition."""
    made = _group_products(pat, Bw, ww, gw, photo, cam, white)
    if scatters is None:
        return made
    _check_scatters(made, scatters)
    sums = [None if b is None else sc.sums(b) for b, sc in zip((made.pp, made.pc, made.cc), scatters)]
    return made._replace(pp=sums[0], pc=sums[1], cc=sums[2], summed=True)


def _check_scatters(products: GroupProducts, scatters) -> None:
    m, k = products.photo.shape
    if products.one_camera and scatters[1].P.shape[1] != m * k:
        raise ValueError("a chunk of long one-camera tracks needs BlockPattern.scatters with camera_summed")


def group_misclosures(pat: BlockPattern, Bw, ww, gw, photo, cam) -> GroupProducts:
    """What a chunk adds to u, w^T P w and g^T P g, without N's blocks (pp, pc and cc None;
    arguments as group_products): an iteration that solves on the factor of an earlier N
    (conditions_method.adjust, chord steps) forms no new N."""
    Bw, full_cols, ug, one_camera = _misclosure_products(pat, Bw, ww, gw, photo, cam)
    return GroupProducts(None, None, None, ug, full_cols.reshape(photo.shape[0], -1), float(np.sum(ww * ww)),
                         float(np.sum(gw * gw)), photo, cam, one_camera, summed=True)


def _misclosure_products(pat: BlockPattern, Bw, ww, gw, photo, cam):
    """Bw with the columns that count (only the 6 photo columns of each ray when the cameras are
    held), their full-space columns (m, k, 6 + w), ``B~^T [w~ g~]`` (m, k (6 + w), 2) and whether
    the chunk sums its camera columns (sums_camera_columns)."""
    m, k = photo.shape
    full_cols = ray_columns(pat, photo, cam)  # (m, k, 6 + w)
    if not pat.with_cameras:  # cameras held: only the 6 photo columns of each ray count
        Bw = Bw.reshape(m, Bw.shape[1], k, -1)[..., :6].reshape(m, -1, 6 * k)
        full_cols = full_cols[..., :6]
    ug = np.matmul(np.swapaxes(Bw, 1, 2), np.stack([ww, gw], -1))
    return Bw, full_cols, ug, sums_camera_columns(pat, cam)


def _group_products(pat: BlockPattern, Bw, ww, gw, photo, cam, white: Whitened | None) -> GroupProducts:
    m, k = photo.shape
    wPw, gPg = float(np.sum(ww * ww)), float(np.sum(gw * gw))
    Bw, full_cols, ug, one_camera = _misclosure_products(pat, Bw, ww, gw, photo, cam)
    width = full_cols.shape[-1]
    if white is not None and white.by_ray is not None and (one_camera or not pat.with_cameras):
        pp, pc, cc = _blocks_by_ray(white, pat.with_cameras)
        return GroupProducts(pp, pc, cc, ug, full_cols.reshape(m, k * width), wPw, gPg, photo, cam, one_camera)
    pc = cc = None
    # the ray-pair blocks B~_a^T B~_b directly in pattern order (m, k, k, r, s): batched products
    # of the rays' column groups, no transposed copy of a (m, 6k, 6k) product
    if one_camera:
        # long tracks of one camera each (close range): the camera columns of a group's rays
        # summed first (they are the same unknowns), then one (6k + w)^2 product per group;
        # the camera-summed scatters take photo a with the camera once per ray (m, k, 6, w)
        # and the camera with itself once per group (m, w, w)
        nc = Bw.shape[1]
        B4 = Bw.reshape(m, nc, k, width)
        Bc = B4[..., 6:].sum(axis=2)  # (m, nc, w)
        Bpc = np.concatenate([B4[..., :6].reshape(m, nc, 6 * k), Bc], axis=2)
        full = np.matmul(np.swapaxes(Bpc, 1, 2), Bpc)
        pp = full[:, : 6 * k, : 6 * k].reshape(m, k, 6, k, 6).transpose(0, 1, 3, 2, 4)
        w = width - 6
        pc = full[:, : 6 * k, 6 * k :].reshape(m, k, 1, 6, w)
        cc = full[:, None, None, 6 * k :, 6 * k :]
    elif k >= FULL_PRODUCT_RAYS:
        # long tracks: one (k width)^2 product per group in BLAS, then viewed as ray-pair blocks
        full = np.matmul(np.swapaxes(Bw, 1, 2), Bw).reshape(m, k, width, k, width).transpose(0, 1, 3, 2, 4)
        pp = full[..., :6, :6]
        if pat.with_cameras:
            pc, cc = full[..., :6, 6:], full[..., 6:, 6:]
    else:
        B4 = Bw.reshape(m, Bw.shape[1], k, width)
        left = B4.transpose(0, 2, 3, 1)[:, :, None]  # (m, k, 1, width, nc)
        right = B4.transpose(0, 2, 1, 3)[:, None]  # (m, 1, k, nc, width)
        pp = np.matmul(left[..., :6, :], right[..., :6])
        if pat.with_cameras:
            pc = np.matmul(left[..., :6, :], right[..., 6:])
            cc = np.matmul(left[..., 6:, :], right[..., 6:])
    return GroupProducts(pp, pc, cc, ug, full_cols.reshape(m, k * width), wPw, gPg, photo, cam, one_camera)


def _blocks_by_ray(white: Whitened, with_cameras: bool):
    """The blocks pp (m, k, k, 6, 6), pc (m, k, 1, 6, w) and cc (m, 1, 1, w, w) (None without
    cameras) of ``B^T M^-1 B`` of a chunk of long one-camera tracks (group_products' one-camera
    layout: the camera columns summed over each group's rays), from B by ray (RayColumns.quadratic_blocks,
    RayColumns.transposed); M^-1 = L^-T L^-1."""
    rc = white.by_ray
    Minv = np.matmul(np.swapaxes(white.Linv, 1, 2), white.Linv)
    pp = rc.quadratic_blocks(Minv, 6)
    if not with_cameras:
        return pp, None, None
    Bcam = rc.summed[..., 6:]  # (m, nc, w): the camera columns summed over the rays
    Yc = np.matmul(Minv, Bcam)
    pc = rc.transposed(Yc, 6)[:, :, None]  # (m, k, 1, 6, w)
    cc = np.matmul(np.swapaxes(Bcam, 1, 2), Yc)[:, None, None]
    return pp, pc, cc


class PatternAccumulator:
    """Sums the whitened groups into the block pattern (module doc); the same outputs as
    NormalAccumulator (N, u, wPw, ug, gPg) once :meth:`finish` has been called; with normals False
    (chunks of group_products with normals False) all but N, which is None."""

    def __init__(self, pattern: BlockPattern, S: sp.csr_matrix, normals: bool = True):
        self.pattern, self.S, self.normals = pattern, S, normals
        self.pp = np.zeros(len(pattern.pp) * 36 if normals else 0)
        self.pc = np.zeros(len(pattern.pc) * 6 * pattern.camera_width if normals else 0)
        self.cc = np.zeros(len(pattern.cc) * pattern.camera_width**2 if normals else 0)
        self.u_full = np.zeros(pattern.n_full)
        self.ug_full = np.zeros(pattern.n_full)
        self.wPw = 0.0
        self.gPg = 0.0
        self.extra = NormalAccumulator(S.shape[1])

    def add_groups(self, Bw, ww, gw, photo, cam, scatters=None) -> None:
        """Bw: (m, nc, wk) whitened B with w columns per ray (6 photo, then NCP camera when the
        cameras are estimated); photo, cam: (m, k); scatters: the chunk's BlockPattern.scatters
        when worked out before (computed here otherwise)."""
        self.add_products(group_products(self.pattern, Bw, ww, gw, photo, cam), scatters)

    def add_products(self, products: "GroupProducts", scatters=None) -> None:
        """A chunk's group_products summed into N's blocks and u (the chunk's scatters as in add_groups)."""
        pat = self.pattern
        self.wPw += products.wPw
        self.gPg += products.gPg
        photo, cam = products.photo, products.cam
        if scatters is None:
            scatters = pat.scatters(photo, cam, sums_camera_columns(pat, cam))
        if not products.summed:
            _check_scatters(products, scatters)

        def add(scatter: ChunkScatter, target: np.ndarray, numbers: np.ndarray) -> None:
            if products.summed:  # summed by position in the chunk's thread (group_products)
                scatter.add_sums(target, numbers)
            else:
                scatter.add(target, numbers)

        if products.pp is not None:
            add(scatters[0], self.pp, products.pp)
        if products.pc is not None:
            add(scatters[1], self.pc, products.pc)
            add(scatters[2], self.cc, products.cc)
        cols = products.full_cols.ravel()
        self.u_full += np.bincount(cols, weights=products.ug[..., 0].ravel(), minlength=pat.n_full)
        self.ug_full += np.bincount(cols, weights=products.ug[..., 1].ravel(), minlength=pat.n_full)

    def add_rows(self, grad, cols, misclosure, sigma) -> None:
        """Parameter observations (in the reduced columns), as NormalAccumulator.add_rows."""
        self.extra.add_rows(grad, cols, misclosure, sigma)

    def finish(self) -> "PatternAccumulator":
        pat, S = self.pattern, self.S
        w = pat.camera_width
        self.N = None if not self.normals else pat.reduced_matrix(
            S, self.pp.reshape(-1, 6, 6), self.pc.reshape(len(pat.pc), 6, w), self.cc.reshape(len(pat.cc), w, w))
        self.pp = self.pc = self.cc = None  # N holds the numbers now
        if self.normals and self.extra.N.nnz:
            self.N = (self.N + self.extra.N).tocsr()
            self.N.sum_duplicates()
        self.u = S.T @ self.u_full + self.extra.u
        self.ug = S.T @ self.ug_full + self.extra.ug
        self.wPw += self.extra.wPw
        self.gPg += self.extra.gPg
        return self
