"""Selected inversion: chosen blocks of Qxx = N^-1 without the dense inverse (DESIGN section 6).

The mean errors of the orientation elements need only the 6x6 diagonal block of each photo, the
camera blocks and a few off-diagonal blocks (a base component between neighbouring photos) of
``Z = N^-1``. All of them lie inside the pattern of the Cholesky factor ``N = L L'`` (or are
cheap to reach from it), and the entries of Z on that pattern follow from L alone by the
Takahashi equations (Takahashi, Fagan and Chin 1973; Hager and Golub; Erisman and Tinney 1975).
From ``L' Z = L^-1`` (``L^-1`` lower triangular with diagonal ``1/L_jj``), for a column block J
of L whose rows below J are K (``L_KJ`` the part of L there, every other row of those columns zero):

    Z_KJ = -Z_KK L_KJ L_JJ^-1                        (the rows of L' Z above the diagonal, = 0)
    Z_JJ = L_JJ^-T (L_JJ^-1 - L_KJ' Z_KJ)             (its diagonal block, = L_JJ^-1)

Going backwards from the last column block, ``Z_KK`` has always been computed already, and it lies
inside the pattern of L because the rows below a column of L form a clique of the filled graph.
So the recurrence never leaves the pattern of L and costs what the factorisation costs.

Three routes (``method``), all on the Jacobi-scaled matrix ``N~ = D N D``, ``D = diag(N)^-1/2``
(unit diagonal, so metres, radians and millimetres are alike; ``N^-1 = D N~^-1 D``), all with the
pivot test of :mod:`striptri.solvers` (so the same N counts as singular everywhere):

* ``banded`` - a strip: N's photo part is banded (half-bandwidth w of about 17 photos' columns)
  and the camera columns, last, couple everything (an arrowhead). See :class:`BandedInverse`.
* ``sparse`` - a block: a fill-reducing order of the block graph (one node per photo or camera
  block), a block-level symbolic factorisation with supernodes, a supernodal Cholesky and the
  recurrence on the supernodes, all with dense BLAS kernels. See :class:`SupernodalInverse`.
* ``cholmod`` - the same, but CHOLMOD (scikit-sparse, optional) does the numeric factorisation in
  that order and its L is read into the supernodes: an independent factorisation, for checking.
  It is not faster (CHOLMOD's numeric factorisation in this order takes 3-4 times as long as the
  supernodal one here, the whole selected inversion twice as long, on synthetic blocks of 10,000
  photos with single-threaded BLAS: scripts/bench/bench_selected_inverse.py), so ``auto`` never
  picks it.
* ``dense`` - the reference for tiny systems: the dense inverse.

Entries outside the computed pattern (e.g. the block of two photos at opposite ends of a strip)
are columns of N^-1 obtained by solving with the factor already in hand: O(nnz(L)) per column.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.linalg import blas, lapack

from .solvers import (
    BANDED_MAX_BANDWIDTH,
    DENSE_LIMIT,
    SingularNormalMatrix,
    Structure,
    jacobi_scaled,
)
from .solvers.banded import choose_split
from .solvers.base import check_pivots
from .solvers.blocks import Blocks, partition
from .solvers.direct import block_order, dense_cholesky
from .solvers.sparse_cholesky import cholmod_available, cholmod_module

METHODS = ("auto", "dense", "banded", "sparse", "cholmod")

MIN_BAND_BLOCK = 32  # smallest column block of the banded recurrence (fewer Python steps)
RELAXED_SUPERNODE = 48  # columns up to which a chain of blocks is merged into one supernode
RELAXED_ZEROS = 0.5  # ... if at most this fraction of the merged supernode is explicit zeros
SOLVE_CHUNK = 4_000_000  # entries of the n x q right-hand sides solved at once (32 MB)
BLOCK_ORDERING = "nesdis"  # order of the sparse route: "nesdis" (when CHOLMOD is there) or "mmd"
ENTRY_CHUNK = 1 << 20  # entries looked up at once by SelectedInverse.entries (a few 8 MB index arrays)


# ----------------------------------------------------------------------------------------- API


class SelectedInverse:
    """Selected blocks of N^-1 (unscaled, in the units of N's unknowns).

    ``block(i)``: the diagonal block ``N^-1[I, I]`` of the unknown set ``I = blocks[i]`` (an index
    array; a column -1 is a fixed element and gives a zero row and column). ``pair(i, j)``:
    ``N^-1[I, J]``; pairs named when the inverse was computed cost nothing more, others are looked
    up in the computed pattern or, outside it, solved for with the factor (O(nnz(L)) per column).
    ``diag()``: the whole diagonal of N^-1. ``solve(b)`` and ``quadratic_form(f)`` (``f' N^-1 f``,
    Schmid 81-84) reuse the factor. ``info``: the route taken and its sizes.
    """

    def __init__(self, engine, scale: np.ndarray, blocks: list[np.ndarray], pairs: Sequence[tuple[int, int]]):
        self._engine = engine
        self._s = scale
        self.blocks = blocks
        self.n = len(scale)
        self.method = engine.name
        self._flat = _FlatBlocks(blocks)
        nb = len(blocks)
        keys = np.concatenate([np.repeat(np.arange(nb), 2).reshape(nb, 2),
                               np.asarray(pairs, dtype=int).reshape(-1, 2)])
        rows, cols, start = self._flat.requests(keys)
        values, self._diag = engine.compute_with_diag(rows, cols)
        self._values = self._unscaled(values, rows, cols)
        self._start = dict(zip(map(tuple, keys.tolist()), start.tolist()))
        self._extra: dict[tuple[int, int], np.ndarray] = {}
        self.info = dict(engine.info)

    def _unscaled(self, values: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        s = np.append(self._s, 0.0)  # index -1 (a fixed element) reads a zero scale: zero entries
        return values * s[rows] * s[cols]

    def _lookup(self, i: int, j: int) -> np.ndarray | None:
        st = self._start.get((i, j))
        if st is None:
            return None
        li, lj = len(self.blocks[i]), len(self.blocks[j])
        return self._values[st: st + li * lj].reshape(li, lj)

    def diag(self) -> np.ndarray:
        """(n,) the diagonal of N^-1."""
        return self._diag * self._s**2

    def block(self, i: int) -> np.ndarray:
        """(m_i, m_i) N^-1 on the unknown set blocks[i]."""
        return self._lookup(int(i), int(i)).copy()

    def pair(self, i: int, j: int) -> np.ndarray:
        """(m_i, m_j) N^-1[blocks[i], blocks[j]]."""
        i, j = int(i), int(j)
        for key, transpose in (((i, j), False), ((j, i), True)):
            found = self._lookup(*key)
            if found is None:
                found = self._extra.get(key)
            if found is not None:
                return (found.T if transpose else found).copy()
        rows, cols, _ = self._flat.requests(np.array([[i, j]]))
        value = self._unscaled(self._engine.compute(rows, cols), rows, cols)
        value = value.reshape(len(self.blocks[i]), len(self.blocks[j]))
        self._extra[(i, j)] = value
        return value.copy()

    def entries(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """N^-1[rows, cols] elementwise (broadcast; -1 reads zero), e.g. the unknowns of the photos
        and cameras of every point group at once: ``entries(c[:, :, None], c[:, None, :])``. Entries
        of unknowns that share a condition (or a camera) lie in the computed pattern; others are
        solved for (O(nnz(L)) per distinct column). Read ENTRY_CHUNK at a time (memory bounded)
        where the route can look entries up (sparse, dense); the solves are made once at the end."""
        r, c = np.broadcast_arrays(np.asarray(rows, dtype=int), np.asarray(cols, dtype=int))
        shape = r.shape
        if r.ndim == 0:
            r, c = r.reshape(1), c.reshape(1)
        size, inner = r.size, int(np.prod(r.shape[1:], dtype=np.int64))
        if not self._engine.looks_up or size <= ENTRY_CHUNK:
            return self._entries_flat(r.ravel(), c.ravel()).reshape(shape)
        out = np.empty(size)
        missing = []
        step = max(1, ENTRY_CHUNK // max(inner, 1))
        for a in range(0, r.shape[0], step):
            rr, cc = r[a: a + step].ravel(), c[a: a + step].ravel()
            self._check(rr, cc)
            values, found = self._engine.lookup(rr, cc)
            out[a * inner: a * inner + len(rr)] = self._unscaled(values, rr, cc)
            if not found.all():
                missing.append(a * inner + np.flatnonzero(~found))
        if missing:
            at = np.concatenate(missing)
            rr, cc = r.reshape(-1)[at], c.reshape(-1)[at]
            out[at] = self._unscaled(self._engine.solved_entries(rr, cc), rr, cc)
        return out.reshape(shape)

    def _check(self, r: np.ndarray, c: np.ndarray) -> None:
        if len(r) and (min(r.min(), c.min()) < -1 or max(r.max(), c.max()) >= self.n):
            raise IndexError(f"indices must lie in -1..{self.n - 1}")

    def _entries_flat(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        self._check(r, c)
        return self._unscaled(self._engine.compute(r, c), r, c)

    def stack(self, ids: Sequence[int] | None = None) -> np.ndarray:
        """(len(ids), m, m) the diagonal blocks of equal size m (all blocks when ids is None)."""
        ids = np.arange(len(self.blocks)) if ids is None else np.asarray(ids, dtype=int)
        sizes = np.unique(self._flat.length[ids])
        if len(sizes) > 1:
            raise ValueError(f"blocks of different sizes {sizes.tolist()} cannot be stacked")
        m = int(sizes[0]) if len(sizes) else 0
        first = np.array([self._start[(int(i), int(i))] for i in ids], dtype=int)
        return self._values[first[:, None] + np.arange(m * m)[None, :]].reshape(len(ids), m, m)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """N^-1 b (b: (n,) or (n, q)) with the factor."""
        b = np.asarray(b, dtype=float)
        if len(b) != self.n:
            raise ValueError(f"b has {len(b)} rows, N {self.n}")
        B = b.reshape(self.n, 1 if b.ndim == 1 else b.shape[1]) * self._s[:, None]
        X = self._engine.solve(B) * self._s[:, None] if self.n else B
        return X[:, 0] if b.ndim == 1 else X

    def quadratic_form(self, f: np.ndarray):
        """f' N^-1 f, the weight coefficient of a function of the unknowns with gradient f (Schmid
        81-84): a float for f (n,), or (q,) for the q columns of f (n, q)."""
        f = np.asarray(f, dtype=float)
        q = np.einsum("i...,i...->...", f, self.solve(f))
        return float(q) if f.ndim == 1 else q


def selected_inverse(N: sp.spmatrix, blocks=None, pairs: Sequence[tuple[int, int]] = (), *,
                     block_starts: np.ndarray | None = None, method: str = "auto",
                     keep_factor: bool = True) -> SelectedInverse:
    """Selected blocks of N^-1 for a symmetric positive definite N (n x n, sparse or dense).

    blocks: the unknown sets whose diagonal blocks of N^-1 are wanted - a sequence of index arrays
    (-1 = a fixed element: zero row and column), or a 1-D integer array of block starts (contiguous
    blocks ``[starts[i], starts[i+1])``, the last up to n), or None (only ``diag()``).
    pairs: (i, j) block pairs whose off-diagonal block ``N^-1[blocks[i], blocks[j]]`` is wanted.
    block_starts: the partition of the columns into photo/camera blocks that the sparse route
    orders and factorises by (``UnknownLayout.block_starts()``); by default the blocks' own
    starts, or consecutive blocks of 6. It affects the speed only.
    method: one of METHODS; ``auto`` picks ``dense`` up to DENSE_LIMIT unknowns, ``banded`` when the
    photo part (camera columns split off as a border) has a half-bandwidth of at most
    BANDED_MAX_BANDWIDTH (the thresholds of the solvers' ``auto``), else ``sparse``.
    keep_factor: the sparse routes keep the Cholesky factor beside the selected inverse (for
    ``solve``, ``quadratic_form`` and entries outside the pattern); False lets the inverse take the
    factor's place (half the memory) and factorises again only if a solve is asked for.

    Raises SingularNormalMatrix when N is not positive definite (the pivot test of the solvers).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    N = N if sp.issparse(N) else sp.csr_matrix(np.asarray(N, dtype=float))
    n = N.shape[0]
    if N.shape != (n, n):
        raise ValueError(f"N must be square, not {N.shape}")
    block_list = _as_blocks(blocks, n)
    for i, j in pairs:
        if not (0 <= i < len(block_list) and 0 <= j < len(block_list)):
            raise IndexError(f"pair ({i}, {j}) names a block outside 0..{len(block_list) - 1}")
    if n == 0:
        return SelectedInverse(_EmptyInverse(), np.zeros(0), block_list, pairs)
    As, s = jacobi_scaled(N)
    structure = Structure(n, _partition_starts(block_list, block_starts, n))
    chosen = _choose_method(method, As, structure)
    engine = {
        "dense": lambda: DenseInverse(As),
        "banded": lambda: BandedInverse(As, structure),
        "sparse": lambda: SupernodalInverse(As, structure, "numpy", keep_factor, lambda: jacobi_scaled(N)[0]),
        "cholmod": lambda: SupernodalInverse(As, structure, "cholmod", keep_factor, lambda: jacobi_scaled(N)[0]),
    }[chosen]()
    return SelectedInverse(engine, s, block_list, pairs)


def for_layout(N: sp.spmatrix, layout, photo_pairs: Sequence[tuple[int, int]] = (), *,
               method: str = "auto", keep_factor: bool = True) -> SelectedInverse:
    """Selected inverse with the blocks of an UnknownLayout: block i < n_photos is photo i's 6
    elements (``layout.photo_cols[i]``, fixed elements zero, a column shared by an enforced base
    component appears in both photos), block n_photos + j is camera j's (c, xp, yp).
    photo_pairs: (photo, photo) pairs whose 6x6 off-diagonal block is wanted."""
    blocks = [np.asarray(c, dtype=int) for c in (*layout.photo_cols, *layout.camera_cols)]
    return selected_inverse(N, blocks, photo_pairs, block_starts=layout.block_starts(), method=method,
                            keep_factor=keep_factor)


def photo_blocks(N: sp.spmatrix, layout, *, method: str = "auto") -> np.ndarray:
    """(n_photos, 6, 6) the diagonal blocks of N^-1 of every photo (fixed elements: zero rows and
    columns), in the order (X0, Y0, Z0, rotation unknowns) of ``layout.photo_cols``."""
    inv = for_layout(N, layout, method=method)
    return inv.stack(range(len(layout.photo_cols)))


# ------------------------------------------------------------------------------------- helpers


def _as_blocks(blocks, n: int) -> list[np.ndarray]:
    """The index arrays of the blocks: from a 1-D integer numpy array of starts, or as given."""
    if blocks is None:
        return []
    if isinstance(blocks, np.ndarray) and blocks.ndim == 1 and np.issubdtype(blocks.dtype, np.integer):
        starts = blocks.astype(int)
        if len(starts) and (starts[0] != 0 or np.any(np.diff(starts) <= 0) or starts[-1] >= n):
            raise ValueError("block starts must begin at 0, increase and lie below n")
        ends = np.append(starts[1:], n)
        return [np.arange(a, b) for a, b in zip(starts, ends)]
    out = []
    for b in blocks:
        b = np.asarray(b, dtype=int).reshape(-1)
        if np.any((b < -1) | (b >= n)):
            raise IndexError(f"block indices must lie in -1..{n - 1}")
        out.append(b)
    return out


class _FlatBlocks:
    """The blocks' index arrays concatenated (``cat``; block i at ``first[i]``, ``length[i]`` long)."""

    def __init__(self, blocks: list[np.ndarray]):
        self.length = np.array([len(b) for b in blocks], dtype=int)
        self.first = np.concatenate([[0], np.cumsum(self.length)[:-1]]).astype(int) if len(blocks) else np.zeros(0, int)
        self.cat = np.concatenate(blocks).astype(int) if len(blocks) else np.zeros(0, dtype=int)

    def requests(self, keys: np.ndarray):
        """Row and column indices of every entry of the blocks N^-1[blocks[i], blocks[j]] for the
        (i, j) in keys (k, 2), each flattened row-major and one after the other, and where each starts."""
        i, j = keys[:, 0], keys[:, 1]
        count = self.length[i] * self.length[j]
        start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(int) if len(keys) else np.zeros(0, int)
        key = np.repeat(np.arange(len(keys)), count)
        local = np.arange(int(count.sum())) - start[key]
        lj = self.length[j][key]
        rows = self.cat[self.first[i][key] + local // np.maximum(lj, 1)]
        cols = self.cat[self.first[j][key] + local % np.maximum(lj, 1)]
        return rows, cols, start


def _partition_starts(blocks: list[np.ndarray], block_starts, n: int) -> np.ndarray:
    """Starts of contiguous column blocks for the sparse route: the given ones, else the first
    column of each requested block; blocks longer than 12 are cut into pieces of 6."""
    if block_starts is not None and len(block_starts):
        starts = np.asarray(block_starts, dtype=int)
    else:
        flat = _FlatBlocks(blocks)
        owner = np.repeat(np.arange(len(blocks)), flat.length)
        firsts = np.full(len(blocks), n)
        np.minimum.at(firsts, owner, np.where(flat.cat >= 0, flat.cat, n))
        starts = np.unique(np.concatenate([[0], firsts[firsts < n]])).astype(int)
    starts = np.unique(starts[(starts >= 0) & (starts < n)])
    if not len(starts) or starts[0] != 0:
        starts = np.concatenate([[0], starts])
    sizes = np.diff(np.append(starts, n))
    long = sizes > 12
    if np.any(long):
        pieces = [np.arange(a, a + m, 6) for a, m in zip(starts[long], sizes[long])]
        starts = np.unique(np.concatenate([starts] + pieces))
    return starts


def _choose_method(method: str, As: sp.csr_matrix, structure: Structure) -> str:
    if method != "auto":
        if method == "cholmod":
            cholmod_module()  # SolverUnavailable with the install command
        return method
    n = As.shape[0]
    if n <= DENSE_LIMIT:
        return "dense"
    _, w = choose_split(As, structure)
    return "banded" if w <= BANDED_MAX_BANDWIDTH else "sparse"


class _Engine:
    """What the routes share: entries of N~^-1 on request, and solves with the factor."""

    name = "base"
    n = 0
    looks_up = False  # True: lookup() reads entries of the computed pattern without solving

    def __init__(self):
        self.info: dict = {}

    def solve(self, B: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def compute(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def diag(self) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def compute_with_diag(self, rows, cols):
        return self.compute(rows, cols), self.diag()

    def lookup(self, rows: np.ndarray, cols: np.ndarray):  # pragma: no cover - interface
        """(values, found): entries in the computed pattern (0 where fixed, -1, or not found) and
        which were found or are fixed; the others are for solved_entries."""
        raise NotImplementedError

    def solved_entries(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Entries of N~^-1 from whole columns of it, solved for with the factor (columns taken
        from whichever side has fewer distinct indices)."""
        if len(rows) == 0:
            return np.zeros(0)
        if len(np.unique(rows)) < len(np.unique(cols)):
            rows, cols = cols, rows  # symmetric
        want, where = np.unique(cols, return_inverse=True)
        out = np.empty(len(rows))
        chunk = max(1, SOLVE_CHUNK // max(self.n, 1))
        for a in range(0, len(want), chunk):
            E = np.zeros((self.n, min(chunk, len(want) - a)))
            E[want[a: a + chunk], np.arange(E.shape[1])] = 1.0
            X = self.solve(E)
            sel = (where >= a) & (where < a + chunk)
            out[sel] = X[rows[sel], where[sel] - a]
        return out


def _valid(rows, cols):
    """Mask of requested entries that are not fixed (-1), and the values array to fill."""
    ok = (rows >= 0) & (cols >= 0)
    return ok, np.zeros(len(rows))


class _EmptyInverse(_Engine):
    name = "empty"

    def compute(self, rows, cols):
        return np.zeros(len(rows))

    def diag(self):
        return np.zeros(0)

    def solve(self, B):
        return B


class DenseInverse(_Engine):
    """The reference: the dense inverse of the scaled matrix (LAPACK Cholesky)."""

    name = "dense"

    def __init__(self, As: sp.csr_matrix):
        super().__init__()
        self.n = As.shape[0]
        c = dense_cholesky(As.toarray())
        self._factor = c
        self._Z = la.cho_solve((c, True), np.eye(self.n), check_finite=False)

    looks_up = True

    def compute(self, rows, cols):
        ok, out = _valid(rows, cols)
        out[ok] = self._Z[rows[ok], cols[ok]]
        return out

    def lookup(self, rows, cols):
        return self.compute(rows, cols), np.ones(len(rows), dtype=bool)

    def diag(self):
        return np.diag(self._Z).copy()

    def solve(self, B):
        return la.cho_solve((self._factor, True), B, check_finite=False)


# ------------------------------------------------------------------------------------- banded


def _lower_band(A: sp.csr_matrix, k: int, w: int) -> np.ndarray:
    """LAPACK lower band storage ab[i - j, j] = A[i, j] of the leading k x k part of A."""
    ab = np.zeros((w + 1, k))
    end = A.indptr[k]
    rows = np.repeat(np.arange(k), np.diff(A.indptr[: k + 1]))
    cols = A.indices[:end]
    below = rows - cols
    keep = (below >= 0) & (cols < k)
    ab[below[keep], cols[keep]] = A.data[:end][keep]
    return ab


def _from_band(cb: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """Dense L[r0:r1, c0:c1] from lower band storage cb[i - j, j] = L[i, j]."""
    d, cols, inside = _band_index(cb.shape[0] - 1, r0 - c0, r1 - r0, c1 - c0)
    return np.where(inside, cb[d, cols + c0], 0.0)


@functools.lru_cache(maxsize=8)
def _band_index(w: int, shift: int, n_rows: int, n_cols: int):
    """Index arrays of an (n_rows, n_cols) window, rows starting ``shift`` below the columns, in band
    storage of lower bandwidth w: (clipped diagonal, column offset, inside the band)."""
    d = shift + np.arange(n_rows)[:, None] - np.arange(n_cols)[None, :]
    inside = (d >= 0) & (d <= w)
    return np.clip(d, 0, w), np.broadcast_to(np.arange(n_cols)[None, :], d.shape), inside


class BandedInverse(_Engine):
    """Selected inversion of a strip's N: banded photo part A, dense border of camera columns.

    Split (as the ``banded`` solver does, :func:`striptri.solvers.banded.choose_split`)

        N~ = [A  B]    A: k x k, lower bandwidth w;  B: k x m;  C: m x m (m border columns)
             [B' C]

    **Banded part.** ``A = L L'`` by LAPACK pbtrf (scipy.linalg.cholesky_banded). The columns are
    cut into blocks of nb >= w columns; L is then block bidiagonal (column block t has rows only in
    blocks t and t+1), and the Takahashi equations of the module docstring become, with
    ``M = L_{t+1,t}``,

        Z_{t+1,t} = -Z_{t+1,t+1} M L_tt^-1,      Z_tt = L_tt^-T (L_tt^-1 - M' Z_{t+1,t}),

    run from the last block back to the first with dense BLAS kernels on nb x nb blocks:
    O(k nb^2) = O(k w^2) work (the cost of the factorisation) and O(nb^2) memory beyond the factor:
    only ``Z_{t+1,t+1}`` is carried from one step to the next. The requested entries are read as the
    pass goes by: every entry whose two indices are less than nb apart (so every 6x6 block of
    photos within two photos of each other) lies in ``Z_tt`` or ``Z_{t+1,t}``.

    **Border (arrowhead).** Block elimination ``N~ = [I 0; Y' I] [A 0; 0 S] [I Y; 0 I]`` with
    ``Y = A^-1 B`` (pbtrs) and the Schur complement ``S = C - B' Y`` (dense Cholesky
    ``S = R R'``) gives

        N~^-1 = [A^-1 + Y S^-1 Y'   -Y S^-1]
                [-S^-1 Y'            S^-1  ]

    So the camera block is ``S^-1``, the photo-camera blocks are ``-Y S^-1``, and the photo part
    is the banded part's inverse plus a correction of rank m: with ``W = Y R^-T`` (k x m),
    ``(Y S^-1 Y')_ij = W_i . W_j``, which costs m per requested entry and is added only to the
    entries asked for (the recurrence itself runs on A alone). The pivots are those of the
    Cholesky factorisation of the whole N~ (the same test as the ``banded`` solver).

    Entries further than nb apart are solved for with the factor (``solve``).

    **The band of the inverse, kept.** The first request runs the pass once and keeps the band of
    ``A^-1`` within the bandwidth w of the diagonal (lower band storage, the size of the factor);
    every later request reads its entries there (``hi - lo <= w``: all 6x6 blocks of photos that
    share a point in a strip) or, beyond the band, solves for them. Requests come chunk by chunk
    (covariance.group_forms), so a pass per request would cost O(k^2 w^2 / chunk) on a long strip:
    at 100,000 photos 67 s instead of 3 s.
    """

    name = "banded"

    def __init__(self, As: sp.csr_matrix, structure: Structure):
        super().__init__()
        n = self.n = As.shape[0]
        k, w = choose_split(As, structure)
        m = n - k
        self.k, self.w, self.m = k, w, m
        self.nb = max(w, min(MIN_BAND_BLOCK, k), 1)
        cb, info = lapack.dpbtrf(_lower_band(As, k, w), lower=1)
        if info > 0:
            raise SingularNormalMatrix(info - 1)
        check_pivots(cb[0])
        self.cb = cb
        if m:
            B = As[:k, k:].toarray()
            C = As[k:, k:].toarray()
            Y, info = lapack.dpbtrs(cb, B, lower=1)
            S = C - B.T @ Y
            try:
                R = dense_cholesky(S)
            except SingularNormalMatrix as exc:
                raise SingularNormalMatrix(k + exc.column if exc.column is not None else None) from exc
            self.Y, self.R = Y, R
            self.W = la.solve_triangular(R, Y.T, lower=True, check_finite=False).T  # Y R^-T
            self.S_inv = la.cho_solve((R, True), np.eye(m), check_finite=False)
            self.cross = -Y @ self.S_inv  # N~^-1[:k, k:]
        self.info = {"bandwidth": w, "border": m, "block": self.nb}
        self.band = None  # (w + 1, k): band[d, j] = A^-1[j + d, j], filled by the first pass

    def solve(self, B):
        k = self.k
        y1, _ = lapack.dpbtrs(self.cb, B[:k], lower=1)
        if not self.m:
            return y1
        y2 = la.cho_solve((self.R, True), B[k:] - self.Y.T @ B[:k], check_finite=False)
        return np.vstack([y1 - self.Y @ y2, y2])

    def compute(self, rows, cols):
        """Entries asked for afterwards: from the kept band of the inverse (one pass fills it);
        before it exists, from solves when they lie in fewer than nb columns (each solve costs
        about what the pass spends on nb columns)."""
        few = self.band is None and len(np.unique(np.minimum(rows, cols))) < self.nb
        return self._run(rows, cols, in_pass=not few)[0]

    def compute_with_diag(self, rows, cols):
        return self._run(rows, cols, in_pass=True)

    def _run(self, rows, cols, in_pass: bool):
        k = self.k
        ok, out = _valid(rows, cols)
        hi, lo = np.maximum(rows, cols), np.minimum(rows, cols)
        photo = ok & (hi < k)
        border = ok & (lo >= k)
        mixed = ok & (lo < k) & (hi >= k)
        if self.m:
            out[border] = self.S_inv[hi[border] - k, lo[border] - k]
            out[mixed] = self.cross[lo[mixed], hi[mixed] - k]
        if in_pass and self.band is None:
            self.band = np.empty((self.w + 1, k))
            self._pass(self.band)
        if self.band is not None:
            near = photo & (hi - lo <= self.w)
            out[near] = self.band[hi[near] - lo[near], lo[near]]
        else:
            near = np.zeros_like(photo)
        far = photo & ~near
        diag = self.band[0].copy() if in_pass else None
        if np.any(far):
            out[far] = self._solved_banded(hi[far], lo[far])
        if self.m:  # the rank-m correction Y S^-1 Y' of the photo part
            out[photo] += np.einsum("ij,ij->i", self.W[hi[photo]], self.W[lo[photo]])
            if in_pass:
                diag = np.concatenate([diag + np.einsum("ij,ij->i", self.W, self.W), np.diag(self.S_inv)])
        return out, diag

    def _pass(self, band):
        """The backward block recurrence over A; writes the band of A^-1 within w of the diagonal
        into ``band`` (lower band storage, band[d, j] = A^-1[j + d, j]) as it passes."""
        k, nb, cb, w = self.k, self.nb, self.cb, self.w
        n_blocks = -(-k // nb)
        Z_next = None
        for t in range(n_blocks - 1, -1, -1):
            s0, e0 = t * nb, min((t + 1) * nb, k)
            Ltt = _from_band(cb, s0, e0, s0, e0)
            Linv, info = lapack.dtrtri(Ltt, lower=1)
            if Z_next is None:
                Z_tt = Linv.T @ Linv
                Z_down = None
            else:
                e1 = min(e0 + nb, k)
                M = _from_band(cb, e0, e1, s0, e0)
                Z_down = -(Z_next @ M) @ Linv  # Z_{t+1,t}
                Z_tt = Linv.T @ (Linv - M.T @ Z_down)
            Z_tt = 0.5 * (Z_tt + Z_tt.T)
            # the band of the block's columns: rows j..j+w, in Z_tt or (below the block) Z_down
            d, c = np.meshgrid(np.arange(w + 1), np.arange(e0 - s0), indexing="ij")
            r = c + d  # row offset from s0
            in_tt = r < e0 - s0
            values = np.zeros(d.shape)
            values[in_tt] = Z_tt[r[in_tt], c[in_tt]]
            if Z_down is not None:
                below = ~in_tt & (r < e0 - s0 + Z_down.shape[0])
                values[below] = Z_down[r[below] - (e0 - s0), c[below]]
            band[:, s0:e0] = values
            Z_next = Z_tt

    def _solved_banded(self, rows, cols):
        """Entries of A^-1 (the banded part alone) from its columns."""
        want, where = np.unique(cols, return_inverse=True)
        out = np.empty(len(rows))
        chunk = max(1, SOLVE_CHUNK // max(self.k, 1))
        for a in range(0, len(want), chunk):
            E = np.zeros((self.k, min(chunk, len(want) - a)))
            E[want[a: a + chunk], np.arange(E.shape[1])] = 1.0
            X, _ = lapack.dpbtrs(self.cb, E, lower=1)
            sel = (where >= a) & (where < a + chunk)
            out[sel] = X[rows[sel], where[sel] - a]
        return out

    def diag(self):  # pragma: no cover - compute_with_diag is used
        return self._run(np.zeros(0, dtype=int), np.zeros(0, dtype=int), in_pass=True)[1]


# --------------------------------------------------------------------------------- supernodal


@dataclass
class _Supernodes:
    """Block-level symbolic factorisation in a fill-reducing order, with supernodes.

    order: position -> column of N~ (blocks kept together). Supernode p owns the positions
    [start[p], start[p+1]); rows[p]: the sorted positions of its rows in L (its own columns first,
    then ``below``, the rows under it). targets[p]: for each later supernode q that owns some of
    ``below``: (q, s, e, pos, local) - below[s:e] are q's columns (``local`` = their offsets in q)
    and ``pos`` the places of below[s:] in rows[q] (all there: ``below`` is a clique).
    """

    order: np.ndarray
    start: np.ndarray
    rows: list
    targets: list
    offset: np.ndarray  # start of each supernode's (rows x columns) array in the flat storage
    info: dict = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.start) - 1

    def width(self, p: int) -> int:
        return int(self.start[p + 1] - self.start[p])

    def locate(self, pi: np.ndarray, pj: np.ndarray):
        """Flat storage index of the entries (pi, pj), pi >= pj (positions), and whether each lies in
        the stored pattern. Vectorised: the rows of every supernode, keyed ``p * n + row``, form one
        sorted array, searched once for all entries."""
        n = len(self.order)
        keys, first = self._row_keys
        sn = np.searchsorted(self.start, pj, side="right") - 1
        want = sn * np.int64(n) + pi
        pos = np.searchsorted(keys, want)
        found = keys[np.minimum(pos, len(keys) - 1)] == want
        local = np.where(found, pos - first[sn], 0)
        widths = np.diff(self.start)
        flat = self.offset[sn] + local * widths[sn] + (pj - self.start[sn])
        return flat, found

    @functools.cached_property
    def _row_keys(self):
        """(sorted keys ``p * n + row`` of the rows of every supernode p, where each p's rows start)."""
        n = np.int64(len(self.order))
        lengths = np.array([len(r) for r in self.rows], dtype=np.int64)
        first = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        keys = np.repeat(np.arange(self.count, dtype=np.int64) * n, lengths) + np.concatenate(self.rows)
        return keys, first


def _block_pattern(A: sp.csr_matrix, blocks: Blocks) -> sp.csr_matrix:
    """(nb, nb) pattern of the blocks of A that hold a nonzero (the columns of each row are first
    collapsed to their blocks, so the matrix built is about a block's width smaller than A)."""
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    bc = blocks.of_column[A.indices]
    new = np.ones(len(bc), dtype=bool)
    new[1:] = (bc[1:] != bc[:-1]) | (rows[1:] != rows[:-1])  # sorted indices: a run per block
    br, bc = blocks.of_column[rows[new]], bc[new]
    nb = len(blocks.starts)
    G = sp.csr_matrix((np.ones(len(br)), (br, bc)), shape=(nb, nb))
    G.sum_duplicates()
    return G


def _block_sequence(graph: sp.csr_matrix, blocks: Blocks) -> np.ndarray:
    """Fill-reducing order of the blocks: nested dissection of the block graph (CHOLMOD's NESDIS:
    METIS separators, constrained minimum degree within them) when scikit-sparse is installed, else
    SuperLU's multiple minimum degree (solvers.direct.block_order). On the benchmark blocks
    (scripts/bench/bench_selected_inverse.py) nested dissection stores 5 % (5,000 photos) and 17 %
    (20,000 photos) less than minimum degree and the selected inversion takes 10 % and 30 % less
    time: its top separator is smaller (1,800 columns instead of 2,800 at 20,000 photos)."""
    if BLOCK_ORDERING == "nesdis" and graph.shape[0] > 1 and cholmod_available():
        cholmod = cholmod_module()
        nb = graph.shape[0]
        pattern = sp.csc_matrix((np.ones(graph.nnz), graph.indices, graph.indptr), shape=(nb, nb))
        pattern = (pattern + pattern.T + sp.identity(nb, format="csc") * (nb + 1.0)).tocsc()
        return np.asarray(cholmod.analyze(pattern, ordering_method="nesdis").P(), dtype=int)
    order = block_order(graph, blocks)
    of = blocks.of_column[order]
    return of[np.r_[True, of[1:] != of[:-1]]]


def _elimination_tree(graph: sp.csr_matrix, seq: np.ndarray):
    """Rows of L below each block column (block positions, sorted) and the elimination tree, for the
    blocks in the order ``seq``: struct(j) = (neighbours after j) + (struct(c) minus j for each
    child c of j); parent(j) = the first of struct(j)."""
    nb = len(seq)
    inv = np.empty(nb, dtype=int)
    inv[seq] = np.arange(nb)
    G = graph.tocoo()
    r, c = inv[G.row], inv[G.col]
    low = r > c
    later = sp.csr_matrix((np.ones(int(low.sum())), (c[low], r[low])), shape=(nb, nb))
    later.sum_duplicates()
    struct: list[np.ndarray] = [np.zeros(0, dtype=int)] * nb
    parent = np.full(nb, -1)
    children: list[list[int]] = [[] for _ in range(nb)]
    for j in range(nb):
        parts = [later.indices[later.indptr[j]: later.indptr[j + 1]]] + [struct[ch][1:] for ch in children[j]]
        sj = np.unique(np.concatenate(parts))
        struct[j] = sj
        if len(sj):
            parent[j] = sj[0]
            children[sj[0]].append(j)
    return struct, parent, children


def _postorder(parent: np.ndarray, children: list[list[int]]) -> np.ndarray:
    post = []
    for root in np.flatnonzero(parent < 0):
        stack = [(int(root), 0)]
        while stack:
            node, i = stack.pop()
            if i < len(children[node]):
                stack.append((node, i + 1))
                stack.append((children[node][i], 0))
            else:
                post.append(node)
    return np.array(post, dtype=int)


def _supernode_partition(struct: list[np.ndarray], parent: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """First block of each supernode (and the block count last): a chain j -> j + 1 of the tree is
    merged when the columns share their rows, or when the merged supernode has at most
    RELAXED_SUPERNODE columns of which at most RELAXED_ZEROS of the stored entries are zeros."""
    nb = len(struct)
    below = np.array([int(sizes[st].sum()) for st in struct])
    first = [0]
    width, zeros = int(sizes[0]), 0  # of the current supernode
    for j in range(1, nb):
        merge, added = False, 0
        if parent[j - 1] == j:
            added = int(sizes[j] + below[j] - below[j - 1])  # rows the current columns gain (>= 0)
            merged = width + int(sizes[j])
            merge = added == 0 or (
                merged <= RELAXED_SUPERNODE and zeros + width * added <= RELAXED_ZEROS * merged * (merged + below[j])
            )
        if merge:
            zeros += width * added
            width += int(sizes[j])
        else:
            first.append(j)
            width, zeros = int(sizes[j]), 0
    return np.array(first + [nb], dtype=int)


def _symbolic(As: sp.csr_matrix, structure: Structure) -> _Supernodes:
    """Order, block-level symbolic factorisation and supernodes of the scaled N (see SupernodalInverse)."""
    n = As.shape[0]
    blocks = partition(structure, n)
    graph = _block_pattern(As, blocks)
    seq = _block_sequence(graph, blocks)
    struct, parent, children = _elimination_tree(graph, seq)
    # postorder (an equivalent order with the same fill) so that chains parent(j) = j + 1 are long
    post = _postorder(parent, children)
    relabel = np.empty(len(seq), dtype=int)
    relabel[post] = np.arange(len(seq))
    struct = [np.sort(relabel[struct[b]]) for b in post]
    parent = np.where(parent[post] >= 0, relabel[np.maximum(parent[post], 0)], -1)
    seq = seq[post]
    sizes = blocks.sizes[seq]
    bstart = np.concatenate([[0], np.cumsum(sizes)])
    order = np.concatenate([np.arange(blocks.starts[b], blocks.starts[b] + blocks.sizes[b]) for b in seq])
    sn_first = _supernode_partition(struct, parent, sizes)
    sn_of_block = np.repeat(np.arange(len(sn_first) - 1), np.diff(sn_first))
    start = bstart[sn_first]
    count = len(start) - 1
    rows = []
    for p in range(count):
        bb = struct[sn_first[p + 1] - 1]  # rows below a supernode: those below its last block
        below = np.concatenate([np.arange(bstart[b], bstart[b + 1]) for b in bb]) if len(bb) else np.zeros(0, int)
        rows.append(np.concatenate([np.arange(start[p], start[p + 1]), below]))
    targets = []
    for p in range(count):
        bb = struct[sn_first[p + 1] - 1]
        below = rows[p][start[p + 1] - start[p]:]
        tp = []
        if len(bb):
            sn = sn_of_block[bb]
            cut = np.flatnonzero(np.r_[True, sn[1:] != sn[:-1], True])
            scalar_cut = np.concatenate([[0], np.cumsum(sizes[bb])])
            for a, b in zip(cut[:-1], cut[1:]):
                q = int(sn[a])
                s, e = int(scalar_cut[a]), int(scalar_cut[b])
                pos = np.searchsorted(rows[q], below[s:])
                if np.any(rows[q][np.minimum(pos, len(rows[q]) - 1)] != below[s:]):  # pragma: no cover
                    raise RuntimeError("rows below a supernode are not a clique of the filled graph")
                tp.append((q, s, e, pos, below[s:e] - start[q]))
        targets.append(tp)
    stored = np.array([len(rw) * (start[p + 1] - start[p]) for p, rw in enumerate(rows)], dtype=np.int64)
    offset = np.concatenate([[0], np.cumsum(stored)])
    info = {"blocks": len(seq), "supernodes": count, "stored": int(offset[-1]),
            "largest_supernode": int(np.diff(start).max()), "largest_front": int(max(len(rw) for rw in rows))}
    return _Supernodes(order, start, rows, targets, offset, info)


class SupernodalInverse(_Engine):
    """Selected inversion of a block's N on the supernodes of its sparse Cholesky factor.

    Order: SuperLU's minimum degree on the block graph (photo and camera blocks kept whole; camera
    blocks, coupled to many photos, come late), postordered along its elimination tree. Symbolic
    factorisation on the block graph: the rows of L below block column j are its neighbours after
    it and the rows of its children below j. Consecutive blocks j, j + 1 with parent(j) = j + 1
    form one supernode when they share their rows, or when little is stored in vain
    (RELAXED_SUPERNODE, RELAXED_ZEROS); a supernode is one dense (rows x columns) array: the
    columns of L, and then of Z = N~^-1, on its rows.

    Numeric factorisation, ``numeric="numpy"``: right-looking supernodal Cholesky - per supernode
    ``L11 = chol(F11)`` (LAPACK potrf, with the solvers' pivot test), ``L21 = F21 L11^-T``, and
    ``L21 L21'`` subtracted from the supernodes that own its rows. ``numeric="cholmod"``: CHOLMOD
    factorises N~ in the same order (natural ordering of the permuted matrix) and its L is read in.

    Selected inverse: the Takahashi equations of the module docstring per supernode, backwards:
    ``Z_BP = -Z_BB L21 L11^-1``, ``Z_PP = L11^-T (L11^-1 - L21' Z_BP)``, where ``Z_BB`` (B the rows
    below P, a clique of the filled graph) is gathered from the later supernodes that own them.
    Work and memory are those of the factorisation (``info["stored"]`` entries). Every block of
    N^-1 between two photos that share a point (or a camera) lies in the pattern; other entries are
    solved for with the factor.
    """

    name = "sparse"

    def __init__(self, As: sp.csr_matrix, structure: Structure, numeric: str = "numpy", keep_factor: bool = True,
                 matrix=None):
        super().__init__()
        self.n = As.shape[0]
        self.name = "cholmod" if numeric == "cholmod" else "sparse"
        self._numeric = numeric
        sym = self.sym = _symbolic(As, structure)
        L = self._factor(As)
        if keep_factor:
            self._L, self.Z = L, self._takahashi(L, np.empty_like(L))
        else:  # Z takes L's place; solves factorise again (matrix() gives N~ back)
            self._L, self.Z = None, self._takahashi(L, L)
            self._matrix = matrix if matrix is not None else (lambda: As)
        self.info = dict(sym.info, factor_kept=keep_factor)

    def _factor(self, As: sp.csr_matrix) -> np.ndarray:
        return self._cholmod_factor(As) if self._numeric == "cholmod" else self._numpy_factor(As)

    @property
    def L(self) -> np.ndarray:
        """The supernodal factor (flat storage); factorised again on first use when Z took its place."""
        if self._L is None:
            self._L = self._factor(self._matrix())
        return self._L

    def _view(self, flat: np.ndarray, p: int) -> np.ndarray:
        sym = self.sym
        return flat[sym.offset[p]: sym.offset[p + 1]].reshape(len(sym.rows[p]), sym.width(p))

    def _scatter(self, M: sp.csr_matrix, columns: np.ndarray, row_position: np.ndarray | None) -> np.ndarray:
        """Flat supernodal storage holding the entries of M in the stored pattern (rows at or below the
        supernode's first column). Supernode p takes the columns ``columns[start[p]:start[p+1]]`` of
        the symmetric or lower-triangular CSC/CSR-transposed M (given by indptr/indices/data), whose
        row indices are positions after ``row_position`` (None: they are positions already)."""
        sym = self.sym
        F = np.zeros(int(sym.offset[-1]))
        where = np.full(self.n, -1)
        for p in range(sym.count):
            a, b = sym.start[p], sym.start[p + 1]
            cols = columns[a:b]
            first, count = M.indptr[cols], M.indptr[cols + 1] - M.indptr[cols]
            idx = np.repeat(first - np.concatenate([[0], np.cumsum(count)[:-1]]), count) + np.arange(count.sum())
            r = M.indices[idx] if row_position is None else row_position[M.indices[idx]]
            c = np.repeat(np.arange(b - a), count)
            keep = r >= a
            r, c, v = r[keep], c[keep], M.data[idx][keep]
            rows = sym.rows[p]
            where[rows] = np.arange(len(rows))
            local = where[r]
            inside = local >= 0
            if not np.all(inside):  # CHOLMOD's relaxed supernodes may store zeros elsewhere
                if np.any(v[~inside] != 0):  # pragma: no cover - the symbolic pattern holds L
                    raise RuntimeError("entry of the factor outside the symbolic pattern")
                local, c, v = local[inside], c[inside], v[inside]
            self._view(F, p)[local, c] = v
            where[rows] = -1
        return F

    def _numpy_factor(self, As: sp.csr_matrix) -> np.ndarray:
        sym = self.sym
        L = self._scatter(As, sym.order, self._position())  # As symmetric: its rows are its columns
        for p in range(sym.count):
            F = self._view(L, p)
            w = sym.width(p)
            c, info = lapack.dpotrf(F[:w], lower=1, clean=1, overwrite_a=0)
            if info > 0:
                raise SingularNormalMatrix(int(sym.order[sym.start[p] + info - 1]))
            check_pivots(np.diag(c), sym.order[sym.start[p]: sym.start[p + 1]])
            F[:w] = c
            if len(F) > w:
                L21 = blas.dtrsm(1.0, c, F[w:], side=1, lower=1, trans_a=1)  # F21 L11^-T
                F[w:] = L21
                # the update's lower triangle (the diagonal blocks of later supernodes are read
                # only there by potrf): syrk, half the work of L21 L21'
                U = blas.dsyrk(1.0, L21, lower=1)
                for q, s, e, pos, local in sym.targets[p]:
                    G = self._view(L, q)
                    G[np.ix_(pos, local)] -= U[s:, s:e]
        return L

    def _cholmod_factor(self, As: sp.csr_matrix) -> np.ndarray:
        cholmod = cholmod_module()
        order = self.sym.order
        inv = self._position()
        C = As.tocoo()
        r, c = inv[C.row], inv[C.col]
        low = r >= c  # CHOLMOD reads the lower triangle
        Ap = sp.csc_matrix((C.data[low], (r[low], c[low])), shape=As.shape)
        try:  # CHOLMOD reports a failed factorisation either at once or when L is read
            factor = cholmod.cholesky(Ap, ordering_method="natural")
            Lc = sp.csc_matrix(factor.L())
        except cholmod.CholmodNotPositiveDefiniteError as exc:
            col = getattr(exc, "column", None)
            raise SingularNormalMatrix(int(order[col]) if col is not None and 0 <= col < self.n else None) from exc
        if not np.array_equal(factor.P(), np.arange(self.n)):  # pragma: no cover - natural means natural
            raise RuntimeError("CHOLMOD reordered a matrix given in natural order")
        Lc.sort_indices()
        check_pivots(Lc.diagonal(), order)
        return self._scatter(Lc, np.arange(self.n), None)

    def _takahashi(self, L: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """Z on the stored pattern, supernode by supernode backwards (class doc), into ``Z`` (which
        may be ``L`` itself: a supernode's columns of L are needed only for its own columns of Z).
        ``Y = Z_BB L21`` (symm: reads Z_BB's lower triangle), ``Z_BP = -Y L11^-1`` and
        ``Z_PP = L11^-T (I + L21' Y) L11^-1`` (triangular solves; the last supernode, the root of
        the tree, by LAPACK potri)."""
        sym = self.sym
        for p in range(sym.count - 1, -1, -1):
            F = self._view(L, p)
            w = sym.width(p)
            L11 = F[:w].copy()
            Zp = self._view(Z, p)
            b = len(F) - w
            if b:
                L21 = F[w:]
                Zbb = np.empty((b, b))
                for q, s, e, pos, local in sym.targets[p]:
                    Zbb[s:, s:e] = self._view(Z, q)[np.ix_(pos, local)]
                Y = blas.dsymm(1.0, Zbb, L21, side=0, lower=1)  # Z_BB L21, Z_BB symmetric (lower)
                S = L21.T @ Y
                S[np.diag_indices(w)] += 1.0
                Zp[w:] = blas.dtrsm(-1.0, L11, Y, side=1, lower=1)  # -Y L11^-1
                Zpp = blas.dtrsm(1.0, L11, blas.dtrsm(1.0, L11, S, side=1, lower=1), side=0, lower=1, trans_a=1)
                Zp[:w] = 0.5 * (Zpp + Zpp.T)
            else:
                Zpp, _ = lapack.dpotri(L11, lower=1)
                Zp[:w] = np.tril(Zpp) + np.tril(Zpp, -1).T
        return Z

    @functools.cached_property
    def _position_of(self) -> np.ndarray:
        inv = np.empty(self.n, dtype=int)
        inv[self.sym.order] = np.arange(self.n)
        return inv

    def _position(self) -> np.ndarray:
        """Column of N~ -> its position in the order."""
        return self._position_of

    def _positions(self, rows, cols):
        inv = self._position()
        pr, pc = inv[rows], inv[cols]
        return np.maximum(pr, pc), np.minimum(pr, pc)

    looks_up = True

    def lookup(self, rows, cols):
        ok = (rows >= 0) & (cols >= 0)
        pi, pj = self._positions(rows, cols)  # -1 reads some position: masked by ok
        flat, found = self.sym.locate(pi, pj)
        found &= ok
        vals = self.Z[np.where(found, flat, 0)]
        vals[~found] = 0.0
        return vals, found | ~ok

    def compute(self, rows, cols):
        vals, found = self.lookup(rows, cols)
        if not np.all(found):
            vals[~found] = self.solved_entries(rows[~found], cols[~found])
        return vals

    def diag(self):
        sym = self.sym
        widths = np.diff(sym.start)
        sn = np.repeat(np.arange(sym.count), widths)
        local = np.arange(self.n) - sym.start[sn]
        d_pos = self.Z[sym.offset[sn] + local * widths[sn] + local]
        d = np.empty(self.n)
        d[sym.order] = d_pos
        return d

    def solve(self, B):
        sym = self.sym
        y = B[sym.order].copy()
        for p in range(sym.count):
            F = self._view(self.L, p)
            w = sym.width(p)
            a, b = sym.start[p], sym.start[p + 1]
            y[a:b] = la.solve_triangular(F[:w], y[a:b], lower=True, check_finite=False)
            if len(F) > w:
                y[sym.rows[p][w:]] -= F[w:] @ y[a:b]
        for p in range(sym.count - 1, -1, -1):
            F = self._view(self.L, p)
            w = sym.width(p)
            a, b = sym.start[p], sym.start[p + 1]
            rhs = y[a:b]
            if len(F) > w:
                rhs = rhs - F[w:].T @ y[sym.rows[p][w:]]
            y[a:b] = la.solve_triangular(F[:w], rhs, lower=True, trans="T", check_finite=False)
        X = np.empty_like(y)
        X[sym.order] = y
        return X
