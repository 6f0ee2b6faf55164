"""Output locations: checked before any computation, written whole or not at all, and never at the
expense of a file striptri did not write (README "Safety"; docs/decisions.md "Output safety").

A run that writes ``OUT`` goes through four steps:

1. :func:`check_output_location` (no writes): OUT is not empty, its folders can exist, its name is
   not too long, it neither is, nor lies inside, nor contains an input of the run, and if it exists
   it may be replaced (below). Every command calls this before reading or computing anything.
2. :class:`OutputReservation` (entered before the computation): missing parent folders are made,
   stale temporary entries of earlier runs killed outright (SIGKILL, power loss) are removed from
   the parent, and a temporary sibling ``.striptri-tmp-<hex>`` is created and locked (``flock``:
   the kernel drops the lock when the process dies, which is how the next run tells a stale
   temporary from one a live run is writing). An unwritable folder fails here, before computing.
3. :meth:`OutputReservation.commit`: the files are written into the temporary folder together with
   the marker ``.striptri-output``, which lists every file with its size and SHA-256; then, with
   SIGINT/SIGTERM/SIGHUP held back and the parent folder locked against other striptri runs, an
   existing OUT is renamed aside (``.striptri-old-<hex>``), the new folder renamed to OUT and the
   old one deleted.
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
import errno
import fcntl
import hashlib
import os
import re
import shutil
import signal
import uuid
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path, PurePosixPath

from striptri.errors import InputError

MARKER = ".striptri-output"
PARTIAL = ".striptri-partial"  # inside a temporary folder until its files are complete
TMP_PREFIX = ".striptri-tmp-"
OLD_PREFIX = ".striptri-old-"
_STALE_NAME = re.compile(r"^\.striptri-(tmp|old)-[0-9a-f]{12}(\.[A-Za-z0-9]+)?$")
_MARKER_HEAD = (
    "Written by striptri. The next striptri run with this folder as output replaces it whole, but only\n"
    "while every file in it is one listed below, unchanged (size and SHA-256).\n"
)
_MANIFEST_LINE = re.compile(r"^([0-9a-f]{64}) (\d+) (.+)$")
_HELD_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
OUTPUT_OPTION = "--out"


# --------------------------------------------------------------------------- step 1: the checks


def check_output_location(out, inputs: Iterable = (), kind: str = "folder",
                          owned: Callable[[Path], bool] | None = None) -> Path:
    """Check that ``out`` may be written by this run, without writing anything. -> absolute path.

    kind: "folder" (an output folder) or "file" (a single file, replaced only when ``owned(path)``).
    inputs: every file or folder the run reads; out must not be one, lie inside one or contain one.
    Raises InputError (exit status 2) naming the path and the reason.
    """
    text = os.fspath(out) if out is not None else ""
    if str(text).strip() == "":
        raise InputError(OUTPUT_OPTION, None, "the output path is empty; give a folder name")
    path = Path(os.path.abspath(text))
    if path.parent == path:
        raise InputError(path, None, "the output cannot be the root folder")
    _check_lengths(path)
    existing = _nearest_existing_ancestor(path.parent)
    if existing is not None:
        if not os.access(existing, os.W_OK | os.X_OK):
            raise InputError(existing, None, "folder is not writable, so the output cannot be written there")
    _check_disjoint(path, inputs, "output folder" if kind == "folder" else "output file")
    if path.is_symlink():
        raise InputError(path, None, "output path is a link; give the real location")
    if path.exists():
        if kind == "folder":
            _check_replaceable_folder(path)
        else:
            _check_replaceable_file(path, owned)
    return path


def _check_lengths(path: Path) -> None:
    probe = _nearest_existing_ancestor(path.parent) or Path("/")
    try:
        name_max = os.pathconf(probe, "PC_NAME_MAX")
        path_max = os.pathconf(probe, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    reserve = len(TMP_PREFIX) + 12 + 8  # the temporary sibling's name must fit too
    for part in path.parts[1:]:
        if len(part.encode()) > name_max:
            raise InputError(path, None, f"a folder or file name in the output path has {len(part.encode())} bytes; "
                                         f"this file system allows {name_max}")
    if len(str(path).encode()) + reserve >= path_max:
        raise InputError(path, None, f"the output path is too long for this file system ({path_max} bytes at most)")


def _nearest_existing_ancestor(folder: Path) -> Path | None:
    """The nearest folder at or above ``folder`` that exists; InputError when a file or a broken
    link stands where a folder is needed."""
    probe = folder
    while True:
        if probe.is_symlink() and not probe.exists():
            raise InputError(probe, None, "is a broken link, so the output folder cannot be created there")
        if probe.exists():
            if not probe.is_dir():
                raise InputError(probe, None, "is a file, not a folder, so the output cannot be created inside it")
            return probe
        if probe.parent == probe:
            return None
        probe = probe.parent


def _within(inner: str, outer: str) -> bool:
    return inner == outer or inner.startswith(outer.rstrip(os.sep) + os.sep)


def _check_disjoint(path: Path, inputs: Iterable, what_out: str) -> None:
    """Neither the output inside an input (or equal to it) nor an input inside the output."""
    real_out = os.path.realpath(path)
    for item in inputs:
        if item is None:
            continue
        real_in = os.path.realpath(os.path.abspath(os.fspath(item)))
        if _within(real_out, real_in):
            what = "the input" if real_out == real_in else "inside the input"
            raise InputError(path, None, f"the {what_out} would be {what} {item}; striptri never writes into its "
                                         f"input: choose an {what_out} outside it")
        if _within(real_in, real_out):
            raise InputError(path, None, f"the {what_out} contains the input {item}; writing the output would "
                                         f"replace it: choose another {what_out}")


def _check_replaceable_folder(path: Path) -> None:
    if not path.is_dir():
        raise InputError(path, None, "output path exists and is not a folder")
    problem = foreign_content(path)
    if problem:
        raise InputError(path, None, problem)


def foreign_content(folder: Path) -> str:
    """Why the existing folder may not be replaced ("" when it may: empty, or striptri's own output
    with every file listed and unchanged in its manifest)."""
    try:
        entries = list(os.scandir(folder))
    except OSError as exc:
        return f"output folder cannot be read ({exc.strerror})"
    if not entries:
        return ""
    marker = folder / MARKER
    if not marker.is_file() or marker.is_symlink():
        return (f"output folder exists, is not empty and was not written by striptri (no {MARKER}); refusing to "
                "replace it: remove it or choose another output folder")
    manifest = _read_manifest(marker)
    if manifest is None:
        return (f"output folder was written by an older striptri whose {MARKER} lists no files, so striptri "
                "cannot tell whether you added or changed anything there; remove it yourself or choose another "
                "output folder")
    changed: list[str] = []
    listed_dirs = {str(p) for name in manifest for p in PurePosixPath(name).parents}
    for root, dirs, files in os.walk(folder):
        rel_root = os.path.relpath(root, folder)
        for d in dirs:
            rel = os.path.normpath(os.path.join(rel_root, d)).replace(os.sep, "/")
            if os.path.islink(os.path.join(root, d)) or rel not in listed_dirs:
                changed.append(f"{rel}/ was added")
        for f in files:
            rel = os.path.normpath(os.path.join(rel_root, f)).replace(os.sep, "/")
            full = os.path.join(root, f)
            if rel == MARKER:
                continue
            if rel not in manifest or os.path.islink(full) or not os.path.isfile(full):
                changed.append(f"{rel} was added")
            elif not _same_file(full, *manifest[rel]):
                changed.append(f"{rel} was changed")
        if len(changed) > 3:
            break
    if changed:
        listed = "; ".join(changed[:3]) + (" ..." if len(changed) > 3 else "")
        return (f"output folder was written by striptri, but since then {listed}; refusing to replace it (that "
                "would delete your files): move them, or choose another output folder")
    return ""


def _read_manifest(marker: Path) -> dict[str, tuple[int, str]] | None:
    try:
        text = marker.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    entries: dict[str, tuple[int, str]] = {}
    in_list = False
    for line in text.splitlines():
        if line == "files (sha256 size path):":
            in_list = True
            continue
        if in_list:
            match = _MANIFEST_LINE.match(line)
            if not match:
                return None
            entries[match.group(3)] = (int(match.group(2)), match.group(1))
    return entries if in_list else None


def _same_file(path: str, size: int, digest: str) -> bool:
    try:
        if os.path.getsize(path) != size:
            return False
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest() == digest
    except OSError:
        return False


def _check_replaceable_file(path: Path, owned: Callable[[Path], bool] | None) -> None:
    if not path.is_file():
        raise InputError(path, None, "output path exists and is not a regular file")
    if owned is None or not owned(path):
        raise InputError(path, None, "output file exists and was not written by this striptri command; refusing "
                                     "to replace it: remove it or choose another name")


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
        self.committed = False

    def __enter__(self) -> "OutputReservation":
        self.reserve()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.committed:
            self.abandon()

    def reserve(self) -> None:
        """Make the parent folders, remove stale temporaries of dead runs, create and lock the
        temporary entry. OSError -> InputError (exit status 2), nothing left behind."""
        parent = self.path.parent
        with _signals_held():
            try:
                self._created = _make_parents(parent)
                with _folder_lock(parent):
                    remove_stale_temporaries(parent)
                    self._tmp = parent / f"{TMP_PREFIX}{uuid.uuid4().hex[:12]}"
                    if self.kind == "folder":
                        self._tmp.mkdir()  # not mkdtemp: its mode 0700 would become the output folder's
                        self._fd = os.open(self._tmp, os.O_RDONLY | os.O_DIRECTORY)
                        _lock(self._fd)
                        (self._tmp / PARTIAL).write_bytes(b"")
                    else:
                        self._fd = os.open(self._tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
                        _lock(self._fd)
            except OSError as exc:
                self._cleanup()
                raise _output_error(exc, parent) from None

    def commit(self, files: Mapping[str, str | bytes] | bytes) -> Path:
        """Write the files (folder: relative POSIX path -> text or bytes; file: bytes), then swap
        them in for OUT. -> the absolute OUT."""
        if self._tmp is None:
            raise RuntimeError("commit() of an output that is not reserved")
        try:
            if self.kind == "folder":
                relative = {_safe_relative(name): content for name, content in files.items()}
                _write_files(self._tmp, relative)
                os.unlink(self._tmp / PARTIAL)
            else:
                _write_fd(self._fd, bytes(files))
        except OSError as exc:
            raise _output_error(exc, self.path) from None
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
                    old = self._swap_in()
                except OSError as exc:
                    raise _output_error(exc, self.path) from None
            self.committed = True
            tmp_fd, self._tmp, self._fd = self._fd, None, None
            if old is not None:
                old_path, old_fd = old
                _remove(old_path)
                _close(old_fd)
            _close(tmp_fd)
            _sync_folder(parent)
        return self.path

    def _swap_in(self):
        """Rename OUT aside (locked, so no other run takes it for stale), the temporary in.
        -> (aside path, its lock fd) or None."""
        if not (self.path.exists() or self.path.is_symlink()):
            os.rename(self._tmp, self.path)
            return None
        old = self.path.with_name(f"{OLD_PREFIX}{uuid.uuid4().hex[:12]}")
        old_fd = None
        with contextlib.suppress(OSError):
            old_fd = os.open(self.path, os.O_RDONLY | (os.O_DIRECTORY if self.kind == "folder" else 0))
            with contextlib.suppress(OSError):
                fcntl.flock(old_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.rename(self.path, old)
        try:
            os.rename(self._tmp, self.path)
        except BaseException:
            os.rename(old, self.path)
            _close(old_fd)
            raise
        return old, old_fd

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


def write_output_folder(out_dir, files: Mapping[str, str | bytes], inputs: Iterable = ()) -> Path:
    """Check, reserve and write ``files`` as the folder out_dir in one go (module doc)."""
    with OutputReservation(out_dir, inputs) as reservation:
        return reservation.commit(files)


def remove_stale_temporaries(folder: Path) -> list[str]:
    """Remove the ``.striptri-tmp-*`` / ``.striptri-old-*`` entries of ``folder`` that no live process
    holds locked (left by a run killed outright). Only entries striptri made are touched: the
    name pattern, and for a folder its marker (or nothing at all inside). -> the names removed."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        if not _STALE_NAME.match(entry.name):
            continue
        path = Path(entry.path)
        try:
            is_dir = entry.is_dir(follow_symlinks=False)
            if not is_dir and not entry.is_file(follow_symlinks=False):
                continue
            fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if is_dir else 0) | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                    continue  # a live run holds it
            if is_dir and not _made_by_striptri(path):
                continue
            _remove(path)
            removed.append(entry.name)
        finally:
            _close(fd)
    return removed


def _made_by_striptri(folder: Path) -> bool:
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    return not names or PARTIAL in names or MARKER in names


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


def _write_files(folder: Path, files: Mapping[PurePosixPath, str | bytes]) -> None:
    """Write every file, then the marker with the manifest of them all."""
    lines = []
    for name, content in files.items():
        target = folder.joinpath(*name.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        data = content.encode("utf-8") if isinstance(content, str) else bytes(content)
        write_file(target, data)
        lines.append(f"{hashlib.sha256(data).hexdigest()} {len(data)} {name}")
    write_file(folder / MARKER, (_MARKER_HEAD + "files (sha256 size path):\n" + "\n".join(lines) + "\n").encode())


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
    they are delivered when the block ends."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD_SIGNALS)
    except (OSError, ValueError):  # pragma: no cover - platforms without pthread_sigmask
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
