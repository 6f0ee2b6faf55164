"""Direct solvers without optional dependencies: ``dense`` (the reference) and ``sparse``."""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from .base import NormalSolver, SingularNormalMatrix, SolveResult, check_pivots, jacobi_scaled


def dense_cholesky(A: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a dense, Jacobi-scaled SPD matrix (LAPACK potrf); raises
    SingularNormalMatrix at the column where it breaks down or its pivot fails PIVOT_TOLERANCE."""
    if len(A) == 0:
        return A.copy()
    c, info = lapack.dpotrf(A, lower=1, clean=1, overwrite_a=0)
    if info > 0:
        raise SingularNormalMatrix(info - 1)
    if info < 0:  # pragma: no cover - argument error, cannot happen here
        raise ValueError(f"dpotrf argument {-info} invalid")
    check_pivots(np.diag(c))
    return c


class DenseSolver(NormalSolver):
    """The reference: LAPACK Cholesky of the full, Jacobi-scaled matrix. O(n^3); for tests and tiny
    systems."""

    name = "dense"

    def solve(self, N, b):
        if N.shape[0] == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        c = dense_cholesky(Ns.toarray())
        y = la.cho_solve((c, True), b * s, check_finite=False)
        return SolveResult(y * s, self.name)


class ScipySparseSolver(NormalSolver):
    """scipy's SuperLU with a symmetric minimum-degree ordering (on N + N^T) and diagonal pivots,
    i.e. an LDL^T-like factorisation of the SPD matrix: the fallback when scikit-sparse is absent."""

    name = "sparse"

    def solve(self, N, b):
        if N.shape[0] == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        try:
            lu = spla.splu(
                Ns.T.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
        except RuntimeError as exc:  # exactly singular: SuperLU stops
            raise SingularNormalMatrix() from exc
        # with diagonal pivoting U_jj is the Cholesky pivot squared (the D of L D L^T)
        udiag = lu.U.diagonal()
        pivots = np.sqrt(np.maximum(udiag, 0.0)) * np.sign(udiag)
        check_pivots(pivots, lu.perm_c)
        return SolveResult(lu.solve(b * s) * s, self.name)


def inverse(N) -> np.ndarray:
    """Dense N^-1 (the weight coefficients of the unknowns, Schmid 53), via Jacobi-scaled Cholesky."""
    n = N.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    Ns, s = jacobi_scaled(N)
    c = dense_cholesky(Ns.toarray())
    return la.cho_solve((c, True), np.eye(n), check_finite=False) * s[:, None] * s[None, :]
