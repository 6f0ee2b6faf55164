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
* ``dense`` - the reference for tiny systems, and the route for nearly full ones (close range,
  solvers.selection.nearly_full): the dense inverse (LAPACK ``potri``).

Entries outside the computed pattern (e.g. the block of two photos at opposite ends of a strip)
are columns of N^-1 obtained by solving with the factor already in hand: O(nnz(L)) per column.

The modules, one job each:

* this package's ``__init__`` - the front door: :func:`selected_inverse` (and :func:`for_layout`,
  :func:`photo_blocks`) checks the request, scales N, picks the route and hands it its tunables;
* :mod:`.result` - :class:`SelectedInverse`, the answer in the units of N;
* :mod:`.engine` - what every route provides (entries on request, solves with its factor);
* :mod:`.dense`, :mod:`.banded`, :mod:`.supernodal` - one route each (``sparse`` and ``cholmod``
  share the supernodal one); :mod:`.symbolic` - the order and supernodes of the supernodal route.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..solvers import BANDED_MAX_BANDWIDTH, DENSE_LIMIT, Structure, jacobi_scaled
from ..solvers.banded import choose_split
from ..solvers.selection import nearly_full
from ..solvers.memory import give_back_free_memory, keeps_freed_memory
from ..solvers.sparse_cholesky import cholmod_module
from .banded import BandedInverse
from .dense import DenseInverse
from .engine import SOLVE_CHUNK, EmptyInverse, Engine
from .result import ENTRY_CHUNK, FlatBlocks, SelectedInverse
from .supernodal import SupernodalInverse
from .symbolic import analysed_ahead, symbolic_ahead

METHODS = ("auto", "dense", "banded", "sparse", "cholmod")

# Tunables of the routes, handed to the engines by selected_inverse; they change the speed, never
# the answer (tests/test_selected_inverse.py sets them here).
MIN_BAND_BLOCK = 32  # smallest column block of the banded recurrence (fewer Python steps)
RELAXED_SUPERNODE = 48  # columns up to which a chain of blocks is merged into one supernode
RELAXED_ZEROS = 0.5  # ... if at most this fraction of the merged supernode is explicit zeros
BLOCK_ORDERING = "nesdis"  # order of the sparse route: "nesdis" (when CHOLMOD is there) or "mmd"
# photo and camera blocks up to which for_layout_ahead analyses beside the factorisations: the
# analysis is then held beside the iterations, which at 100,000 photos raised the peak by 343 MiB
# (to 0.96x the peer's) for 3 s of 195 (docs/decisions.md "CHOLMOD without the interpreter lock")
AHEAD_MAX_BLOCKS = 50_000

__all__ = [
    "AHEAD_MAX_BLOCKS", "BLOCK_ORDERING", "ENTRY_CHUNK", "METHODS", "MIN_BAND_BLOCK", "RELAXED_SUPERNODE",
    "RELAXED_ZEROS", "SOLVE_CHUNK",
    "BandedInverse", "DenseInverse", "Engine", "SelectedInverse", "SupernodalInverse", "for_layout", "for_layout_ahead",
    "photo_blocks", "selected_inverse",
]


# ----------------------------------------------------------------------------------------- API


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
    method: one of METHODS; ``auto`` picks ``dense`` up to DENSE_LIMIT unknowns or for a nearly
    full N (solvers.selection.nearly_full), ``banded`` when the
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
        return SelectedInverse(EmptyInverse(), np.zeros(0), block_list, pairs)
    if not keeps_freed_memory():  # the command keeps them: the iterations' freed arrays hold the inverse's
        give_back_free_memory()  # the factor and the inverse are often the largest arrays of a run
    As, s = jacobi_scaled(N)
    structure = Structure(n, _partition_starts(block_list, block_starts, n))
    chosen = _choose_method(method, As, structure)
    # the tunables are read here, when called, so that setting them on the package takes effect
    supernodal = dict(ordering=BLOCK_ORDERING, relaxed_columns=RELAXED_SUPERNODE, relaxed_zeros=RELAXED_ZEROS)
    engine = {
        "dense": lambda: DenseInverse(As),
        "banded": lambda: BandedInverse(As, structure, MIN_BAND_BLOCK),
        "sparse": lambda: SupernodalInverse(As, structure, "numpy", keep_factor, lambda: jacobi_scaled(N)[0],
                                            **supernodal),
        "cholmod": lambda: SupernodalInverse(As, structure, "cholmod", keep_factor, lambda: jacobi_scaled(N)[0],
                                             **supernodal),
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


def for_layout_ahead(N: sp.spmatrix, layout) -> None:
    """Begin what :func:`for_layout` (``method="auto"``) will do first with a matrix of N's
    pattern: the symbolic analysis of the ``sparse`` route, on the other core while the
    factorisations of the adjustment run without the GIL (symbolic.symbolic_ahead; docs/decisions.md
    "CHOLMOD without the interpreter lock"). Nothing for a small N or one another route takes."""
    if not sp.isspmatrix_csr(N) or N.shape[0] <= DENSE_LIMIT or not N.has_canonical_format:
        return  # (a dense N, the close-range blocks': no sparse route)
    if len(layout.photo_cols) + len(layout.camera_cols) > AHEAD_MAX_BLOCKS or analysed_ahead(N):
        return  # (analysed_ahead: the run's later solves, whose N share the first one's pattern)
    n = N.shape[0]
    blocks = [np.asarray(c, dtype=int) for c in (*layout.photo_cols, *layout.camera_cols)]
    structure = Structure(n, _partition_starts(blocks, layout.block_starts(), n))
    symbolic_ahead(N, structure, BLOCK_ORDERING, RELAXED_SUPERNODE, RELAXED_ZEROS, route=_sparse_route)


def _sparse_route(N: sp.csr_matrix, structure: Structure) -> bool:
    """Whether ``auto`` takes the sparse route for a matrix of N's pattern (the choice reads only
    the pattern)."""
    return _choose_method("auto", N, structure) == "sparse"


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
    out = [np.asarray(b, dtype=int).reshape(-1) for b in blocks]
    every = np.concatenate(out) if out else np.zeros(0, dtype=int)  # checked at once: a photo's block is short
    if np.any((every < -1) | (every >= n)):
        raise IndexError(f"block indices must lie in -1..{n - 1}")
    return out


def _partition_starts(blocks: list[np.ndarray], block_starts, n: int) -> np.ndarray:
    """Starts of contiguous column blocks for the sparse route: the given ones, else the first
    column of each requested block; blocks longer than 12 are cut into pieces of 6."""
    if block_starts is not None and len(block_starts):
        starts = np.asarray(block_starts, dtype=int)
    else:
        flat = FlatBlocks(blocks)
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
    if n <= DENSE_LIMIT or nearly_full(As):
        return "dense"
    _, w = choose_split(As, structure)
    return "banded" if w <= BANDED_MAX_BANDWIDTH else "sparse"
