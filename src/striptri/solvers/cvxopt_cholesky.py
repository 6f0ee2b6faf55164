"""``cvxopt``: CHOLMOD's supernodal Cholesky as shipped in cvxopt's wheels - the fast sparse
factorisation for a user who only runs ``pip install`` (no apt, no compiler).

cvxopt's binary wheels carry their own CHOLMOD (SuiteSparse 4.4, AMD ordering; built without METIS)
and their own OpenBLAS, so the supernodal factorisation runs on an optimised BLAS wherever the
wheel installs. On the normal matrices of the benchmark blocks it is as fast as scikit-sparse's
CHOLMOD on Debian's OpenBLAS and 3 to 7 times faster than scipy's SuperLU (``sparse``), in a
third of its memory (docs/solvers.md).

As ``cholmod``: the symbolic factorisation (``cholmod.symbolic``) once per solver object, i.e. once
per adjustment; every outer iteration only refactorises numerically (``cholmod.numeric``) after
writing the new values into the cvxopt matrix kept from the analysis (the lower triangle in
compressed columns, in the order of scipy's CSC with sorted indices). A pattern that differs from the
analysed one is analysed again (``info.analyses``).

A matrix that is not positive definite makes ``cholmod.numeric`` raise ``ArithmeticError`` with
the pivot position; it is mapped to N's column through CHOLMOD's permutation (which cvxopt gives
only by applying it: ``cholmod.solve(F, arange(n), sys=7)``). The pivots (the diagonal of L) are
checked against PIVOT_TOLERANCE as for every solver.

Optional: ``pip install 'striptri[fast]'`` (docs/solvers.md).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .base import NormalSolver, SingularNormalMatrix, SolveResult, SolverUnavailable, check_pivots, jacobi_scaled
from .info import SolverInfo
from .threads import factorisation_threads, limit_new_libraries

INSTALL_HINT = (
    "the 'cvxopt' solver needs cvxopt (binary wheels, no compiler needed): "
    "`pip install 'striptri[fast]'` (or choose another solver, e.g. 'sparse')"
)


def cvxopt_modules():
    """(cvxopt, cvxopt.cholmod), or SolverUnavailable with the install command."""
    try:
        import cvxopt
        from cvxopt import cholmod
    except ImportError as exc:
        raise SolverUnavailable(INSTALL_HINT) from exc
    limit_new_libraries()  # its OpenBLAS under striptri's thread limit (solvers.threads)
    return cvxopt, cholmod


def cvxopt_available() -> bool:
    try:
        cvxopt_modules()
    except SolverUnavailable:
        return False
    return True


def lower_triangle(Ns: sp.csr_matrix):
    """(indptr, row indices, values) of the lower triangle of a symmetric, canonical CSR matrix in
    compressed columns with sorted row indices: column j of the lower triangle is the part of row j
    at and right of the diagonal (symmetry), so this only masks the CSR arrays."""
    n = Ns.shape[0]
    row_of = np.repeat(np.arange(n), np.diff(Ns.indptr))
    keep = Ns.indices >= row_of
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(row_of[keep], minlength=n), out=indptr[1:])
    return indptr, Ns.indices[keep], Ns.data[keep]


class CvxoptSolver(NormalSolver):
    name = "cvxopt"

    def __init__(self, options, structure):
        super().__init__(options, structure)
        self._cvxopt, self._cholmod = cvxopt_modules()
        self._factor = None
        self._matrix = None  # the cvxopt spmatrix of the analysed pattern; values rewritten per solve
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None
        self._perm: np.ndarray | None = None
        self.analyses = 0
        self._held_scale: np.ndarray | None = None  # the last solve's Jacobi scale, when holds_factor

    def _permutation(self, n: int) -> np.ndarray:
        """CHOLMOD's fill-reducing permutation of the analysis: row i of P A P' is row perm[i] of A.
        cvxopt gives it only by applying P with a numeric factor (sys=7), and refuses a factor whose
        factorisation failed: then a diagonally dominant matrix of the same pattern is factorised
        into it first (only on that failure path)."""
        if self._perm is not None:
            return self._perm
        cvx = self._cvxopt
        x = cvx.matrix(np.arange(n, dtype=float))
        try:
            self._cholmod.solve(self._factor, x, sys=7)  # x := P x
        except ArithmeticError:
            indptr, rows = self._pattern
            cols = np.repeat(np.arange(n), np.diff(indptr))
            off = rows != cols
            # off-diagonal entries 1, diagonal entries 1 + the number of off-diagonal entries of
            # the row in the full matrix: strictly diagonally dominant, so positive definite
            degree = np.bincount(rows[off], minlength=n) + np.bincount(cols[off], minlength=n)
            surrogate = cvx.spmatrix(cvx.matrix(np.where(off, 1.0, 1.0 + degree[cols])),
                                     cvx.matrix(rows.astype(np.int64)), cvx.matrix(cols.astype(np.int64)), (n, n))
            with _cholmod_options(self._cholmod):
                self._cholmod.numeric(surrogate, self._factor)
            self._cholmod.solve(self._factor, x, sys=7)
        self._perm = np.rint(np.asarray(x)).astype(np.int64).reshape(-1)
        return self._perm

    def solve(self, N, b):
        self._held_scale = None
        n = N.shape[0]
        if n == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        indptr, rows, values = lower_triangle(Ns)
        cvx = self._cvxopt
        pattern = self._pattern
        if pattern is None or not (np.array_equal(pattern[0], indptr) and np.array_equal(pattern[1], rows)):
            cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
            self._matrix = cvx.spmatrix(cvx.matrix(values), cvx.matrix(rows.astype(np.int64)), cvx.matrix(cols), (n, n))
            with _cholmod_options(self._cholmod):
                self._factor = self._cholmod.symbolic(self._matrix, uplo="L")
            self._pattern = (indptr, rows)
            self._perm = None
            self.analyses += 1
        else:
            self._matrix.V = cvx.matrix(values)
        try:
            with _cholmod_options(self._cholmod), factorisation_threads():
                self._cholmod.numeric(self._matrix, self._factor)
        except ArithmeticError as exc:
            k = exc.args[0] if exc.args and isinstance(exc.args[0], int) else None
            column = int(self._permutation(n)[k]) if k is not None and 0 <= k < n else None
            raise SingularNormalMatrix(column) from exc
        check_pivots(np.asarray(self._cholmod.diag(self._factor)).reshape(-1), self._permutation(n))
        y = self._cvxopt.matrix(b * s)
        self._cholmod.solve(self._factor, y)
        if self.holds_factor:  # the numeric factor stays in self._factor until the next solve
            self._held_scale = s
        return SolveResult(np.asarray(y).reshape(-1) * s, self.name, SolverInfo(analyses=self.analyses))

    def solve_again(self, b):
        if self._held_scale is None:
            return None
        s = self._held_scale
        y = self._cvxopt.matrix(b * s)
        self._cholmod.solve(self._factor, y)
        return np.asarray(y).reshape(-1) * s

    def holding(self) -> bool:
        return self._held_scale is not None

    def release(self):
        self._held_scale = None


class _cholmod_options:
    """cvxopt.cholmod.options is module-global: set the supernodal L L' factorisation (the
    default of cvxopt, made explicit) for the call and restore what the caller had."""

    WANT = {"supernodal": 2, "postorder": True}

    def __init__(self, module):
        self.options = module.options

    def __enter__(self):
        self.saved = {k: self.options[k] for k in self.WANT if k in self.options}
        self.options.update(self.WANT)

    def __exit__(self, *exc):
        for k in self.WANT:
            if k in self.saved:
                self.options[k] = self.saved[k]
            else:
                self.options.pop(k, None)
        return False
