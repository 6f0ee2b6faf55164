"""The ``dense`` route of the selected inversion: the reference for tiny systems, and the route for
nearly full ones (close range).

The whole ``N~^-1`` from a dense LAPACK Cholesky factor (``potri``); every entry is looked up, none
solved for.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.linalg import lapack

from ..solvers.direct import dense_cholesky
from .engine import Engine, not_fixed


class DenseInverse(Engine):
    """The reference: the dense inverse of the scaled matrix (LAPACK Cholesky, then ``potri``, the
    inverse from the factor in a third of the work of n solves)."""

    name = "dense"

    def __init__(self, As: sp.csr_matrix):
        super().__init__()
        self.n = As.shape[0]
        c = dense_cholesky(As.toarray())
        self._factor = c
        Z, info = lapack.dpotri(c, lower=1)
        if info != 0:  # pragma: no cover - the factor passed the pivot test: cannot happen
            raise ValueError(f"dpotri failed (info {info})")
        self._Z = np.tril(Z) + np.tril(Z, -1).T  # potri fills the lower triangle

    def whole(self) -> np.ndarray:
        """The whole N~^-1 (n, n), symmetric."""
        return self._Z

    looks_up = True

    def compute(self, rows, cols):
        ok, out = not_fixed(rows, cols)
        out[ok] = self._Z[rows[ok], cols[ok]]
        return out

    def lookup(self, rows, cols):
        return self.compute(rows, cols), np.ones(len(rows), dtype=bool)

    def diag(self):
        return np.diag(self._Z).copy()

    def solve(self, B):
        return la.cho_solve((self._factor, True), B, check_finite=False)
