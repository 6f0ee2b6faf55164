"""The ``banded`` route of the selected inversion: a strip's N (banded photo part, dense border of
camera columns), by the Takahashi recurrence on column blocks of the band (:class:`BandedInverse`).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.linalg import lapack

from ..solvers import SingularNormalMatrix, Structure
from ..solvers.banded import choose_split
from ..solvers.base import check_pivots
from ..solvers.direct import dense_cholesky
from .engine import SOLVE_CHUNK, Engine, not_fixed


def _lower_band(A: sp.csr_matrix, k: int, w: int) -> np.ndarray:
    """LAPACK lower band storage ab[i - j, j] = A[i, j] of the leading k x k part of A."""
    ab = np.zeros((w + 1, k))
    end = A.indptr[k]
    rows = np.repeat(np.arange(k), np.diff(A.indptr[: k + 1]))
    cols = A.indices[:end]
    below = rows - cols
    keep = (below >= 0) & (cols < k)
    ab[below[keep], cols[keep]] = A.data[:end][keep]
    return ab


def _from_band(cb: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """Dense L[r0:r1, c0:c1] from lower band storage cb[i - j, j] = L[i, j]."""
    d, cols, inside = _band_index(cb.shape[0] - 1, r0 - c0, r1 - r0, c1 - c0)
    return np.where(inside, cb[d, cols + c0], 0.0)


@functools.lru_cache(maxsize=8)
def _band_index(w: int, shift: int, n_rows: int, n_cols: int):
    """Index arrays of an (n_rows, n_cols) window, rows starting ``shift`` below the columns, in band
    storage of lower bandwidth w: (clipped diagonal, column offset, inside the band)."""
    d = shift + np.arange(n_rows)[:, None] - np.arange(n_cols)[None, :]
    inside = (d >= 0) & (d <= w)
    return np.clip(d, 0, w), np.broadcast_to(np.arange(n_cols)[None, :], d.shape), inside


class BandedInverse(Engine):
    """Selected inversion of a strip's N: banded photo part A, dense border of camera columns.

    Split (as the ``banded`` solver does, :func:`striptri.solvers.banded.choose_split`)

        N~ = [A  B]    A: k x k, lower bandwidth w;  B: k x m;  C: m x m (m border columns)
             [B' C]

    **Banded part.** ``A = L L'`` by LAPACK pbtrf (scipy.linalg.cholesky_banded). The columns are
    cut into blocks of nb >= w columns; L is then block bidiagonal (column block t has rows only in
    blocks t and t+1), and the Takahashi equations (package docstring) become, with
    ``M = L_{t+1,t}``,

        Z_{t+1,t} = -Z_{t+1,t+1} M L_tt^-1,      Z_tt = L_tt^-T (L_tt^-1 - M' Z_{t+1,t}),

    run from the last block back to the first with dense BLAS kernels on nb x nb blocks:
    O(k nb^2) = O(k w^2) work (the cost of the factorisation) and O(nb^2) memory beyond the factor:
    only ``Z_{t+1,t+1}`` is carried from one step to the next. The requested entries are read as the
    pass goes by: every entry whose two indices are less than nb apart (so every 6x6 block of
    photos within two photos of each other) lies in ``Z_tt`` or ``Z_{t+1,t}``.

    **Border (arrowhead).** Block elimination ``N~ = [I 0; Y' I] [A 0; 0 S] [I Y; 0 I]`` with
    ``Y = A^-1 B`` (pbtrs) and the Schur complement ``S = C - B' Y`` (dense Cholesky
    ``S = R R'``) gives

        N~^-1 = [A^-1 + Y S^-1 Y'   -Y S^-1]
                [-S^-1 Y'            S^-1  ]

    So the camera block is ``S^-1``, the photo-camera blocks are ``-Y S^-1``, and the photo part
    is the banded part's inverse plus a correction of rank m: with ``W = Y R^-T`` (k x m),
    ``(Y S^-1 Y')_ij = W_i . W_j``, which costs m per requested entry and is added only to the
    entries asked for (the recurrence itself runs on A alone). The pivots are those of the
    Cholesky factorisation of the whole N~ (the same test as the ``banded`` solver).

    Entries further than nb apart are solved for with the factor (``solve``).

    **The band of the inverse, kept.** The first request runs the pass once and keeps the band of
    ``A^-1`` within the bandwidth w of the diagonal (lower band storage, the size of the factor);
    every later request reads its entries there (``hi - lo <= w``: all 6x6 blocks of photos that
    share a point in a strip) or, beyond the band, solves for them. Requests come chunk by chunk
    (covariance.group_forms), so a pass per request would cost O(k^2 w^2 / chunk) on a long strip:
    at 100,000 photos 67 s instead of 3 s.
    """

    name = "banded"

    def __init__(self, As: sp.csr_matrix, structure: Structure, min_block: int):
        """As: the scaled N~ (n x n CSR); min_block: the smallest column block nb of the recurrence
        (fewer, larger Python steps; the package's MIN_BAND_BLOCK)."""
        super().__init__()
        n = self.n = As.shape[0]
        k, w = choose_split(As, structure)
        m = n - k
        self.k, self.w, self.m = k, w, m
        self.nb = max(w, min(min_block, k), 1)
        cb, info = lapack.dpbtrf(_lower_band(As, k, w), lower=1)
        if info > 0:
            raise SingularNormalMatrix(info - 1)
        check_pivots(cb[0])
        self.cb = cb
        if m:
            B = As[:k, k:].toarray()
            C = As[k:, k:].toarray()
            Y, info = lapack.dpbtrs(cb, B, lower=1)
            S = C - B.T @ Y
            try:
                R = dense_cholesky(S)
            except SingularNormalMatrix as exc:
                raise SingularNormalMatrix(k + exc.column if exc.column is not None else None) from exc
            self.Y, self.R = Y, R
            self.W = la.solve_triangular(R, Y.T, lower=True, check_finite=False).T  # Y R^-T
            self.S_inv = la.cho_solve((R, True), np.eye(m), check_finite=False)
            self.cross = -Y @ self.S_inv  # N~^-1[:k, k:]
        self.info = {"bandwidth": w, "border": m, "block": self.nb}
        self.band = None  # (w + 1, k): band[d, j] = A^-1[j + d, j], filled by the first pass

    def solve(self, B):
        k = self.k
        y1, _ = lapack.dpbtrs(self.cb, B[:k], lower=1)
        if not self.m:
            return y1
        y2 = la.cho_solve((self.R, True), B[k:] - self.Y.T @ B[:k], check_finite=False)
        return np.vstack([y1 - self.Y @ y2, y2])

    def compute(self, rows, cols):
        """Entries asked for afterwards: from the kept band of the inverse (one pass fills it);
        before it exists, from solves when they lie in fewer than nb columns (each solve costs
        about what the pass spends on nb columns)."""
        few = self.band is None and len(np.unique(np.minimum(rows, cols))) < self.nb
        return self._run(rows, cols, in_pass=not few)[0]

    def compute_with_diag(self, rows, cols):
        return self._run(rows, cols, in_pass=True)

    def _run(self, rows, cols, in_pass: bool):
        k = self.k
        ok, out = not_fixed(rows, cols)
        hi, lo = np.maximum(rows, cols), np.minimum(rows, cols)
        photo = ok & (hi < k)
        border = ok & (lo >= k)
        mixed = ok & (lo < k) & (hi >= k)
        if self.m:
            out[border] = self.S_inv[hi[border] - k, lo[border] - k]
            out[mixed] = self.cross[lo[mixed], hi[mixed] - k]
        if in_pass and self.band is None:
            self.band = np.empty((self.w + 1, k))
            self._pass(self.band)
        if self.band is not None:
            near = photo & (hi - lo <= self.w)
            out[near] = self.band[hi[near] - lo[near], lo[near]]
        else:
            near = np.zeros_like(photo)
        far = photo & ~near
        diag = self.band[0].copy() if in_pass else None
        if np.any(far):
            out[far] = self._solved_banded(hi[far], lo[far])
        if self.m:  # the rank-m correction Y S^-1 Y' of the photo part
            out[photo] += np.einsum("ij,ij->i", self.W[hi[photo]], self.W[lo[photo]])
            if in_pass:
                diag = np.concatenate([diag + np.einsum("ij,ij->i", self.W, self.W), np.diag(self.S_inv)])
        return out, diag

    def _pass(self, band):
        """The backward block recurrence over A; writes the band of A^-1 within w of the diagonal
        into ``band`` (lower band storage, band[d, j] = A^-1[j + d, j]) as it passes."""
        k, nb, cb, w = self.k, self.nb, self.cb, self.w
        n_blocks = -(-k // nb)
        Z_next = None
        for t in range(n_blocks - 1, -1, -1):
            s0, e0 = t * nb, min((t + 1) * nb, k)
            Ltt = _from_band(cb, s0, e0, s0, e0)
            Linv, info = lapack.dtrtri(Ltt, lower=1)
            if Z_next is None:
                Z_tt = Linv.T @ Linv
                Z_down = None
            else:
                e1 = min(e0 + nb, k)
                M = _from_band(cb, e0, e1, s0, e0)
                Z_down = -(Z_next @ M) @ Linv  # Z_{t+1,t}
                Z_tt = Linv.T @ (Linv - M.T @ Z_down)
            Z_tt = 0.5 * (Z_tt + Z_tt.T)
            # the band of the block's columns: rows j..j+w, in Z_tt or (below the block) Z_down
            d, c = np.meshgrid(np.arange(w + 1), np.arange(e0 - s0), indexing="ij")
            r = c + d  # row offset from s0
            in_tt = r < e0 - s0
            values = np.zeros(d.shape)
            values[in_tt] = Z_tt[r[in_tt], c[in_tt]]
            if Z_down is not None:
                below = ~in_tt & (r < e0 - s0 + Z_down.shape[0])
                values[below] = Z_down[r[below] - (e0 - s0), c[below]]
            band[:, s0:e0] = values
            Z_next = Z_tt

    def _solved_banded(self, rows, cols):
        """Entries of A^-1 (the banded part alone) from its columns."""
        want, where = np.unique(cols, return_inverse=True)
        out = np.empty(len(rows))
        chunk = max(1, SOLVE_CHUNK // max(self.k, 1))
        for a in range(0, len(want), chunk):
            E = np.zeros((self.k, min(chunk, len(want) - a)))
            E[want[a: a + chunk], np.arange(E.shape[1])] = 1.0
            X, _ = lapack.dpbtrs(self.cb, E, lower=1)
            sel = (where >= a) & (where < a + chunk)
            out[sel] = X[rows[sel], where[sel] - a]
        return out

    def diag(self):  # pragma: no cover - compute_with_diag is used
        return self._run(np.zeros(0, dtype=int), np.zeros(0, dtype=int), in_pass=True)[1]
