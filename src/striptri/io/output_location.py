"""Step 1 of writing an output (io.output): the checks of the output location, made before anything
is read or computed and without writing anything: OUT is not empty, its folders can exist, its
name is not too long, it neither is, nor lies inside, nor contains an input of the run, and if it
exists it may be replaced (an empty folder, or one striptri wrote whose every file its marker lists
unchanged)."""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path, PurePosixPath

from striptri.errors import InputError

MARKER = ".striptri-output"
TMP_PREFIX = ".striptri-tmp-"
_MANIFEST_LINE = re.compile(r"^([0-9a-f]{64}) (\d+) (.+)$")
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
