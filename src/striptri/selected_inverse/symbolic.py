"""The symbolic analysis of the ``sparse`` and ``cholmod`` routes: the pattern they factorise and
invert on.

One node per photo or camera block: a fill-reducing order of the block graph, postordered along
its elimination tree; the rows of L below each block column (block-level symbolic factorisation);
chains of blocks merged into supernodes. -> :class:`Supernodes`, used by
:class:`striptri.selected_inverse.supernodal.SupernodalInverse`. No numbers of N are factorised here.
"""

from __future__ import annotations

import functools
import heapq
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..solvers import Structure, beside
from ..solvers.base import pattern_matrix
from ..solvers.blocks import Blocks, partition, ranges
from ..solvers.direct import block_order
from ..solvers.sparse_cholesky import cholmod_available, cholmod_module

# the Python around one supernode's kernels, in multiply-adds (Supernodes.work): about 30
# microseconds at a few GFlop/s, what a supernode of a few photos' columns costs in all
SUPERNODE_OVERHEAD = 1e5
PATTERN_ROWS = 4096  # rows of N collapsed to blocks at a time (_block_pattern)
PAUSE_EVERY = 32  # blocks or supernodes between two pauses of an analysis made ahead (about 1 ms)


def _no_pause() -> None:
    pass


@dataclass
class Supernodes:
    """Block-level symbolic factorisation in a fill-reducing order, with supernodes.

    order: position -> column of N~ (blocks kept together). Supernode p owns the positions
    [start[p], start[p+1]); rows[p]: the sorted positions of its rows in L (its own columns first,
    then ``below``, the rows under it). targets[p]: for each later supernode q that owns some of
    ``below``: (q, s, e, pos, runs) - below[s:e] are q's columns and ``pos`` the places of below[s:]
    in rows[q] (all there: ``below`` is a clique); ``runs``: those columns as runs of consecutive
    columns of q, (a, b, c) for below[s + a: s + b] = q's columns c .. c + b - a - 1. A run moves
    with one slice of q's columns and one list of its rows (``pos[a:]``, the lower triangle and
    below): three times as fast as a gather by row and column lists (np.ix_) on the blocks of
    bench_scale.
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
    def parent(self) -> np.ndarray:
        """(count,) the supernode tree: each supernode's parent, the first later supernode among its
        rows (-1 for a root). Supernodes are numbered in postorder, so the subtree of p is the run
        of supernodes ``first_descendant[p] .. p``."""
        return np.array([tp[0][0] if tp else -1 for tp in self.targets], dtype=int)

    @functools.cached_property
    def first_descendant(self) -> np.ndarray:
        first = np.arange(self.count)
        for p, q in enumerate(self.parent):  # children come before their parent
            if q >= 0:
                first[q] = min(first[q], first[p])
        return first

    @functools.cached_property
    def work(self) -> np.ndarray:
        """(count,) each supernode's share of the factorisation and of the inversion, as the
        multiply-adds of its dense kernels (w^3 + b w^2 + b^2 w for w columns and b rows below) and
        SUPERNODE_OVERHEAD for the Python around them."""
        w = np.diff(self.start).astype(float)
        b = np.array([len(r) for r in self.rows], dtype=float) - w
        return w**3 + b * w**2 + b**2 * w + SUPERNODE_OVERHEAD

    def split(self, parts: int) -> tuple[np.ndarray, list[np.ndarray]]:
        """The supernodes cut into ``top`` (ancestors, done alone) and independent subtrees (each the
        sorted supernodes of a run ``first_descendant[r] .. r``; no supernode of one is an ancestor
        of another's) for ``parts`` threads: the largest subtree is replaced by its root (to ``top``)
        and its children while it holds more than its share (1/parts) of the subtrees' work.
        Subtrees are given largest first. One part (or none): everything in ``top``."""
        everything = np.arange(self.count)
        if parts <= 1 or self.count <= 1:
            return everything, []
        cumulative = np.concatenate([[0.0], np.cumsum(self.work)])
        first = self.first_descendant

        def subtree_work(r):
            return cumulative[r + 1] - cumulative[first[r]]

        children = [[] for _ in range(self.count)]
        for p, q in enumerate(self.parent):
            if q >= 0:
                children[q].append(p)
        heap = [(-subtree_work(r), r) for r in np.flatnonzero(self.parent < 0)]
        heapq.heapify(heap)
        top = []
        while heap and -heap[0][0] > sum(-h[0] for h in heap) / parts:
            _, r = heapq.heappop(heap)
            top.append(r)
            for c in children[r]:
                heapq.heappush(heap, (-subtree_work(c), c))
        subtrees = [np.arange(first[r], r + 1) for _, r in sorted(heap)]
        return np.sort(np.array(top, dtype=int)), subtrees

    @functools.cached_property
    def _row_keys(self):
        """(sorted keys ``p * n + row`` of the rows of every supernode p, where each p's rows start)."""
        n = np.int64(len(self.order))
        lengths = np.array([len(r) for r in self.rows], dtype=np.int64)
        first = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        keys = np.repeat(np.arange(self.count, dtype=np.int64) * n, lengths) + np.concatenate(self.rows)
        return keys, first


def _block_pattern(A: sp.csr_matrix, blocks: Blocks, pause=_no_pause) -> sp.csr_matrix:
    """(nb, nb) pattern of the blocks of A that hold a nonzero (ones), made PATTERN_ROWS rows of A
    at a time: each row's columns collapsed to their blocks, then the block pairs of the stretch
    without repeats. Its memory is a few MB beside A (it may run beside a factorisation)."""
    nb = len(blocks.starts)
    of_column = blocks.of_column.astype(np.int64)
    keys = []
    for r0 in range(0, A.shape[0], PATTERN_ROWS):
        pause()
        r1 = min(r0 + PATTERN_ROWS, A.shape[0])
        a, b = A.indptr[r0], A.indptr[r1]
        k = np.repeat(of_column[r0:r1] * nb, np.diff(A.indptr[r0: r1 + 1]))
        k += of_column[A.indices[a:b]]
        run = np.ones(len(k), dtype=bool)  # a row's columns are sorted: its blocks come in runs
        np.not_equal(k[1:], k[:-1], out=run[1:])
        keys.append(np.unique(k[run]))
    key = np.unique(np.concatenate(keys)) if keys else np.zeros(0, dtype=np.int64)
    br, bc = np.divmod(key, nb)
    counts = np.bincount(br, minlength=nb)
    return sp.csr_matrix((np.ones(len(key)), bc, np.concatenate([[0], np.cumsum(counts)])), shape=(nb, nb))


def _block_sequence(graph: sp.csr_matrix, blocks: Blocks, ordering: str) -> np.ndarray:
    """Fill-reducing order of the blocks: with ``ordering="nesdis"``, nested dissection of the block
    graph (CHOLMOD's NESDIS: METIS separators, constrained minimum degree within them) when
    scikit-sparse is installed; else (or with ``"mmd"``) SuperLU's multiple minimum degree
    (solvers.direct.block_order). On the benchmark blocks (scripts/bench/bench_selected_inverse.py)
    nested dissection stores 5 % (5,000 photos) and 17 % (20,000 photos) less than minimum degree
    and the selected inversion takes 10 % and 30 % less time: its top separator is smaller (1,800
    columns instead of 2,800 at 20,000 photos)."""
    if ordering == "nesdis" and graph.shape[0] > 1 and cholmod_available():
        cholmod = cholmod_module()
        nb = graph.shape[0]
        pattern = sp.csc_matrix((np.ones(graph.nnz), graph.indices, graph.indptr), shape=(nb, nb))
        pattern = (pattern + pattern.T + sp.identity(nb, format="csc") * (nb + 1.0)).tocsc()
        return np.asarray(cholmod.analyze(pattern, ordering_method="nesdis").P(), dtype=int)
    order = block_order(graph, blocks)
    of = blocks.of_column[order]
    return of[np.r_[True, of[1:] != of[:-1]]]


def _elimination_tree(graph: sp.csr_matrix, seq: np.ndarray, pause=_no_pause):
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
        if j % PAUSE_EVERY == 0:
            pause()
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


def _supernode_partition(struct: list[np.ndarray], parent: np.ndarray, sizes: np.ndarray, relaxed_columns: int,
                         relaxed_zeros: float, pause=_no_pause) -> np.ndarray:
    """First block of each supernode (and the block count last): a chain j -> j + 1 of the tree is
    merged when the columns share their rows, or when the merged supernode has at most
    ``relaxed_columns`` columns of which at most the fraction ``relaxed_zeros`` of the stored
    entries are zeros."""
    nb = len(struct)
    below = np.array([int(sizes[st].sum()) for st in struct])
    first = [0]
    width, zeros = int(sizes[0]), 0  # of the current supernode
    for j in range(1, nb):
        if j % PAUSE_EVERY == 0:
            pause()
        merge, added = False, 0
        if parent[j - 1] == j:
            added = int(sizes[j] + below[j] - below[j - 1])  # rows the current columns gain (>= 0)
            merged = width + int(sizes[j])
            merge = added == 0 or (
                merged <= relaxed_columns and zeros + width * added <= relaxed_zeros * merged * (merged + below[j])
            )
        if merge:
            zeros += width * added
            width += int(sizes[j])
        else:
            first.append(j)
            width, zeros = int(sizes[j]), 0
    return np.array(first + [nb], dtype=int)


def _runs(local: np.ndarray) -> tuple:
    """Runs of consecutive entries of the sorted column offsets ``local``: (a, b, local[a]) for each
    stretch local[a:b] that counts up by one."""
    if local[-1] - local[0] + 1 == len(local):  # most often one run (and the test is cheap)
        return ((0, len(local), int(local[0])),)
    cut = np.flatnonzero(np.diff(local) != 1) + 1
    firsts, ends = np.concatenate(([0], cut)), np.concatenate((cut, [len(local)]))
    return tuple((int(a), int(b), int(local[a])) for a, b in zip(firsts, ends))


def symbolic(As: sp.csr_matrix, structure: Structure, ordering: str, relaxed_columns: int,
             relaxed_zeros: float) -> Supernodes:
    """Order, block-level symbolic factorisation and supernodes of the scaled N (see
    SupernodalInverse). ordering: "nesdis" or "mmd" (_block_sequence); relaxed_columns,
    relaxed_zeros: how far chains of blocks are merged into supernodes (_supernode_partition).
    The analysis of the same pattern started by :func:`symbolic_ahead` is taken when there is one."""
    params = (ordering, relaxed_columns, relaxed_zeros)
    found = _take_ahead(As, structure, params)
    return found if found is not None else _symbolic(As, structure, *params)


def symbolic_ahead(N: sp.csr_matrix, structure: Structure, ordering: str, relaxed_columns: int,
                   relaxed_zeros: float, route=lambda N, structure: True) -> None:
    """Start the analysis of N's pattern (canonical CSR) on the other core, in the windows of the
    factorisations that run without the GIL (solvers.beside), for the :func:`symbolic` call that
    will come with a matrix of the same pattern arrays (the adjustments' N share them). One
    analysis is kept ahead at a time; asked again for the same pattern, nothing happens.
    ``route(N, structure)``: whether the analysis will be wanted (checked on that core first)."""
    global _ahead
    params = (ordering, relaxed_columns, relaxed_zeros)
    if _ahead is not None and _ahead.matches(N, structure, params):
        return
    _drop_ahead()
    if not N.has_canonical_format:
        return
    _ahead = _Ahead(_Held.of(N.indptr), _Held.of(N.indices), N.shape, np.asarray(structure.block_starts),
                    params, beside.BesideTask(_analysis_ahead, _pattern_of(N), structure, params, route))


def analysed_ahead(N: sp.csr_matrix) -> bool:
    """Whether an analysis of N's pattern arrays is under way or done (for any structure)."""
    ahead = _ahead
    return (ahead is not None and ahead.shape == N.shape and ahead.indptr.same(N.indptr)
            and ahead.indices.same(N.indices))


def _pattern_of(N: sp.csr_matrix) -> sp.csr_matrix:
    """N's pattern with its index arrays and without its numbers: what the analysis reads, and all
    that a task waiting for its windows holds (a strip's N, whose analysis is never asked for,
    would otherwise be held for the whole run)."""
    return pattern_matrix(N.indptr, N.indices, N.shape)


def _analysis_ahead(N, structure: Structure, params: tuple, route, pause) -> Supernodes | None:
    return _symbolic(N, structure, *params, pause=pause) if route(N, structure) else None


@dataclass(frozen=True)
class _Held:
    """Where an index array lies, and the array that owns that memory (held weakly)."""

    address: int
    shape: tuple
    strides: tuple
    dtype: np.dtype
    owner: weakref.ref

    @classmethod
    def of(cls, a: np.ndarray) -> "_Held":
        owner = a
        while isinstance(owner.base, np.ndarray):
            owner = owner.base
        alive = weakref.ref(owner) if owner.base is None else (lambda: None)  # foreign memory: never matched
        return cls(a.__array_interface__["data"][0], a.shape, a.strides, a.dtype, alive)

    def same(self, a: np.ndarray) -> bool:
        """a reads the same memory the same way, and the owner of that memory still lives (so it was
        not handed to another array: the same pattern; patterns are never changed in place)."""
        return (self.owner() is not None and a.__array_interface__["data"][0] == self.address
                and a.shape == self.shape and a.strides == self.strides and a.dtype == self.dtype)


@dataclass
class _Ahead:
    """An analysis under way beside the factorisations, and the pattern it is of."""

    indptr: _Held
    indices: _Held
    shape: tuple
    block_starts: np.ndarray
    params: tuple
    task: beside.BesideTask

    def matches(self, A: sp.csr_matrix, structure: Structure, params: tuple) -> bool:
        return (self.shape == A.shape and self.params == params and self.indptr.same(A.indptr)
                and self.indices.same(A.indices)
                and np.array_equal(self.block_starts, np.asarray(structure.block_starts)))


_ahead: _Ahead | None = None


def _take_ahead(As: sp.csr_matrix, structure: Structure, params: tuple) -> Supernodes | None:
    global _ahead
    ahead = _ahead
    if ahead is None:
        return None
    if not ahead.matches(As, structure, params):
        _drop_ahead()
        return None
    _ahead = None
    return ahead.task.result()  # None when it failed: then computed here


def _drop_ahead() -> None:
    global _ahead
    if _ahead is not None:
        _ahead.task.cancel()
        _ahead = None


def _symbolic(As: sp.csr_matrix, structure: Structure, ordering: str, relaxed_columns: int, relaxed_zeros: float,
              pause=_no_pause) -> Supernodes:
    """symbolic's work; ``pause()`` is called between short steps (solvers.beside)."""
    n = As.shape[0]
    blocks = partition(structure, n)
    graph = _block_pattern(As, blocks, pause)
    pause()
    seq = _block_sequence(graph, blocks, ordering)
    pause()
    struct, parent, children = _elimination_tree(graph, seq, pause)
    # postorder (an equivalent order with the same fill) so that chains parent(j) = j + 1 are long
    post = _postorder(parent, children)
    relabel = np.empty(len(seq), dtype=int)
    relabel[post] = np.arange(len(seq))
    struct = [np.sort(relabel[struct[b]]) for b in post]
    parent = np.where(parent[post] >= 0, relabel[np.maximum(parent[post], 0)], -1)
    seq = seq[post]
    sizes = blocks.sizes[seq]
    bstart = np.concatenate([[0], np.cumsum(sizes)])
    order = ranges(blocks.starts[seq], blocks.sizes[seq])
    pause()
    sn_first = _supernode_partition(struct, parent, sizes, relaxed_columns, relaxed_zeros, pause)
    sn_of_block = np.repeat(np.arange(len(sn_first) - 1), np.diff(sn_first))
    start = bstart[sn_first]
    count = len(start) - 1
    rows = []
    for p in range(count):
        if p % PAUSE_EVERY == 0:
            pause()
        bb = struct[sn_first[p + 1] - 1]  # rows below a supernode: those below its last block
        below = ranges(bstart[bb], sizes[bb])
        rows.append(np.concatenate([np.arange(start[p], start[p + 1]), below]))
    targets = []
    for p in range(count):
        if p % PAUSE_EVERY == 0:
            pause()
        bb = struct[sn_first[p + 1] - 1]
        below = rows[p][start[p + 1] - start[p]:]
        tp = []
        if len(bb):
            sn = sn_of_block[bb]
            cut = np.flatnonzero(np.concatenate(([True], sn[1:] != sn[:-1], [True])))
            scalar_cut = np.concatenate([[0], np.cumsum(sizes[bb])])
            for a, b in zip(cut[:-1], cut[1:]):
                q = int(sn[a])
                s, e = int(scalar_cut[a]), int(scalar_cut[b])
                pos = np.searchsorted(rows[q], below[s:])
                if np.any(rows[q][np.minimum(pos, len(rows[q]) - 1)] != below[s:]):  # pragma: no cover
                    raise RuntimeError("rows below a supernode are not a clique of the filled graph")
                tp.append((q, s, e, pos, _runs(below[s:e] - start[q])))
        targets.append(tp)
    stored = np.array([len(rw) * (start[p + 1] - start[p]) for p, rw in enumerate(rows)], dtype=np.int64)
    offset = np.concatenate([[0], np.cumsum(stored)])
    info = {"blocks": len(seq), "supernodes": count, "stored": int(offset[-1]),
            "largest_supernode": int(np.diff(start).max()), "largest_front": int(max(len(rw) for rw in rows))}
    return Supernodes(order, start, rows, targets, offset, info)
