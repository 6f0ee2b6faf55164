"""Block-iterative solvers: ``gauss-seidel`` (block Gauss-Seidel / SOR, Schmid's suggestion for the
inner loop of each outer iteration) and ``pcg`` (block-Jacobi preconditioned conjugate gradients).

Both work on the Jacobi-scaled system ``N~ y = b~`` (unit diagonal) with the 6x6 photo blocks of
``Structure.block_starts`` (each camera its own block) and stop at a relative residual
``|b~ - N~ y| / |b~| < SolverOptions.inner_tolerance``.

Block Gauss-Seidel without a loop over blocks. With the block Cholesky factors ``D_i = C_i C_i'`` of
the diagonal blocks, the block-diagonal change of variables ``z = C' y`` turns ``N~`` into
``G = C^-1 N~ C^-T``, whose diagonal blocks are identities; block Gauss-Seidel on N~ is the same
iteration as on G (block-diagonal transformations keep the block-triangular splitting). For G,
``D + omega L`` is *unit lower triangular*, so one SOR sweep

    (I + omega L) z_new = omega (g - U z) + (1 - omega) z

is one sparse triangular solve (scipy.sparse.linalg.spsolve_triangular, SuperLU's compiled
substitution; a dense one up to DENSE_SWEEP_LIMIT unknowns, where it is faster) and one product
with U = L'. Its residual needs no extra product:
``g - G z_new = (U - (1/omega - 1) I)(z - z_new)``.

Convergence. SOR converges for every symmetric positive definite N and 0 < omega < 2
(Ostrowski-Reich), at a rate that degrades with N's condition number: a long strip held by control
only at its ends converges very slowly. A sweep count above SLOW_SWEEPS, or no convergence at all,
is reported (``info.slow``) and warned about; so is a residual that has not fallen by 1 % in
STAGNATION_SWEEPS sweeps (the rounding floor of an ill-conditioned N, ``info.stagnated``), where
the sweeps stop. A residual that grows beyond DIVERGED times the
first proves that N is not positive definite (SingularNormalMatrix).

PCG breaks down when a search direction has curvature ``p' N~ p <= 1e-14 p'p`` (N~ has a unit
diagonal, so that is a direction N does not determine): SingularNormalMatrix.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import progress
from .base import PIVOT_TOLERANCE, NormalSolver, SingularNormalMatrix, SolveResult, jacobi_scaled
from .blocks import block_cholesky, block_diagonal_matrix, partition, strictly_block_lower
from .info import SolverInfo

SLOW_SWEEPS = 500  # Gauss-Seidel sweeps (PCG iterations: SLOW_PCG) beyond which convergence is "slow"
SLOW_PCG = 500
DIVERGED = 1e8
DENSE_SWEEP_LIMIT = 600  # unknowns up to which a sweep uses a dense triangular solve (measured faster)
STAGNATION_SWEEPS = 200  # Gauss-Seidel stops when its residual has not fallen 1 % in this many sweeps


class SlowConvergenceWarning(RuntimeWarning):
    """An iterative solver needed many inner iterations or did not reach its tolerance."""


class _IterativeSolver(NormalSolver):
    """Common parts: warm start and the report (with the slow-convergence warning)."""

    slow_limit = SLOW_SWEEPS
    unit = "iterations"
    advice = ("N is ill-conditioned for it (e.g. a long strip with little control). A direct solver ('banded', "
              "'cholmod', 'sparse') is faster and exact here.")
    iterative = True

    def __init__(self, options, structure):
        super().__init__(options, structure)
        self._previous: np.ndarray | None = None

    def _empty(self) -> SolveResult:
        """The solution of a 0 x 0 system."""
        return SolveResult(np.zeros(0), self.name, SolverInfo(inner_iterations=0, relative_residual=0.0,
                                                              converged=True, slow=False))

    def _start(self, Ns, s, b) -> np.ndarray:
        """Initial y (scaled unknowns) per SolverOptions.warm_start."""
        n = len(b)
        prev = self._previous
        if self.options.warm_start == "zero" or prev is None or len(prev) != n:
            return np.zeros(n)
        y = prev / s
        if self.options.warm_start == "previous":
            return y
        # projected: the multiple alpha y minimising the energy norm of the error, alpha = y'b / y'Ny
        Ny = Ns @ y
        curv = float(y @ Ny)
        return y * (float(y @ (b * s)) / curv) if curv > 0 else np.zeros(n)

    def _report(self, dx, iterations, residual, converged, extra: SolverInfo | None = None) -> SolveResult:
        """The SolveResult of dx: ``extra`` (what this solver reports besides) with the figures every
        iterative solver reports; warns when the convergence was slow."""
        tol = self.options.inner_tolerance
        slow = (not converged) or iterations > self.slow_limit
        info = (extra or SolverInfo()).merged(
            inner_iterations=int(iterations),
            relative_residual=float(residual),
            converged=bool(converged),
            slow=bool(slow),
            tolerance=tol,
            warm_start=self.options.warm_start,
        )
        if slow:
            what = "did not reach" if not converged else "needed many " + self.unit + " to reach"
            warnings.warn(
                f"{self.name} solver {what} the relative residual {tol:g} "
                f"({iterations} {self.unit}, residual {residual:.3g}); " + self.advice,
                SlowConvergenceWarning,
                stacklevel=3,
            )
        self._previous = dx.copy()
        return SolveResult(dx, self.name, info)


class GaussSeidelSolver(_IterativeSolver):
    """Block Gauss-Seidel / SOR with the 6x6 diagonal photo blocks, one sparse triangular solve per
    sweep (module doc)."""

    name = "gauss-seidel"
    slow_limit = SLOW_SWEEPS
    unit = "sweeps"

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return self._empty()
        opts = self.options
        omega = opts.relaxation
        Ns, s = jacobi_scaled(N)
        blocks = partition(self.structure, n)
        C = block_cholesky(Ns, blocks)
        Cinv = np.linalg.inv(C)  # lower triangular blocks
        Cs = block_diagonal_matrix(C, blocks, lower_only=True)
        Ci = block_diagonal_matrix(Cinv, blocks, lower_only=True)
        G = (Ci @ Ns @ Ci.T).tocsr()
        L = strictly_block_lower(G, blocks)
        U = L.T.tocsr()
        T = (sp.identity(n, format="csr") + omega * L).tocsc()
        T.sort_indices()
        if n <= DENSE_SWEEP_LIMIT:  # small: a dense substitution has less overhead per sweep
            T_dense = T.toarray()

            def lower_solve(rhs):
                return la.solve_triangular(T_dense, rhs, lower=True, unit_diagonal=True, check_finite=False)
        else:
            def lower_solve(rhs):
                return spla.spsolve_triangular(T, rhs, lower=True, unit_diagonal=True, overwrite_A=True,
                                               overwrite_b=True)
        bs = b * s
        g = Ci @ bs
        bnorm = float(np.linalg.norm(bs))
        y0 = self._start(Ns, s, b)
        if bnorm == 0.0:
            return self._report(np.zeros(n), 0, 0.0, True, SolverInfo(relaxation=omega))
        z = Cs.T @ y0
        Uz = U @ z
        # residual of the start, in the scaled system
        res0 = float(np.linalg.norm(bs - Ns @ y0)) / bnorm
        residual, sweeps, converged = res0, 0, res0 < opts.inner_tolerance
        best, best_sweep, stagnated = res0, 0, False
        while not converged and not stagnated and sweeps < opts.max_inner_iterations:
            rhs = omega * (g - Uz) + (1.0 - omega) * z
            z_new = lower_solve(rhs)
            Uz_new = U @ z_new
            dz = z - z_new
            r = (Uz - Uz_new) - (1.0 / omega - 1.0) * dz  # g - G z_new
            residual = float(np.linalg.norm(Cs @ r)) / bnorm  # back to the scaled system
            z, Uz = z_new, Uz_new
            sweeps += 1
            if not np.isfinite(residual) or residual > DIVERGED * max(res0, 1.0):
                raise SingularNormalMatrix(None, "Gauss-Seidel diverged, which it cannot do for a "
                                                 "positive definite matrix")
            converged = residual < opts.inner_tolerance
            if sweeps % INNER_REPORT_EVERY == 0:
                progress.inner(self.name, sweeps, residual)
            if residual < 0.99 * best:
                best, best_sweep = residual, sweeps
            # rounding floor reached (or hopelessly slow): more sweeps would not help
            stagnated = sweeps - best_sweep >= STAGNATION_SWEEPS
        y = Ci.T @ z
        return self._report(y * s, sweeps, residual, converged, SolverInfo(relaxation=omega, stagnated=stagnated))


class PcgSolver(_IterativeSolver):
    """Conjugate gradients on N~ preconditioned by the inverses of its 6x6 diagonal blocks."""

    name = "pcg"
    slow_limit = SLOW_PCG

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return self._empty()
        opts = self.options
        Ns, s = jacobi_scaled(N)
        blocks = partition(self.structure, n)
        C = block_cholesky(Ns, blocks)
        Cinv = np.linalg.inv(C)
        Ci = block_diagonal_matrix(Cinv, blocks, lower_only=True)
        Minv = (Ci.T @ Ci).tocsr()  # block-diagonal inverse of the diagonal blocks
        bs = b * s
        bnorm = float(np.linalg.norm(bs))
        y = self._start(Ns, s, b)
        if bnorm == 0.0:
            return self._report(np.zeros(n), 0, 0.0, True)
        y, iterations, residual, converged, restarts = preconditioned_cg(
            Ns, bs, y, lambda r: Minv @ r, bnorm, opts.inner_tolerance, opts.max_inner_iterations, self.name)
        return self._report(y * s, iterations, residual, converged, SolverInfo(restarts=restarts))


INNER_REPORT_EVERY = 25  # inner iterations between two progress.inner calls (the reporter throttles by time)


def preconditioned_cg(A, b, y, precondition, bnorm, tol, max_iterations, name="pcg"):
    """Preconditioned conjugate gradients from y on A y = b to ``|b - A y| < tol |b|`` (the true
    residual, checked when the recursive one gets there; at most 3 restarts from the true
    residual), announcing its progress (progress.inner) under ``name``.
    Returns (y, iterations, relative residual, converged, restarts)."""
    iterations, restarts = 0, 0
    r = b - A @ y
    residual = float(np.linalg.norm(r)) / bnorm
    converged = residual < tol
    while not converged and iterations < max_iterations:
        z = precondition(r)
        p = z.copy()
        rz = float(r @ z)
        while iterations < max_iterations:
            Ap = A @ p
            curv = float(p @ Ap)
            if not curv > PIVOT_TOLERANCE**2 * float(p @ p):
                raise SingularNormalMatrix(None, "conjugate gradients met a direction of zero or negative curvature")
            alpha = rz / curv
            y += alpha * p
            r -= alpha * Ap
            iterations += 1
            recursive = float(np.linalg.norm(r)) / bnorm
            if recursive < tol:
                break
            if iterations % INNER_REPORT_EVERY == 0:
                progress.inner(name, iterations, recursive)
            z = precondition(r)
            rz_new = float(r @ z)
            p = z + (rz_new / rz) * p
            rz = rz_new
        r = b - A @ y
        residual = float(np.linalg.norm(r)) / bnorm
        converged = residual < tol
        if not converged:
            restarts += 1
            if restarts > 3:
                break
    return y, iterations, residual, converged, restarts
