"""Dense BLAS and LAPACK kernels on C-ordered arrays that release the GIL while they compute.

scipy's own wrappers (scipy.linalg.blas, .lapack: f2py) hold the GIL for the whole call and copy
C-ordered operands into Fortran order first. On two threads over independent supernodes (the
selected inversion, :mod:`striptri.selected_inverse.supernodal`) they took turns: 1.06-1.25x of one
thread for dsymm, dtrsm and dsyrk on 600 x 300 operands, against 2.0x through these. The routines
are scipy's, the ones its Cython API exports (``scipy.linalg.cython_blas`` / ``cython_lapack``, a
public interface), called through ctypes, which releases the GIL for a foreign call.

A C-ordered (r x c) array is the Fortran (c x r) array of its transpose, so every kernel calls
the Fortran routine on the transposed problem: the lower triangle in C order is the upper one in
Fortran order, a product from the left becomes one from the right. Each function states its
result in C-order terms; operands must be C-contiguous float64 (checked), results are written in
place where the docstring says so. Where a Python or scipy build does not export the routines
that way (``releases_gil()`` is then False), each kernel takes scipy's f2py wrapper instead: the
same results, the GIL held.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

_P = ctypes.c_void_p


ARGUMENTS = {"dpotrf": 5, "dpotri": 5, "dtrsm": 11, "dsyrk": 10, "dsymm": 12}


@functools.cache
def _routine(module: str, name: str):
    """The Fortran routine ``name`` of scipy.linalg.cython_blas or cython_lapack as a ctypes
    function (every argument a pointer, no result); None where this Python or scipy does not
    export it so (the kernels then take scipy's f2py wrappers: the same numbers, the GIL held)."""
    import importlib

    try:
        capsule = importlib.import_module(f"scipy.linalg.{module}").__pyx_capi__[name]
        api = ctypes.pythonapi
        api.PyCapsule_GetName.restype = ctypes.c_char_p
        api.PyCapsule_GetName.argtypes = [ctypes.py_object]
        api.PyCapsule_GetPointer.restype = ctypes.c_void_p
        api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        address = api.PyCapsule_GetPointer(capsule, api.PyCapsule_GetName(capsule))
    except (ImportError, AttributeError, KeyError, TypeError, ValueError):  # pragma: no cover - exotic builds
        return None
    return ctypes.CFUNCTYPE(None, *[_P] * ARGUMENTS[name])(address)


def releases_gil() -> bool:
    """Whether every kernel runs through ctypes (the GIL released), not scipy's f2py wrappers."""
    return all(_routine("cython_lapack" if n.startswith("dpo") else "cython_blas", n) is not None for n in ARGUMENTS)


def _char(c: str):
    return _CHARS[c]


# the option characters of the kernels, made once: the routines only read them (from any thread)
_CHARS = {c: ctypes.byref(ctypes.c_char(c.encode())) for c in "LNRTU"}


def _int(i: int):
    return ctypes.byref(ctypes.c_int(int(i)))


def _double(x: float):
    return ctypes.byref(ctypes.c_double(float(x)))


def _checked(A: np.ndarray) -> np.ndarray:
    if A.dtype != np.float64 or not A.flags.c_contiguous:
        raise ValueError("the kernels take C-contiguous float64 arrays")
    return A


def _array(A: np.ndarray):
    """A pointer to A's data for a kernel: a ctypes double laid over A's buffer (half a microsecond;
    numpy's ``A.ctypes.data_as``, 3 microseconds, was a fifth of a small kernel's call), or
    through numpy where the buffer cannot take one (read-only, empty)."""
    _checked(A)
    try:
        return ctypes.byref(ctypes.c_double.from_buffer(A))
    except (TypeError, ValueError, BufferError):
        return A.ctypes.data_as(_P)


def cholesky_lower(A: np.ndarray) -> int:
    """In place: the lower triangle of the symmetric (n x n) A (only it is read) becomes L with
    A = L L'; the strict upper triangle is left as it was. Returns LAPACK's info: 0, or the
    (1-based) column whose pivot was not positive."""
    return _lower_in_place("dpotrf", A, clean=0)


def inverse_from_cholesky(L: np.ndarray) -> int:
    """In place: the lower triangle of L (A = L L', from :func:`cholesky_lower`) becomes the lower
    triangle of A^-1. Returns LAPACK's info."""
    return _lower_in_place("dpotri", L)


def _lower_in_place(name: str, A: np.ndarray, **f2py_options) -> int:
    """LAPACK's ``name`` (dpotrf, dpotri) on the lower triangle of the square A, in place; its info."""
    n = A.shape[0]
    routine = _routine("cython_lapack", name)
    if routine is None:
        from scipy.linalg import lapack

        out, info = getattr(lapack, name)(_checked(A), lower=1, **f2py_options)
        low = np.tril_indices(n)
        A[low] = out[low]
        return int(info)
    info = ctypes.c_int(0)
    routine(_char("U"), _int(n), _array(A), _int(n), ctypes.byref(info))
    return info.value


def solve_lower(L: np.ndarray, B: np.ndarray, *, right: bool, transposed: bool, alpha: float = 1.0) -> None:
    """In place on B (C-ordered): with L lower triangular (n x n, only its lower triangle read),
    B <- alpha B L^-1 (right, not transposed), alpha B L^-T (right, transposed), alpha L^-1 B
    (left) or alpha L^-T B (left, transposed)."""
    m, n = B.shape
    # C order: B is the Fortran B' (n x m), L the Fortran upper triangular U = L'.
    # B L^-1 = (L^-T B')' = (U^-1 B')': from the left with U, not transposed; B L^-T: with U'.
    # L^-1 B = (B' L^-T)' = (B' U^-1)': from the right with U; L^-T B: with U'.
    routine = _routine("cython_blas", "dtrsm")
    if routine is None:
        from scipy.linalg import blas

        B[...] = blas.dtrsm(alpha, _checked(L), _checked(B), side=int(right), lower=1, trans_a=int(transposed))
        return
    side = "L" if right else "R"
    trans = "T" if transposed else "N"
    routine(_char(side), _char("U"), _char(trans), _char("N"), _int(n), _int(m), _double(alpha), _array(L),
            _int(L.shape[0]), _array(B), _int(n))


def lower_product(A: np.ndarray, out: np.ndarray) -> None:
    """Into the lower triangle of ``out`` (m x m): A A' for A (m x k); the strict upper triangle of
    ``out`` is left as it was."""
    m, k = A.shape
    routine = _routine("cython_blas", "dsyrk")
    if routine is None:
        from scipy.linalg import blas

        low = np.tril_indices(m)
        _checked(out)[low] = blas.dsyrk(1.0, _checked(A), lower=1)[low]
        return
    # C order: A is the Fortran A' (k x m); A A' = (A')' (A'), Fortran trans "T"; C-lower = F-upper
    routine(_char("U"), _char("T"), _int(m), _int(k), _double(1.0), _array(A), _int(k), _double(0.0), _array(out),
            _int(m))


def symmetric_times(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S B for S symmetric (m x m, only its lower triangle read) and B (m x k)."""
    m, k = B.shape
    routine = _routine("cython_blas", "dsymm")
    if routine is None:
        from scipy.linalg import blas

        return np.ascontiguousarray(blas.dsymm(1.0, _checked(S), _checked(B), side=0, lower=1))
    out = np.empty((m, k))
    # C order: (S B)' = B' S, S from the right; its C-lower triangle is the Fortran upper one
    routine(_char("R"), _char("U"), _int(k), _int(m), _double(1.0), _array(S), _int(m), _array(B), _int(k),
            _double(0.0), _array(out), _int(k))
    return out
