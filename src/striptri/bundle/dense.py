"""The reduced camera system summed dense, for small blocks with long tracks (close range).

Eliminating a point adds ``-Y N_pc`` to the reduced camera system (bundle.reduced), with
``Y = N_cp N_pp^-1`` (3 columns, rows in the columns of the point's rays). Set the Y of all points
side by side in one matrix G_Y (rows: the full parameter space of block_pattern.BlockPattern;
3 columns per point), their N_cp likewise in G_N, and the points' share of the whole system is
``-G_Y G_N^T``: one BLAS product for all points instead of k^2 ray-pair blocks per point scattered
into the pattern. Likewise ``b_rcs`` gets ``-G_Y b_p`` (b_p of all points stacked) and the reduced
sum of squares ``sum b_p^T N_pp^-1 b_p``. The block-diagonal ``N_cc`` (each ray's ``Jc^T Jc``) is
added in place. (``N_pp^-1`` as the other ways form it, not by a Cholesky factor: a nearly
singular N_pp, c in the wrong unit, must fail where they fail.)

The product costs ``n_full^2`` per point column, whatever the tracks; the ray pairs cost
``(6k)^2`` per point. So it pays where the system is small and the tracks are long, N's blocks
mostly filled (close range: every target seen by half the photos); :func:`dense_pays` decides once
per adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..equations.block_pattern import BlockPattern, ray_columns

# Dense when the product's work, n_full^2 per point, is at most this many times the ray pairs'
# (6k)^2 per point: BLAS does the one product so much faster than numpy the small blocks and their
# scatter. Measured (one thread, a close range of 115 photos and 1,500 targets, rays dropped at
# random; the work ratio, then an assembly dense against by ray pairs): 2.8, 0.26 s against 1.16 s;
# 11, 0.18 s against 0.30 s; 30, 0.147 s against 0.135 s; 67, 0.141 s against 0.075 s.
DENSE_WORK_RATIO = 16
DENSE_BYTES = 2**26  # the largest dense N_full, G_Y and G_N held (64 MiB each)


def dense_pays(pattern: BlockPattern, photo_of_chunks) -> bool:
    """Whether the reduced camera system of these point chunks (photo_index (m, k) of each) is
    summed dense (module doc): N_full, G_Y and G_N each fit in DENSE_BYTES and the product's work
    is at most DENSE_WORK_RATIO times the ray pairs'."""
    n = pattern.n_full
    n_points = sum(len(photo) for photo in photo_of_chunks)
    ray_pairs = sum(photo.shape[0] * photo.shape[1] ** 2 for photo in photo_of_chunks)
    return (n_points > 0 and 8 * n * n <= DENSE_BYTES and 8 * n * 3 * n_points <= DENSE_BYTES
            and n * n * n_points <= DENSE_WORK_RATIO * 36 * ray_pairs)


@dataclass(frozen=True)
class DenseScatter:
    """Where one chunk's numbers go in a DenseSchur, worked out once per adjustment (they depend only
    on the chunk's photos and cameras): full_cols (m, k, w) the full-space columns of each ray;
    first: the chunk's first point column in G_Y and G_N (3 per point, chunks in assembly order);
    at_G (m k w 3,) and at_N (m k w w,): flat places in G_Y / G_N and in N_full (int32: a dense
    system has fewer than 2^31 places, DENSE_BYTES)."""

    full_cols: np.ndarray
    first: int
    at_G: np.ndarray
    at_N: np.ndarray


def dense_scatters(pattern: BlockPattern, chunks) -> list[DenseScatter]:
    """The DenseScatter of each chunk, (photo_index (m, k), camera_index (m, k)) in assembly order."""
    n_cols = 3 * sum(len(photo) for photo, _ in chunks)
    out, first = [], 0
    for photo, cam in chunks:
        full_cols = ray_columns(pattern, photo, cam)
        full_cols = full_cols if pattern.with_cameras else full_cols[..., :6]
        out.append(DenseScatter(full_cols, first, *_places(full_cols, first, n_cols, pattern.n_full)))
        first += 3 * len(photo)
    return out


def _places(full_cols: np.ndarray, first: int, n_cols: int, n_full: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat places in G (n_full, n_cols) of the chunk's N_cp and Y, (m, k, w, 3), and in N_full of
    its rays' N_cc, (m, k, w, w)."""
    m = len(full_cols)
    point_cols = first + 3 * np.arange(m)[:, None] + np.arange(3)  # (m, 3) columns of G
    at_G = (full_cols[..., None] * n_cols + point_cols[:, None, None, :]).ravel()
    at_N = (full_cols[..., :, None] * n_full + full_cols[..., None, :]).ravel()
    return at_G.astype(np.int32), at_N.astype(np.int32)


class DenseSchur:
    """Sums the points' share of the reduced camera system dense in the full space (module doc):
    N_cc, G_Y, G_N chunk by chunk, ``-G_Y G_N^T`` and ``-G_Y b_p`` at :meth:`finish`."""

    def __init__(self, n_full: int, n_points: int):
        self.N_full = np.zeros((n_full, n_full))
        self.G_Y = np.zeros((n_full, 3 * n_points))
        self.G_N = np.zeros((n_full, 3 * n_points))
        self.b_p = np.zeros(3 * n_points)
        self.used = 0  # columns of G_Y and G_N filled

    def add(self, Jc: np.ndarray, Jp: np.ndarray, N_pp: np.ndarray, b_p: np.ndarray, full_cols: np.ndarray,
            scatter: DenseScatter | None = None) -> float:
        """Add m points with k rays each: Jc (m, k, 2, w) whitened orientation Jacobians in the
        full-space columns full_cols (m, k, w) (the camera columns of rays of one camera are the
        same), Jp (m, k, 2, 3), N_pp (m, 3, 3), b_p (m, 3); scatter: the chunk's DenseScatter when
        worked out before (used where its first column is the next free one). Returns
        sum b_p^T N_pp^-1 b_p."""
        m = len(N_pp)
        n_full, n_cols = self.G_Y.shape
        if scatter is not None and scatter.first == self.used:
            at_G, at_N = scatter.at_G, scatter.at_N
        else:
            at_G, at_N = _places(full_cols, self.used, n_cols, n_full)
        N_pp_inv = np.linalg.inv(N_pp)
        Jc_T = np.swapaxes(Jc, 2, 3)
        N_cp = Jc_T @ Jp  # (m, k, w, 3)
        Y = N_cp @ N_pp_inv[:, None]
        np.add.at(self.G_Y.reshape(-1), at_G, Y.ravel())  # shared camera columns summed
        np.add.at(self.G_N.reshape(-1), at_G, N_cp.ravel())
        self.b_p[self.used : self.used + 3 * m] = b_p.ravel()
        self.used += 3 * m
        N_cc = Jc_T @ Jc  # (m, k, w, w): each ray's block
        np.add.at(self.N_full.reshape(-1), at_N, N_cc.ravel())
        return float(np.sum(np.einsum("mi,mij,mj->m", b_p, N_pp_inv, b_p)))

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """The points' share of the reduced camera system in the full space: N_full (n_full, n_full)
        ``N_cc - G_Y G_N^T`` and ``-G_Y b_p`` (n_full,), the share of b beyond ``Jc^T e``."""
        G_Y, G_N = self.G_Y[:, : self.used], self.G_N[:, : self.used]
        self.N_full -= G_Y @ G_N.T
        return self.N_full, -(G_Y @ self.b_p[: self.used])
