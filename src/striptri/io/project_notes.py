"""What a project's files hold that striptri does not use, as :class:`striptri.errors.Note`
(docs/file-formats.md, "Notes"). Nothing in the input is ignored silently: the pipeline prints
every note (``striptri: warning: ...``) and lists it in report.html and summary.json.

One note per kind of problem and file, naming the line of the first case, with the count and the
first MAX_LISTED cases (ids and lines), never one note per row:

* columns of a CSV file that no reader asks for (a misspelt ``sigma_x0`` would otherwise leave an
  observed element free), with "did you mean" for a known column that differs in case or a letter;
* files and folders of the project folder that striptri does not read (known and skipped: the
  input files, ``truth/`` and ``README*`` that the simulator and people add, ``striptri_ids.csv``
  and hidden files such as ``.striptri-output``);
* control.csv: control or check points measured on no photo (with "did you mean" for a measured
  id equal up to case or the spelling of a number), height or check points measured on one photo
  only (no condition; no intersection to compare), coordinates the kind does not use (X, Y of a
  Z point) and sigmas that are not observations (of check points, of unused coordinates);
* image_points.csv: tie points measured on one photo only (they give no condition);
* photos.csv: photos with no measurements; cameras.csv: cameras that no photo uses.

No file is opened here: the reader hands over its parsed tables.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from striptri import model
from striptri.errors import Note
from striptri.io.csvtable import CsvTable

MAX_LISTED = 5
# entries of a project folder that are not inputs but belong there (besides the input files and
# hidden files): the simulator's truth, people's READMEs, the converter's id table
KNOWN_OTHER_ENTRIES = ("truth", "striptri_ids.csv")


def project_notes(tables: Mapping[str, CsvTable], cameras: model.Cameras, photos: model.Photos,
                  image_points: model.ImagePoints, points: model.ObjectPoints, n_control: int,
                  active: np.ndarray | None = None) -> list[Note]:
    """Every note on the parsed tables (file name -> CsvTable) of a project that read without error.
    points: the first n_control are the rows of control.csv, in its order. active: (m,) bool over
    image_points' rows (None: all): rays and measured photos count the active rows only."""
    notes = [n for table in tables.values() for n in [_column_note(table)] if n is not None]
    used = np.arange(len(image_points.point_index)) if active is None else np.flatnonzero(active)
    point_index, photo_index = image_points.point_index[used], image_points.photo_index[used]
    rays = np.bincount(point_index, minlength=len(points))
    if "control.csv" in tables:
        notes += _control_notes(tables["control.csv"], points, rays, n_control)
    ip_table = tables["image_points.csv"]
    _, first_row = np.unique(point_index, return_index=True)
    first = np.full(len(points), -1)
    first[point_index[first_row]] = used[first_row]
    lonely = np.flatnonzero(rays[n_control:] == 1) + n_control
    lonely = lonely[np.argsort(first[lonely], kind="stable")]  # in the order of image_points.csv
    notes += _note(ip_table.path, [
        (ip_table.lines[first[j]], f"'{points.ids[j]}'", f"photo '{photos.ids[image_points.photo_index[first[j]]]}'")
        for j in lonely[:MAX_LISTED]], "tie point measured on one photo only; it gives no condition and is not used",
        "tie points measured on one photo only; they give no condition and are not used", len(lonely))
    ph_table = tables["photos.csv"]
    unmeasured = np.flatnonzero(np.bincount(photo_index, minlength=len(photos)) == 0)
    notes += _note(ph_table.path, [(ph_table.lines[i], f"'{photos.ids[i]}'", "") for i in unmeasured[:MAX_LISTED]],
                   "photo with no measurements in image_points.csv; no ray of it enters the adjustment",
                   "photos with no measurements in image_points.csv; no ray of them enters the adjustment",
                   len(unmeasured))
    cam_table = tables["cameras.csv"]
    unused = np.flatnonzero(np.bincount(photos.camera_index, minlength=len(cameras)) == 0)
    notes += _note(cam_table.path, [(cam_table.lines[j], f"'{cameras.ids[j]}'", "") for j in unused[:MAX_LISTED]],
                   "camera that no photo of photos.csv uses; not used",
                   "cameras that no photo of photos.csv uses; not used", len(unused))
    return notes


def unread_files_note(folder: Path, names: Iterable[str], input_files: Sequence[str]) -> Note | None:
    """One note listing the entries of a project folder that striptri does not read (module doc),
    or None."""
    unread = []
    for name in sorted(names):
        if (name.startswith(".") or name in input_files or name in KNOWN_OTHER_ENTRIES
                or name.casefold().startswith("readme")):
            continue
        hint = _suggest(name, input_files)
        label = f"'{name}/'" if (folder / name).is_dir() else f"'{name}'"
        unread.append(label + (f" (did you mean '{hint}'?)" if hint else ""))
    if not unread:
        return None
    head = (f"{len(unread)} files or folders" if len(unread) > 1 else "a file or folder")
    return Note(str(folder), None, f"{head} in the project folder that striptri does not read (ignored): "
                                   f"{_listing(unread)}")


# --------------------------------------------------------------------------- the notes


def _column_note(table: CsvTable) -> Note | None:
    """Columns of the table that no reader asked for, with "did you mean" among those it asked for."""
    unused = table.unused_columns()
    if not unused:
        return None
    known = sorted(table.used)
    labels = []
    for name in unused:
        hint = _suggest(name, known)
        labels.append(f"'{name}'" + (f" (did you mean '{hint}'?)" if hint else ""))
    head = "column" if len(unused) == 1 else f"{len(unused)} columns"
    return Note(str(table.path), table.header_line, f"{head} that striptri does not read, values ignored: "
                                                    f"{_listing(labels)}")


def _control_notes(table: CsvTable, points: model.ObjectPoints, rays: np.ndarray, n_control: int) -> list[Note]:
    """control.csv: unmeasured control, control without a condition, values the kind does not use."""
    notes = []
    unmeasured = np.flatnonzero(rays[:n_control] == 0)
    measured_ties = {}
    if len(unmeasured):  # every tie point is measured (the reader makes them from measurements)
        for j in range(n_control, len(points)):
            measured_ties.setdefault(_id_key(points.ids[j]), points.ids[j])
    items = []
    for i in unmeasured:
        hint = measured_ties.get(_id_key(points.ids[i]))
        kind = model.KIND_NAMES[int(points.kind[i])]
        items.append((table.lines[i], f"'{points.ids[i]}' ({kind})",
                      f"did you mean '{hint}', measured in image_points.csv?" if hint else ""))
    notes += _note(table.path, items, "control point measured on no photo; it takes no part in the adjustment",
                   "control points measured on no photo; they take no part in the adjustment")
    weak = [i for i in range(n_control) if rays[i] == 1 and points.kind[i] in (model.HEIGHT, model.CHECK)]
    notes += _note(table.path, [(table.lines[i], f"'{points.ids[i]}' ({model.KIND_NAMES[int(points.kind[i])]})", "")
                                for i in weak],
                   "control point measured on one photo only, which gives it no condition (a height point "
                   "needs two rays; a check point needs two to be intersected and compared)",
                   "control points measured on one photo only, which gives them no condition (a height point "
                   "needs two rays; a check point needs two to be intersected and compared)")
    items = []
    needed_rows = model.needed_axes(points.kind[:n_control]).reshape(-1, 3)
    given_rows = model.given_axes(points.kind[:n_control]).reshape(-1, 3)
    for i in range(n_control):
        kind = int(points.kind[i])
        needed, given = needed_rows[i], given_rows[i]
        unused = [a for a, n in zip("XYZ", needed) if not n and table.text(i, a) != ""]
        unused += [f"sigma_{a}" for a, g in zip("XYZ", given) if not g and table.text(i, f"sigma_{a}") != ""]
        if unused:
            items.append((table.lines[i], f"{', '.join(unused)} of {model.KIND_NAMES[kind]} point '{points.ids[i]}'",
                          ""))
    notes += _note(table.path, items,
                   "a value that the kind of the point does not use (ignored; check points are not observations)",
                   "values that the kind of the point does not use (ignored; check points are not observations)")
    return notes


# --------------------------------------------------------------------------- helpers


def _note(path, items: list[tuple[int, str, str]], singular: str, plural: str, count: int | None = None
          ) -> list[Note]:
    """[] or one Note at the line of the first item. items: (line, label, remark) of the first
    cases (at least the first MAX_LISTED); count: how many cases there are (default len(items))."""
    count = len(items) if count is None else count
    if not items:
        return []
    if count == 1:
        line, label, remark = items[0]
        return [Note(str(path), int(line), f"{singular}: {label}" + (f" ({remark})" if remark else ""))]
    labels = [f"{label} (line {line}" + (f"; {remark})" if remark else ")") for line, label, remark in items]
    return [Note(str(path), int(items[0][0]), f"{count} {plural}: {_listing(labels, count)}")]


def _listing(labels: Sequence[str], count: int | None = None) -> str:
    """The first MAX_LISTED labels, and how many more of count (default len(labels)) there are."""
    shown = ", ".join(labels[:MAX_LISTED])
    more = (len(labels) if count is None else count) - min(len(labels), MAX_LISTED)
    return shown + (f" and {more} more" if more > 0 else "")


def _suggest(name: str, candidates: Iterable[str]) -> str | None:
    """A candidate equal to name up to case and surrounding whitespace, else a close spelling, else None."""
    candidates = [c for c in candidates if c != name]
    key = name.strip().casefold()
    for c in candidates:
        if c.strip().casefold() == key:
            return c
    close = difflib.get_close_matches(name, candidates, n=1, cutoff=0.85)
    return close[0] if close else None


def _id_key(point_id: str) -> str:
    """An id up to case, surrounding whitespace and the spelling of a number ('007', '7', '7.0')."""
    key = point_id.strip().casefold()
    try:
        value = float(key)
    except ValueError:
        return key
    return repr(value) if value == value else key
