"""Will a direct factor of N fit in memory? Estimated from N's pattern before factorising (auto).

The estimate of the entries of the sparse Cholesky factor L (nested-dissection ordering) is

    nnz(L) ~ max(nnz(N), min(n (w + 1), nnz(N) (ND_SLOPE log2 n + ND_INTERCEPT)))

with nnz(N) the stored entries of the whole symmetric N, n its columns and w the bandwidth of its
photo part in the adjustment's order (strip after strip):

* ``nnz(N) (a log2 n + b)``: nested dissection of a block, a 2-D mesh of photos, fills like
  ``n log n`` (George 1973). a, b are fitted to CHOLMOD's supernodal factor (NESDIS) of the
  benchmark blocks (docs/solvers.md, "strip-pcg"): nnz(L) / nnz(N) = 2.17, 3.18, 4.03 at
  1,000, 5,000 and 20,000 photos (6,000, 30,000, 120,000 columns);
* ``n (w + 1)``: the band of the order as it is, an upper bound for a strip-like N (a long strip:
  n x 18), which nested dissection does not beat by much;
* ``nnz(N)``: L holds at least N's lower half, and on a strip CHOLMOD's L is as large as N
  (10,000-photo strip: 1.81 million entries for 1.80 million in N).

Bytes per entry of L (:data:`BYTES_PER_ENTRY`), from the peak memory of the factorisations of the
20,000-photo block (docs/solvers.md, "Factorisations of real normal matrices": 600, 941 and 2412 MB
for 43 million entries): cholmod 14, cvxopt 22, sparse (SuperLU: L and U, a worse ordering) 56;
rounded up. banded: exactly ``8 (w + 1) k``.

The budget (:func:`memory_budget`): the environment variable ``STRIPTRI_MEMORY_BUDGET`` (bytes, or
with a suffix K, M, G: ``"2G"``), else :data:`MEMORY_BUDGET` when set (tests), else the kernel's
``MemAvailable`` (/proc/meminfo). A direct factor is taken while its estimate is at most
:data:`FACTOR_SHARE` of the budget (the rest is for N, the assembly and the solver's work).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import os

import scipy.sparse as sp

ND_SLOPE, ND_INTERCEPT = 0.430, -3.23  # nnz(L) / nnz(N) against log2(n), fitted (module doc)
BYTES_PER_ENTRY = {"cholmod": 16, "cvxopt": 24, "sparse": 60, "banded": 8, "dense": 8}
FACTOR_SHARE = 0.5
MEMORY_BUDGET: int | None = None  # bytes; overrides MemAvailable (not the environment variable)
ENVIRONMENT = "STRIPTRI_MEMORY_BUDGET"
_SUFFIX = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def factor_entries(N: sp.spmatrix, bandwidth: int) -> float:
    """Estimated entries of a sparse Cholesky factor of N (module doc); ``bandwidth``: of N's
    photo part in its own order."""
    n, nnz = N.shape[0], N.nnz
    if n == 0:
        return 0.0
    nested = nnz * (ND_SLOPE * math.log2(max(n, 2)) + ND_INTERCEPT)
    return float(max(nnz, min(n * (bandwidth + 1.0), nested)))


def factor_bytes(N: sp.spmatrix, bandwidth: int, solver: str) -> float:
    """Estimated memory of the factor of N made by ``solver`` (cholmod, cvxopt, sparse, dense)."""
    if solver == "dense":
        return 8.0 * N.shape[0] ** 2
    return BYTES_PER_ENTRY[solver] * factor_entries(N, bandwidth)


def parse_bytes(text: str) -> int:
    """'2G' -> 2147483648; '500M', '123456' (bytes)."""
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    unit = t[-1:] if t[-1:] in _SUFFIX and not t[-1:].isdigit() else ""
    number = t[: len(t) - len(unit)]
    try:
        value = float(number) * _SUFFIX[unit]
    except ValueError:
        raise ValueError(f"{ENVIRONMENT}: not a size in bytes: {text!r} (e.g. 2G, 500M, 123456)") from None
    if not value > 0:
        raise ValueError(f"{ENVIRONMENT} must be positive, not {text!r}")
    return int(value)


def available_memory() -> int | None:
    """MemAvailable of /proc/meminfo in bytes (None where there is no such file)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def memory_budget() -> int | None:
    """The memory a solve may use (module doc); None when unknown (then everything fits)."""
    text = os.environ.get(ENVIRONMENT)
    if text:
        return parse_bytes(text)
    if MEMORY_BUDGET is not None:
        return int(MEMORY_BUDGET)
    return available_memory()


def fits(estimate_bytes: float, budget: int | None = None) -> bool:
    """True when a factor of ``estimate_bytes`` fits FACTOR_SHARE of the budget."""
    budget = memory_budget() if budget is None else budget
    return budget is None or estimate_bytes <= FACTOR_SHARE * budget


@functools.cache
def _libc_function(name: str, argtypes: tuple, restype):
    """The C library's function ``name`` (glibc's malloc_trim, mallopt), or None (another C library,
    or none found)."""
    try:
        function = getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None
    function.argtypes, function.restype = list(argtypes), restype
    return function


def _malloc_trim():
    """glibc's malloc_trim, or None."""
    return _libc_function("malloc_trim", (ctypes.c_size_t,), ctypes.c_int)


# A library run of fewer plate measurements is small: its peaks of memory are not at stake, so the
# conditions method does not trim around its assemblies (conditions_method.adjust.TRIM_FROM). The
# command keeps the pages it frees at every size (keep_freed_memory) and then trims only between
# its phases (docs/decisions.md "Freed pages kept at every size")
SMALL_RUN_MEASUREMENTS = 50_000

# glibc's mallopt parameters (malloc.h) and what keep_freed_memory sets them to
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_MMAP_MAX = -1, -3, -4
KEPT_MMAP_THRESHOLD = 32 * 2**20  # the largest glibc takes (DEFAULT_MMAP_THRESHOLD_MAX, 64-bit)
KEPT_TRIM_THRESHOLD = 2**30
KEPT_MMAP_MAX = 0  # no array mapped by itself: the largest ones too come from the heap and go back to it
USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES")
_kept: list[bool] = []  # [True] once keep_freed_memory has set the thresholds in this process


def keep_freed_memory() -> bool:
    """Let this process keep the C heap's freed pages for its next allocations (glibc's
    ``mallopt``: the mmap threshold at its largest, 32 MB, the trim threshold at 1 GB, and no
    allocation mapped by itself), for the rest of the process; give_back_free_memory still hands
    them back where called. For a command run (pipeline.run_adjust), whose sweeps allocate and free
    the same arrays again and again: with glibc's own thresholds the top of the heap was handed
    back after each of them and its pages came back zeroed by the kernel (page faults;
    docs/decisions.md "Freed pages kept in a small run", "Freed pages kept at every size"). The
    threshold of mmap is set with the one of trimming: a trim threshold alone would fix the mmap
    threshold at its start value, 128 kB, and map every larger array anew. Arrays above 32 MB (N,
    the factors, the selected inverse and its factor) come from the heap too, so that each one's
    pages serve the next instead of being unmapped and faulted in again (docs/decisions.md "The
    largest arrays from the heap too"). A MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_,
    MALLOC_MMAP_MAX_ or GLIBC_TUNABLES in the environment is the user's choice and is left alone.
    True when set (glibc), else False."""
    if any(os.environ.get(name) for name in USER_SETTINGS):
        return False
    mallopt = _libc_function("mallopt", (ctypes.c_int, ctypes.c_int), ctypes.c_int)
    if mallopt is None:
        return False
    kept = (bool(mallopt(M_MMAP_THRESHOLD, KEPT_MMAP_THRESHOLD))
            and bool(mallopt(M_TRIM_THRESHOLD, KEPT_TRIM_THRESHOLD))
            and bool(mallopt(M_MMAP_MAX, KEPT_MMAP_MAX)))
    if kept and not _kept:
        _kept.append(True)
    return kept


def keeps_freed_memory() -> bool:
    """Whether keep_freed_memory has set this process's thresholds: its sweeps then reuse the
    pages they free, and trimming between them would only hand those pages back to be zeroed
    anew (conditions_method.adjust)."""
    return bool(_kept)


def give_back_free_memory() -> None:
    """Hand the free pages of the C heap back to the system (glibc's ``malloc_trim(0)``; nothing
    elsewhere), between phases whose temporaries are gone.

    numpy's arrays below glibc's mmap threshold (which grows to 32 MB as large arrays are freed) come
    from the heap, and each chunk thread allocates from an arena of its own. What a phase frees stays
    resident there: the next phase, allocating from another arena or in other sizes, cannot reuse
    it, and the process's peak resident set counts it. Trimming all arenas between the phases
    (a few milliseconds) keeps that out of the peak (docs/decisions.md "Free memory handed back")."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


# warm_heap: a command run of an early-read project touches this many bytes of heap per byte of its
# image_points.csv while it waits for the reader (about 210 MB at 5,000 photos, whose run holds
# 400 MB), at most WARM_MAX_BYTES (below KEPT_TRIM_THRESHOLD: the freed block stays in the heap), a
# chunk of pages at a time. The reader holds about 12 bytes per byte of its own meanwhile: with 30,
# the two together made the run's peak at 5,000 photos (445 against 420-430 MiB later in the run;
# docs/decisions.md "The heap warmed while the project is read")
WARM_BYTES_PER_INPUT_BYTE = 22
WARM_MAX_BYTES = 512 * 2**20
WARM_CHUNK_BYTES = 8 * 2**20
PAGE_BYTES = 4096


def warm_heap(budget: int, stop=lambda: False) -> int:
    """Touch up to ``budget`` bytes of new heap pages, a chunk at a time until ``stop()`` is true, and
    free them again, in a process that keeps its freed pages (keep_freed_memory; else nothing):
    the heap keeps them, faulted in, for the run's first allocations (docs/decisions.md "The heap
    warmed while the project is read"). For the idle time of the command while the early reader
    (io.early_read) reads the project: a page touched first costs 4-8 microseconds in this VM,
    and the run takes its heap's pages in the iterations, on the chunk threads' critical path.
    Returns the bytes touched."""
    if not keeps_freed_memory() or budget <= 0:
        return 0
    import numpy as np

    try:
        block = np.empty(int(budget), dtype=np.uint8)  # address space only, until touched
    except MemoryError:  # a limit on the address space: the run is not to fail for a warm-up
        return 0
    touched = 0
    while touched < len(block) and not stop():
        block[touched: touched + WARM_CHUNK_BYTES: PAGE_BYTES] = 0
        touched = min(touched + WARM_CHUNK_BYTES, len(block))
    del block
    return touched
