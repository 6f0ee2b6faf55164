"""The ``sparse`` and ``cholmod`` routes of the selected inversion: a block's N, by the Takahashi
recurrence on the supernodes of its sparse Cholesky factor (:class:`SupernodalInverse`).

The pattern comes from :mod:`.symbolic`; the numeric factorisation is a supernodal Cholesky here
(``sparse``) or CHOLMOD's (``cholmod``), read into the same supernodes.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from ..parallel import run_all
from ..solvers import SingularNormalMatrix, Structure, kernels
from ..solvers.base import check_pivots
from ..solvers.threads import chunk_threads
from ..solvers.blocks import ranges
from ..solvers.sparse_cholesky import cholmod_module
from .engine import Engine
from .symbolic import symbolic


# the work (Supernodes.work, multiply-adds) below which the supernodes are done on one thread: the
# synthetic blocks of the tests, a strip's few supernodes
PARALLEL_MIN_WORK = 2e8


class SupernodalInverse(Engine):
    """Selected inversion of a block's N on the supernodes of its sparse Cholesky factor.

    Order (:mod:`.symbolic`): nested dissection (CHOLMOD, when installed) or SuperLU's minimum degree
    on the block graph (photo and camera blocks kept whole; camera blocks, coupled to many photos,
    come late), postordered along its elimination tree. Symbolic
    factorisation on the block graph: the rows of L below block column j are its neighbours after
    it and the rows of its children below j. Consecutive blocks j, j + 1 with parent(j) = j + 1
    form one supernode when they share their rows, or when little is stored in vain
    (``relaxed_columns``, ``relaxed_zeros``); a supernode is one dense (rows x columns) array: the
    columns of L, and then of Z = N~^-1, on its rows.

    Numeric factorisation, ``numeric="numpy"``: right-looking supernodal Cholesky - per supernode
    ``L11 = chol(F11)`` (LAPACK potrf, with the solvers' pivot test), ``L21 = F21 L11^-T``, and
    ``L21 L21'`` subtracted from the supernodes that own its rows. ``numeric="cholmod"``: CHOLMOD
    factorises N~ in the same order (natural ordering of the permuted matrix) and its L is read in.

    Selected inverse: the Takahashi equations (package docstring) per supernode, backwards:
    ``Z_BP = -Z_BB L21 L11^-1``, ``Z_PP = L11^-T (L11^-1 - L21' Z_BP)``, where ``Z_BB`` (B the rows
    below P, a clique of the filled graph) is gathered from the later supernodes that own them.
    The recurrence takes the independent subtrees of the supernode tree (``Supernodes.split``) on
    the chunk threads; both passes use the BLAS and LAPACK kernels of :mod:`striptri.solvers.kernels`,
    which release the GIL (docs/decisions.md "The selected inversion on both cores"). The
    factorisation runs the subtrees on the threads too, but takes the updates of the supernodes
    above them in the one-thread order (:meth:`_factor_on_threads`): every run, on any number of
    threads, gives the same numbers to the last bit.
    Work and memory are those of the factorisation (``info["stored"]`` entries; on threads, while
    the subtrees run, also their kept updates of the top: a fifth to a third of L at 5,000 to
    100,000 photos). Every block of
    N^-1 between two photos that share a point (or a camera) lies in the pattern; other entries are
    solved for with the factor.
    """

    name = "sparse"

    def __init__(self, As: sp.csr_matrix, structure: Structure, numeric: str = "numpy", keep_factor: bool = True,
                 matrix=None, *, ordering: str, relaxed_columns: int, relaxed_zeros: float):
        """As: the scaled N~ (n x n CSR). keep_factor False: Z takes L's place, and ``matrix()``
        gives N~ back to factorise again for a solve. ordering, relaxed_columns, relaxed_zeros: the
        symbolic analysis (:func:`.symbolic.symbolic`; the package's BLOCK_ORDERING,
        RELAXED_SUPERNODE, RELAXED_ZEROS)."""
        super().__init__()
        self.n = As.shape[0]
        self.name = "cholmod" if numeric == "cholmod" else "sparse"
        self._numeric = numeric
        sym = self.sym = symbolic(As, structure, ordering, relaxed_columns, relaxed_zeros)
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
            idx = ranges(first, count)
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
        """The supernodal factorisation: its independent subtrees on the chunk threads
        (:meth:`_factor_on_threads`), the same numbers to the last bit as on one thread."""
        L = self._scatter(As, self.sym.order, self._position())  # As symmetric: its rows are its columns
        threads = self._threads()
        if threads > 1:
            self._factor_on_threads(L, threads)
        else:
            self._factor_supernodes(L, range(self.sym.count))
        return L

    def _factor_on_threads(self, L: np.ndarray, threads: int) -> None:
        """The factorisation with the independent subtrees of the supernode tree (Supernodes.split)
        on ``threads`` threads, bit for bit the one-thread factorisation's (docs/decisions.md "Qxx
        read a block at a time; the selected inversion's factorisation on both cores, in order").

        Every entry of L must take its updates in the one-thread order, ascending by the supernode
        that sends them: sums in another order differ in the last bits, and would differ from run to
        run with the threads' timing. A subtree's supernodes update supernodes of their own subtree
        (in order, its thread doing them one after the other) and of ``top``. Their updates of
        ``top`` are kept instead; then, in ascending order over all supernodes, the kept ones are
        subtracted and the supernodes of ``top`` factorised (each subtracting its own updates at
        once), so that every entry of ``top`` takes its updates in the one-thread order too. A
        singular pivot is raised as one thread raises it: at the first failing supernode."""
        sym = self.sym
        top, subtrees = sym.split(threads)
        in_top = np.zeros(sym.count, dtype=bool)
        in_top[top] = True
        kept: dict[int, list] = {}
        failed: dict[int, SingularNormalMatrix] = {}

        def subtree(nodes):
            for p in nodes:
                try:
                    self._factor_supernodes(L, (p,), in_top, kept)
                except SingularNormalMatrix as exc:
                    failed[int(p)] = exc  # the subtree stops there, as one thread would
                    return

        run_all(subtree, subtrees, threads)
        first_failure = min(failed, default=sym.count)
        for p in np.union1d(top, np.fromiter(kept, dtype=int, count=len(kept))):
            if p >= first_failure:
                break
            if in_top[p]:
                self._factor_supernodes(L, (p,))
                continue
            for q, pos, parts in kept.pop(int(p)):
                G = self._view(L, q)
                for a, b, c, part in parts:
                    G[pos[a:], c: c + b - a] -= part
        if failed:
            raise failed[first_failure]

    def _factor_supernodes(self, L: np.ndarray, nodes, deferred: np.ndarray | None = None,
                           kept: dict | None = None) -> None:
        """Right-looking: each supernode p of ``nodes`` (ascending) factorised, ``L11 = chol(F11)``
        (with the solvers' pivot test), ``L21 = F21 L11^-T``, and ``L21 L21'`` subtracted from the
        supernodes that own its rows; its parts for the supernodes marked in ``deferred`` are kept
        instead (``kept[p]``: (q, pos, [(a, b, c, the part of a run)]), for _factor_on_threads)."""
        sym = self.sym
        for p in nodes:
            F = self._view(L, p)
            w = sym.width(p)
            F11 = F[:w]
            info = kernels.cholesky_lower(F11)  # its strict upper triangle keeps N~'s numbers, never read
            if info > 0:
                raise SingularNormalMatrix(int(sym.order[sym.start[p] + info - 1]))
            check_pivots(np.diag(F11), sym.order[sym.start[p]: sym.start[p + 1]])
            if len(F) > w:
                L21 = F[w:]
                kernels.solve_lower(F11, L21, right=True, transposed=True)  # F21 L11^-T
                # the update's lower triangle (the diagonal blocks of later supernodes are read
                # only there by potrf): syrk, half the work of L21 L21'
                U = np.zeros((len(L21), len(L21)))
                kernels.lower_product(L21, U)
                for q, s, _, pos, runs in sym.targets[p]:
                    if deferred is not None and deferred[q]:
                        kept.setdefault(int(p), []).append(
                            (q, pos, [(a, b, c, U[s + a:, s + a: s + b].copy()) for a, b, c in runs]))
                        continue
                    G = self._view(L, q)
                    for a, b, c in runs:  # the lower triangle of the run's columns and the rows below
                        G[pos[a:], c: c + b - a] -= U[s + a:, s + a: s + b]

    def _threads(self) -> int:
        """Threads over the independent subtrees of the recurrence: every core the command may use
        (chunk_threads), one for a small N (the Python around the kernels would only take turns)."""
        return 1 if float(self.sym.work.sum()) < PARALLEL_MIN_WORK else chunk_threads()

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
        may be ``L`` itself: a supernode's columns of L are needed only for its own columns of Z):
        the top of the tree first, then its independent subtrees on the threads (each reads Z only
        of its own supernodes and of their ancestors)."""
        top, subtrees = self.sym.split(self._threads())
        self._invert_supernodes(L, Z, top[::-1])
        run_all(lambda nodes: self._invert_supernodes(L, Z, nodes[::-1]), subtrees, self._threads())
        return Z

    def _invert_supernodes(self, L: np.ndarray, Z: np.ndarray, nodes) -> None:
        """Each supernode p of ``nodes`` (descending), its ancestors done: ``Y = Z_BB L21`` (symm:
        reads Z_BB's lower triangle), ``Z_BP = -Y L11^-1`` and ``Z_PP = L11^-T (I + L21' Y) L11^-1``
        (triangular solves; a root of the tree by LAPACK potri)."""
        sym = self.sym
        for p in nodes:
            F = self._view(L, p)
            w = sym.width(p)
            L11 = F[:w].copy()
            Zp = self._view(Z, p)
            b = len(F) - w
            if b:
                L21 = F[w:]
                Zbb = np.empty((b, b))
                for q, s, _, pos, runs in sym.targets[p]:
                    Zq = self._view(Z, q)
                    for a, e, c in runs:  # the lower triangle, which is all symm reads
                        Zbb[s + a:, s + a: s + e] = Zq[pos[a:], c: c + e - a]
                Y = kernels.symmetric_times(Zbb, L21)  # Z_BB L21
                S = L21.T @ Y
                S[np.diag_indices(w)] += 1.0
                Zp[w:] = Y
                kernels.solve_lower(L11, Zp[w:], right=True, transposed=False, alpha=-1.0)  # -Y L11^-1
                kernels.solve_lower(L11, S, right=True, transposed=False)
                kernels.solve_lower(L11, S, right=False, transposed=True)
                Zp[:w] = 0.5 * (S + S.T)
            else:
                kernels.inverse_from_cholesky(L11)
                Zp[:w] = np.tril(L11) + np.tril(L11, -1).T

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

    def block_lookup(self, ca: np.ndarray, cb: np.ndarray):
        """(values (u, wa, wb), ok (u,)): the blocks Z[ca[i], cb[i]] of sets whose columns are
        consecutive positions of the order (a photo's or a camera's block, kept whole by the
        symbolic analysis), each found with one lookup (Supernodes.locate) instead of one per entry:
        the block sits in the columns of the earlier set's supernode, on the consecutive rows of the
        later set. ``ok`` false (values unset): a fixed element, columns apart in the order, or a
        block outside the computed pattern; entries for those."""
        sym = self.sym
        pos = self._position()
        (u, wa), wb = ca.shape, cb.shape[1]
        ok = (ca >= 0).all(axis=1) & (cb >= 0).all(axis=1)
        qa, qb = pos[np.maximum(ca, 0)], pos[np.maximum(cb, 0)]
        pa, pb = qa[:, 0], qb[:, 0]
        ok &= (qa == pa[:, None] + np.arange(wa)).all(axis=1) & (qb == pb[:, None] + np.arange(wb)).all(axis=1)
        a_first = pa <= pb  # the block of a's columns on b's rows (else b's columns on a's rows)
        lo, hi = np.where(a_first, pa, pb), np.where(a_first, pb, pa)
        w_lo, w_hi = np.where(a_first, wa, wb), np.where(a_first, wb, wa)
        flat, found = sym.locate(hi, lo)
        last, found_last = sym.locate(hi + w_hi - 1, lo)
        sn = np.searchsorted(sym.start, lo, side="right") - 1
        width = np.diff(sym.start)[sn]
        ok &= found & found_last & (last == flat + (w_hi - 1) * width) & (lo + w_lo <= sym.start[sn + 1])
        values = np.zeros((u, wa, wb))
        take = np.flatnonzero(ok & a_first)  # stored as b's rows by a's columns: transposed
        values[take] = np.swapaxes(self.Z[self._block_places(flat[take], width[take], wb, wa)], 1, 2)
        take = np.flatnonzero(ok & ~a_first)  # a's rows by b's columns
        values[take] = self.Z[self._block_places(flat[take], width[take], wa, wb)]
        return values, ok

    @staticmethod
    def _block_places(flat: np.ndarray, width: np.ndarray, rows: int, cols: int) -> np.ndarray:
        """(u, rows, cols) flat places of blocks whose first entry is at ``flat`` in supernodes of
        ``width`` columns (row-major storage of each supernode)."""
        return flat[:, None, None] + np.arange(rows)[:, None] * width[:, None, None] + np.arange(cols)

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

