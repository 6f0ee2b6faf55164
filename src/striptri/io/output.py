"""Output locations: checked before any computation, written whole or not at all, and never at the
expense of a file striptri did not write (README "Safety"; docs/decisions.md "Output safety").

A run that writes ``OUT`` goes through four steps:

1. :func:`check_output_location` (no writes): OUT is not empty, its folders can exist, its name is
   not too long, it neither is, nor lies inside, nor contains an input of the run, and if it exists
   it may be replaced (below). Every command calls this before reading or computing anything.
2. :class:`OutputReservation` (entered before the computation): missing parent folders are made,
   stale temporary entries of earlier runs killed outright (SIGKILL, power loss) are removed from
   the parent (only what striptri marked: :func:`remove_stale_temporaries`), and a temporary
   sibling folder ``.striptri-tmp-<hex>`` is created, locked (``flock``: the kernel drops the lock
   when the process dies, which is how the next run tells a stale temporary from one a live run is
   writing) and marked with ``.striptri-partial``. An unwritable folder fails here, before computing.
3. :meth:`OutputReservation.commit`: the files are written into the temporary folder together with
   the marker ``.striptri-output``, which lists every file with its size and SHA-256; then, with
   SIGINT/SIGTERM/SIGHUP held back in every thread and the parent folder locked against other
   striptri runs, the new folder and an existing OUT exchange names atomically (``renameat2``
   RENAME_EXCHANGE; a journalled pair of renames where the file system cannot), and the old one
   is deleted. At no instant is OUT missing or partial.
4. On any failure or signal (:meth:`OutputReservation.abandon`): the temporary entry and the
   parent folders made in step 2 are removed; an existing OUT is left exactly as it was.

An existing OUT may be replaced only when it is an empty folder, or a folder an earlier striptri
run wrote whose every file is listed, unchanged, in its marker's manifest; a file or folder the
user added or changed there, an older marker without a manifest, a link, or a file at OUT stop the
run with exit status 2 before anything is computed. A single-file output (``striptri structure``)
replaces an existing file only when the caller's ``owned`` test recognises it as its own output.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import functools
import hashlib
import os
import re
import shutil
import signal
import sys
import threading
import uuid
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path, PurePosixPath

from striptri.errors import InputError
from striptri.io.output_location import (  # noqa: F401  (check_output_location: the API of this module too)
    MARKER, TMP_PREFIX, _check_replaceable_file, _check_replaceable_folder, check_output_location,
)

PARTIAL = ".striptri-partial"  # inside a temporary folder until its files are complete
PARTIAL_TEXT = b"striptri: the temporary folder of a run that is writing its output\n"
PAYLOAD = "output"  # a single-file output, inside its temporary folder until it is renamed into place
OLD_PREFIX = ".striptri-old-"
SWAP_PREFIX = ".striptri-swap-"
JOURNAL_TEXT = b"striptri: swap journal; the old output waits beside it to go back to the name below\n"
NO_EXCHANGE_VARIABLE = "STRIPTRI_NO_RENAME_EXCHANGE"  # tests: take the journalled swap
_TEMP_NAME = re.compile(r"^\.striptri-(tmp|old)-[0-9a-f]{12}$")
_JOURNAL_NAME = re.compile(r"^\.striptri-swap-([0-9a-f]{12})$")
_MARKER_HEAD = (
    "Written by striptri. The next striptri run with this folder as output replaces it whole, but only\n"
    "while every file in it is one listed below, unchanged (size and SHA-256).\n"
)
_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_COMMITTED: list[Path] = []  # the outputs this process put in place
STEP_HOOK: Callable[[str], None] | None = None  # tests: called at each named step of reserve and commit


def _step(name: str) -> None:
    if STEP_HOOK is not None:
        STEP_HOOK(name)


# --------------------------------------------------------------------------- steps 2-4


class OutputReservation:
    """The output location of one run, reserved before the computation (module doc).

    Use as a context manager: leaving the block without :meth:`commit` (an error, a signal)
    abandons the reservation and leaves nothing behind::

        with OutputReservation(out, inputs=[project_dir]) as reservation:
            files = compute()
            reservation.commit(files)
    """

    def __init__(self, out, inputs: Iterable = (), kind: str = "folder",
                 owned: Callable[[Path], bool] | None = None):
        self.inputs = [i for i in inputs if i is not None]
        self.kind = kind
        self.owned = owned
        self.path = check_output_location(out, self.inputs, kind, owned)
        self._tmp: Path | None = None
        self._fd: int | None = None
        self._created: list[Path] = []
        self._staged: list[str] = []  # manifest lines of the files stage() wrote
        self.committed = False

    def __enter__(self) -> "OutputReservation":
        try:
            self.reserve()
        except BaseException:  # a signal held back during reserve() is raised at its end
            self.abandon()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.committed:
            self.abandon()

    def reserve(self) -> None:
        """Make the parent folders, remove stale temporaries of dead runs, create, lock and mark the
        temporary folder. OSError -> InputError (exit status 2), nothing left behind."""
        parent = self.path.parent
        with _signals_held():
            try:
                self._created = _make_parents(parent)
                _step("reserve:parents")
                with _folder_lock(parent):
                    remove_stale_temporaries(parent)
                    tmp = parent / f"{TMP_PREFIX}{uuid.uuid4().hex[:12]}"
                    tmp.mkdir()  # not mkdtemp: its mode 0700 would become the output folder's
                    self._tmp = tmp
                    _step("reserve:made")
                    self._fd = os.open(tmp, os.O_RDONLY | os.O_DIRECTORY)
                    _lock(self._fd)
                    write_file(tmp / PARTIAL, PARTIAL_TEXT)
                    _step("reserve:marked")
            except OSError as exc:
                self._cleanup()
                raise _output_error(exc, parent) from None
            except BaseException:
                self._cleanup()
                raise

    def stage(self, files: Mapping[str, str | bytes]) -> None:
        """Write some files of a folder output now (relative POSIX path -> text or bytes), so that a
        large output made one piece at a time (rendered images) need not be held in memory whole;
        commit() writes the rest and lists them all in the marker. A name written twice, or any
        write error, is an InputError; the reservation still leaves nothing behind."""
        if self._tmp is None or self.kind != "folder":
            raise RuntimeError("stage() of an output that is not a reserved folder")
        try:
            self._staged += _write_payload(self._tmp, {_safe_relative(n): c for n, c in files.items()})
        except OSError as exc:
            raise _output_error(exc, self.path) from None

    def commit(self, files: Mapping[str, str | bytes] | bytes) -> Path:
        """Write the files (folder: relative POSIX path -> text or bytes; file: bytes), then swap
        them in for OUT. -> the absolute OUT."""
        if self._tmp is None:
            raise RuntimeError("commit() of an output that is not reserved")
        try:
            if self.kind == "folder":
                relative = {_safe_relative(name): content for name, content in files.items()}
                _write_files(self._tmp, relative, self._staged)
                os.unlink(self._tmp / PARTIAL)  # the marker with its manifest now says whose it is
            else:
                write_file(self._tmp / PAYLOAD, bytes(files))
        except OSError as exc:
            raise _output_error(exc, self.path) from None
        _step("commit:written")
        parent = self.path.parent
        with _signals_held():
            with _folder_lock(parent):
                try:
                    if self.path.exists() or self.path.is_symlink():
                        # another run may have written OUT since the check: the same rules again
                        if self.kind == "folder":
                            _check_replaceable_folder(self.path)
                        else:
                            _check_replaceable_file(self.path, self.owned)
                    _step("swap:checked")
                    old = self._swap_in()
                except OSError as exc:
                    raise _output_error(exc, self.path) from None
            self.committed = True
            _COMMITTED.append(self.path)
            tmp_fd, self._tmp, self._fd = self._fd, None, None
            if old is not None:
                old_path, old_fd, journal = old
                _remove(old_path)
                _step("swap:old-removed")
                if journal is not None:
                    _remove(journal)
                _close(old_fd)
            _close(tmp_fd)
            _sync_folder(parent)
            _step("commit:done")
        return self.path

    def _swap_in(self):
        """Put the new output at OUT so that at every instant OUT is either the old output, whole, or
        the new one, whole (module doc). -> (what to delete, its lock fd, the swap journal) or None."""
        if self.kind == "file":
            # rename(2) replaces a file atomically; the temporary folder keeps only its mark
            os.rename(self._tmp / PAYLOAD, self.path)
            _step("swap:renamed")
            return self._tmp, None, None
        if not (self.path.exists() or self.path.is_symlink()):
            os.rename(self._tmp, self.path)
            _step("swap:renamed")
            return None
        old_fd = None
        with contextlib.suppress(OSError):  # locked, so that no other run takes the old one for stale
            old_fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY)
            with contextlib.suppress(OSError):
                fcntl.flock(old_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        try:
            if _exchange(self._tmp, self.path):
                _step("swap:exchanged")
                return self._tmp, old_fd, None
            return _journalled_swap(self._tmp, self.path, old_fd)
        except BaseException:
            _close(old_fd)
            raise

    def abandon(self) -> None:
        """Remove the temporary entry and the parent folders this run made (if still empty)."""
        with _signals_held():
            self._cleanup()

    def _cleanup(self) -> None:
        if self._tmp is not None:
            _remove(self._tmp)
            self._tmp = None
        _close(self._fd)
        self._fd = None
        for folder in reversed(self._created):
            try:
                folder.rmdir()
            except OSError:
                break
        self._created = []


def _exchange(a: Path, b: Path) -> bool:
    """Exchange two paths atomically (Linux renameat2 RENAME_EXCHANGE). -> False where the system or
    the file system cannot (the caller then swaps with a journal); other OSErrors are raised."""
    call = _renameat2()
    if call is None:
        return False
    if call(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EXDEV):
        return False
    raise OSError(err, os.strerror(err), str(b))


_AT_FDCWD, _RENAME_EXCHANGE = -100, 2


@functools.lru_cache(maxsize=1)
def _renameat2():
    if not sys.platform.startswith("linux") or os.environ.get(NO_EXCHANGE_VARIABLE):
        return None
    try:
        call = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    call.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    call.restype = ctypes.c_int
    return call


def _journalled_swap(tmp: Path, out: Path, old_fd):
    """The swap where no atomic exchange exists: a journal naming OUT is written first, then OUT is
    renamed aside and the new folder renamed in. A run killed between the two renames leaves OUT
    missing for an instant; the next run's sweep reads the journal and renames the old output back
    (remove_stale_temporaries), so the old output is never lost. -> (aside path, its lock fd, journal)."""
    token = uuid.uuid4().hex[:12]
    journal = out.parent / f"{SWAP_PREFIX}{token}"
    old = out.parent / f"{OLD_PREFIX}{token}"
    write_file(journal, JOURNAL_TEXT + os.fsencode(out.name) + b"\n")
    _step("swap:journal")
    os.rename(out, old)
    _step("swap:aside")
    try:
        os.rename(tmp, out)
    except BaseException:
        os.rename(old, out)
        _remove(journal)
        raise
    _step("swap:renamed")
    return old, old_fd, journal


def write_output_folder(out_dir, files: Mapping[str, str | bytes], inputs: Iterable = ()) -> Path:
    """Check, reserve and write ``files`` as the folder out_dir in one go (module doc)."""
    with OutputReservation(out_dir, inputs) as reservation:
        return reservation.commit(files)


def committed_outputs() -> list[Path]:
    """The outputs this process has put in place (for the message of a signal that arrives after)."""
    return list(_COMMITTED)


def remove_stale_temporaries(folder: Path) -> list[str]:
    """Clean up after runs killed outright (SIGKILL, power loss) in ``folder``: -> the names removed.

    * A swap journal ``.striptri-swap-<hex>`` (recognised by its first line) whose run died between
      its two renames: the old output ``.striptri-old-<hex>`` goes back to the name the journal gives
      when nothing is there, and is deleted only when the new output stands in its place.
    * A ``.striptri-tmp-*`` / ``.striptri-old-*`` folder that no live process holds locked (the kernel
      drops a dead process's locks) and that striptri made, as its marker shows: the partial marker
      with striptri's text, or an output marker with its manifest head; or an empty folder (rmdir,
      which cannot delete anything). A file, a link or a folder with anything else in it is never
      touched, whatever its name.
    """
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _JOURNAL_NAME.match(entry.name)
        if match and entry.is_file(follow_symlinks=False) and _is_journal(Path(entry.path)):
            removed += _recover_swap(Path(folder), Path(entry.path), match.group(1))
    for entry in entries:
        if not _TEMP_NAME.match(entry.name) or not os.path.isdir(entry.path) or os.path.islink(entry.path):
            continue
        path = Path(entry.path)
        try:
            fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                    continue  # a live run holds it
            if not _made_by_striptri(path):
                with contextlib.suppress(OSError):  # a run killed between mkdir and its mark: rmdir
                    os.rmdir(path)                  # takes an empty folder only, so it loses nothing
                    removed.append(entry.name)
                continue
            if entry.name.startswith(OLD_PREFIX) and (folder / f"{SWAP_PREFIX}{entry.name[len(OLD_PREFIX):]}").exists():
                continue  # its journal still names where it belongs
            _remove(path)
            removed.append(entry.name)
        finally:
            _close(fd)
    return removed


def _is_journal(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(JOURNAL_TEXT)) == JOURNAL_TEXT
    except OSError:
        return False


def _recover_swap(folder: Path, journal: Path, token: str) -> list[str]:
    """Finish or undo the swap of a run that died between its renames (remove_stale_temporaries)."""
    try:
        name = os.fsdecode(journal.read_bytes()[len(JOURNAL_TEXT):].rstrip(b"\n"))
    except OSError:
        return []
    if not name or "/" in name or name in (".", ".."):
        return []
    old, target = folder / f"{OLD_PREFIX}{token}", folder / name
    fd = None
    with contextlib.suppress(OSError):
        fd = os.open(old, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                    return []  # the run is alive and finishing its swap
            if not _made_by_striptri(old):
                return []
            if os.path.lexists(target):
                _remove(old)  # the new output is in place: the old one may go
            else:
                os.rename(old, target)  # the run died between the renames: the old output comes back
        _remove(journal)
        return [journal.name]
    except OSError:
        return []
    finally:
        _close(fd)


def _made_by_striptri(folder: Path) -> bool:
    """A folder striptri made: its partial marker with striptri's text, or an output marker."""
    for name, head in ((PARTIAL, PARTIAL_TEXT), (MARKER, _MARKER_HEAD.encode())):
        path = folder / name
        try:
            if path.is_symlink() or not path.is_file():
                continue
            with open(path, "rb") as f:
                if f.read(len(head)) == head:
                    return True
        except OSError:
            continue
    return False


# --------------------------------------------------------------------------- helpers


def _safe_relative(name: str) -> PurePosixPath:
    """A relative path inside the output folder (no absolute paths, no '..', not the marker)."""
    path = PurePosixPath(name)
    if path.is_absolute() or not path.parts or ".." in path.parts or str(path) in (MARKER, PARTIAL):
        raise ValueError(f"output file name {name!r} is not a plain relative path inside the folder")
    return path


def _make_parents(parent: Path) -> list[Path]:
    """Create parent and its missing ancestors; -> the folders created, outermost first."""
    missing = []
    probe = parent
    while not probe.exists():
        missing.append(probe)
        probe = probe.parent
    created = []
    try:
        for folder in reversed(missing):
            folder.mkdir()
            created.append(folder)
    except OSError:
        for folder in reversed(created):
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return created


def _write_files(folder: Path, files: Mapping[PurePosixPath, str | bytes], staged: Iterable[str] = ()) -> None:
    """Write every file, then the marker with the manifest of them all (and of those staged before)."""
    lines = [*staged, *_write_payload(folder, files)]
    write_file(folder / MARKER, (_MARKER_HEAD + "files (sha256 size path):\n" + "\n".join(lines) + "\n").encode())


def _write_payload(folder: Path, files: Mapping[PurePosixPath, str | bytes]) -> list[str]:
    """Write the files; -> their manifest lines (sha256 size path)."""
    lines = []
    for name, content in files.items():
        target = folder.joinpath(*name.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        data = content.encode("utf-8") if isinstance(content, str) else bytes(content)
        write_file(target, data)
        lines.append(f"{hashlib.sha256(data).hexdigest()} {len(data)} {name}")
    return lines


def write_file(path: Path, data: bytes) -> None:
    """Create ``path`` (it must not exist), write data and flush it to the disk."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        _write_fd(fd, data)
    finally:
        os.close(fd)


def _write_fd(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]
    os.fsync(fd)


def _output_error(exc: OSError, where: Path) -> InputError:
    """An OSError while preparing or writing the output, as the user's problem (exit status 2)."""
    name = str(exc.filename) if exc.filename else str(where)
    name = re.sub(r"\.striptri-(tmp|old)-[0-9a-f]{12}(\.[A-Za-z0-9]+)?", lambda m: "", name).rstrip("/") or str(where)
    reason = exc.strerror or str(exc)
    hints = {
        errno.ENOSPC: " (the disk is full)",
        errno.EDQUOT: " (your disk quota is used up)",
        errno.EFBIG: " (a file-size limit was reached)",
        errno.EROFS: " (the file system is read-only)",
        errno.EACCES: " (no permission to write there)",
        errno.EPERM: " (no permission to write there)",
        errno.ENAMETOOLONG: " (a name is too long)",
    }
    return InputError(where, None, f"cannot write the output: {reason}{hints.get(exc.errno, '')} "
                                   f"({name}); nothing was written")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _close(fd: int | None) -> None:
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)


def _lock(fd: int) -> None:
    with contextlib.suppress(OSError):  # file systems without flock: no stale detection, still correct
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _sync_folder(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Exclusive among striptri runs: creating, swapping and cleaning up in ``folder``."""
    fd = None
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        yield
    finally:
        _close(fd)


@contextlib.contextmanager
def _signals_held():
    """Hold SIGINT, SIGTERM and SIGHUP back while the file system is between two consistent states;
    they take effect when the block ends, in the order they came.

    A signal sent to the process goes to any thread that does not block it: BLAS, tqdm and executor
    threads, not only the main one. So the block masks the signals in this thread and, in the main
    thread, puts a handler in place for the whole process (signal dispositions are per process)
    that only notes them; that handler runs in the main thread, which is inside this block."""
    noted: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in _HELD_SIGNALS:
            handler = signal.getsignal(sig)
            if handler is None or handler is signal.SIG_IGN:
                continue  # installed outside Python, or ignored: leave it
            with contextlib.suppress(OSError, ValueError):
                signal.signal(sig, lambda signum, frame: noted.append(signum))
                previous[sig] = handler
    try:
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD_SIGNALS)
    except (OSError, ValueError):  # pragma: no cover - platforms without pthread_sigmask
        mask = None
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # pending ones now reach the noting handler
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in noted:
            signal.raise_signal(sig)
