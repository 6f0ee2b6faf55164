"""Solvers of the normal equations N dx = b behind one interface (DESIGN section 5).

A solver is made once per adjustment by :func:`make_solver` (so that a sparse Cholesky can analyse
the pattern once and an iterative solver can start from its last solution) and called once per
outer iteration with the numeric N of that iteration. Every solver returns a :class:`SolveResult`
(its report of the solve a :class:`SolverInfo`, :mod:`.info`) and raises :class:`SingularNormalMatrix` when N is not positive definite. All work on the
Jacobi-scaled matrix ``D N D``, ``D = diag(N)^-1/2``. :func:`describe` says in words which
factorisation and which BLAS library (found at run time) a solver used, for summary.json.

* ``dense`` - the reference: LAPACK Cholesky of the full matrix (:mod:`.direct`);
* ``sparse`` - scipy's SuperLU with a symmetric minimum-degree ordering, the fallback (:mod:`.direct`);
* ``banded`` - LAPACK banded Cholesky for strips, camera columns as a dense border (:mod:`.banded`);
* ``cholmod`` - CHOLMOD's supernodal sparse Cholesky, analysed once per adjustment; needs the
  optional scikit-sparse (:mod:`.sparse_cholesky`);
* ``cvxopt`` - the same CHOLMOD from cvxopt's binary wheels (with their own OpenBLAS): the fast
  path after a plain ``pip install`` (:mod:`.cvxopt_cholesky`);
* ``gauss-seidel`` - block Gauss-Seidel / SOR with the 6x6 photo blocks (:mod:`.iterative`);
* ``pcg`` - block-Jacobi preconditioned conjugate gradients (:mod:`.iterative`);
* ``strip-pcg`` - conjugate gradients preconditioned by block relaxation over whole strips, each
  strip's banded factor one block (:mod:`.strips`);
* ``auto`` - picks from N's pattern at the first solve (:func:`resolve_solver`, docs/solvers.md).
"""

from .banded import BandedSolver, bandwidth
from .base import (
    PIVOT_TOLERANCE,
    SOLVERS,
    WARM_STARTS,
    NormalSolver,
    SingularNormalMatrix,
    SolveResult,
    SolverOptions,
    SolverUnavailable,
    Structure,
    holding_factor,
    jacobi_scaled,
)
from .cvxopt_cholesky import CvxoptSolver, cvxopt_available
from .describe import blas, describe
from .direct import DenseSolver, ScipySparseSolver, inverse
from .info import SolverInfo
from .iterative import SLOW_PCG, SLOW_SWEEPS, GaussSeidelSolver, PcgSolver, SlowConvergenceWarning
from .selection import (
    BANDED_MAX_BANDWIDTH,
    DENSE_LIMIT,
    AutoSolver,
    make_solver,
    resolve_solver,
    solve,
    sparse_choice,
)
from .sparse_cholesky import CholmodSolver, cholmod_available
from .strips import SLOW_STRIP_PCG, StripPcgSolver, strip_partition

__all__ = [
    "SOLVERS", "WARM_STARTS", "PIVOT_TOLERANCE", "DENSE_LIMIT", "BANDED_MAX_BANDWIDTH", "SLOW_SWEEPS", "SLOW_PCG",
    "SingularNormalMatrix", "SolverUnavailable", "SlowConvergenceWarning",
    "SolverOptions", "Structure", "SolveResult", "SolverInfo", "NormalSolver",
    "DenseSolver", "ScipySparseSolver", "BandedSolver", "CholmodSolver", "CvxoptSolver", "GaussSeidelSolver",
    "PcgSolver", "StripPcgSolver", "SLOW_STRIP_PCG", "strip_partition",
    "AutoSolver", "make_solver", "resolve_solver", "sparse_choice", "solve", "inverse", "jacobi_scaled", "bandwidth",
    "holding_factor",
    "cholmod_available", "cvxopt_available", "describe", "blas",
]
