"""The answer of the selected inversion: :class:`SelectedInverse`, the requested blocks of N^-1 in
the units of N's unknowns, with the entries outside them and the solves that the route's engine
(:mod:`.engine`) provides on the scaled ``N~``.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

ENTRY_CHUNK = 1 << 20  # entries looked up at once by SelectedInverse.entries (a few 8 MB index arrays)


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
        self._flat = FlatBlocks(blocks)
        nb = len(blocks)
        keys = np.concatenate([np.repeat(np.arange(nb), 2).reshape(nb, 2),
                               np.asarray(pairs, dtype=int).reshape(-1, 2)])
        rows, cols, start = self._flat.requests(keys)
        values, self._diag = engine.compute_with_diag(rows, cols)
        self._values = self._unscaled(values, rows, cols)
        self._start = dict(zip(map(tuple, keys.tolist()), start.tolist()))
        self._extra: dict[tuple[int, int], np.ndarray] = {}
        self.info = dict(engine.info)

    def release(self, rebuild: Callable[[], "SelectedInverse"]) -> None:
        """Drop the engine (the computed pattern of the inverse, the factor: the bulk of the memory,
        84 MB at 5,000 photos). The requested blocks (``block``, ``stack``), the pairs named at the
        start and ``diag`` stay; what needs the engine later (other entries, solves) makes it again
        with ``rebuild`` (a SelectedInverse of the same N), at the cost of a new inversion."""
        self._engine = _Rebuilt(rebuild)

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

    def block_entries(self, ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
        """(u, wa, wb) the blocks N^-1[ca[i], cb[i]] between the column sets ca (u, wa) and cb
        (u, wb): ``entries(ca[:, :, None], cb[:, None, :])``, the same numbers, but one lookup a
        block where the route's engine can (``block_lookup``: sets whose columns lie together in its
        order, e.g. a photo's six, in the computed pattern); entries for the others."""
        ca, cb = np.asarray(ca, dtype=int), np.asarray(cb, dtype=int)
        lookup = getattr(self._engine, "block_lookup", None)
        if lookup is None or not len(ca) or ca.shape[1] == 0 or cb.shape[1] == 0:
            return self.entries(ca[:, :, None], cb[:, None, :])
        self._check(ca, cb)
        values, ok = lookup(ca, cb)
        s = np.append(self._s, 0.0)
        out = np.empty(values.shape)
        out[ok] = values[ok] * s[ca[ok]][:, :, None] * s[cb[ok]][:, None, :]  # as _unscaled
        if not ok.all():
            out[~ok] = self.entries(ca[~ok][:, :, None], cb[~ok][:, None, :])
        return out

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

    def whole(self) -> np.ndarray:
        """The whole N^-1 (n, n), symmetric: the route's own where it holds it (dense), else n
        solves with the factor."""
        Z = self._engine.whole()
        if Z is None:
            Q = self.solve(np.eye(self.n))
            return 0.5 * (Q + Q.T)
        return Z * np.outer(self._s, self._s)  # s_i s_j: symmetric to the last bit, as Z

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


class FlatBlocks:
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


class _Rebuilt:
    """A released engine (SelectedInverse.release): made again on the first use."""

    def __init__(self, rebuild: Callable[[], SelectedInverse]):
        self._rebuild = rebuild
        self._engine = None

    @property
    def rebuilt(self) -> bool:
        return self._engine is not None

    def __getattr__(self, name: str):
        if name.startswith("_"):  # only the engine's own attributes (not copy's or pickle's probes)
            raise AttributeError(name)
        if self._engine is None:
            self._engine = self._rebuild()._engine
        return getattr(self._engine, name)
