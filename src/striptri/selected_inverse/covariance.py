"""The cofactor matrix of the unknowns, Qxx = N^-1 (Schmid 53), without forming it.

Everything precision needs is read from here: entries of Qxx (``entries``), the 6x6 photo blocks
(``photo_blocks``), the diagonal, the weight coefficient ``f^T Qxx f`` of any function of the
unknowns (Schmid 81-84), and ``G Qxx G^T`` for a batch of point groups (``group_forms``: the
orientation part of a point's covariance, Schmid 90, and ``B Qxx B^T`` of the residual cofactors).
Underneath is the selected inversion of ``striptri.selected_inverse`` (banded for strips,
supernodal for blocks).

For a free network (datum.FreeNetwork) Qxx is the inverse under the inner constraints,
``Q = S Q_min S^T`` with ``S = I - H K C^T``, ``K = (C^T H)^-1`` and Q_min the inverse of N under
the minimum constraints (held unknowns: zero rows and columns). An entry is then
``Q_min[r, c] - (HK)[r].Y[c] - Y[r].(HK)[c] + (HK)[r] (C^T Y) (HK)[c]^T`` with ``Y = Q_min C``.
The point datum (striptri.equations.point_datum) adds ``(HK)[r] V (HK)[c]^T`` (FreeNetwork.extra = V).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from . import for_layout


class Covariance:
    def __init__(self, N: sp.spmatrix, layout, free_network=None):
        self.layout = layout
        self.n = N.shape[0]
        self.free_network = free_network
        self._store = BlockStore()  # blocks of Qxx read for group_forms, kept for later batches
        if free_network is None:
            # the factor is not kept: every entry precision reads lies in the pattern of the inverse
            # (quadratic_form factorises again when asked)
            self._inv = for_layout(N, layout, keep_factor=False)
            self._rebuild = lambda: for_layout(N, layout, keep_factor=False)
            return
        N_min, mask = free_network.minimum_constraint_system(N)
        self._inv = for_layout(N_min, layout)
        self._keep = 1.0 - mask
        C, H = free_network.C, free_network.H
        Y = self._inv.solve(C) * self._keep[:, None]
        self._HK = H @ np.linalg.inv(C.T @ H)
        self._Y = Y
        self._CtY = C.T @ Y
        if free_network.extra is not None:  # the point datum: + HK V HK^T (point_datum)
            self._CtY = self._CtY + free_network.extra

    def release(self, keep_blocks: bool = False) -> bool:
        """Free the inverse's computed pattern once the run has read all it needs beyond the photo
        blocks and the diagonal, which stay (docs/decisions.md "The inverse let go before the
        tables"), and the blocks kept for group_forms unless ``keep_blocks`` (the point precision
        after the gross-error tests reads the photo pairs the residual cofactors have read:
        docs/decisions.md "The point precision without the inverse"). Anything else read later
        makes the inverse again. Not for a free network (its photo blocks are entries). Returns
        whether it was released."""
        if self.free_network is not None:
            return False
        self._inv.release(self._rebuild)
        if not keep_blocks:
            self._store = BlockStore()
        return True

    def entries(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Qxx[rows, cols] elementwise (broadcast; index -1, a fixed element, reads zero)."""
        r, c = np.broadcast_arrays(np.asarray(rows, dtype=int), np.asarray(cols, dtype=int))
        q = self._inv.entries(r, c)
        if self.free_network is None:
            return q
        keep = np.append(self._keep, 0.0)
        q = q * keep[r] * keep[c]
        pad = lambda a: np.vstack([a, np.zeros((1, a.shape[1]))])  # noqa: E731  (row -1 reads zeros)
        HK, Y = pad(self._HK), pad(self._Y)
        hr, hc, yr, yc = HK[r], HK[c], Y[r], Y[c]
        return (q - np.einsum("...a,...a->...", hr, yc) - np.einsum("...a,...a->...", yr, hc)
                + np.einsum("...a,ab,...b->...", hr, self._CtY, hc))

    def block_entries(self, ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
        """(u, wa, wb) the blocks Qxx[ca[i], cb[i]] between the column sets ca (u, wa) and cb (u, wb):
        ``entries(ca[:, :, None], cb[:, None, :])``, the same numbers, read a block at a time where
        the selected inverse can (SelectedInverse.block_entries)."""
        if self.free_network is not None:
            return self.entries(ca[:, :, None], cb[:, None, :])
        return self._inv.block_entries(ca, cb)

    def group_forms(self, parts: Sequence["Slots"]) -> np.ndarray:
        """``G Qxx G^T`` of every group of a batch (group_forms with this Qxx)."""
        return group_forms(self.entries, parts, store=self._store, blocks=self.block_entries)

    def set_blocks(self, parts: Sequence["Slots"]) -> np.ndarray:
        """Qxx among the unknown sets of every group of a batch (set_blocks with this Qxx)."""
        return set_blocks(self.entries, parts, store=self._store, blocks=self.block_entries)

    def photo_blocks(self) -> np.ndarray:
        """(n_photos, 6, 6) blocks of Qxx of every photo's elements (fixed elements zero)."""
        cols = self.layout.photo_cols
        if self.free_network is None:
            return self._inv.stack(range(len(cols)))
        return self.entries(cols[:, :, None], cols[:, None, :])

    def diag(self) -> np.ndarray:
        idx = np.arange(self.n)
        return self._inv.diag() if self.free_network is None else self.entries(idx, idx)

    def quadratic_form(self, f: np.ndarray) -> float:
        """f^T Qxx f (Schmid 83), f the gradient of a function of the unknowns."""
        f = np.asarray(f, dtype=float)
        if self.free_network is None:
            return float(self._inv.quadratic_form(f))
        fn = self.free_network
        h = self._HK.T @ f
        g = f - fn.C @ h  # S^T f
        extra = float(h @ fn.extra @ h) if fn.extra is not None else 0.0
        return float(g @ (self._inv.solve(g) * self._keep)) + extra

    def dense(self) -> np.ndarray:
        idx = np.arange(self.n)
        return self.entries(idx[:, None], idx[None, :])

    def dense_solved(self) -> np.ndarray:
        """The whole Qxx (n, n): the dense route's inverse, or n solves with the factor; for small
        systems several times faster than ``dense`` (every entry looked up), equal to rounding."""
        if self.free_network is not None:
            return self.dense()
        return self._inv.whole()


# ------------------------------------------------------------------------ G Qxx G^T of groups

BLOCK_CHUNK = 1 << 21  # entries of the gathered Qxx blocks of a batch held at once (16 MB)


@dataclass(frozen=True)
class Slots:
    """Unknown sets of one kind (photos, or cameras) in a batch of m groups.

    G: (m, r, s, w) the derivatives of r quantities of each group with respect to the w unknowns of
    each of its s sets; sets: (m, s) the row of ``columns`` that each set is; columns: (n_sets, w)
    the columns of Qxx of every set (-1: a fixed element, which reads zero). by_ray: None, or G's
    first w columns of each set grouped by set, as equations.ray_columns.RayColumns (an object with
    ``groups(part)`` and ``quadratic(Q, w)``), which group_forms uses for ``G Q G^T`` of the slot
    with itself.
    """

    G: np.ndarray
    sets: np.ndarray
    columns: np.ndarray
    by_ray: object = None


def ray_slots(G: np.ndarray, photo: np.ndarray, photo_cols: np.ndarray, camera: np.ndarray | None = None,
              camera_cols: np.ndarray | None = None, by_ray=None) -> list[Slots]:
    """Slots of groups of k rays: G (m, r, k, 6 + e) with respect to each ray's photo elements
    (``photo_cols[photo]``, (n_photos, 6)) and then the e estimated elements of its camera
    (``camera_cols[camera]``, (n_cameras, e)). When every group's rays share one camera (the usual
    case) the camera derivatives of its rays are added into one camera set; a camera part whose
    elements are all fixed is left out.

    by_ray: the same G grouped by ray (equations.ray_columns.RayColumns, its first 6 columns the
    photo's), for long tracks: ``G Q G^T`` of the photo slots is then formed ray by ray."""
    out = [Slots(G[..., :6], photo, photo_cols, by_ray)]
    if camera is None or camera_cols is None or not camera_cols.shape[1] or not (camera_cols >= 0).any():
        return out
    Gc = G[..., 6:]
    if camera.shape[1] and np.all(camera == camera[:, :1]):
        Gc, camera = Gc.sum(axis=2, keepdims=True), camera[:, :1]
    return out + [Slots(Gc, camera, camera_cols)]


def strongest_correlations(correlations: np.ndarray, width: int) -> list[tuple[int, int, float]]:
    """For each row of ``correlations`` (m, n_blocks * width) of an element with the elements of a
    group of blocks (photos: width 6; centres: width 3), the largest in magnitude as (block, element,
    correlation); (-1, -1, nan) for a row without a finite correlation."""
    out = []
    for row in correlations:
        finite = np.isfinite(row)
        if not finite.any():
            out.append((-1, -1, float("nan")))
            continue
        k = int(np.nanargmax(np.where(finite, np.abs(row), -1.0)))
        out.append((k // width, k % width, float(row[k])))
    return out


def group_forms(entries: Callable[[np.ndarray, np.ndarray], np.ndarray], parts: Sequence[Slots],
                block_chunk: int = BLOCK_CHUNK, store: "BlockStore | None" = None,
                blocks: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """``G Q G^T`` (m, r, r) for every group of a batch, G the derivatives of the slots ``parts``
    (one G of the group, split by kind of unknown set) and Q the entries of Qxx that
    ``entries(rows, cols)`` gives (broadcast; -1 reads zero); ``blocks(ca, cb)``, when given, reads
    the same numbers a block at a time (Covariance.block_entries).

    Q is read by blocks: the distinct pairs of sets of the batch (two photos that share a point,
    a photo and a camera, ...) are each read once (and kept in ``store`` for later batches, when
    given), then gathered for the groups in chunks of at most ``block_chunk`` entries and
    contracted by matrix products: memory linear in the batch, and work ``m r (s w)^2`` instead
    of the ``m r^2 (s w)^2`` of a three-operand einsum.
    """
    m, r = parts[0].G.shape[:2]
    out = np.zeros((m, r, r))
    if m == 0:
        return out
    for a, b, table, index, swap in _set_pairs(_reader(entries, blocks), parts, store):
        Pa, Pb = parts[a], parts[b]
        sa, wa = Pa.G.shape[2:]
        sb, wb = Pb.G.shape[2:]
        step = max(1, block_chunk // max(sa * sb * wa * wb, 1))
        for c0 in range(0, m, step):
            c1 = min(c0 + step, m)
            Q = _set_pair_block(table, index, swap, slice(c0, c1))
            if a == b and Pa.by_ray is not None:  # few sets per row of G: ray by ray
                out[c0:c1] += Pa.by_ray.groups(slice(c0, c1)).quadratic(Q, wa)
                continue
            Ga = Pa.G[c0:c1].reshape(c1 - c0, r, sa * wa)
            Gb = Pb.G[c0:c1].reshape(c1 - c0, r, sb * wb)
            T = (Ga @ Q) @ np.swapaxes(Gb, 1, 2)
            out[c0:c1] += T if a == b else T + np.swapaxes(T, 1, 2)
    return out


def _reader(entries, blocks):
    """``read(ca, cb)``: the (u, wa, wb) blocks of Q between column sets, by ``blocks`` or by entries."""
    return blocks if blocks is not None else (lambda ca, cb: entries(ca[:, :, None], cb[:, None, :]))


def _set_pairs(read, parts: Sequence["Slots"], store: "BlockStore | None"):
    """(a, b, table, index, swap) for every pair a <= b of a batch's slots, the blocks of Q between
    their unknown sets read once (``read``, _reader) through ``store`` (BlockStore.blocks)."""
    store = BlockStore() if store is None else store
    for a, Pa in enumerate(parts):
        for b in range(a, len(parts)):
            yield (a, b, *store.blocks(read, Pa, parts[b], same=a == b))


def _set_pair_block(table: np.ndarray, index: np.ndarray, swap: np.ndarray | None, groups: slice) -> np.ndarray:
    """Q between two slots' unknowns for ``groups`` of a batch, from BlockStore.blocks' table:
    (mc, sa * wa, sb * wb), each set's w columns together (set-major)."""
    Q = _set_pair_blocks(table, index, swap, groups)
    mc, sa, sb, wa, wb = Q.shape
    return Q.transpose(0, 1, 3, 2, 4).reshape(mc, sa * wa, sb * wb)


def _set_pair_blocks(table: np.ndarray, index: np.ndarray, swap: np.ndarray | None, groups: slice) -> np.ndarray:
    """The blocks of _set_pair_block as gathered, (mc, sa, sb, wa, wb): block (i, j) of a group the
    one between its set i of the first slot and set j of the second."""
    Q = np.take(table, index[groups], axis=0)
    if swap is not None:  # only the swapped blocks turned: 40 % less time than a where() over all
        turned = np.flatnonzero(swap[groups])
        flat = Q.reshape(-1, *Q.shape[3:])  # a view: Q is a fresh contiguous array
        flat[turned] = np.swapaxes(flat[turned], -1, -2)
    return Q


def set_blocks(entries: Callable[[np.ndarray, np.ndarray], np.ndarray], parts: Sequence[Slots],
               store: "BlockStore | None" = None,
               blocks: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Q restricted to the unknown sets of every group of a batch: (m, D, D) with D = sum over
    ``parts`` of s * w, the sets of parts[0] first, each set's w columns together (set-major), as
    ``P.G.reshape(m, r, s * w)`` orders a group's derivatives. Q is read by blocks of set pairs as
    in group_forms (only ``sets`` and ``columns`` of the slots are read). Memory m D^2: the caller
    chunks its groups."""
    m = len(parts[0].sets)
    sizes = [P.sets.shape[1] * P.columns.shape[1] for P in parts]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    out = np.zeros((m, starts[-1], starts[-1]))
    if m == 0:
        return out
    for a, b, table, index, swap in _set_pairs(_reader(entries, blocks), parts, store):
        Q = _set_pair_blocks(table, index, swap, slice(None))  # (m, sa, sb, wa, wb)
        _, sa, sb, wa, wb = Q.shape
        # written straight into out's (set, column) layout, without a set-major copy first
        out[:, starts[a]:starts[a + 1], starts[b]:starts[b + 1]].reshape(m, sa, wa, sb, wb)[...] = \
            Q.transpose(0, 1, 3, 2, 4)
        if a != b:
            out[:, starts[b]:starts[b + 1], starts[a]:starts[a + 1]].reshape(m, sb, wb, sa, wa)[...] = \
                Q.transpose(0, 2, 4, 1, 3)
    return out


TABLE_GROWTH = 1.5  # BlockStore: a full table grows to this many times its size


class BlockStore:
    """Blocks of Qxx between unknown sets, read once and kept: per pair of ``columns`` arrays (told
    apart by their contents), the sorted keys ``i * n_b + j`` of the set pairs read so far and their
    blocks ``Q[columns_a[i], columns_b[j]]``. Within one kind (``same``) only (min, max) is kept."""

    def __init__(self):
        self._tables: dict = {}
        self._lock = threading.Lock()  # the chunks of a sweep read it from several threads
        self._tags: dict = {}  # id(columns) -> (columns, tag): the arrays seen, each hashed once

    def _tag(self, columns: np.ndarray):
        """The contents of a ``columns`` array as a key, hashed once per array object: every chunk of
        a sweep passes the layout's same (n_photos, 6) photo columns, whose hash over all photos in
        every chunk grew the sweeps like n^2 (4.8 MB per call at 100,000 photos, 780 chunks of the
        point precision)."""
        seen = self._tags.get(id(columns))
        if seen is not None and seen[0] is columns:
            return seen[1]
        c = np.ascontiguousarray(columns)
        tag = c.shape, hash(c.tobytes())
        self._tags[id(columns)] = (columns, tag)
        return tag

    def blocks(self, read, Pa: Slots, Pb: Slots, same: bool):
        """(table (u, wa, wb), index (m, sa, sb) into it, swap (m, sa, sb) or None) for the set pairs
        of a batch, the blocks not kept yet read by ``read(ca, cb)`` ((u, wa, wb) blocks between
        column sets): where swap is true the block is read transposed (Q[b, a] = Q[a, b]^T)."""
        i = np.broadcast_to(Pa.sets[:, :, None], Pa.sets.shape + Pb.sets.shape[1:])
        j = np.broadcast_to(Pb.sets[:, None, :], i.shape)
        nb = np.int64(len(Pb.columns))
        swap = None
        if same:
            swap = i > j
            i, j = np.minimum(i, j), np.maximum(i, j)
            swap = swap if swap.any() else None
        key = i.astype(np.int64) * nb + j
        tag = (self._tag(Pa.columns), self._tag(Pb.columns), same)
        kept = self._kept(tag, key)  # all read before (an earlier batch, an earlier pass): no lock
        if kept is not None:
            return kept + (swap,)
        with self._lock:
            return self._blocks(read, Pa, Pb, key, tag, nb) + (swap,)

    def _kept(self, tag, key: np.ndarray):
        """(table, index) of ``key`` when every block is kept already, else None. Reads one snapshot
        of the kept table (replaced whole under the lock; its rows below ``used`` never change)."""
        kept = self._tables.get(tag)
        if kept is None:
            return None
        keys, rows, table, used = kept
        if not len(keys):
            return None
        pos = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
        if not np.array_equal(keys[pos], key):
            return None
        return table[:used], rows[pos]

    def _blocks(self, read, Pa: Slots, Pb: Slots, key: np.ndarray, tag, nb):
        """The blocks of ``key`` (read now where not yet kept) and their rows in the kept table. The
        table grows by TABLE_GROWTH at a time (the blocks read before are copied only then, not with
        every batch: a sweep's batches copied the whole table each, 0.7 GB over the 5,000-photo
        block's residual cofactors); its sorted keys point into it."""
        wa, wb = Pa.columns.shape[1], Pb.columns.shape[1]
        keys, rows, table, used = self._tables.get(
            tag, (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, wa, wb)), 0))
        wanted = np.unique(key)
        pos = np.searchsorted(keys, wanted)
        missing = wanted[(pos == len(keys)) | (keys[np.minimum(pos, max(len(keys) - 1, 0))] != wanted)] if len(
            keys) else wanted
        if len(missing):
            ui, uj = missing // nb, missing % nb
            new = read(Pa.columns[ui], Pb.columns[uj])
            if used + len(new) > len(table):  # a larger table; earlier batches keep the old one
                grown = np.empty((max(int(TABLE_GROWTH * len(table)), used + len(new)), wa, wb))
                grown[:used] = table[:used]
                table = grown
            table[used: used + len(new)] = new
            keys, rows = np.concatenate([keys, missing]), np.concatenate([rows, np.arange(used, used + len(new))])
            order = np.argsort(keys, kind="stable")
            keys, rows, used = keys[order], rows[order], used + len(new)
            self._tables[tag] = (keys, rows, table, used)
        return table[:used], rows[np.searchsorted(keys, key)]

    @property
    def nbytes(self) -> int:
        return sum(k.nbytes + r.nbytes + t.nbytes for k, r, t, _ in self._tables.values())
