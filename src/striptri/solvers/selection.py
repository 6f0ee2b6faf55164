"""Choosing a solver: the names, ``auto``, and the factory used once per adjustment."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .banded import BandedSolver, choose_split
from .base import SOLVERS, NormalSolver, SolveResult, SolverOptions, Structure
from .direct import DenseSolver, ScipySparseSolver
from .iterative import GaussSeidelSolver, PcgSolver
from .strips import StripPcgSolver
from .cvxopt_cholesky import CvxoptSolver, cvxopt_available
from .describe import on_reference_blas
from .memory import factor_bytes, fits
from .sparse_cholesky import CholmodSolver, cholmod_available

# auto: measured on a 2-core machine (scripts/bench/bench_solvers.py, docs/solvers.md)
DENSE_LIMIT = 120  # unknowns up to which the dense reference is as fast as anything (~20 photos)
# ... and up to DENSE_FULL_LIMIT unknowns (a 72 MB matrix) where N is nearly full, at least DENSE_FILL
# of its entries nonzero (close range: every target on half the photos, N 98 % full): a sparse or
# banded factor of a full matrix is the dense one with index work on top. The close-range block's
# 695 unknowns: a solve 7.3 ms dense against 15.5 ms banded, the whole inverse 12 ms against 43 ms
# (docs/solvers.md).
DENSE_FULL_LIMIT = 3000
DENSE_FILL = 0.5
BANDED_MAX_BANDWIDTH = 500  # bandwidth of the photo part up to which banded beats cholmod and sparse
BANDED_MAX_STORAGE = 50_000_000  # band entries (400 MB) beyond which banded is not chosen

_SOLVER_CLASSES = {
    "dense": DenseSolver,
    "sparse": ScipySparseSolver,
    "banded": BandedSolver,
    "cholmod": CholmodSolver,
    "cvxopt": CvxoptSolver,
    "gauss-seidel": GaussSeidelSolver,
    "pcg": PcgSolver,
    "strip-pcg": StripPcgSolver,
}


def resolve_solver(name: str, n_unknowns: int, N: sp.spmatrix | None = None,
                   structure: Structure | None = None) -> str:
    """The concrete solver ``name`` stands for (or the name itself, validated).

    ``auto`` (docs/solvers.md): ``dense`` up to DENSE_LIMIT unknowns, or where N is nearly full
    (:func:`nearly_full`); else ``banded`` when the
    photo part of N (camera columns split off as a border) has a lower bandwidth of at most
    BANDED_MAX_BANDWIDTH (and its band fits BANDED_MAX_STORAGE and the memory budget) - a strip,
    or a block of strips of up to about 80 photos numbered strip after strip; else the sparse
    Cholesky of :func:`sparse_choice` when its factor, estimated from N's pattern before
    factorising (:mod:`.memory`), fits the memory budget; else ``strip-pcg``, which needs no
    factor of N. Without N (its pattern not yet known) the choice after ``dense`` is the sparse one.
    """
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; choose one of {', '.join(SOLVERS)}")
    if name != "auto":
        return name
    if n_unknowns <= DENSE_LIMIT or (N is not None and nearly_full(N)):
        return "dense"
    if N is not None:
        A = sp.csr_matrix(N)
        A.sort_indices()
        k, w = choose_split(A, structure or Structure(n_unknowns))
        band_bytes = 8.0 * (w + 1 + n_unknowns - k) * k  # the band and Z = A^-1 B
        if w <= BANDED_MAX_BANDWIDTH and (w + 1) * k <= BANDED_MAX_STORAGE and fits(band_bytes):
            return "banded"
        choice = sparse_choice()
        if not fits(factor_bytes(A, w, choice)):
            return "strip-pcg"
        return choice
    return sparse_choice()


def nearly_full(N) -> bool:
    """Whether N (n x n, sparse or dense) is solved and inverted dense beyond DENSE_LIMIT: at most
    DENSE_FULL_LIMIT unknowns with at least DENSE_FILL of its entries nonzero."""
    n = N.shape[0]
    nonzeros = N.nnz if sp.issparse(N) else np.count_nonzero(N)
    return n <= DENSE_FULL_LIMIT and nonzeros >= DENSE_FILL * n * n


def sparse_choice() -> str:
    """The sparse factorisation ``auto`` takes for blocks (docs/solvers.md, measured on the
    benchmark blocks): ``cholmod`` (scikit-sparse) when installed, unless its CHOLMOD runs on the
    reference BLAS and ``cvxopt`` is installed (cvxopt's wheels bring their own OpenBLAS, 4 to 5
    times faster there); then ``cvxopt``; ``sparse`` (scipy's SuperLU) when neither is installed.
    cvxopt is imported only where it may be taken: its import and its own OpenBLAS cost a run that
    CHOLMOD solves 0.01-0.07 s and some memory (docs/decisions.md "cvxopt imported only when taken")."""
    if cholmod_available() and not (on_reference_blas("cholmod") and cvxopt_available()):
        return "cholmod"
    if cvxopt_available():
        return "cvxopt"
    return "sparse"


class AutoSolver(NormalSolver):
    """``auto``: picks the concrete solver from N's pattern at the first solve and keeps it (so a
    CHOLMOD analysis or a warm start carries over); ``name`` becomes the concrete solver's."""

    name = "auto"

    def __init__(self, options, structure):
        super().__init__(options, structure)
        self._chosen: NormalSolver | None = None

    @property
    def iterative(self) -> bool:
        """Whether the solver chosen (none yet: False) is an iterative one."""
        return self._chosen is not None and self._chosen.iterative

    def solve(self, N, b) -> SolveResult:
        self._choose(N)
        self._chosen.holds_factor = self.holds_factor
        return self._chosen.solve(N, b)

    def prepare(self, pattern) -> None:
        """The choice made from the pattern now (it reads nothing else), and the pattern passed on."""
        self._choose(pattern)
        self._chosen.prepare(pattern)

    def _choose(self, N) -> None:
        if self._chosen is None or self._chosen.structure.n_unknowns != N.shape[0]:
            concrete = resolve_solver("auto", N.shape[0], N, self.structure)
            self._chosen = _SOLVER_CLASSES[concrete](self.options, self.structure)
            self.name = concrete

    def solve_again(self, b):
        return None if self._chosen is None else self._chosen.solve_again(b)

    def holding(self) -> bool:
        return self._chosen is not None and self._chosen.holding()

    def release(self):
        if self._chosen is not None:
            self._chosen.holds_factor = self.holds_factor
            self._chosen.release()


def make_solver(options: SolverOptions, structure: Structure) -> NormalSolver:
    """The solver object of one adjustment (made once, called once per outer iteration).
    Raises SolverUnavailable for ``cholmod`` without scikit-sparse (with the install command)."""
    if options.name == "auto":
        return AutoSolver(options, structure)
    return _SOLVER_CLASSES[options.name](options, structure)


def solve(N: sp.spmatrix, b: np.ndarray, solver: str, structure: Structure | None = None) -> SolveResult:
    """One-off solve of N dx = b with the named solver."""
    return make_solver(SolverOptions(name=solver), structure or Structure(N.shape[0])).solve(N, b)



