"""The solver interface: options in, result out, one exception for a singular N (DESIGN section 5)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..model import SOLVERS  # noqa: F401  (re-exported: the solvers' names, kept with the project's settings)
from .info import SolverInfo

WARM_STARTS = ("zero", "previous", "projected")

# A pivot of the Cholesky factor of the Jacobi-scaled N (unit diagonal) below this counts as zero:
# the column is then a combination of the preceding ones to about 1e-14 of its own weight.
# Every solver uses the same test, so they agree on what "singular" means.
PIVOT_TOLERANCE = 1e-7


class SingularNormalMatrix(Exception):
    """N is not positive definite; ``column`` is where the factorisation broke down (or None)."""

    def __init__(self, column=None, detail: str = ""):
        self.column = column
        message = "normal matrix is singular" + ("" if column is None else f" at column {column}")
        super().__init__(message + (f" ({detail})" if detail else ""))


class SolverUnavailable(ImportError):
    """The named solver needs an optional package that is not installed."""


@dataclass(frozen=True)
class SolverOptions:
    """name: one of SOLVERS.

    The iterative solvers (``gauss-seidel``, ``pcg``, ``strip-pcg``) stop at a relative residual
    ``|b~ - N~ y| / |b~| < inner_tolerance`` of the Jacobi-scaled system ``N~ = D N D``,
    ``b~ = D b``, ``dx = D y`` (a scale-free measure: metres, radians and millimetres alike), or after
    ``max_inner_iterations`` sweeps / iterations. ``relaxation`` is the over-relaxation factor
    omega of ``gauss-seidel`` (1 = plain Gauss-Seidel; SOR needs 0 < omega < 2). ``warm_start``:
    where an iterative solver starts - ``zero`` (the unknowns are corrections, so zero is the natural
    start), ``previous`` (the last solution of this solver object) or ``projected`` (the multiple of
    the last solution that is closest to the new one in the energy norm, never worse than zero);
    docs/solvers.md has the measurements behind the default.
    """

    name: str = "auto"
    inner_tolerance: float = 1e-12
    max_inner_iterations: int = 5000
    relaxation: float = 1.0
    warm_start: str = "zero"

    def __post_init__(self):
        if self.name not in SOLVERS:
            raise ValueError(f"unknown solver {self.name!r}; choose one of {', '.join(SOLVERS)}")
        if not 0.0 < self.relaxation < 2.0:
            raise ValueError(f"relaxation must lie in (0, 2) for SOR to converge, not {self.relaxation}")
        if not self.inner_tolerance > 0.0:
            raise ValueError("inner_tolerance must be positive")
        if self.max_inner_iterations < 1:
            raise ValueError("max_inner_iterations must be at least 1")
        if self.warm_start not in WARM_STARTS:
            raise ValueError(f"unknown warm_start {self.warm_start!r}; choose one of {', '.join(WARM_STARTS)}")


@dataclass(frozen=True)
class Structure:
    """What a solver may know of N before seeing numbers: its size and its 6x6 photo blocks
    (``block_starts``: first column of each photo's block, camera columns after the last).
    Without ``block_starts`` the solvers that need blocks take consecutive blocks of 6 columns.

    ``groups`` (optional, one per block of ``block_starts``): the strip of each photo block (0, 1,
    ...), -1 for a camera block or a photo of no strip. The strip solvers (:mod:`.strips`) relax
    over these groups; without them they make groups of consecutive photos."""

    n_unknowns: int
    block_starts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    groups: np.ndarray | None = None


@dataclass
class SolveResult:
    """dx: the solution; solver: the concrete solver's name; info: what it reports (SolverInfo:
    e.g. the inner iterations, residual and convergence of an iterative solver, the bandwidth of
    ``banded``)."""

    dx: np.ndarray
    solver: str
    info: SolverInfo = field(default_factory=SolverInfo)


class NormalSolver:
    """Base class: ``solve(N, b) -> SolveResult``; raises SingularNormalMatrix.

    One object serves a whole adjustment: it may keep what does not change between outer
    iterations (a symbolic factorisation, the last solution)."""

    name = "base"
    iterative = False  # True: the solution is approximate (inner iterations), no factor of N is made

    def __init__(self, options: SolverOptions, structure: Structure):
        self.options, self.structure = options, structure
        # True: a direct solver keeps the factor of its last solve for solve_again until release()
        # (the adjustments hold it from a solve to their convergence test, and past a converged
        # one for the final checks); False: dropped after each solve, as memory asks
        self.holds_factor = False

    def solve(self, N: sp.csr_matrix, b: np.ndarray) -> SolveResult:  # pragma: no cover - interface
        raise NotImplementedError

    def prepare(self, pattern: sp.csr_matrix) -> None:
        """N's pattern before its first numbers (the adjustments tell it once they have made it): a
        solver may begin its analysis meanwhile. Nothing by default; never a change of result."""

    def solve_again(self, b: np.ndarray) -> np.ndarray | None:
        """N^-1 b for the N of the last solve, with its factor when the solver holds one
        (``holds_factor``; the CHOLMOD solvers); None when it does not (then solve N again)."""
        return None

    def holding(self) -> bool:
        """Whether solve_again would solve with a held factor (and not answer None)."""
        return False

    def release(self) -> None:
        """Drop the factor held for solve_again (nothing when none is held). While ``holds_factor``
        a solver may keep its memory for the next factorisation (cholmod: ``cholesky_inplace``)."""


@contextlib.contextmanager
def holding_factor(solver: NormalSolver):
    """The solver holds its factor inside the block (an adjustment's run): solve_again serves the
    N of its last solve until release, and each factorisation is made in the memory of the last
    (cholmod: ``cholesky_inplace``; docs/decisions.md "Refactorised in place"). At the end the
    solver stops holding and lets the factor go."""
    solver.holds_factor = True
    try:
        yield solver
    finally:
        solver.holds_factor = False
        solver.release()


def jacobi_scaled(N: sp.spmatrix):
    """D N D with D = diag(N)^-1/2 (unknowns in mixed units: metres, radians, mm) and D's diagonal.

    Returns a canonical CSR matrix (sorted indices, no duplicates) whose diagonal is 1."""
    N = sp.csr_matrix(N)
    if not N.has_canonical_format:
        N = N.copy()  # never reorder the caller's arrays
        N.sum_duplicates()  # also sorts the indices
    d = N.diagonal()
    if np.any(d <= 0) or not np.all(np.isfinite(d)):
        raise SingularNormalMatrix(int(np.flatnonzero(~(d > 0))[0]) if np.any(~(d > 0)) else None,
                                   "non-positive or non-finite diagonal element")
    s = 1.0 / np.sqrt(d)
    data = N.data * np.repeat(s, np.diff(N.indptr))  # the row's factor
    data *= s[N.indices]
    # the index arrays are shared with N: callers never change a scaled matrix's pattern in place
    Ns = sp.csr_matrix((data, N.indices, N.indptr), shape=N.shape, copy=False)
    Ns.has_sorted_indices = True
    return Ns, s


def pattern_matrix(indptr: np.ndarray, indices: np.ndarray, shape: tuple) -> sp.csr_matrix:
    """A canonical CSR matrix with these index arrays (shared, not copied) and a 1.0 seen at every
    entry (one number in memory): a pattern handed to an analysis that reads no numbers."""
    ones = np.lib.stride_tricks.as_strided(np.ones(1), shape=indices.shape, strides=(0,))
    P = sp.csr_matrix((ones, indices, indptr), shape=shape, copy=False)
    P.has_sorted_indices = P.has_canonical_format = True
    return P


def check_pivots(pivots: np.ndarray, columns: np.ndarray | None = None) -> None:
    """Raise SingularNormalMatrix if a Cholesky pivot (diagonal of L for the Jacobi-scaled N) is
    below PIVOT_TOLERANCE; ``columns`` maps pivot positions to columns of N (a permutation)."""
    if len(pivots) == 0:
        return
    bad = ~(np.abs(pivots) >= PIVOT_TOLERANCE)  # also catches NaN
    if np.any(bad):
        j = int(np.flatnonzero(bad)[0])
        raise SingularNormalMatrix(int(columns[j]) if columns is not None else j)
