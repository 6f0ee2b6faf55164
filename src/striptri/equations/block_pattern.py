"""The block pattern of N (Schmid's banded 6n x 6n matrix, with the cameras' columns): which photo
and camera blocks of N are nonzero, where each chunk's ray-pair products go in its data
(``ChunkScatter``), and its reduction from the full element space to the unknowns (``S``,
``ReducedPattern``). Worked out once per adjustment; normal_equations sums into it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.lens import NCP

SPAN_FILL = 0.25  # ChunkScatter: a chunk whose positions fill at least this much of their span adds a slice


class ChunkScatter:
    """Where one chunk's ray-pair blocks go in a BlockPattern's data, worked out once per adjustment:
    the distinct pattern positions the chunk touches (``positions``) and a 0/1 summation matrix
    (``P``: positions x ray pairs, a sparse matrix) that sums the pairs landing on the same
    position. Each iteration then adds ``P @ blocks`` at those positions: one sparse product per
    chunk, instead of a scatter over the whole pattern.

    A chunk whose positions fill much of the stretch between its first and last (SPAN_FILL; long
    tracks, where a few points couple most pairs of photos) sums onto every position of that
    stretch instead (``span``; P has a row for each, empty where the chunk adds nothing) and adds
    them as one slice: a fancy-indexed ``+=`` of 6,400 rows of 36 numbers took 1.4 ms, 0.59 s of the
    close-range block's 3.5 s adjustment, all of it in the thread that gathers the chunks (0.34 s
    as slices)."""

    def __init__(self, pos: np.ndarray):
        # one stable sort of the pairs by position gives the distinct positions and P's rows at
        # once (P's columns in each row in pair order, as a COO -> CSR conversion would leave them)
        pos = np.asarray(pos).ravel()
        n_pairs = len(pos)
        order = np.argsort(pos, kind="stable")
        ordered = pos[order]
        first_of_run = np.ones(n_pairs, dtype=bool)
        first_of_run[1:] = ordered[1:] != ordered[:-1]
        self.positions = ordered[first_of_run]
        self.span = None
        row = np.cumsum(first_of_run) - 1  # of each pair in order
        rows = len(self.positions)
        if rows:
            first, last = int(self.positions[0]), int(self.positions[-1])
            if rows >= SPAN_FILL * (last - first + 1):
                self.span = slice(first, last + 1)
                row, rows = ordered - first, last - first + 1
        index = np.int32 if max(n_pairs, rows) < 2**31 else np.int64
        indptr = np.zeros(rows + 1, dtype=index)
        np.cumsum(np.bincount(row, minlength=rows), out=indptr[1:])
        self.P = sp.csr_matrix((np.ones(n_pairs), order.astype(index), indptr), shape=(rows, n_pairs))

    def add(self, target: np.ndarray, blocks: np.ndarray) -> None:
        """target (n_positions * r * s,) += the blocks (m, k, k, r, s) (block (a, b) of group m is
        blocks[m, a, b]) summed at their positions."""
        self.add_sums(target, self.sums(blocks))

    def sums(self, blocks: np.ndarray) -> np.ndarray:
        """The blocks (m, k, k, r, s) summed by position (n_positions, r s): the part of add that
        changes nothing shared (done in the chunk threads, group_products)."""
        size = blocks.shape[-2] * blocks.shape[-1]
        return self.P @ np.ascontiguousarray(blocks).reshape(-1, size)

    def add_sums(self, target: np.ndarray, sums: np.ndarray) -> None:
        """target += sums (ChunkScatter.sums) at their positions (or over their span)."""
        target.reshape(-1, sums.shape[1])[self.positions if self.span is None else self.span] += sums


class BlockPattern:
    """The block sparsity pattern of N in the full parameter space, computed once per adjustment.

    Full space: 6 columns per photo (centre, rotation unknowns), then NCP per camera
    (lens.CAMERA_ELEMENTS). A group couples every pair of its photos (6x6 blocks) and, when
    cameras are estimated, each of its photos with each of their cameras (6 x w) and those
    cameras with each other (w x w), w the camera elements estimated in some camera
    (UnknownLayout.camera_elements). Each
    iteration fills the blocks' numbers (:class:`PatternAccumulator`) and the reduced N of the
    free unknowns is ``S^T N_full S`` with the 0/1 selection S of ``selection_matrix`` (fixed
    elements dropped, tied elements summed).
    """

    def __init__(self, n_photos: int, n_cameras: int, with_cameras: bool, chunks, camera_elements=None):
        """chunks: iterable of (photo_index (m, k), camera_index (m, k)) of all group chunks;
        camera_elements: the camera elements in the blocks (default all NCP)."""
        self.n_photos, self.n_cameras, self.with_cameras = n_photos, n_cameras, with_cameras
        self.camera_elements = np.arange(NCP) if camera_elements is None else np.asarray(camera_elements, dtype=int)
        self.camera_width = len(self.camera_elements)
        # the pairs from the incidence of groups and photos (cameras): M^T M, M^T C and C^T C in
        # sparse products, rather than the unique keys of every ray pair chunk by chunk
        group, photos, cams, n_groups = [], [], [], 0
        for photo, cam in chunks:
            m, k = photo.shape
            group.append(np.repeat(np.arange(n_groups, n_groups + m), k))
            photos.append(photo.ravel())
            cams.append(cam.ravel())
            n_groups += m
        group, photos, cams = (np.concatenate(a) if a else np.zeros(0, dtype=np.int64) for a in (group, photos, cams))
        M = self._incidence(group, photos, n_groups, n_photos)
        # every photo and camera keeps its diagonal block (N stays square even for unmeasured photos)
        self.pp = self._pair_keys(M.T @ M + sp.identity(n_photos, format="csr"))
        if with_cameras:
            C = self._incidence(group, cams, n_groups, n_cameras)
            self.pc = self._pair_keys(M.T @ C)
            self.cc = self._pair_keys(C.T @ C + sp.identity(n_cameras, format="csr"))
        else:
            self.pc = self.cc = np.zeros(0, dtype=np.int64)
        self.n_full = 6 * n_photos + NCP * n_cameras
        self._reduction = None  # (S, ReducedPattern): the CSR structure of S^T N_full S, worked out once
        self._dense_places = None  # the place of every block number in a dense N_full (reduced_matrix_of_dense)

    @staticmethod
    def _incidence(group, member, n_groups, n_members):
        """(n_groups, n_members) sparse matrix with a nonzero where the group holds the member."""
        return sp.csr_matrix((np.ones(len(group)), (group, member)), shape=(n_groups, n_members))

    @staticmethod
    def _pair_keys(P) -> np.ndarray:
        """Sorted keys ``a nb + b`` (int64) of the nonzeros (a, b) of the (na, nb) sparse matrix P."""
        P = sp.csr_matrix(P)
        P.sum_duplicates()  # one entry per place (the entries are counts: none is zero)
        P.sort_indices()
        rows = np.repeat(np.arange(P.shape[0], dtype=np.int64), np.diff(P.indptr))
        return rows * P.shape[1] + P.indices.astype(np.int64)

    @staticmethod
    def _keys(a, b, nb):
        return (a[:, :, None].astype(np.int64) * nb + b[:, None, :]).ravel()

    def positions(self, photo, cam):
        """Block positions of a chunk's (a, b) pairs: pp (m, k, k), pc (m, k, k), cc (m, k, k)."""
        m, k = photo.shape
        pos_pp = np.searchsorted(self.pp, self._keys(photo, photo, self.n_photos)).reshape(m, k, k)
        if not self.with_cameras:
            return pos_pp, None, None
        pos_pc = np.searchsorted(self.pc, self._keys(photo, cam, self.n_cameras)).reshape(m, k, k)
        pos_cc = np.searchsorted(self.cc, self._keys(cam, cam, self.n_cameras)).reshape(m, k, k)
        return pos_pp, pos_pc, pos_cc

    def scatters(self, photo, cam, camera_summed: bool = False):
        """ChunkScatter of a chunk's photo-photo, photo-camera and camera-camera pairs (the last two
        None when the cameras are held).

        camera_summed: every group of the chunk has one camera (``cam == cam[:, :1]``), whose
        columns the caller sums over the group's rays first: its photo-camera blocks then come
        one per ray (pairs (a, 0), blocks (m, k, 1, 6, w)) and its camera-camera block one per
        group (pair (0, 0), blocks (m, 1, 1, w, w))."""
        pos_pp, pos_pc, pos_cc = self.positions(photo, cam)
        if not self.with_cameras:
            return ChunkScatter(pos_pp), None, None
        if camera_summed:
            return ChunkScatter(pos_pp), ChunkScatter(pos_pc[:, :, :1]), ChunkScatter(pos_cc[:, :1, :1])
        return ChunkScatter(pos_pp), ChunkScatter(pos_pc), ChunkScatter(pos_cc)

    def _full_indices(self):
        n = self.n_photos
        dt = np.int32 if self.n_full < 2**31 else np.int64  # the set-up's largest arrays: half the memory
        a, b = (x.astype(dt) for x in np.divmod(self.pp, n))
        i6, j6 = (x.astype(dt) for x in np.meshgrid(np.arange(6), np.arange(6), indexing="ij"))
        rows = [(6 * a[:, None, None] + i6).ravel()]
        cols = [(6 * b[:, None, None] + j6).ravel()]
        if self.with_cameras:
            nc = self.n_cameras
            p, c = (x.astype(dt) for x in np.divmod(self.pc, nc))
            el = np.asarray(self.camera_elements, dtype=dt)
            i, j = np.meshgrid(np.arange(6, dtype=dt), el, indexing="ij")
            r_pc = (6 * p[:, None, None] + i).ravel()
            c_pc = (6 * n + NCP * c[:, None, None] + j).ravel()
            rows += [r_pc, c_pc]
            cols += [c_pc, r_pc]
            ca, cb = (x.astype(dt) for x in np.divmod(self.cc, nc))
            i3, j3 = np.meshgrid(el, el, indexing="ij")
            rows.append((6 * n + NCP * ca[:, None, None] + i3).ravel())
            cols.append((6 * n + NCP * cb[:, None, None] + j3).ravel())
        return np.concatenate(rows), np.concatenate(cols)

    @staticmethod
    def _block_data(pp, pc, cc, with_cameras) -> np.ndarray:
        """The block numbers in the order of _full_indices (without cameras pp itself, no copy)."""
        return np.concatenate([pp.ravel(), pc.ravel(), pc.ravel(), cc.ravel()]) if with_cameras else pp.ravel()

    def matrix(self, pp, pc, cc) -> sp.csr_matrix:
        """N_full from the block data: pp (nb, 6, 6), pc (nbpc, 6, w), cc (nbcc, w, w)."""
        rows, cols = self._full_indices()
        return sp.csr_matrix((self._block_data(pp, pc, cc, self.with_cameras), (rows, cols)),
                             shape=(self.n_full, self.n_full))

    def reduced_matrix(self, S: sp.csr_matrix, pp, pc, cc) -> sp.csr_matrix:
        """``S^T N_full S`` from the block data, the same matrix as ``S.T @ self.matrix(...) @ S``
        but without forming N_full or a product: N's CSR structure and the place of every block
        number in it are worked out at the first call for this S (:class:`ReducedPattern`); every
        later iteration only gathers (and, for tied elements, sums) the numbers."""
        return self.reduction(S).matrix(self._block_data(pp, pc, cc, self.with_cameras))

    def reduced_matrix_of_dense(self, S: sp.csr_matrix, N_full: np.ndarray) -> sp.csr_matrix:
        """``S^T N_full S`` (as :meth:`reduced_matrix`) from a dense N_full (n_full, n_full) that is
        zero outside the pattern: its block numbers gathered (the places worked out at the first
        call); the camera-photo blocks are the photo-camera blocks transposed, as in
        :meth:`reduced_matrix`."""
        if self._dense_places is None:
            rows, cols = self._full_indices()
            if self.with_cameras:  # the transposed copy of pc read where pc is (N_full[r_pc, c_pc])
                start = len(self.pp) * 36
                n_pc = len(self.pc) * 6 * self.camera_width
                rows[start + n_pc : start + 2 * n_pc] = rows[start : start + n_pc]
                cols[start + n_pc : start + 2 * n_pc] = cols[start : start + n_pc]
            self._dense_places = rows.astype(np.int64) * self.n_full + cols
        return self.reduction(S).matrix(N_full.reshape(-1)[self._dense_places])

    def reduction(self, S: sp.csr_matrix) -> "ReducedPattern":
        """The ReducedPattern of S, worked out at the first call (the adjustments call this when
        they make the pattern, before any chunk is linearised, when memory is lowest)."""
        if self._reduction is None or self._reduction[0] is not S:
            # photo blocks only, numbered in order: placed without a sort (ReducedPattern.of_photo_blocks)
            fast = None if self.with_cameras else ReducedPattern.of_photo_blocks(self.pp, self.n_photos, S)
            self._reduction = (S, fast if fast is not None else ReducedPattern(self._full_indices(), S))
        return self._reduction[1]


class ReducedPattern:
    """The CSR structure of ``N = S^T N_full S`` and, for each of its entries, the block numbers
    that sum to it (BlockPattern.reduced_matrix).

    S maps each full element to at most one unknown (0/1, fixed elements have none; elements tied
    to one unknown share it). An entry (i, j) of N_full lands at (col[i], col[j]) of N, or nowhere
    when either element is fixed; entries landing on the same place (tied elements) are summed.
    Kept: ``order`` (the kept block numbers in CSR order), N's ``indptr`` and ``indices``, and, only
    when elements are tied, the starts of each entry's run in ``order``."""

    def __init__(self, full_indices, S: sp.csr_matrix):
        rows, cols = full_indices
        n_block_numbers = len(rows)
        S = sp.csr_matrix(S)
        n = S.shape[1]
        col_of = _columns_of(S)
        # few and small temporaries: at 20,000 photos these arrays hold ten million entries, and
        # each one made anew is paid for in first touches of its pages (docs/decisions.md,
        # fourteenth round)
        r = col_of[rows]
        del rows
        c = col_of[cols]
        del cols, full_indices
        kept = None  # every block number lands in N (no element fixed): no index of the kept ones
        keep = (r >= 0) & (c >= 0)
        if not keep.all():
            kept = np.flatnonzero(keep)
            r, c = r[kept], c[kept]
        del keep
        key = r.astype(np.int64)
        key *= n
        key += c
        by_key = np.argsort(key, kind="stable")
        del key
        r, c = r[by_key], c[by_key]  # in CSR order
        position_type = np.int32 if n_block_numbers < 2**31 else np.int64
        self.order = (by_key if kept is None else kept[by_key]).astype(position_type)
        del by_key, kept
        first = np.ones(len(r), dtype=bool)
        first[1:] = (r[1:] != r[:-1]) | (c[1:] != c[:-1])
        self.starts = None if first.all() else np.flatnonzero(first)
        if self.starts is not None:
            r, c = r[first], c[first]
        index_type = np.int32 if max(n, len(r)) < 2**31 else np.int64
        self.indices = c.astype(index_type, copy=False)
        self.indptr = np.zeros(n + 1, dtype=index_type)
        np.cumsum(np.bincount(r, minlength=n), out=self.indptr[1:])
        self.shape = (n, n)

    @classmethod
    def of_photo_blocks(cls, pp: np.ndarray, n_photos: int, S: sp.csr_matrix) -> "ReducedPattern | None":
        """The ReducedPattern of a pattern of 6 x 6 photo blocks only (pp: their sorted keys
        ``a n_photos + b``; BlockPattern._full_indices lists their entries block by block, row by
        row) without sorting its entries: where S numbers the kept photo elements in their order and
        ties none, an entry's place in N's CSR order is its row's start, the widths of the blocks
        before its own in the block row, and its column's rank among its photo's kept elements. The
        same order, indices and indptr as the sort (tests/test_normal_equations.py); None where S
        ties photo elements or numbers them out of order (the caller sorts)."""
        S = sp.csr_matrix(S)
        col_of = _columns_of(S)
        photo = col_of[: 6 * n_photos].reshape(n_photos, 6)
        numbered = photo[photo >= 0]
        if np.any(numbered[1:] <= numbered[:-1]):
            return None
        n = S.shape[1]
        a, b = np.divmod(pp, n_photos)
        keep = photo >= 0
        width = keep.sum(axis=1)[b]  # each block's kept columns
        row_length = np.bincount(a, weights=width, minlength=n_photos).astype(np.int64)  # a kept row of photo a
        before = np.cumsum(width) - width  # the kept columns of all earlier blocks
        offset = before - (np.cumsum(row_length) - row_length)[a]  # ... of the earlier blocks in its block row
        lengths = np.zeros(n, dtype=np.int64)
        lengths[photo[keep]] = np.repeat(row_length, keep.sum(axis=1))
        nnz = int(lengths.sum())
        index_type = np.int32 if max(n, nnz) < 2**31 else np.int64
        position_type = np.int32 if 36 * len(pp) < 2**31 else np.int64
        out = cls.__new__(cls)
        out.indptr = np.zeros(n + 1, dtype=index_type)
        np.cumsum(lengths, out=out.indptr[1:])
        rank = np.cumsum(keep, axis=1) - 1  # a kept column's place among its photo's kept columns
        row_start = np.where(keep, out.indptr[np.maximum(photo, 0)], -1)  # (n_photos, 6): each kept row's start
        place = row_start[a][:, :, None] + (offset[:, None, None] + rank[b][:, None, :])  # (nb, 6, 6)
        out.order = np.empty(nnz, dtype=position_type)
        out.indices = np.empty(nnz, dtype=index_type)
        if keep.all():  # every entry lands in N
            place = place.ravel()
            out.order[place] = np.arange(len(place), dtype=position_type)
            out.indices[place] = np.broadcast_to(photo[b][:, None, :], (len(pp), 6, 6)).ravel()
        else:
            lands = (keep[a][:, :, None] & keep[b][:, None, :]).ravel()
            place = place.ravel()[lands]
            out.order[place] = np.flatnonzero(lands).astype(position_type)
            out.indices[place] = np.broadcast_to(photo[b][:, None, :], (len(pp), 6, 6)).ravel()[lands]
        out.starts = None
        out.shape = (n, n)
        return out

    def matrix(self, block_data: np.ndarray) -> sp.csr_matrix:
        data = block_data[self.order]
        if self.starts is not None:
            data = np.add.reduceat(data, self.starts)
        # canonical CSR (sorted, unique indices): scipy need not check or sort it
        N = sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape, copy=False)
        N.has_sorted_indices = True
        N.has_canonical_format = True
        return N


def _columns_of(S: sp.csr_matrix) -> np.ndarray:
    """Each full element's unknown (-1: fixed) under the 0/1 selection S (CSR)."""
    n = S.shape[1]
    per_row = np.diff(S.indptr)
    if per_row.max(initial=0) > 1 or not np.all(S.data == 1.0):
        raise ValueError("S must map each full element to at most one unknown with weight 1")
    col_of = np.full(S.shape[0], -1, dtype=np.int32 if n < 2**31 else np.int64)
    col_of[per_row == 1] = S.indices
    return col_of


def ray_columns(pattern: BlockPattern, photo: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Full-space columns (m, k, 6 + w) of each ray's photo and camera elements (BlockPattern)."""
    return np.concatenate(
        [6 * photo[..., None] + np.arange(6), 6 * pattern.n_photos + NCP * cam[..., None] + pattern.camera_elements],
        -1)


def selection_matrix(photo_cols: np.ndarray, camera_cols: np.ndarray, n_unknowns: int) -> sp.csr_matrix:
    """S (n_full, n_unknowns): full element -> its column (0/1; fixed elements have none)."""
    full = np.concatenate([photo_cols.ravel(), camera_cols.ravel()])
    keep = full >= 0
    return sp.csr_matrix((np.ones(int(keep.sum())), (np.flatnonzero(keep), full[keep])),
                         shape=(len(full), n_unknowns))
