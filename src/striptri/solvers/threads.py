"""BLAS threads set by striptri, not by the environment a user happens to have (issue 26).

A user's default environment lets OpenBLAS spread every dense product over all cores. Most of
striptri's dense work is batches of small matrices (3x3 to 60x60 per point or group, matrix
products of a few hundred rows): there the threads only synchronise, and on a 2-core machine the
5,000-photo block took 2.7 times as long without ``OPENBLAS_NUM_THREADS=1`` as with it
(docs/benchmarks.md "BLAS threads"). So every command runs with one BLAS thread
(:func:`single_threaded`), and only the sparse factorisation, whose supernodes are large dense
blocks, may take more (:func:`factorisation_threads`) where measurement shows it pays: the number
is ``STRIPTRI_THREADS`` when set, else FACTORISATION_THREADS.

threadpoolctl finds every BLAS and OpenMP runtime loaded in the process (numpy's OpenBLAS,
Debian's OpenBLAS under CHOLMOD, cvxopt's) and sets their thread counts for the block.
"""

from __future__ import annotations

import contextlib
import os

THREADS_VARIABLE = "STRIPTRI_THREADS"
FACTORISATION_THREADS = 1  # measured: docs/benchmarks.md "BLAS threads" (2 threads did not pay on 2 cores)


def available_cores() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):  # pragma: no cover - platforms without affinity
        return max(os.cpu_count() or 1, 1)


def requested_threads() -> int | None:
    """STRIPTRI_THREADS as a number of threads (None when unset or not a positive integer)."""
    text = os.environ.get(THREADS_VARIABLE, "").strip()
    if not text:
        return None
    try:
        n = int(text)
    except ValueError:
        return None
    return n if n > 0 else None


@contextlib.contextmanager
def single_threaded():
    """One BLAS (and OpenMP) thread for the block: striptri's small dense kernels."""
    with _limits(1):
        yield


@contextlib.contextmanager
def factorisation_threads():
    """The BLAS threads of a sparse factorisation: STRIPTRI_THREADS, else FACTORISATION_THREADS."""
    n = requested_threads() or FACTORISATION_THREADS
    with _limits(min(n, available_cores())):
        yield


@contextlib.contextmanager
def _limits(n: int):
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; without it the environment decides
        yield
        return
    with threadpool_limits(limits=n, user_api="blas"):
        yield
