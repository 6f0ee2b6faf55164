"""The project read by a second process while the command loads (issue 29; docs/decisions.md "The
project read while the command loads").

``striptri adjust DIR ...`` first imports scipy and the rest of striptri (0.3-0.4 s) and then reads
the project (0.4 s at 5,000 photos, 1.9 s at 20,000), both on one core. The console script
(striptri._entry) calls :func:`start` once numpy and this package are imported, before the rest:
when DIR's image_points.csv holds at least EARLY_READ_BYTES, a forked child reads the project with
the same code (project_reader.read_project) and sends it back pickled through a pipe, while the
command goes on loading. The pipeline takes it (:func:`take`) where it would have read the
project, after checking the output location as before.

The child writes no file. Its result is used only when it read that folder and succeeded: on bad
input, an interruption or a crash of the child, the command reads the project itself and so says
exactly what it always said. Linux only (a fork before the command starts any thread); the
library, and other platforms, read as before.
"""

from __future__ import annotations

import atexit
import os
import pickle
import signal
import sys

# image_points.csv sizes from which the project is read early: below (about 40,000 measurements)
# the read takes less than the fork and the pickle's round trip gain
EARLY_READ_BYTES = 2 * 2**20

_pending: list = []  # (the folder's absolute path, the child's pid, the pipe's read end)


def start(argv: list[str]) -> bool:
    """Fork the reader for ``adjust DIR ...`` (``argv``: the command's arguments after the program),
    DIR its first argument when that is not an option. True when a reader runs."""
    if _pending or len(argv) < 2 or argv[0] != "adjust" or argv[1].startswith("-"):
        return False
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    folder = argv[1]
    try:
        if os.stat(os.path.join(folder, "image_points.csv")).st_size < EARLY_READ_BYTES:
            return False
        read_end, write_end = os.pipe()
    except (OSError, ValueError):
        return False
    try:
        pid = os.fork()
    except OSError:
        os.close(read_end)
        os.close(write_end)
        return False
    if pid == 0:  # pragma: no cover - the child (tests/test_early_read.py runs it in a subprocess)
        _read_and_send(folder, read_end, write_end)
    os.close(write_end)
    _pending.append((os.path.abspath(folder), pid, read_end))
    atexit.register(discard)
    return True


def _read_and_send(folder: str, read_end: int, write_end: int) -> None:  # pragma: no cover - in the child
    """The child: read, send the pickled project, end without the parent's exit handlers; on any
    failure send nothing (the command then reads the project itself)."""
    status = 1
    try:
        os.close(read_end)
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # the command gone: end at once
        from .project_reader import read_project

        data = pickle.dumps(read_project(folder), protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(data)
        status = 0
    except BaseException:  # noqa: BLE001 - bad input, an interruption: the command reads itself
        pass
    finally:
        os._exit(status)


def waiting_for(folder) -> bool:
    """Whether a reader for ``folder`` runs and has not sent the project yet (its pipe is empty)."""
    if not _pending or os.path.abspath(os.fspath(folder)) != _pending[-1][0]:
        return False
    return not ready()


def ready() -> bool:
    """Whether the reader has ended or its project can be read from the pipe (no reader: True)."""
    if not _pending:
        return True
    import select

    try:
        readable, _, _ = select.select([_pending[-1][2]], [], [], 0)
    except (OSError, ValueError):
        return True
    return bool(readable)


def take(folder) -> object | None:
    """The project the reader read for ``folder`` (waiting for it), or None: no reader ran for
    it, or it failed (the caller then reads the project itself)."""
    if not _pending:
        return None
    where, pid, read_end = _pending.pop()
    try:
        if os.path.abspath(os.fspath(folder)) != where:
            return None
        with os.fdopen(read_end, "rb") as pipe:
            read_end = None
            data = pipe.read()
        _, status = os.waitpid(pid, 0)
        pid = None
        if status != 0 or not data:
            return None
        return pickle.loads(data)
    except Exception:  # noqa: BLE001 - whatever went wrong, the caller reads the project itself
        return None
    finally:
        _end(pid, read_end)


def discard() -> None:
    """Stop a reader that was not taken (the command ended before it read the project)."""
    while _pending:
        _, pid, read_end = _pending.pop()
        _end(pid, read_end)


def _end(pid: int | None, read_end: int | None) -> None:
    if read_end is not None:
        try:
            os.close(read_end)
        except OSError:
            pass
    if pid is not None:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (OSError, ChildProcessError):
            pass
