"""Which factorisation and which BLAS solved the normal equations (summary.json, report.html).

:func:`describe` names the factorisation of a solver in words and finds, at run time, the BLAS
library its dense kernels call: it asks the dynamic linker where the BLAS symbol that the solver's
compiled module calls resolves to (``dlsym`` from that module's handle, then ``dladdr``), and asks
that library what it is (OpenBLAS: ``openblas_get_config``, its kernels, threading and threads).
The answer is therefore the library actually used, whatever a Debian alternative, ``LD_LIBRARY_PATH``
or a wheel's bundled copy made it, not what the package was built against.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import re

from .base import SOLVERS
from .info import SolverInfo
from .sparse_cholesky import MODE, ORDERING
from .strips import PRECONDITIONER

# BLAS symbols a solver's module may call, tried in this order (scipy's wheels prefix theirs)
_BLAS_SYMBOLS = ("dgemm_", "scipy_dgemm_", "scipy_dgemm_64_", "dgemm_64_", "dpotrf_", "scipy_dpotrf_", "dtrsv_",
                 "scipy_dtrsv_")
_PARALLEL = {0: "sequential", 1: "pthreads", 2: "OpenMP"}


class _DlInfo(ctypes.Structure):
    _fields_ = [("dli_fname", ctypes.c_char_p), ("dli_fbase", ctypes.c_void_p),
                ("dli_sname", ctypes.c_char_p), ("dli_saddr", ctypes.c_void_p)]


def _library_of_symbol(module_file: str) -> str | None:
    """Path of the shared library that a BLAS symbol called by ``module_file`` resolves to."""
    try:
        handle = ctypes.CDLL(module_file)  # already loaded: the same handle, no second copy
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None)
        dladdr = libc.dladdr
    except (OSError, AttributeError):
        return None
    dladdr.argtypes = [ctypes.c_void_p, ctypes.POINTER(_DlInfo)]
    dladdr.restype = ctypes.c_int
    for symbol in _BLAS_SYMBOLS:
        try:
            address = ctypes.cast(getattr(handle, symbol), ctypes.c_void_p).value
        except AttributeError:
            continue
        info = _DlInfo()
        if dladdr(address, ctypes.byref(info)) and info.dli_fname:
            return os.fsdecode(info.dli_fname)
    return None


def _call(lib, names, restype):
    for name in names:
        try:
            f = getattr(lib, name)
        except AttributeError:
            continue
        f.restype, f.argtypes = restype, []
        return f()
    return None


def _blas_in_words(path: str) -> str:
    """What the BLAS library at ``path`` is: OpenBLAS with version, kernels, threading and
    threads, MKL, BLIS, or the reference BLAS; always followed by the path."""
    real = os.path.realpath(path)
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return path
    config = _call(lib, ("openblas_get_config", "scipy_openblas_get_config", "scipy_openblas_get_config64_",
                         "openblas_get_config64_"), ctypes.c_char_p)
    if config:
        version = config.decode(errors="replace").split()
        name = " ".join(version[:2]) if len(version) >= 2 else "OpenBLAS"
        core = _call(lib, ("openblas_get_corename", "scipy_openblas_get_corename", "scipy_openblas_get_corename64_",
                           "openblas_get_corename64_"), ctypes.c_char_p)
        parallel = _call(lib, ("openblas_get_parallel", "scipy_openblas_get_parallel", "scipy_openblas_get_parallel64_",
                               "openblas_get_parallel64_"), ctypes.c_int)
        threads = _call(lib, ("openblas_get_num_threads", "scipy_openblas_get_num_threads",
                              "scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_"), ctypes.c_int)
        parts = [f"{core.decode(errors='replace')} kernels" if core else None, _PARALLEL.get(parallel),
                 None if threads is None else f"{threads} thread{'s' if threads != 1 else ''}"]
        return f"{name} ({', '.join(p for p in parts if p)}; {real})"
    mkl = ctypes.create_string_buffer(256)
    try:
        lib.MKL_Get_Version_String(mkl, 256)
        return f"{mkl.value.decode(errors='replace').strip()} ({real})"
    except AttributeError:
        pass
    blis = _call(lib, ("bli_info_get_version_str",), ctypes.c_char_p)
    if blis:
        return f"BLIS {blis.decode(errors='replace')} ({real})"
    base = os.path.basename(real)
    if base.startswith(("libblas.so", "libblas.", "libcblas")):
        m = re.search(r"\.so\.(\d+(?:\.\d+)*)$", base)
        version = m.group(1) if m and m.group(1).count(".") >= 1 else ""
        return f"reference BLAS (Netlib){' ' + version if version else ''} ({real})"
    return real


def _module_file(solver: str) -> str | None:
    """The compiled module whose BLAS calls do the factorisation of ``solver``."""
    try:  # imported here: scikit-sparse and cvxopt are optional (ImportError: not installed)
        if solver == "cholmod":
            from sksparse import cholmod as module
        elif solver == "cvxopt":
            from cvxopt import cholmod as module
        elif solver == "sparse":
            from scipy.sparse.linalg._dsolve import _superlu as module
        else:  # dense, banded, gauss-seidel, pcg, strip-pcg: scipy.linalg's LAPACK
            from scipy.linalg import _flapack as module
    except ImportError:
        return None
    return getattr(module, "__file__", None)


def blas_path(solver: str) -> str | None:
    """Path of the BLAS library the factorisation of ``solver`` calls (None if not found)."""
    module_file = _module_file(solver)
    return _library_of_symbol(module_file) if module_file else None


def on_reference_blas(solver: str) -> bool:
    """True when ``solver``'s BLAS calls go to the unoptimised reference (Netlib) BLAS."""
    path = blas_path(solver)
    return bool(path) and _blas_in_words(path).startswith("reference BLAS")


def blas(solver: str) -> str:
    """The BLAS library the factorisation of ``solver`` runs on, in words, with its path."""
    path = blas_path(solver)
    if path:
        return _blas_in_words(path)
    if solver in ("cholmod", "cvxopt"):
        return "unknown"
    try:  # scipy's own record of the BLAS it was built with
        import scipy

        blas = scipy.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name', 'unknown')} {blas.get('version', '')} (as scipy was built)".strip()
    except Exception:  # noqa: BLE001 - a description must never fail an adjustment
        return "unknown"


def _cholmod_version(module_file: str) -> str:
    """'CHOLMOD 3.0.14 (SuiteSparse 5.12.0)' from the library the module is linked to."""
    try:
        handle = ctypes.CDLL(module_file)
    except OSError:
        return "CHOLMOD"
    out = ["CHOLMOD"]
    for symbol, label in (("cholmod_version", ""), ("SuiteSparse_version", "SuiteSparse ")):
        v = (ctypes.c_int * 3)()
        try:
            getattr(handle, symbol)(v)
        except AttributeError:
            continue
        text = f"{label}{v[0]}.{v[1]}.{v[2]}"
        out.append(text if not label else f"({text})")
    return " ".join(out)


_ORDERING_WORDS = {
    "nesdis": "nested dissection (CHOLMOD's NESDIS: METIS and constrained minimum degree)",
    "metis": "nested dissection (METIS)",
    "amd": "approximate minimum degree (AMD)",
    "colamd": "COLAMD (AMD for a symmetric matrix)",
    "best": "the best of CHOLMOD's orderings",
    "default": "CHOLMOD's default ordering (AMD, METIS where it helps)",
    "natural": "no reordering",
}


def factorisation(solver: str, info: SolverInfo | None = None) -> str:
    """The factorisation of ``solver`` in words; ``info`` (a SolveResult's info, e.g. the last
    iteration's ``solver_info``) adds what the solver reported (bandwidth, mode, ordering)."""
    info = info if info is not None else SolverInfo()
    if solver == "dense":
        return "LAPACK dense Cholesky (potrf)"
    if solver == "banded":
        text = "LAPACK banded Cholesky (pbtrf)"
        if info.bandwidth is not None:
            text += f", bandwidth {info.bandwidth}"
            if info.border:
                text += f", dense border of {info.border} camera columns"
        return text
    if solver == "sparse":
        return "scipy SuperLU (L D U with diagonal pivots), minimum-degree ordering of the photo blocks"
    if solver == "cholmod":
        mode = info.mode if info.mode is not None else MODE
        ordering = info.ordering if info.ordering is not None else ORDERING
        module_file = _module_file("cholmod")
        name = _cholmod_version(module_file) if module_file else "CHOLMOD"
        return f"{name} {mode}, {_ORDERING_WORDS.get(ordering, ordering)} ordering (scikit-sparse)"
    if solver == "cvxopt":
        module_file = _module_file("cvxopt")
        name = _cholmod_version(module_file) if module_file else "CHOLMOD"
        return f"{name} supernodal, approximate minimum degree (AMD) ordering (cvxopt)"
    if solver == "gauss-seidel":
        return "block Gauss-Seidel / SOR with the 6x6 photo blocks (no factorisation of N)"
    if solver == "pcg":
        return "block-Jacobi preconditioned conjugate gradients (no factorisation of N)"
    if solver == "strip-pcg":
        kind = {"ssor": "symmetric block Gauss-Seidel", "jacobi": "block Jacobi"}
        preconditioner = info.preconditioner if info.preconditioner is not None else PRECONDITIONER
        text = (f"conjugate gradients preconditioned by {kind[preconditioner]} "
                "over the strips (LAPACK banded Cholesky pbtrf of each strip; no factorisation of N)")
        if info.strips is not None:
            text += f", {info.strips} strips of bandwidth {info.bandwidth}"
            if info.dense_block:
                text += f", a dense block of {info.dense_block} camera columns"
        return text
    raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(s for s in SOLVERS if s != 'auto')}")


def describe(solver, info: SolverInfo | None = None) -> dict:
    """``{"factorisation": ..., "blas": ...}`` for summary.json and the report.

    ``solver``: a concrete solver name (``AdjustmentResult.solver``) or a solver object (an
    ``auto`` solver after its first solve describes the solver it chose); ``info``: the
    ``SolveResult.info`` of its last solve (``result.history[-1].solver_info``), optional.
    Never raises for a known solver: what cannot be found is "unknown"."""
    name = getattr(solver, "name", solver)
    if name == "auto":
        raise ValueError("describe a concrete solver: 'auto' has not chosen one before its first solve")
    return {"factorisation": factorisation(name, info), "blas": blas(name)}
