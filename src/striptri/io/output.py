"""Write a whole folder atomically: it appears complete or not at all (DESIGN section 10).

Procedure: every file goes into a fresh temporary sibling folder ``.<name>.tmp-*`` next to
``out_dir``; when all are written, an existing ``out_dir`` is renamed aside to ``.<name>.old-*``,
the new folder is renamed to ``out_dir`` and the old one is deleted. On any failure the temporary
folder is removed, the old ``out_dir`` is put back, and parent folders created for the run are
removed again, so nothing is left behind.

To avoid deleting a folder that is not ours (a mistyped ``--out``), an existing ``out_dir`` is
replaced only when it is empty or carries the marker file ``.striptri-output`` that every folder
written here gets.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Mapping
from pathlib import Path, PurePosixPath

from striptri.errors import InputError

MARKER = ".striptri-output"
_MARKER_TEXT = "Written by striptri; the next run with this folder as output may replace it whole.\n"


def write_output_folder(out_dir: str | Path, files: Mapping[str, str | bytes]) -> Path:
    """Write ``files`` (relative POSIX path -> text or bytes) as the folder out_dir, atomically.

    Text is written as UTF-8 without newline translation. Sub-folders ("truth/points.csv") are
    created. Returns the absolute out_dir. Raises InputError when out_dir is an existing file or a
    non-empty folder without the striptri marker; ValueError for a path that leaves out_dir.
    """
    out_dir = Path(out_dir).absolute()
    relative = {_safe_relative(name): content for name, content in files.items()}
    _check_replaceable(out_dir)
    created_root = _make_parents(out_dir.parent)
    tmp_dir = None
    try:
        tmp_dir = _sibling(out_dir, "tmp")
        tmp_dir.mkdir()  # not tempfile.mkdtemp: its mode 0700 would become the output folder's
        _write_files(tmp_dir, relative)
        _swap_in(tmp_dir, out_dir)
        tmp_dir = None
    except BaseException:
        if tmp_dir is not None:
            shutil.rmtree(tmp_dir, ignore_errors=True)
        if created_root is not None:
            shutil.rmtree(created_root, ignore_errors=True)
        raise
    return out_dir


def _safe_relative(name: str) -> PurePosixPath:
    """A relative path inside the output folder (no absolute paths, no '..', not the marker)."""
    path = PurePosixPath(name)
    if path.is_absolute() or not path.parts or ".." in path.parts or str(path) == MARKER:
        raise ValueError(f"output file name {name!r} is not a plain relative path inside the folder")
    return path


def _check_replaceable(out_dir: Path) -> None:
    """out_dir must be absent, an empty folder, or a folder striptri wrote (it has the marker)."""
    if not out_dir.exists() and not out_dir.is_symlink():
        return
    if not out_dir.is_dir() or out_dir.is_symlink():
        raise InputError(out_dir, None, "output path exists and is not a folder")
    if any(out_dir.iterdir()) and not (out_dir / MARKER).is_file():
        raise InputError(
            out_dir,
            None,
            f"output folder exists, is not empty and was not written by striptri (no {MARKER}); "
            "refusing to replace it: remove it or choose another output folder",
        )


def _make_parents(parent: Path) -> Path | None:
    """Create parent (and its missing ancestors); return the topmost folder created, or None."""
    missing = None
    probe = parent
    while not probe.exists():
        missing = probe
        probe = probe.parent
    parent.mkdir(parents=True, exist_ok=True)
    return missing


def _sibling(out_dir: Path, tag: str) -> Path:
    """A fresh hidden sibling name ``.<name>.<tag>-<random>`` of out_dir."""
    return out_dir.with_name(f".{out_dir.name}.{tag}-{uuid.uuid4().hex[:12]}")


def _write_files(folder: Path, files: Mapping[PurePosixPath, str | bytes]) -> None:
    """Write every file, and the marker, into folder."""
    (folder / MARKER).write_text(_MARKER_TEXT, encoding="utf-8")
    for name, content in files.items():
        target = folder.joinpath(*name.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        data = content.encode("utf-8") if isinstance(content, str) else bytes(content)
        target.write_bytes(data)


def _swap_in(new_dir: Path, out_dir: Path) -> None:
    """Replace out_dir by new_dir: old aside, new in, old deleted; on failure restore the old one."""
    if not out_dir.exists():
        os.rename(new_dir, out_dir)
        return
    old_dir = _sibling(out_dir, "old")
    os.rename(out_dir, old_dir)
    try:
        os.rename(new_dir, out_dir)
    except BaseException:
        os.rename(old_dir, out_dir)
        raise
    shutil.rmtree(old_dir, ignore_errors=True)
