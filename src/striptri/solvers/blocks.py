"""The 6x6 photo blocks (and camera blocks) of N: partition, block-diagonal Cholesky, block
triangular parts. Used by the block-iterative solvers and by the banded solver's border choice."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .base import PIVOT_TOLERANCE, SingularNormalMatrix, Structure

DEFAULT_BLOCK = 6  # exterior elements of a photo


@dataclass(frozen=True)
class Blocks:
    """A partition of the columns 0..n-1 into consecutive blocks."""

    starts: np.ndarray  # (nb,) first column of each block
    sizes: np.ndarray  # (nb,)
    of_column: np.ndarray  # (n,) block of each column

    @property
    def n(self) -> int:
        return len(self.of_column)

    @property
    def largest(self) -> int:
        return int(self.sizes.max()) if len(self.sizes) else 0


def ranges(starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """The ranges [starts[i], starts[i] + sizes[i]) one after the other, as one int64 array (the
    columns of blocks taken in some order, the entries of some rows of a CSR matrix)."""
    sizes = np.asarray(sizes, dtype=np.int64)
    if not len(sizes):
        return np.zeros(0, dtype=np.int64)
    first = np.cumsum(sizes) - sizes  # where each range begins in the output
    return np.repeat(np.asarray(starts, dtype=np.int64) - first, sizes) + np.arange(int(sizes.sum()))


def partition(structure: Structure, n: int) -> Blocks:
    """Blocks from ``structure.block_starts`` (photos, then cameras); consecutive blocks of 6
    columns when the structure gives none or does not fit a matrix of size n."""
    starts = np.asarray(structure.block_starts, dtype=int)
    valid = (
        len(starts) > 0 and starts[0] == 0 and np.all(np.diff(starts) > 0) and starts[-1] < n
    )
    if not valid:
        starts = np.arange(0, n, DEFAULT_BLOCK, dtype=int)
    sizes = np.diff(np.append(starts, n))
    of_column = np.repeat(np.arange(len(starts)), sizes)
    return Blocks(starts=starts, sizes=sizes, of_column=of_column)


def _coo_parts(A: sp.csr_matrix):
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    return rows, A.indices, A.data


def diagonal_blocks(A: sp.csr_matrix, blocks: Blocks) -> np.ndarray:
    """(nb, m, m) diagonal blocks of A padded to the largest size m with an identity (so that batched
    Cholesky and inverses work on blocks of every size at once)."""
    m = blocks.largest
    D = np.zeros((len(blocks.starts), m, m))
    pad = np.arange(m)[None, :] >= blocks.sizes[:, None]  # (nb, m)
    D[:, np.arange(m), np.arange(m)] = pad.astype(float)
    rows, cols, data = _coo_parts(A)
    br, bc = blocks.of_column[rows], blocks.of_column[cols]
    inside = br == bc
    start = blocks.starts[br[inside]]
    D[br[inside], rows[inside] - start, cols[inside] - start] = data[inside]
    return D


def block_cholesky(A: sp.csr_matrix, blocks: Blocks) -> np.ndarray:
    """(nb, m, m) lower Cholesky factors C of A's diagonal blocks (padded); raises
    SingularNormalMatrix at the first column whose pivot fails PIVOT_TOLERANCE (A Jacobi-scaled)."""
    D = diagonal_blocks(A, blocks)
    try:
        C = np.linalg.cholesky(D)
    except np.linalg.LinAlgError:
        C = None
    if C is not None:
        piv = np.einsum("bii->bi", C)
        bad = ~(piv >= PIVOT_TOLERANCE)
        if not np.any(bad):
            return C
    # error path only: find the first failing column block by block
    for b in range(len(D)):
        j = _first_bad_pivot(D[b])
        if j is not None:
            raise SingularNormalMatrix(int(blocks.starts[b] + j), "diagonal block not positive definite")
    raise SingularNormalMatrix(None, "diagonal block not positive definite")  # pragma: no cover


def _first_bad_pivot(A: np.ndarray) -> int | None:
    """Column where an unpivoted Cholesky of a small dense A breaks down (for the error message)."""
    n = len(A)
    L = np.zeros_like(A)
    for j in range(n):
        d = A[j, j] - L[j, :j] @ L[j, :j]
        if not d >= PIVOT_TOLERANCE**2:
            return j
        L[j, j] = np.sqrt(d)
        L[j + 1 :, j] = (A[j + 1 :, j] - L[j + 1 :, :j] @ L[j, :j]) / L[j, j]
    return None


def block_diagonal_matrix(blocks_values: np.ndarray, blocks: Blocks, lower_only: bool = False) -> sp.csr_matrix:
    """Sparse block-diagonal matrix from padded (nb, m, m) blocks (the padding is dropped)."""
    nb, m, _ = blocks_values.shape
    r, c = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    keep = (r[None] < blocks.sizes[:, None, None]) & (c[None] < blocks.sizes[:, None, None])
    if lower_only:
        keep &= (r >= c)[None]
    start = blocks.starts[:, None, None]
    rows = np.broadcast_to(start + r[None], keep.shape)[keep]
    cols = np.broadcast_to(start + c[None], keep.shape)[keep]
    n = blocks.n
    return sp.csr_matrix((blocks_values[keep], (rows, cols)), shape=(n, n))


def strictly_block_lower(A: sp.csr_matrix, blocks: Blocks) -> sp.csr_matrix:
    """The part of A below the diagonal blocks (rows of a later block than the column)."""
    rows, cols, data = _coo_parts(A)
    keep = blocks.of_column[rows] > blocks.of_column[cols]
    M = sp.csr_matrix((data[keep], (rows[keep], cols[keep])), shape=A.shape)
    return M
