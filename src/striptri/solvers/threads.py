"""BLAS threads set by striptri, not by the environment a user happens to have (issue 26).

A user's default environment lets OpenBLAS spread every dense product over all cores. Most of
striptri's dense work is batches of small matrices (3x3 to 60x60 per point or group, matrix
products of a few hundred rows): there the threads only synchronise, and on a 2-core machine the
5,000-photo block took 2.7 times as long without ``OPENBLAS_NUM_THREADS=1`` as with it
(docs/benchmarks.md "BLAS threads"). So every command runs with one BLAS thread
(:func:`single_threaded`), and only the sparse factorisation, whose supernodes are large dense
blocks, may take more (:func:`factorisation_threads`) where measurement shows it pays: the number
is ``STRIPTRI_FACTORISATION_THREADS`` when set, else FACTORISATION_THREADS (one: on 2 cores a
second thread made the factorisations of a 5,000-photo block 2.2x and of a 20,000-photo block 2.4x
slower), and never more than ``--threads`` or ``STRIPTRI_THREADS`` allow.

The cores themselves are used by threads over the chunks of a sweep (the linearisation and
whitening of the condition groups, parallel.map_ordered): :func:`chunk_threads`, every core unless
``--threads`` (:func:`use_threads`) or ``STRIPTRI_THREADS`` says fewer. Each thread runs its
numpy kernels with one BLAS thread, so the cores are never oversubscribed.

threadpoolctl finds every BLAS and OpenMP runtime loaded in the process (numpy's OpenBLAS,
Debian's OpenBLAS under CHOLMOD, cvxopt's) and sets their thread counts for the block.
"""

from __future__ import annotations

import contextlib
import os

THREADS_VARIABLE = "STRIPTRI_THREADS"
FACTORISATION_VARIABLE = "STRIPTRI_FACTORISATION_THREADS"
FACTORISATION_THREADS = 1  # measured: docs/decisions.md "BLAS threads" (2 threads cost 2.2-2.4x on 2 cores)


def available_cores() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):  # pragma: no cover - platforms without affinity
        return max(os.cpu_count() or 1, 1)


_CHOSEN: list[int] = []  # the threads a command was given (--threads, use_threads), innermost last


@contextlib.contextmanager
def use_threads(n: int | None):
    """The number of threads for the block (the command's ``--threads``; None: the environment's)."""
    if n is not None and n < 1:
        raise ValueError(f"the number of threads must be at least 1, not {n}")
    if n is None:
        yield
        return
    _CHOSEN.append(int(n))
    try:
        yield
    finally:
        _CHOSEN.pop()


def requested_threads() -> int | None:
    """The threads asked for: ``--threads`` (use_threads), else STRIPTRI_THREADS as a number (None
    when neither is given or the variable is not a positive integer)."""
    if _CHOSEN:
        return _CHOSEN[-1]
    return _variable(THREADS_VARIABLE)


def _variable(name: str) -> int | None:
    """The environment variable ``name`` as a positive integer, else None."""
    text = os.environ.get(name, "").strip()
    try:
        n = int(text)
    except ValueError:
        return None
    return n if n > 0 else None


_ACTIVE: list[list] = []  # per active single_threaded block: the limits put on libraries loaded inside it


@contextlib.contextmanager
def single_threaded():
    """One BLAS thread for the block: striptri's small dense kernels. A BLAS loaded later inside
    the block (Debian's OpenBLAS under CHOLMOD comes with scikit-sparse, imported at the first
    solve) gets the same limit from :func:`limit_new_libraries`; all are restored at the end."""
    later: list = []
    _ACTIVE.append(later)
    try:
        with _limits(1):
            try:
                yield
            finally:  # the later limits first: each restores what it found, inside the outer one
                for limiter in reversed(later):
                    limiter.restore_original_limits()
    finally:
        _ACTIVE.pop()


def limit_new_libraries() -> None:
    """Called after a module that loads a BLAS of its own is imported: inside a single_threaded
    block, that BLAS gets one thread too (threadpoolctl limits only what is loaded when it is
    called; measured: without this the plain environment ran the 5,000-photo block 10 % slower)."""
    if not _ACTIVE:
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency
        return
    _ACTIVE[-1].append(threadpool_limits(limits=1, user_api="blas"))


# A sweep whose groups hold fewer ray pairs than this runs its chunks in the caller's thread: 4,096
# groups of three rays. The work of a group (its whitening, its blocks of N) grows like k^2.
PARALLEL_MIN_RAY_PAIRS = 4096 * 9


def chunk_threads(pairs: int | None = None) -> int:
    """Threads over the chunks of a sweep whose groups hold ``pairs`` ray pairs (the sum of k^2 over
    its groups of k rays, equations.groups.sweep_size): the threads asked for, else every core (at
    most the cores); one below PARALLEL_MIN_RAY_PAIRS,
    where a chunk's numpy work is too small to release the GIL for long and the threads would only
    take turns (every test project). The 150 targets of 30 to 93 rays of the close-range benchmark
    are above it (652,000 pairs): their whitening and products are large BLAS calls."""
    if pairs is not None and pairs < PARALLEL_MIN_RAY_PAIRS:
        return 1
    return min(requested_threads() or available_cores(), available_cores())


@contextlib.contextmanager
def factorisation_threads():
    """The BLAS threads of a sparse factorisation (:func:`factorisation_thread_count`)."""
    with _limits(factorisation_thread_count()):
        yield


def factorisation_thread_count() -> int:
    """STRIPTRI_FACTORISATION_THREADS, else FACTORISATION_THREADS; at most the threads asked for
    (``--threads``, STRIPTRI_THREADS) and the cores. ``--threads 2`` asks for at most two threads,
    not for a second BLAS thread where it was measured to lose."""
    n = _variable(FACTORISATION_VARIABLE) or FACTORISATION_THREADS
    return max(min(n, requested_threads() or n, available_cores()), 1)


@contextlib.contextmanager
def _limits(n: int):
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; without it the environment decides
        yield
        return
    with threadpool_limits(limits=n, user_api="blas"):
        yield
