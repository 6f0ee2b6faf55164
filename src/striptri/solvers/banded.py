"""``banded``: LAPACK banded Cholesky of a strip's N with a dense border (arrowhead).

With photos numbered along a strip, N has nonzero 6x6 blocks only within two photos of the
diagonal (Schmid Fig. 10): a band of about 17 below the diagonal. Camera parameters, ordered last,
couple everything and would widen the band to the whole matrix, so the matrix is split

    N = [A  B]     A: the banded photo part (k columns), B: k x m, C: m x m (m camera columns)
        [B' C]

and solved by block elimination: the banded Cholesky ``A = L L'`` (LAPACK pbtrf, the routine behind
scipy.linalg.cholesky_banded), ``Z = A^-1 B`` (pbtrs, behind cho_solve_banded), the Schur complement
``S = C - B' Z`` (dense Cholesky), then ``x2 = S^-1 (b2 - B' A^-1 b1)``, ``x1 = A^-1 b1 - Z x2``.
This is the Cholesky factorisation of the whole N in another form, so its pivots are N's.

The bandwidth is read from N's actual pattern at every solve (it is cheap: the first column of
each row of a sorted CSR matrix), and the split k is the one of least estimated work
``k w^2 + 2 k w m + k m^2 + m^3 / 3`` among the block starts near the end of the matrix.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.linalg import lapack

from .base import NormalSolver, SingularNormalMatrix, SolveResult, Structure, check_pivots, jacobi_scaled
from .direct import dense_cholesky
from .info import SolverInfo

MAX_BORDER = 600  # columns the dense border may have (memory k x m for Z)


def lower_reach(A: sp.csr_matrix) -> np.ndarray:
    """For each row i of a sorted CSR matrix, i - (first column of row i): its reach below the
    diagonal (0 for an empty or diagonal-only row)."""
    n = A.shape[0]
    nonempty = np.diff(A.indptr) > 0
    first = np.arange(n)
    first[nonempty] = A.indices[A.indptr[:-1][nonempty]]
    return np.maximum(np.arange(n) - first, 0)


def choose_split(A: sp.csr_matrix, structure: Structure) -> tuple[int, int]:
    """(k, w): the banded part is columns [0, k), of lower bandwidth w; columns [k, n) the border."""
    n = A.shape[0]
    reach = lower_reach(A)
    prefix = np.maximum.accumulate(reach) if n else reach  # bandwidth of the leading k x k part
    starts = np.asarray(structure.block_starts, dtype=int)
    candidates = np.unique(np.concatenate([starts[(starts > 0) & (starts <= n)], np.arange(n - 12, n + 1)]))
    candidates = candidates[(candidates >= max(1, n - MAX_BORDER)) & (candidates <= n)]
    if n == 0:
        return 0, 0
    k = candidates.astype(float)
    w = prefix[candidates - 1].astype(float)
    m = n - k
    work = k * (w + 1) ** 2 + 2 * k * (w + 1) * m + k * m**2 + m**3 / 3
    best = int(np.argmin(work))
    return int(candidates[best]), int(prefix[candidates[best] - 1])


def bandwidth(A: sp.spmatrix) -> int:
    """Lower bandwidth of a symmetric sparse matrix (max i - j over its nonzeros)."""
    A = sp.csr_matrix(A)
    A.sort_indices()
    return int(lower_reach(A).max()) if A.shape[0] else 0


def _band_storage(A: sp.csr_matrix, k: int, w: int) -> np.ndarray:
    """LAPACK lower band storage ab[i - j, j] = A[i, j] of the leading k x k part."""
    ab = np.zeros((w + 1, k))
    end = A.indptr[k]  # rows >= k (the border) are not needed
    rows = np.repeat(np.arange(k), np.diff(A.indptr[: k + 1]))
    cols = A.indices[:end]
    below = rows - cols
    keep = below >= 0
    np.put(ab, below[keep] * k + cols[keep], A.data[:end][keep])
    return ab


class BandedSolver(NormalSolver):
    """Banded Cholesky of the photo part, dense Schur complement for the camera columns."""

    name = "banded"

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return SolveResult(np.zeros(0), self.name)
        A, s = jacobi_scaled(N)
        k, w = choose_split(A, self.structure)
        m = n - k
        cb, info = lapack.dpbtrf(_band_storage(A, k, w), lower=1)
        if info > 0:
            raise SingularNormalMatrix(info - 1)
        check_pivots(cb[0])
        bs = b * s
        if m == 0:
            y, _ = lapack.dpbtrs(cb, bs[:, None], lower=1)
            return SolveResult(y[:, 0] * s, self.name, SolverInfo(bandwidth=w, border=0))
        B = A[:k, k:].toarray()
        C = A[k:, k:].toarray()
        rhs = np.column_stack([bs[:k], B])
        sol, _ = lapack.dpbtrs(cb, rhs, lower=1)
        y1, Z = sol[:, 0], sol[:, 1:]
        S = C - B.T @ Z
        try:
            cS = dense_cholesky(S)
        except SingularNormalMatrix as exc:
            raise SingularNormalMatrix(k + exc.column if exc.column is not None else None) from exc
        y2 = la.cho_solve((cS, True), bs[k:] - B.T @ y1, check_finite=False)
        y = np.concatenate([y1 - Z @ y2, y2])
        return SolveResult(y * s, self.name, SolverInfo(bandwidth=w, border=m))
