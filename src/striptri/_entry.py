"""The ``striptri`` console script. It puts the signal handling in place before numpy, scipy and
matplotlib are imported, so that SIGINT, SIGTERM or SIGHUP in the first second of a run (while the
command is still loading) also end with one message and no traceback; ``striptri.cli`` takes over
once loaded (cli.reports_errors)."""

from __future__ import annotations

import signal
import sys
from typing import NoReturn

from striptri.errors import Interrupted, deferred_while_importing


def _raise_interrupted(signum, frame):
    if deferred_while_importing(signum, frame):  # raised once the import has ended
        return
    raise Interrupted(signum)


def main() -> None:
    # SIGINT too as Interrupted, not KeyboardInterrupt: click would turn one that comes after the
    # command's own handling into "Aborted!" and exit status 1
    try:  # from the first handler on, every Interrupted is inside this block
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
            signal.signal(sig, _raise_interrupted)
        one_malloc_arena()  # before any thread (OpenBLAS's start with numpy)
        defer_unused_numpy_modules()
        from striptri.io import early_read

        early_read.start(sys.argv[1:])  # the project read by a child while the rest loads (adjust)
        from striptri.cli import main as command
    except KeyboardInterrupt:
        _stop(signal.SIGINT)
    except Interrupted as exc:
        _stop(exc.signum)
    try:
        command()
    except KeyboardInterrupt:  # after the command's own handling ended (cli.reports_errors)
        _stop(signal.SIGINT, starting=False)
    except Interrupted as exc:
        _stop(exc.signum, starting=False)
    except SystemExit as exc:  # the command has ended (click exits with its status)
        if sys.gettrace() is None and sys.getprofile() is None:
            leave(exc.code)
        raise  # under a profiler or a coverage tracer, which write their data at the normal exit


def leave(code) -> NoReturn:
    """End the process with the status of ``sys.exit(code)`` once the command has ended: the
    exit handlers run and the standard streams are flushed as at a normal exit, but the
    interpreter's teardown of every module and object is left to the end of the process, which
    gives the memory back at once (that teardown took 0.06-0.1 s after the close-range block and
    after 5,000 photos, with numpy, scipy and the results loaded). Every file of the run is
    complete and closed by then (the output's commit), and the drawing worker has been stopped;
    threads still alive are idle pool threads. For the console script only: a caller of
    ``striptri.cli.main`` keeps its interpreter, and so does a command run under a profiler or
    a tracer (``python -m cProfile -m striptri``, coverage), whose data are written at the
    interpreter's exit."""
    import atexit
    import os

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message"): printed, status 1
        sys.stderr.write(f"{code}\n")
        status = 1
    try:
        atexit._run_exitfuncs()  # noqa: SLF001 - what the interpreter would run now (logging's flush, finalizers)
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed pipe: nothing more can be said there
                pass
        os._exit(status & 0xFF)  # as the operating system takes sys.exit(status)


DEFERRED = ("numpy.f2py", "numpy.testing")


def defer_unused_numpy_modules() -> list[str]:
    """Load numpy.f2py and numpy.testing only when first used (importlib.util.LazyLoader).

    scipy 1.17's array API layer copies numpy's whole namespace when scipy.linalg is imported
    (``array_api_compat._internal.clone_module``: ``hasattr(numpy, name)`` for every name of
    ``dir(numpy)``), which imports numpy's lazily loaded submodules: f2py (with charset_normalizer)
    and testing cost 0.08-0.1 s of every command's start, and a run uses neither. Registered lazy,
    they are bound by that copy without being executed; any later use loads them in full. For the
    console script only (before numpy's first import by striptri): a library caller's imports are
    the caller's. Best effort: anything unexpected leaves numpy as it is. Returns the names
    deferred."""
    import importlib.util

    deferred = []
    try:
        import numpy
    except ImportError:  # pragma: no cover - numpy is a dependency
        return deferred
    for name in DEFERRED:
        if name in sys.modules:
            continue
        try:
            spec = importlib.util.find_spec(name)
            if spec is None or spec.loader is None:
                continue
            spec.loader = importlib.util.LazyLoader(spec.loader)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
            # bound on numpy too: "import numpy.testing as testing" in numpy's own __getattr__ reads
            # the attribute, which must not call __getattr__ again
            setattr(numpy, name.rpartition(".")[2], module)
        except (ImportError, AttributeError, ValueError):  # pragma: no cover - left as numpy has it
            sys.modules.pop(name, None)
            continue
        deferred.append(name)
    return deferred


M_ARENA_MAX = -8  # glibc's mallopt parameter (malloc.h)


def one_malloc_arena() -> bool:
    """The C heap of this process in one arena (glibc's ``mallopt(M_ARENA_MAX, 1)``): the threads of
    a sweep then allocate from the main arena instead of each from its own, where what a chunk
    frees stays resident for the peak until the next trim (docs/decisions.md "One malloc arena for
    the command"). For the command's own process, before its first thread; a MALLOC_ARENA_MAX in
    the environment is the user's choice and is left alone. True when set (glibc), else False."""
    import os

    if os.environ.get("MALLOC_ARENA_MAX"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(ctypes.c_int(M_ARENA_MAX), ctypes.c_int(1)))
    except (OSError, AttributeError):  # not glibc
        return False


def _stop(signum: int, starting: bool = True) -> None:
    name = signal.Signals(signum).name
    if starting:
        sys.stderr.write(f"striptri: error: interrupted ({name}) while starting; nothing was written\n")
    else:
        from striptri.io.output import committed_outputs

        written = committed_outputs()
        where = (f"{written[-1]} holds this run's whole result" if written else "no output was left half-written")
        sys.stderr.write(f"striptri: error: interrupted ({name}) as the command ended; {where}\n")
    sys.exit(128 + signum)
