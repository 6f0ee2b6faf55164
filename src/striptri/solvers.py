"""Solvers of the normal equations N dx = b behind one interface (DESIGN section 5).

This module holds the direct solvers: ``dense`` (the reference: LAPACK Cholesky of the full
matrix) and ``sparse`` (scipy's sparse LU on the symmetric matrix, the fallback when no
specialised solver applies). ``auto`` takes ``dense`` for small systems and ``sparse`` otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

SOLVERS = ("auto", "dense", "sparse")
DENSE_LIMIT = 1500  # unknowns up to which auto picks the dense reference


class SingularNormalMatrix(Exception):
    """N is not positive definite; ``column`` is where the factorisation broke down (or None)."""

    def __init__(self, column=None):
        self.column = column
        super().__init__("normal matrix is singular" + ("" if column is None else f" at column {column}"))


@dataclass
class SolveResult:
    dx: np.ndarray
    solver: str
    info: dict = field(default_factory=dict)


def resolve_solver(name: str, n_unknowns: int) -> str:
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; choose one of {', '.join(SOLVERS)}")
    if name == "auto":
        return "dense" if n_unknowns <= DENSE_LIMIT else "sparse"
    return name


def _scaled(N: sp.csr_matrix):
    """Jacobi scaling D N D with D = diag(N)^-1/2 (unknowns in mixed units: metres, radians, mm)."""
    d = N.diagonal()
    if np.any(d <= 0):
        raise SingularNormalMatrix(int(np.flatnonzero(d <= 0)[0]))
    s = 1.0 / np.sqrt(d)
    return sp.diags(s) @ N @ sp.diags(s), s


def solve(N: sp.csr_matrix, b: np.ndarray, solver: str) -> SolveResult:
    """Solve N dx = b. Raises SingularNormalMatrix when N is not positive definite."""
    n = N.shape[0]
    if n == 0:
        return SolveResult(np.zeros(0), solver)
    Ns, s = _scaled(N)
    bs = b * s
    if solver == "dense":
        A = Ns.toarray()
        try:
            c, low = la.cho_factor(A, lower=True, check_finite=False)
        except la.LinAlgError as exc:
            raise SingularNormalMatrix(_first_bad_pivot(A)) from exc
        if np.min(np.abs(np.diag(c))) < 1e-7:
            raise SingularNormalMatrix(int(np.argmin(np.abs(np.diag(c)))))
        y = la.cho_solve((c, low), bs, check_finite=False)
    elif solver == "sparse":
        try:
            lu = spla.splu(Ns.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0)
        except RuntimeError as exc:
            raise SingularNormalMatrix() from exc
        udiag = np.abs(lu.U.diagonal())
        if np.min(udiag) < 1e-14:
            raise SingularNormalMatrix(int(lu.perm_c[np.argmin(udiag)]))
        y = lu.solve(bs)
    else:
        raise ValueError(f"solver {solver!r} not available")
    return SolveResult(y * s, solver)


def _first_bad_pivot(A: np.ndarray) -> int | None:
    """Column where an unpivoted Cholesky of A breaks down (for the error message)."""
    n = len(A)
    L = np.zeros_like(A)
    for j in range(n):
        d = A[j, j] - L[j, :j] @ L[j, :j]
        if d <= 1e-10:
            return j
        L[j, j] = np.sqrt(d)
        L[j + 1 :, j] = (A[j + 1 :, j] - L[j + 1 :, :j] @ L[j, :j]) / L[j, j]
    return None


def inverse(N: sp.csr_matrix) -> np.ndarray:
    """Dense N^-1 (the weight coefficients of the unknowns, Schmid 53), via Jacobi-scaled Cholesky."""
    n = N.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    Ns, s = _scaled(N)
    c = la.cho_factor(Ns.toarray(), lower=True, check_finite=False)
    return la.cho_solve(c, np.eye(n), check_finite=False) * s[:, None] * s[None, :]
