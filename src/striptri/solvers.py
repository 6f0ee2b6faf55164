"""Solvers of the normal equations N dx = b behind one interface (DESIGN section 5).

A solver is made once per adjustment by :func:`make_solver` (so that a sparse Cholesky can analyse
the pattern once and an iterative solver can start from its last solution) and called once per
outer iteration with the numeric N of that iteration. Every solver returns a :class:`SolveResult`.

* ``dense`` - the reference: LAPACK Cholesky of the full, Jacobi-scaled matrix;
* ``sparse`` - scipy's sparse LU, the fallback when no specialised solver applies.

``auto`` picks ``dense`` for small systems and ``sparse`` otherwise.
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


@dataclass(frozen=True)
class SolverOptions:
    """name: one of SOLVERS. The iterative solvers stop at a relative residual
    ``|b - N dx| / |b| < inner_tolerance`` or after ``max_inner_iterations``."""

    name: str = "auto"
    inner_tolerance: float = 1e-12
    max_inner_iterations: int = 5000
    relaxation: float = 1.0

    def __post_init__(self):
        if self.name not in SOLVERS:
            raise ValueError(f"unknown solver {self.name!r}; choose one of {', '.join(SOLVERS)}")


@dataclass(frozen=True)
class Structure:
    """What a solver may know of N before seeing numbers: its size and its 6x6 photo blocks
    (``block_starts``: first column of each photo's block, camera columns after the last)."""

    n_unknowns: int
    block_starts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


@dataclass
class SolveResult:
    dx: np.ndarray
    solver: str
    info: dict = field(default_factory=dict)


class NormalSolver:
    """Base class: ``solve(N, b) -> SolveResult``; raises SingularNormalMatrix."""

    name = "base"

    def __init__(self, options: SolverOptions, structure: Structure):
        self.options, self.structure = options, structure

    def solve(self, N: sp.csr_matrix, b: np.ndarray) -> SolveResult:  # pragma: no cover - interface
        raise NotImplementedError


def jacobi_scaled(N: sp.csr_matrix):
    """D N D with D = diag(N)^-1/2 (unknowns in mixed units: metres, radians, mm) and D's diagonal."""
    d = N.diagonal()
    if np.any(d <= 0):
        raise SingularNormalMatrix(int(np.flatnonzero(d <= 0)[0]))
    s = 1.0 / np.sqrt(d)
    return sp.diags(s) @ N @ sp.diags(s), s


class DenseSolver(NormalSolver):
    name = "dense"

    def solve(self, N, b):
        if N.shape[0] == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        A = Ns.toarray()
        try:
            c, low = la.cho_factor(A, lower=True, check_finite=False)
        except la.LinAlgError as exc:
            raise SingularNormalMatrix(_first_bad_pivot(A)) from exc
        if np.min(np.abs(np.diag(c))) < 1e-7:
            raise SingularNormalMatrix(int(np.argmin(np.abs(np.diag(c)))))
        y = la.cho_solve((c, low), b * s, check_finite=False)
        return SolveResult(y * s, self.name)


class ScipySparseSolver(NormalSolver):
    name = "sparse"

    def solve(self, N, b):
        if N.shape[0] == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        try:
            lu = spla.splu(Ns.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0)
        except RuntimeError as exc:
            raise SingularNormalMatrix() from exc
        udiag = np.abs(lu.U.diagonal())
        if np.min(udiag) < 1e-14:
            raise SingularNormalMatrix(int(lu.perm_c[np.argmin(udiag)]))
        return SolveResult(lu.solve(b * s) * s, self.name)


_SOLVER_CLASSES = {"dense": DenseSolver, "sparse": ScipySparseSolver}


def resolve_solver(name: str, n_unknowns: int) -> str:
    """The concrete solver ``auto`` stands for (or the name itself, validated)."""
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; choose one of {', '.join(SOLVERS)}")
    if name == "auto":
        return "dense" if n_unknowns <= DENSE_LIMIT else "sparse"
    return name


def make_solver(options: SolverOptions, structure: Structure) -> NormalSolver:
    name = resolve_solver(options.name, structure.n_unknowns)
    return _SOLVER_CLASSES[name](options, structure)


def solve(N: sp.csr_matrix, b: np.ndarray, solver: str) -> SolveResult:
    """One-off solve of N dx = b with the named solver."""
    return make_solver(SolverOptions(name=solver), Structure(N.shape[0])).solve(N, b)


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
    Ns, s = jacobi_scaled(N)
    c = la.cho_factor(Ns.toarray(), lower=True, check_finite=False)
    return la.cho_solve(c, np.eye(n), check_finite=False) * s[:, None] * s[None, :]
