"""Direct solvers without optional dependencies: ``dense`` (the reference) and ``sparse``."""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from .base import NormalSolver, SingularNormalMatrix, SolveResult, check_pivots, jacobi_scaled
from .blocks import Blocks, partition, ranges
from .info import SolverInfo


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
    """scipy's SuperLU on N in a fill-reducing order, with diagonal pivots (so an L D U of the SPD
    matrix whose pivots are Cholesky's, squared): the fallback when scikit-sparse is absent.

    The ordering is a minimum-degree ordering of the *block graph* (one node per photo or camera
    block, :func:`block_order`), expanded to the columns. It keeps each 6x6 block together and is
    36 times smaller than the column graph, so it costs a fraction of SuperLU's own column ordering
    (0.1 s instead of 1 s for a 10000-photo strip) at the same fill. It is kept while N's block
    pattern does not change (once per adjustment)."""

    name = "sparse"

    def __init__(self, options, structure):
        super().__init__(options, structure)
        self._order: np.ndarray | None = None
        self._block_pattern: tuple | None = None
        self.orderings = 0

    def solve(self, N, b):
        n = N.shape[0]
        if n == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        blocks = partition(self.structure, n)
        graph = block_graph(Ns, blocks)
        key = (n, graph.indptr.tobytes(), graph.indices.tobytes())
        if self._block_pattern != key:
            self._order = block_order(graph, blocks)
            self._block_pattern = key
            self.orderings += 1
        order = self._order
        Np = Ns[order][:, order]
        try:
            lu = spla.splu(Np.T.tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
        except RuntimeError as exc:  # exactly singular: SuperLU stops
            raise SingularNormalMatrix() from exc
        # with diagonal pivoting U_jj is the Cholesky pivot squared (the D of L D L^T); step i of
        # SuperLU eliminates column argsort(perm_c)[i] of the matrix it was given
        udiag = lu.U.diagonal()
        pivots = np.sqrt(np.maximum(udiag, 0.0)) * np.sign(udiag)
        check_pivots(pivots, order[np.argsort(lu.perm_c)])
        y = np.empty(n)
        y[order] = lu.solve((b * s)[order])
        return SolveResult(y * s, self.name, SolverInfo(orderings=self.orderings))


def block_graph(A: sp.csr_matrix, blocks: Blocks) -> sp.csr_matrix:
    """The pattern of A between blocks: (nb, nb), 1 where two blocks are coupled."""
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    br, bc = blocks.of_column[rows], blocks.of_column[A.indices]
    nb = len(blocks.starts)
    G = sp.csr_matrix((np.ones(len(br)), (br, bc)), shape=(nb, nb))
    G.sum_duplicates()
    return G


def block_order(graph: sp.csr_matrix, blocks: Blocks) -> np.ndarray:
    """Column order from a minimum-degree ordering of the block graph. scipy exposes SuperLU's
    multiple-minimum-degree ordering only through a factorisation, so it factorises a diagonally
    dominant matrix with the graph's pattern (small: one row per block) and reads the order."""
    nb = graph.shape[0]
    degree = np.diff(graph.indptr)
    surrogate = sp.csr_matrix((np.ones(graph.nnz), graph.indices, graph.indptr), shape=(nb, nb))
    surrogate = (surrogate + sp.diags(degree + 1.0)).tocsc()
    lu = spla.splu(surrogate, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    block_sequence = np.argsort(lu.perm_c)
    return ranges(blocks.starts[block_sequence], blocks.sizes[block_sequence])


def inverse(N) -> np.ndarray:
    """Dense N^-1 (the weight coefficients of the unknowns, Schmid 53), via Jacobi-scaled Cholesky."""
    n = N.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    Ns, s = jacobi_scaled(N)
    c = dense_cholesky(Ns.toarray())
    return la.cho_solve((c, True), np.eye(n), check_finite=False) * s[:, None] * s[None, :]
