"""``cholmod``: CHOLMOD's sparse Cholesky (scikit-sparse) with a fill-reducing ordering.

CHOLMOD is called directly (:mod:`.cholmod_direct`: the library scikit-sparse is linked to, through
ctypes) where that can be done (CHOLMOD 3, a matrix with 32-bit indices), else through
scikit-sparse; the same settings, the same factor to the last bit. Called directly, the numeric
factorisation runs without the GIL, and work that does not need the factor goes on beside it
(:mod:`.beside`). The rest of this doc holds for both routes (scikit-sparse's calls named).

The symbolic factorisation (ordering and the pattern of L, ``cholmod.analyze``) is made once per
solver object, i.e. once per adjustment, at the first solve; every outer iteration then only
refactorises numerically. Without ``holds_factor`` that is a new numeric factor from the kept
analysis (``Factor.cholesky``), dropped after the solve, so that it does not occupy memory while the
next iteration assembles. With ``holds_factor`` (both adjustment methods, for their whole run) the
factor is kept for ``solve_again`` until ``release``, and its memory until the solver stops holding:
the next factorisation writes into it (``Factor.cholesky_inplace``), the same numbers, without
taking the factor's pages from the system again, zeroed (5,000 photos: 25,000 page faults and 0.18 s
a factorisation fewer; docs/decisions.md "Refactorised in place"). If N's pattern ever grows beyond the one
analysed (an entry that was not there before), the solver analyses again and counts it in
``info.analyses``; a pattern that only loses entries (exact zeros) is fine as it is.

Mode and ordering (:data:`MODE`, :data:`ORDERING`) were chosen by measurement on the normal
matrices of the benchmark blocks of 1,000, 5,000 and 20,000 photos (docs/solvers.md,
``scripts/bench/bench_solvers.py --projects``): the *supernodal* factorisation, which does its work
in dense BLAS kernels, with CHOLMOD's nested dissection (METIS on the graph, then constrained
minimum degree on the parts). With an optimised BLAS under CHOLMOD (Debian's OpenBLAS) that is 5 to
10 times faster than the simplicial factorisation; on the reference BLAS it is still no slower.

OpenMP: CHOLMOD 3.0 (SuiteSparse 5, Debian 12's) clears and copies memory in its supernodal
factorisation in OpenMP regions with a compiled-in ``num_threads(4)`` (CHOLMOD_OMP_NUM_THREADS),
whatever OMP_NUM_THREADS says: a fork and join for every large supernode. On a busy 2-core machine
that made the numeric factorisation 2 to 3 times slower (and 15 times slower with the thread limit 2).
:func:`cholmod_module` therefore switches libgomp's dynamic adjustment on (``omp_set_dynamic(1)``,
in the calling thread, for the libgomp CHOLMOD is linked to): the runtime then gives those regions no
more threads than there are idle cores. ``OMP_THREAD_LIMIT=1`` in the environment makes it one thread
always (docs/solvers.md has the measurements).

scikit-sparse is optional: ``pip install 'striptri[cholmod]'`` after
``apt-get install libsuitesparse-dev libopenblas0-serial`` (docs/solvers.md).
"""

from __future__ import annotations

import ctypes
import threading

import numpy as np
import scipy.sparse as sp

from . import beside
from .base import NormalSolver, SingularNormalMatrix, SolveResult, SolverUnavailable, check_pivots, jacobi_scaled
from .cholmod_direct import DirectFactor, direct_library
from .info import SolverInfo
from .threads import factorisation_threads, limit_new_libraries

MODES = ("supernodal", "simplicial")
ORDERINGS = ("nesdis", "metis", "amd", "colamd", "best", "default", "natural")
MODE = "supernodal"
ORDERING = "nesdis"

INSTALL_HINT = (
    "the 'cholmod' solver needs scikit-sparse: install SuiteSparse's headers and the extra with "
    "`apt-get install libsuitesparse-dev && pip install 'striptri[cholmod]'` "
    "(or choose another solver, e.g. 'banded' or 'sparse')"
)


DIRECT = True  # CHOLMOD's own calls where they can be made (module doc); the tests compare both routes
OPENMP_DYNAMIC = True  # the module doc; the benchmark switches it off to show why it is on
_tamed = threading.local()


def _tame_openmp(module) -> None:
    """omp_set_dynamic(1) in this thread for the libgomp that ``module``'s CHOLMOD calls (once per
    thread; nothing when CHOLMOD was built without OpenMP)."""
    if not OPENMP_DYNAMIC or getattr(_tamed, "done", False):
        return
    try:
        ctypes.CDLL(module.__file__).omp_set_dynamic(1)  # dlsym from the module: its own libgomp
    except (OSError, AttributeError, TypeError):
        pass
    _tamed.done = True


def cholmod_module():
    """sksparse.cholmod, or SolverUnavailable with the install command; in the calling thread,
    CHOLMOD's OpenMP regions get no more threads than idle cores (module doc)."""
    try:
        from sksparse import cholmod
    except ImportError as exc:
        raise SolverUnavailable(INSTALL_HINT) from exc
    _tame_openmp(cholmod)
    limit_new_libraries()  # its OpenBLAS under striptri's thread limit (solvers.threads)
    return cholmod


def cholmod_available() -> bool:
    try:
        cholmod_module()
    except SolverUnavailable:
        return False
    return True


class CholmodSolver(NormalSolver):
    """``mode`` and ``ordering`` default to :data:`MODE` and :data:`ORDERING` (the benchmark
    script passes others to compare them)."""

    name = "cholmod"

    def __init__(self, options, structure, *, mode: str = MODE, ordering: str = ORDERING):
        super().__init__(options, structure)
        if mode not in MODES:
            raise ValueError(f"unknown CHOLMOD mode {mode!r}; choose one of {', '.join(MODES)}")
        if ordering not in ORDERINGS:
            raise ValueError(f"unknown CHOLMOD ordering {ordering!r}; choose one of {', '.join(ORDERINGS)}")
        self.mode, self.ordering = mode, ordering
        self._cholmod = cholmod_module()
        self._factor = None
        self._pattern: tuple | None = None  # (indptr, indices, shape) of the analysed matrix
        self.analyses = 0
        self._held = None  # (numeric factor, Jacobi scale) of the last solve, when holds_factor
        self._numeric = None  # while holds_factor: the last numeric factor, whose memory the next one reuses
        self._prepared = None  # (the pattern's CSC view, the thread analysing it, [its DirectFactor]): prepare

    def _pattern_fits(self, A: sp.csc_matrix) -> bool:
        if self._pattern is None:
            return False
        indptr, indices, shape = self._pattern
        if shape != A.shape:
            return False
        if np.array_equal(indptr, A.indptr) and np.array_equal(indices, A.indices):
            return True
        P = sp.csc_matrix((np.ones(len(indices)), indices, indptr), shape=shape)
        ones = sp.csc_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
        return (P + ones).nnz == P.nnz

    def solve(self, N, b):
        self._held = None
        n = N.shape[0]
        if n == 0:
            return SolveResult(np.zeros(0), self.name)
        Ns, s = jacobi_scaled(N)
        A = Ns.T  # CSC view of the symmetric matrix; CHOLMOD reads its lower triangle
        if not self._pattern_fits(A) and not self._take_prepared(A):
            self._analyse(A)
        _tame_openmp(self._cholmod)  # this thread may not be the one that made the solver
        factor = self._factor_direct(A) if isinstance(self._factor, DirectFactor) else self._factor_scikit(A)
        y = _solved(factor, b * s)
        if self.holds_factor:
            self._held, self._numeric = (factor, s), factor
        elif isinstance(factor, DirectFactor):
            factor.drop_values()
        return SolveResult(np.asarray(y).reshape(-1) * s, self.name,
                           SolverInfo(analyses=self.analyses, mode=self.mode, ordering=self.ordering))

    def _analyse(self, A: sp.csc_matrix) -> None:
        """The symbolic factorisation of A's pattern: by CHOLMOD's own calls where they can be
        made (cholmod_direct), else by scikit-sparse."""
        if isinstance(self._factor, DirectFactor):
            self._factor.close()  # before the new one is made: never two at once
        lib = direct_library(self._cholmod.__file__) if DIRECT and DirectFactor.usable(A) else None
        if lib is not None:
            self._install(DirectFactor(lib, A, self.mode, self.ordering), A)
        else:
            self._install(self._cholmod.analyze(A, mode=self.mode, ordering_method=self.ordering), A)

    def _install(self, analysis, A: sp.csc_matrix) -> None:
        """``analysis`` (of A's pattern) becomes the solver's, in place of the one before."""
        if isinstance(self._factor, DirectFactor):
            self._factor.close()  # (closed already when _analyse made it: closing twice is nothing)
        self._factor = analysis
        self._pattern = (A.indptr.copy(), A.indices.copy(), A.shape)  # the analysed pattern
        self._numeric = None
        self.analyses += 1

    def prepare(self, pattern: sp.csr_matrix) -> None:
        """The analysis of N's pattern, and the first factor's memory taken and touched, on a
        thread while the first linearisation runs (CHOLMOD's own calls run without the GIL; the
        supernodal mode only). The first solve takes it if its N has that pattern."""
        A = pattern.T
        if (self._factor is not None or self._prepared is not None or self.mode != "supernodal" or not DIRECT
                or not DirectFactor.usable(A)):
            return
        lib = direct_library(self._cholmod.__file__)
        if lib is None:
            return
        made: list = []

        def analyse():
            try:
                factor = DirectFactor(lib, A, self.mode, self.ordering)
                factor.allocate_values()
                made.append(factor)
            except Exception:  # noqa: BLE001 - the first solve analyses as without
                pass

        thread = threading.Thread(target=analyse, name="striptri-analysis", daemon=True)
        thread.start()
        self._prepared = (A, thread, made)

    def _take_prepared(self, A: sp.csc_matrix) -> bool:
        """Whether the analysis of :meth:`prepare` was of A's pattern and is now the solver's."""
        if self._prepared is None:
            return False
        pattern, thread, made = self._prepared
        self._prepared = None
        thread.join()
        same = (pattern.shape == A.shape and np.array_equal(pattern.indptr, A.indptr)
                and np.array_equal(pattern.indices, A.indices))
        if not (same and made):
            return False
        self._install(made[0], A)
        return True

    def _factor_direct(self, A: sp.csc_matrix) -> DirectFactor:
        """Factorised in the analysis' own memory, without the GIL: work beside it may go on."""
        factor = self._factor
        with factorisation_threads(), beside.factorising():
            failed = factor.factorize(A)
        if failed is not None:
            raise SingularNormalMatrix(int(factor.perm[failed]))
        check_pivots(factor.pivots(), factor.perm)
        return factor

    def _factor_scikit(self, A: sp.csc_matrix):
        perm = self._factor.P()
        factor, self._numeric = self._numeric, None
        try:
            with factorisation_threads():
                if factor is None:  # a new numeric factor from the kept analysis (symbolic only)
                    factor = self._factor.cholesky(A)
                else:  # into the memory of the last one (module doc)
                    factor.cholesky_inplace(A)
        except self._cholmod.CholmodNotPositiveDefiniteError as exc:
            col = getattr(exc, "column", None)
            raise SingularNormalMatrix(int(perm[col]) if col is not None and 0 <= col < A.shape[0] else None) from exc
        # D(): the squared diagonal of L (supernodal, L L') or D itself (simplicial, L D L')
        check_pivots(np.sqrt(np.maximum(factor.D(), 0.0)), perm)
        return factor

    def solve_again(self, b):
        if self._held is None:
            return None
        factor, s = self._held
        return np.asarray(_solved(factor, b * s)).reshape(-1) * s

    def holding(self) -> bool:
        return self._held is not None

    def release(self):
        self._held = None
        if not self.holds_factor:
            self._numeric = None
            if isinstance(self._factor, DirectFactor):
                self._factor.drop_values()


def _solved(factor, rhs: np.ndarray) -> np.ndarray:
    """A^-1 rhs with either route's factor (cholmod_direct's, or scikit-sparse's Factor)."""
    return factor.solve(rhs) if isinstance(factor, DirectFactor) else factor.solve_A(rhs)
