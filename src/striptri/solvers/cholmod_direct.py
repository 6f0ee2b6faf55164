"""CHOLMOD called directly, so that its factorisation lets the interpreter go (:class:`DirectFactor`).

scikit-sparse holds the GIL through CHOLMOD's numeric factorisation: no thread of striptri works
while it runs, and on a 2-core machine one core idles for the 0.8 s that a 5,000-photo block's
five factorisations take (docs/decisions.md "CHOLMOD without the interpreter lock"). A foreign
function called through ``ctypes.CDLL`` runs without the GIL, so the ``cholmod`` solver calls the
same library (the ``libcholmod`` that scikit-sparse's module is linked to, found through it) for
the analysis, the factorisation and the solve, and :mod:`.beside` lets chosen work go on meanwhile.

The structures below mirror ``cholmod_core.h`` of CHOLMOD 3.0 (SuiteSparse 5, Debian 12's, the one
scikit-sparse 0.4.16 builds against). :func:`direct_library` takes the library only when it says it
is CHOLMOD 3 and ``cholmod_start`` fills the mirrored Common with CHOLMOD 3's documented defaults
(so that every field this module sets or reads lies where the library has it); otherwise it answers
None and the solver keeps to scikit-sparse. The settings are scikit-sparse's (one ordering method,
supernodal or simplicial, the defaults otherwise), so the factor is the same to the last bit
(tests/test_cholmod_direct.py), with two differences a user sees: CHOLMOD prints nothing (its
``print`` level 0), and a matrix that is not positive definite names its column.
"""

from __future__ import annotations

import ctypes as C
import functools

import numpy as np
import scipy.sparse as sp

# cholmod_core.h / cholmod_cholesky.h of CHOLMOD 3.0
_VERSION = 3
_INT, _DOUBLE, _PATTERN, _REAL = 0, 0, 0, 1
_SIMPLICIAL, _SUPERNODAL = 0, 2
_NOT_POSDEF = 1
_SOLVE_A = 0
ORDERING_CODES = {"natural": 0, "amd": 2, "metis": 3, "nesdis": 4, "colamd": 5}
_METHODS = 10  # CHOLMOD_MAXMETHODS + 1
# what cholmod_start sets in CHOLMOD 3 (its documentation), checked before the library is trusted
_DEFAULTS = dict(grow0=1.2, maxrank=8, supernodal_switch=40.0, final_asis=1, zrelax=(0.8, 0.1, 0.05),
                 nrelax=(4, 16, 48), nmethods=0, postorder=1, metis_dswitch=0.66, metis_nswitch=3000,
                 itype=_INT, dtype=_DOUBLE, status=0, orderings=(1, 2, 3, 4, 0, 4, 4, 4, 5, 2))


class _Method(C.Structure):
    _fields_ = [("lnz", C.c_double), ("fl", C.c_double), ("prune_dense", C.c_double),
                ("prune_dense2", C.c_double), ("nd_oksep", C.c_double), ("other_1", C.c_double * 4),
                ("nd_small", C.c_size_t), ("other_2", C.c_size_t * 4), ("aggressive", C.c_int),
                ("order_for_lu", C.c_int), ("nd_compress", C.c_int), ("nd_camd", C.c_int),
                ("nd_components", C.c_int), ("ordering", C.c_int), ("other_3", C.c_size_t * 4)]


class _Common(C.Structure):
    """cholmod_common up to its statistics; ``_rest`` is room for the fields after them (GPU and
    SPQR bookkeeping, about 600 bytes in CHOLMOD 3), which this module never touches."""

    _fields_ = [("dbound", C.c_double), ("grow0", C.c_double), ("grow1", C.c_double), ("grow2", C.c_size_t),
                ("maxrank", C.c_size_t), ("supernodal_switch", C.c_double), ("supernodal", C.c_int),
                ("final_asis", C.c_int), ("final_super", C.c_int), ("final_ll", C.c_int),
                ("final_pack", C.c_int), ("final_monotonic", C.c_int), ("final_resymbol", C.c_int),
                ("zrelax", C.c_double * 3), ("nrelax", C.c_size_t * 3), ("prefer_zomplex", C.c_int),
                ("prefer_upper", C.c_int), ("quick_return_if_not_posdef", C.c_int), ("prefer_binary", C.c_int),
                ("print", C.c_int), ("precise", C.c_int), ("try_catch", C.c_int), ("error_handler", C.c_void_p),
                ("nmethods", C.c_int), ("current", C.c_int), ("selected", C.c_int), ("method", _Method * _METHODS),
                ("postorder", C.c_int), ("default_nesdis", C.c_int), ("metis_memory", C.c_double),
                ("metis_dswitch", C.c_double), ("metis_nswitch", C.c_size_t), ("nrow", C.c_size_t),
                ("mark", C.c_int64), ("iworksize", C.c_size_t), ("xworksize", C.c_size_t), ("Flag", C.c_void_p),
                ("Head", C.c_void_p), ("Xwork", C.c_void_p), ("Iwork", C.c_void_p), ("itype", C.c_int),
                ("dtype", C.c_int), ("no_workspace_reallocate", C.c_int), ("status", C.c_int),
                ("fl", C.c_double), ("lnz", C.c_double), ("anz", C.c_double), ("modfl", C.c_double),
                ("malloc_count", C.c_size_t), ("memory_usage", C.c_size_t), ("memory_inuse", C.c_size_t),
                ("_rest", C.c_char * 4096)]


class _Sparse(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("p", C.c_void_p),
                ("i", C.c_void_p), ("nz", C.c_void_p), ("x", C.c_void_p), ("z", C.c_void_p),
                ("stype", C.c_int), ("itype", C.c_int), ("xtype", C.c_int), ("dtype", C.c_int),
                ("sorted", C.c_int), ("packed", C.c_int)]


class _Dense(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("d", C.c_size_t),
                ("x", C.c_void_p), ("z", C.c_void_p), ("xtype", C.c_int), ("dtype", C.c_int)]


class _Factor(C.Structure):
    _fields_ = [("n", C.c_size_t), ("minor", C.c_size_t), ("Perm", C.c_void_p), ("ColCount", C.c_void_p),
                ("IPerm", C.c_void_p), ("nzmax", C.c_size_t), ("p", C.c_void_p), ("i", C.c_void_p),
                ("x", C.c_void_p), ("z", C.c_void_p), ("nz", C.c_void_p), ("next", C.c_void_p),
                ("prev", C.c_void_p), ("nsuper", C.c_size_t), ("ssize", C.c_size_t), ("xsize", C.c_size_t),
                ("maxcsize", C.c_size_t), ("maxesize", C.c_size_t), ("super", C.c_void_p), ("pi", C.c_void_p),
                ("px", C.c_void_p), ("s", C.c_void_p), ("ordering", C.c_int), ("is_ll", C.c_int),
                ("is_super", C.c_int), ("is_monotonic", C.c_int), ("itype", C.c_int), ("xtype", C.c_int),
                ("dtype", C.c_int), ("useGPU", C.c_int)]


def _declare(lib) -> None:
    P, I = C.c_void_p, C.c_int
    for name, args, res in [
        ("cholmod_version", [P], I), ("cholmod_start", [P], I), ("cholmod_finish", [P], I),
        ("cholmod_analyze", [P, P], C.POINTER(_Factor)), ("cholmod_factorize", [P, P, P], I),
        ("cholmod_solve", [I, P, P, P], C.POINTER(_Dense)), ("cholmod_free_dense", [P, P], I),
        ("cholmod_free_factor", [P, P], I), ("cholmod_change_factor", [I, I, I, I, I, P, P], I),
    ]:
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = args, res


@functools.lru_cache(maxsize=None)
def direct_library(module_file: str):
    """The CHOLMOD that the extension module ``module_file`` (scikit-sparse's) is linked to, when
    it is CHOLMOD 3 and its Common lies as mirrored here (module doc); else None."""
    try:
        lib = C.CDLL(module_file)  # dlsym through the module finds its libcholmod
        _declare(lib)
    except (OSError, AttributeError):
        return None
    version = (C.c_int * 3)()
    lib.cholmod_version(version)
    if version[0] != _VERSION:
        return None
    common = _Common()
    lib.cholmod_start(C.byref(common))
    try:
        ok = _has_defaults(common)
    finally:
        lib.cholmod_finish(C.byref(common))
    return lib if ok else None


def _has_defaults(common: _Common) -> bool:
    d = _DEFAULTS
    scalars = all(getattr(common, k) == v for k, v in d.items() if k not in ("zrelax", "nrelax", "orderings"))
    return (scalars and tuple(common.zrelax) == d["zrelax"] and tuple(common.nrelax) == d["nrelax"]
            and tuple(common.method[k].ordering for k in range(_METHODS)) == d["orderings"])


def _ints(address: int, count: int) -> np.ndarray:
    return np.ctypeslib.as_array(C.cast(address, C.POINTER(C.c_int)), shape=(count,))


def _doubles(address: int, count: int) -> np.ndarray:
    return np.ctypeslib.as_array(C.cast(address, C.POINTER(C.c_double)), shape=(count,))


class DirectFactor:
    """One analysis of a pattern (``mode`` supernodal or simplicial, one ``ordering`` method) and
    the numeric factor made from it again and again in the same memory, with CHOLMOD's own calls.
    ``factorize`` runs without the GIL. A: the lower triangle is read of a CSC matrix with sorted
    32-bit indices (a symmetric matrix's CSR transposed, as the solvers hand it)."""

    def __init__(self, lib, A: sp.csc_matrix, mode: str, ordering: str):
        self._lib = lib
        self._common = _Common()
        self._L = None
        lib.cholmod_start(C.byref(self._common))
        c = self._common
        c.print = 0  # CHOLMOD's messages would go to standard output; the solver raises instead
        c.supernodal = _SUPERNODAL if mode == "supernodal" else _SIMPLICIAL
        if ordering == "best":
            c.nmethods = _METHODS - 1  # every method, the one with the least fill taken
        elif ordering != "default":  # "default": CHOLMOD's own choice (nmethods 0)
            c.nmethods = 1
            c.method[0].ordering = ORDERING_CODES[ordering]
        self._L = lib.cholmod_analyze(C.byref(self._view(A)), C.byref(c))
        if not self._L:
            raise MemoryError(f"CHOLMOD could not analyse the normal matrix (status {c.status})")
        L = self._L.contents
        self.n = int(L.n)
        self.perm = _ints(L.Perm, self.n).astype(np.int64)
        self._diagonal_at = None  # where the diagonal of L lies in its values (made at the first factor)

    @staticmethod
    def usable(A: sp.csc_matrix) -> bool:
        """Whether CHOLMOD's 32-bit calls can read A as it is."""
        return A.indices.dtype == np.int32 and A.indptr.dtype == np.int32 and A.has_sorted_indices

    def _view(self, A: sp.csc_matrix) -> _Sparse:
        data = np.ascontiguousarray(A.data, dtype=np.float64)  # A's own numbers when they are so already
        self._held = (A.indptr, A.indices, data)  # alive while CHOLMOD reads them
        return _Sparse(nrow=A.shape[0], ncol=A.shape[1], nzmax=len(A.indices), p=A.indptr.ctypes.data,
                       i=A.indices.ctypes.data, nz=None, x=data.ctypes.data, z=None, stype=-1, itype=_INT,
                       xtype=_REAL, dtype=_DOUBLE, sorted=1, packed=1)

    def factorize(self, A: sp.csc_matrix) -> int | None:
        """The numeric factor of A (the analysed pattern, or a part of it) in the factor's memory.
        None when it is positive definite; else the position in the ordering (a column of the
        permuted A) at which it is not."""
        c = self._common
        self._lib.cholmod_factorize(C.byref(self._view(A)), self._L, C.byref(c))
        self._held = None
        if c.status == _NOT_POSDEF:
            minor = int(self._L.contents.minor)
            self.drop_values()  # a part of a factor: the next factorisation starts from the analysis
            return minor
        if c.status < 0:
            raise MemoryError(f"CHOLMOD's factorisation failed (status {c.status}: out of memory or too large)")
        return None

    def pivots(self) -> np.ndarray:
        """The diagonal of the Cholesky factor in the ordering: L's (supernodal, L L') or sqrt(D)'s
        (simplicial, L D L')."""
        L = self._L.contents
        if self._diagonal_at is None:
            if L.is_super:
                ns = int(L.nsuper)
                first, pi, px = _ints(L.super, ns + 1), _ints(L.pi, ns + 1), _ints(L.px, ns + 1)
                width = np.diff(first)
                of = np.repeat(np.arange(ns), width)
                k = np.arange(self.n) - first[of]
                self._diagonal_at = px[of].astype(np.int64) + k * (np.diff(pi)[of] + 1)
            else:
                self._diagonal_at = _ints(L.p, self.n).astype(np.int64)
        values = _doubles(L.x, int(L.xsize if L.is_super else L.nzmax))[self._diagonal_at]
        return values if L.is_super else np.sqrt(np.maximum(values, 0.0))

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b with the factor (b: a vector)."""
        b = np.ascontiguousarray(b, dtype=float)
        B = _Dense(nrow=self.n, ncol=1, nzmax=self.n, d=self.n, x=b.ctypes.data, z=None, xtype=_REAL, dtype=_DOUBLE)
        X = self._lib.cholmod_solve(_SOLVE_A, self._L, C.byref(B), C.byref(self._common))
        if not X:
            raise MemoryError(f"CHOLMOD's solve failed (status {self._common.status})")
        try:
            return _doubles(X.contents.x, self.n).copy()
        finally:
            self._lib.cholmod_free_dense(C.byref(X), C.byref(self._common))

    def allocate_values(self) -> None:
        """Make room for the numeric factor now and touch it (a supernodal analysis; the first
        factorize then writes into it, as into an earlier factor's memory): its page faults, a third
        of a first factorisation's time at 5,000 photos, are taken by the thread that calls this."""
        L = self._L.contents
        if L.xtype != _PATTERN or not L.is_super:
            return
        self._lib.cholmod_change_factor(_REAL, 1, 1, 1, 1, self._L, C.byref(self._common))
        L = self._L.contents
        if L.xtype == _REAL and L.x:
            C.memset(L.x, 0, int(L.xsize) * 8)  # a foreign call: without the GIL

    def drop_values(self) -> None:
        """Give the numeric values back, keeping the analysis (the next factorize makes them anew)."""
        L = self._L.contents
        if L.xtype != _PATTERN:
            self._lib.cholmod_change_factor(_PATTERN, L.is_ll, L.is_super, 1, 1, self._L, C.byref(self._common))

    def close(self) -> None:
        if self._L is not None:
            self._lib.cholmod_free_factor(C.byref(self._L), C.byref(self._common))
            self._L = None
            self._lib.cholmod_finish(C.byref(self._common))

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - at interpreter exit the library may be gone
            pass
