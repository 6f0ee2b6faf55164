"""``cholmod``: CHOLMOD's sparse Cholesky (scikit-sparse) with a fill-reducing ordering.

The symbolic factorisation (ordering and the pattern of L, ``cholmod.analyze``) is made once per
solver object, i.e. once per adjustment, at the first solve; every outer iteration then only
refactorises numerically (``Factor.cholesky_inplace``). If N's pattern ever grows beyond the one
analysed (an entry that was not there before), the solver analyses again and counts it in
``info["analyses"]``; a pattern that only loses entries (exact zeros) is fine as it is.

scikit-sparse is optional: ``pip install 'striptri[cholmod]'`` after
``apt-get install libsuitesparse-dev`` (docs/solvers.md).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .base import NormalSolver, SingularNormalMatrix, SolveResult, SolverUnavailable, check_pivots, jacobi_scaled

INSTALL_HINT = (
    "the 'cholmod' solver needs scikit-sparse: install SuiteSparse's headers and the extra with "
    "`apt-get install libsuitesparse-dev && pip install 'striptri[cholmod]'` "
    "(or choose another solver, e.g. 'banded' or 'sparse')"
)


def cholmod_module():
    """sksparse.cholmod, or SolverUnavailable with the install command."""
    try:
        from sksparse import cholmod
    except ImportError as exc:
        raise SolverUnavailable(INSTALL_HINT) from exc
    return cholmod


def cholmod_available() -> bool:
    try:
        cholmod_module()
    except SolverUnavailable:
        return False
    return True


class CholmodSolver(NormalSolver):
    name = "cholmod"

    def __init__(self, options, structure):
        super().__init__(options, structure)
        self._cholmod = cholmod_module()
        self._factor = None
        self._pattern: sp.csc_matrix | None = None
        self.analyses = 0

    def _pattern_fits(self, A: sp.csc_matrix) -> bool:
        P = self._pattern
        if P is None or P.shape != A.shape:
            return False
        if np.array_equal(P.indptr, A.indptr) and np.array_equal(P.indices, A.indices):
            return True
        ones = sp.csc_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
        return (P + ones).nnz == P.nnz

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        A = Ns.T  # CSC view of the symmetric matrix; CHOLMOD reads its lower triangle
        if not self._pattern_fits(A):
            # simplicial with AMD: Debian's SuiteSparse links the reference BLAS, which makes the
            # supernodal mode slower here (block of 1000 photos: 58 against 99 ms per factorisation)
            self._factor = self._cholmod.analyze(A, mode="simplicial", ordering_method="amd")
            self._pattern = sp.csc_matrix((np.ones(A.nnz), A.indices.copy(), A.indptr.copy()), shape=A.shape)
            self.analyses += 1
        factor = self._factor
        perm = factor.P()
        try:
            factor.cholesky_inplace(A)
        except self._cholmod.CholmodNotPositiveDefiniteError as exc:
            col = getattr(exc, "column", None)
            raise SingularNormalMatrix(int(perm[col]) if col is not None and 0 <= col < n else None) from exc
        check_pivots(np.sqrt(np.maximum(factor.D(), 0.0)), perm)
        y = factor.solve_A(b * s)
        return SolveResult(np.asarray(y).reshape(-1) * s, self.name, {"analyses": self.analyses})
