"""Relaxation over strips, not photos (issue 12; Schmid's strip-by-strip view of a block).

``strip-pcg``: conjugate gradients on the Jacobi-scaled ``N~`` preconditioned by *block* relaxation
in which a block is a whole strip. Each strip's diagonal block of ``N~`` (its photos' columns, in
their own column order: along the strip) is banded, bandwidth about 17 (Schmid Fig. 10), so it is
factorised exactly by LAPACK's banded Cholesky; the couplings between strips (the sidelap points)
and with the camera columns are what the iteration resolves.

The strips' blocks laid end to end form one block-diagonal matrix, which is itself banded: ONE
``dpbtrf`` factorises every strip at once (the band is as wide as the widest strip's), and one
``dpbtrs`` over all of them applies block Jacobi. Camera columns (blocks of group -1) are one dense
block, factorised by ``dpotrf``. Two preconditioners (:data:`PRECONDITIONERS`):

* ``jacobi`` - block Jacobi over the strips: ``M = blockdiag(N_ss)``, one banded solve;
* ``ssor`` - symmetric block Gauss-Seidel over the strips (one forward and one backward sweep,
  block SSOR with omega = 1): ``M = (D + L) D^-1 (D + L')``, symmetric and positive definite, so
  usable in CG. Each sweep visits the strips in turn (a loop over strips, not photos: one banded
  solve and one sparse product with the strip's row of couplings each).

docs/solvers.md has the measurements behind the default (:data:`PRECONDITIONER`).

Groups come from ``Structure.groups`` (the adjustment gives each photo's strip). Blocks of group
-1 (camera columns, and photos of no strip) form the dense block while they have at most
DENSE_REST columns; beyond that they are cut into runs of RUN_BLOCKS consecutive blocks, each
treated as a strip (so a project without strip ids, or a structure without groups, still gets a
useful preconditioner). Any partition is correct (the diagonal blocks of a positive definite
matrix are positive definite); only the speed depends on it.

Singular N: a strip block or the camera block that is not positive definite (a pivot below
PIVOT_TOLERANCE) raises SingularNormalMatrix at its column; a direction N does not determine met by
CG (curvature ``p' N~ p <= 1e-14 p'p``) raises it without a column; a datum defect across strips may
instead end without convergence, which is reported and warned about (``info.converged``).

``strip-gauss-seidel`` (the pure relaxation, forward block Gauss-Seidel sweeps over the strips) is
not offered: docs/solvers.md has the sweep counts that ruled it out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.linalg import lapack

from .base import SingularNormalMatrix, Structure, check_pivots, jacobi_scaled
from .blocks import partition
from .direct import dense_cholesky
from .info import SolverInfo
from .iterative import _IterativeSolver, preconditioned_cg

PRECONDITIONERS = ("ssor", "jacobi")
PRECONDITIONER = "jacobi"  # measured: as fast or faster than ssor in time (docs/solvers.md, "strip-pcg")
SLOW_STRIP_PCG = 500  # CG iterations beyond which convergence counts as slow
DENSE_REST = 600  # columns of group -1 (cameras, photos of no strip) up to which they are one dense block
RUN_BLOCKS = 100  # blocks per run when group -1 has more columns than DENSE_REST


@dataclass(frozen=True)
class StripPartition:
    """The columns reordered strip after strip (each strip in its own column order), the dense
    rest (cameras) last: ``order`` (n,) column of N at each position; ``bounds`` (G + 1,) the
    positions where the G banded groups begin and end (the rest from ``bounds[-1]`` to n)."""

    order: np.ndarray
    bounds: np.ndarray

    @property
    def n_groups(self) -> int:
        return len(self.bounds) - 1

    @property
    def k(self) -> int:
        """Columns in banded groups (the rest, ``n - k``, is the dense block)."""
        return int(self.bounds[-1])


def strip_partition(structure: Structure, n: int) -> StripPartition:
    """Groups of columns from ``structure`` (module doc): its strips, then runs of the blocks of
    group -1 when there are more than DENSE_REST such columns, else those are the dense rest."""
    blocks = partition(structure, n)
    nb = len(blocks.starts)
    groups = structure.groups
    if groups is None or len(groups) != nb or not np.array_equal(blocks.starts, structure.block_starts):
        groups = np.full(nb, -1, dtype=int)
    groups = np.asarray(groups, dtype=int).copy()
    rest = groups < 0
    if blocks.sizes[rest].sum() > DENSE_REST:
        base = groups.max(initial=-1) + 1
        groups[rest] = base + np.arange(int(rest.sum())) // RUN_BLOCKS
        rest = groups < 0
    # group of each column; the rest sorts last; stable, so every group keeps its column order
    col_group = np.where(rest, np.iinfo(np.int64).max, groups)[blocks.of_column]
    order = np.argsort(col_group, kind="stable")
    banded = col_group[order] != np.iinfo(np.int64).max
    k = int(banded.sum())
    g = col_group[order][:k]
    bounds = np.flatnonzero(np.r_[True, g[1:] != g[:-1], True]) if k else np.zeros(1, dtype=int)
    return StripPartition(order=order, bounds=bounds.astype(int))


def _within_group_band(P: sp.csr_matrix, part: StripPartition) -> tuple[np.ndarray, int]:
    """LAPACK lower band storage of the banded groups' diagonal blocks of P (the permuted N~),
    laid end to end (entries between groups dropped), and its lower bandwidth."""
    k = part.k
    end = P.indptr[k]
    rows = np.repeat(np.arange(k), np.diff(P.indptr[: k + 1]))
    cols = P.indices[:end]
    group = np.repeat(np.arange(part.n_groups), np.diff(part.bounds))
    below = rows - cols
    keep = (below >= 0) & (cols < k)
    keep[keep] &= group[rows[keep]] == group[cols[keep]]
    w = int(below[keep].max(initial=0))
    ab = np.zeros((w + 1, k), order="F")
    ab[below[keep], cols[keep]] = P.data[:end][keep]
    return ab, w


class _StripFactor:
    """The block-diagonal part of P over the groups, factorised: every strip by one banded
    Cholesky, the rest by a dense one; ``solve(r)`` applies its inverse (block Jacobi)."""

    def __init__(self, P: sp.csr_matrix, part: StripPartition):
        self.part, k = part, part.k
        n = P.shape[0]
        self.w = 0
        self.cb = None
        if k:
            ab, self.w = _within_group_band(P, part)
            cb, info = lapack.dpbtrf(ab, lower=1, overwrite_ab=1)
            if info > 0:
                raise SingularNormalMatrix(int(part.order[info - 1]), "a strip's block is not positive definite")
            check_pivots(cb[0], part.order[:k])
            self.cb = np.asfortranarray(cb)
        self.cr = None
        if n > k:
            try:
                self.cr = dense_cholesky(P[k:, k:].toarray())
            except SingularNormalMatrix as exc:
                col = None if exc.column is None else int(part.order[k + exc.column])
                raise SingularNormalMatrix(col, "the camera block is not positive definite") from exc

    def solve(self, r: np.ndarray) -> np.ndarray:
        k = self.part.k
        z = np.empty_like(r)
        if k:
            z[:k] = lapack.dpbtrs(self.cb, r[:k], lower=1)[0]
        if self.cr is not None:
            z[k:] = la.cho_solve((self.cr, True), r[k:], check_finite=False)
        return z

    def solve_group(self, g: int, r: np.ndarray) -> np.ndarray:
        """The inverse of group g's block (g = n_groups: the dense rest) applied to r (its rows)."""
        if g == self.part.n_groups:
            return la.cho_solve((self.cr, True), r, check_finite=False)
        a, b = self.part.bounds[g], self.part.bounds[g + 1]
        return lapack.dpbtrs(self.cb[:, a:b], r, lower=1)[0]


class _SymmetricGaussSeidel:
    """Block SSOR (omega 1) over the groups: ``M^-1 r`` by a forward sweep ``(D + L) w = r`` and a
    backward one ``(D + L') z = D w``, one banded solve and one sparse product per group each."""

    def __init__(self, P: sp.csr_matrix, factor: _StripFactor):
        self.factor = factor
        part = factor.part
        n = P.shape[0]
        ends = np.r_[part.bounds, n] if n > part.k else part.bounds
        self.ends = ends
        group = np.repeat(np.arange(len(ends) - 1), np.diff(ends))
        rows = np.repeat(np.arange(n), np.diff(P.indptr))
        gr, gc = group[rows], group[P.indices]
        # new index arrays: eliminate_zeros compacts them in place, and P's must stay as they are
        lower = sp.csr_matrix((P.data * (gr > gc), P.indices.copy(), P.indptr.copy()), shape=P.shape)
        upper = sp.csr_matrix((P.data * (gr < gc), P.indices.copy(), P.indptr.copy()), shape=P.shape)
        lower.eliminate_zeros()
        upper.eliminate_zeros()
        # each group's rows of the couplings: to earlier groups (forward), to later ones (backward)
        self.lower = [lower[a:b] for a, b in zip(ends[:-1], ends[1:])]
        self.upper = [upper[a:b] for a, b in zip(ends[:-1], ends[1:])]

    def solve(self, r: np.ndarray) -> np.ndarray:
        ends, solve_group = self.ends, self.factor.solve_group
        G = len(ends) - 1
        w = np.zeros_like(r)
        for g in range(G):
            a, b = ends[g], ends[g + 1]
            w[a:b] = solve_group(g, r[a:b] - self.lower[g] @ w)
        z = w
        for g in range(G - 2, -1, -1):  # the last group's z is its w
            a, b = ends[g], ends[g + 1]
            z[a:b] = w[a:b] - solve_group(g, self.upper[g] @ z)
        return z


class StripPcgSolver(_IterativeSolver):
    """Conjugate gradients on N~ preconditioned by block relaxation over strips (module doc)."""

    name = "strip-pcg"
    advice = ("a block of many strips needs many iterations (its bending across the strips). A direct solver "
              "('cholmod', 'cvxopt', 'sparse') is faster where its factor fits in memory (docs/solvers.md, "
              "'strip-pcg'); more control across the block, or cross strips, speed the iteration up.")
    slow_limit = SLOW_STRIP_PCG

    def __init__(self, options, structure, preconditioner: str | None = None):
        super().__init__(options, structure)
        self.preconditioner = preconditioner or PRECONDITIONER
        if self.preconditioner not in PRECONDITIONERS:
            raise ValueError(f"unknown preconditioner {self.preconditioner!r}; choose one of "
                             f"{', '.join(PRECONDITIONERS)}")
        self._part: StripPartition | None = None

    def _partition(self, n: int) -> StripPartition:
        if self._part is None or len(self._part.order) != n:
            self._part = strip_partition(self.structure, n)
        return self._part

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return self._empty()
        opts = self.options
        Ns, s = jacobi_scaled(N)
        part = self._partition(n)
        order = part.order
        P = Ns[order][:, order].tocsr()
        P.sort_indices()
        factor = _StripFactor(P, part)
        M = factor if self.preconditioner == "jacobi" else _SymmetricGaussSeidel(P, factor)
        bs = (b * s)[order]
        bnorm = float(np.linalg.norm(bs))
        extra = SolverInfo(preconditioner=self.preconditioner, strips=part.n_groups, bandwidth=factor.w,
                           dense_block=n - part.k)
        if bnorm == 0.0:
            return self._report(np.zeros(n), 0, 0.0, True, extra)
        y = self._start(Ns, s, b)[order]
        y, iterations, residual, converged, restarts = preconditioned_cg(P, bs, y, M.solve, bnorm, opts.inner_tolerance,
                                                                     opts.max_inner_iterations, self.name)
        dx = np.empty(n)
        dx[order] = y
        return self._report(dx * s, iterations, residual, converged, extra.merged(restarts=restarts))
