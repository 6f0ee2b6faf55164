"""Robustness of the input side (project folders, BAL, COLMAP, DBAT, convert): every case a user
reproduced gets a test that reproduces it, mostly through the real ``striptri`` command.

Bad input: exit status 2, one ``striptri: error: <file>, line <n>: <reason>`` message, no
traceback, nothing written (the output folder absent, the input folder unchanged). Input that is
read but not used: a :class:`striptri.errors.Note` in ``Project.notes``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from cli_support import DATA, assert_clean_failure, copy_project, run, snapshot
from striptri.errors import InputError, Note
from striptri.formats.bal import read_bal
from striptri.formats.dbat import read_dbat
from striptri.io import parse_project, project_files, read_project, read_settings

PAIR_TEXT = {name: (DATA / "pair" / name).read_text() for name in
             ("cameras.csv", "photos.csv", "image_points.csv", "control.csv", "project.toml")}


# --------------------------------------------------------------------------- helpers


def pair(tmp_path: Path, name: str = "proj") -> Path:
    """A copy of the shipped pair project (no truth folder)."""
    return copy_project("pair", tmp_path / name)


def fails_cleanly(args: list, watched: Path, out: Path, where: str, words: list[str], status: int = 2,
                  timeout: float = 120) -> str:
    """Run striptri ARGS; exit status, one message naming ``where`` ("file, line n", "file, line"
    for some line, or "file" for the whole file), the words of the reason, no traceback, nothing
    written (out absent, watched unchanged)."""
    before = snapshot(watched)
    proc = run(*args, timeout=timeout)
    err = assert_clean_failure(proc, status)
    pattern = re.escape(where) + (r" \d+: " if where.endswith(", line") else ": ")
    assert re.search(pattern, err), (where, err)
    for word in words:
        assert word in err, (word, err)
    assert "np.float64" not in err and "np.int64" not in err, err
    assert not os.path.lexists(out), "something was written"
    assert snapshot(watched) == before, "the input changed"
    return err


def adjust_fails(folder: Path, where: str, words: list[str], status: int = 2) -> str:
    """striptri adjust FOLDER fails cleanly naming folder/where."""
    out = folder.parent / (folder.name + "-out")
    return fails_cleanly(["adjust", folder, "--out", out], folder, out, f"{folder}/{where}", words, status)


def notes_of(folder: Path) -> list[Note]:
    return list(read_project(folder).notes)


def lines_of(text: str) -> list[str]:
    return text.splitlines(keepends=True)


# --------------------------------------------------------------------------- case 1


@pytest.mark.parametrize("name", ["cameras.csv", "photos.csv", "image_points.csv", "control.csv", "bases.csv",
                                  "approx_points.csv", "project.toml"])
def test_fifo_as_project_file_is_refused_without_waiting(tmp_path, name):
    """Case 1: a FIFO in place of any project file is refused at once (exit 2, the file named),
    never read (a read would wait for a writer forever; the subprocess timeout guards it)."""
    folder = pair(tmp_path)
    path = folder / name
    if path.exists():
        path.unlink()
    os.mkfifo(path)
    adjust_fails(folder, name, ["FIFO", "not a regular file"])


@pytest.mark.parametrize("name", ["project.toml", "cameras.csv", "control.csv"])
def test_folder_as_project_file_is_refused(tmp_path, name):
    """Case 1: a folder in place of a file (project.toml as a folder ended in a traceback)."""
    folder = pair(tmp_path)
    (folder / name).unlink()
    (folder / name).mkdir()
    adjust_fails(folder, name, ["is a folder, not a file"])


def _bal_file(path: Path) -> Path:
    path.write_text("1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0.1"] * 6 + ["500", "0", "0", "1", "2", "-10"]) + "\n")
    return path


def _colmap_folder(tmp_path: Path) -> Path:
    """strip8 as a COLMAP text model (striptri convert --to colmap)."""
    out = tmp_path / "colmap"
    proc = run("convert", DATA / "strip8", "--to", "colmap", "--out", out)
    assert proc.returncode == 0, proc.stderr
    return out


def _dbat_script(tmp_path: Path, camera_file: bool = False, focal: str = "10",
                 images: str = "1, a/IMG1.JPG\n2, a/IMG2.JPG\n") -> Path:
    """A small DBAT script project: two images with approximate orientations (prior_eo), two
    points, a camera inline or in a camera file."""
    folder = tmp_path / "dbat"
    folder.mkdir(exist_ok=True)
    (folder / "images.txt").write_text("# id, path\n" + images)
    (folder / "pts.txt").write_text("# im,id,x,y,sxy\n1,7,500,400,0.5\n2,7,600,300,0.5\n"
                                    "1,8,200,100,0.5\n2,8,300,200,0.5\n")
    (folder / "prior.txt").write_text("# id,x,y,z,omega,phi,kappa\n1,0,0,100,0,0,0\n2,10,0,100,0,0,0\n")
    camera = ("<camera><id>1</id><unit>mm</unit><sensor>10,8</sensor><image>1000,800</image>"
              f"<focal>{focal}</focal></camera>")
    if camera_file:
        (folder / "cam.xml").write_text(f'<?xml version="1.0"?>\n<document><cameras>{camera}</cameras></document>\n')
        cameras = "<cameras><file>cam.xml</file></cameras>"
    else:
        cameras = f"<cameras>\n{camera}\n</cameras>"
    (folder / "s.xml").write_text(
        '<?xml version="1.0"?>\n<document>\n<input base_dir="$HERE">\n'
        '<images><file format="id,path">images.txt</file></images>\n'
        '<image_pts><file format="im,id,x,y,sxy">pts.txt</file></image_pts>\n'
        '<prior_eo><file format="id,x,y,z,omega,phi,kappa" units="degrees">prior.txt</file></prior_eo>\n'
        f"{cameras}\n</input>\n</document>\n")
    return folder / "s.xml"


def _line_of(path: Path, text: str) -> int:
    """1-based number of the first line of path containing text."""
    return next(n for n, line in enumerate(path.read_text().splitlines(), start=1) if text in line)


@pytest.mark.parametrize("which", ["bal", "colmap cameras.txt", "colmap images.txt", "colmap points3D.txt",
                                   "dbat script", "dbat images.txt", "dbat pts.txt", "dbat camera file"])
def test_fifo_as_input_of_the_other_readers_is_refused_without_waiting(tmp_path, which):
    """Case 1 for BAL, COLMAP, the DBAT script and the files a DBAT script names."""
    out = tmp_path / "out"
    if which == "bal":
        src = tmp_path / "problem.txt"
        os.mkfifo(src)
        watched, fifo, args = tmp_path, src, ["--from", "bal"]
    elif which.startswith("colmap"):
        src = _colmap_folder(tmp_path)
        fifo = src / which.split()[1]
        fifo.unlink()
        os.mkfifo(fifo)
        watched, args = src, []
    else:
        src = _dbat_script(tmp_path, camera_file=which == "dbat camera file")
        fifo = {"dbat script": src, "dbat images.txt": src.parent / "images.txt", "dbat pts.txt": src.parent / "pts.txt",
                "dbat camera file": src.parent / "cam.xml"}[which]
        fifo.unlink()
        os.mkfifo(fifo)
        watched, args = src.parent, []
    fails_cleanly(["convert", src, "--to", "project", "--out", out, *args], watched, out, str(fifo),
                  ["FIFO", "not a regular file"])
    # the reader functions refuse it too, without blocking
    with pytest.raises(InputError, match="not a regular file"):
        if which == "bal":
            read_bal(fifo)
        elif which.startswith("dbat"):
            read_dbat(src)
        else:
            from striptri.formats import read_colmap

            read_colmap(src)


# --------------------------------------------------------------------------- case 2


@pytest.mark.parametrize("name", ["bases.csv", "control.csv", "approx_points.csv", "project.toml", "cameras.csv"])
def test_broken_symlink_for_an_optional_file_is_an_error_not_absent(tmp_path, name):
    """Case 2: bases.csv as a link to a missing file was read as "no bases" (sigma0 30 -> 0.84)."""
    folder = pair(tmp_path)
    if (folder / name).exists():
        (folder / name).unlink()
    (folder / name).symlink_to("gone/" + name)
    adjust_fails(folder, name, ["is a link to 'gone/" + name + "'", "does not exist"])
    with pytest.raises(InputError, match="does not exist"):
        read_settings(folder / name) if name == "project.toml" else read_project(folder)


# --------------------------------------------------------------------------- case 3


def test_project_toml_with_a_byte_order_mark_is_read(tmp_path):
    """Case 3: project.toml with a UTF-8 byte-order mark (CSV files accept one) is read."""
    folder = pair(tmp_path)
    toml = PAIR_TEXT["project.toml"].replace("max_iterations = 30", "max_iterations = 17")
    assert "max_iterations = 17" in toml
    (folder / "project.toml").write_bytes(b"\xef\xbb\xbf" + toml.encode("utf-8"))
    assert read_project(folder).settings.max_iterations == 17
    proc = run("adjust", folder, "--out", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr


# --------------------------------------------------------------------------- case 4


@pytest.mark.parametrize("change, where, words", [
    ({"cameras.csv": "header"}, "cameras.csv, line 1", ["no cameras", "no data rows"]),
    ({"photos.csv": "header"}, "photos.csv, line 1", ["no photos"]),
    ({"image_points.csv": "header"}, "image_points.csv, line 1", ["no plate measurements"]),
    ({n: "header" for n in ("cameras.csv", "photos.csv", "image_points.csv", "control.csv")}, "cameras.csv, line 1",
     ["no cameras"]),
    ({"cameras.csv": "empty"}, "cameras.csv", ["the file is empty", "no cameras"]),
    ({"photos.csv": "comments"}, "photos.csv", ["the file is empty", "no photos"]),
    ({"image_points.csv": "empty"}, "image_points.csv", ["the file is empty", "no plate measurements"]),
    ({"control.csv": "empty"}, "control.csv", ["the file is empty", "point_id"]),
])
def test_header_only_or_empty_required_file_is_refused(tmp_path, change, where, words):
    """Case 4: header-only required files ended in tracebacks; now an InputError naming the file."""
    folder = pair(tmp_path)
    for name, how in change.items():
        text = {"header": lines_of(PAIR_TEXT[name])[0], "empty": "", "comments": "# nothing yet\n\n"}[how]
        (folder / name).write_text(text)
    adjust_fails(folder, where, words)


@pytest.mark.parametrize("optional, status", [("control.csv", 1), ("bases.csv", 0), ("approx_points.csv", 0),
                                              ("all", 1)])
def test_header_only_optional_files_are_allowed_and_the_command_ends_cleanly(tmp_path, optional, status):
    """Case 4: optional files with a header only are fine; without control the adjustment explains
    the datum defect (exit 1), otherwise it runs (exit 0). No traceback either way."""
    folder = pair(tmp_path)
    headers = {"control.csv": "point_id,kind,X,Y,Z\n", "bases.csv": "photo_from,photo_to,component,value,sigma\n",
               "approx_points.csv": "point_id,X,Y,Z\n"}
    for name, header in headers.items():
        if optional in (name, "all"):
            (folder / name).write_text(header)
    assert read_project(folder).notes == ()
    proc = run("adjust", folder, "--out", tmp_path / "out")
    if status == 0:
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    else:
        err = assert_clean_failure(proc, 1)
        assert "datum" in err and not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- case 5


def _set_field(text: str, line: int, column: str, value: str) -> str:
    """text of a CSV file with one field (1-based physical line, column name) replaced."""
    rows = text.splitlines()
    header = rows[0].split(",")
    fields = rows[line - 1].split(",")
    fields[header.index(column)] = value
    rows[line - 1] = ",".join(fields)
    return "\n".join(rows) + "\n"


@pytest.mark.parametrize("file, column, value, words", [
    ("photos.csv", "X0", "1e300", ["column 'X0'", "1e300", "1e9 m"]),
    ("image_points.csv", "x", "1e300", ["column 'x'", "1e300", "plate units"]),
    ("cameras.csv", "c", "1e9", ["camera 'C1'", "c = 1e9", "numerically parallel"]),
    ("control.csv", "Y", "-2e9", ["column 'Y'", "-2e9", "1e9 m"]),
    ("photos.csv", "kappa", "1e6", ["column 'kappa'", "1e6", "10 full turns"]),
    ("image_points.csv", "x", "9000", ["lies 9000", "89.03 deg off the camera axis", "frame camera"]),
    ("image_points.csv", "sigma_y", "1e-200", ["column 'sigma_y'", "1e-200", "plausible range"]),
    ("photos.csv", "sigma_Z0", "1e300", ["column 'sigma_Z0'", "1e300", "plausible range"]),
    ("cameras.csv", "sigma_c", "1e-101", ["column 'sigma_c'", "plausible range"]),
])
def test_absurd_numbers_are_refused_with_file_line_and_limit(tmp_path, file, column, value, words):
    """Case 5: X0 = 1e300, x = 1e300 and c = 1e9 ended in tracebacks (the last one a
    SingularNormalMatrix); every value beyond the plausibility limits is refused with its line."""
    folder = pair(tmp_path)
    (folder / file).write_text(_set_field(PAIR_TEXT[file], 2, column, value))
    adjust_fails(folder, f"{file}, line 2", words)


def test_tiny_but_representable_sigma_is_read(tmp_path):
    """Case 5: a plate sigma of 1e-20 is physically absurd but not meaningless to the arithmetic:
    the reader keeps it (what it does to the adjustment is the adjustment's to explain)."""
    folder = pair(tmp_path)
    (folder / "image_points.csv").write_text(_set_field(PAIR_TEXT["image_points.csv"], 2, "sigma_x", "1e-20"))
    assert read_project(folder).image_points.sigma_xy[0, 0] == 1e-20


# --------------------------------------------------------------------------- case 6


def test_duplicate_id_in_approx_points_is_refused_naming_both_lines(tmp_path):
    """Case 6: approx_points.csv with an id twice was accepted (the last row won)."""
    folder = pair(tmp_path)
    (folder / "approx_points.csv").write_text("point_id,X,Y,Z\n1001C,5000,5000,100\n1002C,5900,5000,90\n"
                                              "1001C,5001,5000,100\n")
    adjust_fails(folder, "approx_points.csv, line 4", ["duplicate point_id '1001C'", "first on line 2"])


# --------------------------------------------------------------------------- case 7


def test_unused_input_gives_notes_never_silence(tmp_path):
    """Case 7: a control point no photo measures (an id typed in another case), tie points on one
    photo, a photo without measurements, a camera no photo uses, values the kind does not use,
    columns and files striptri does not read: one note each, naming file and line."""
    folder = pair(tmp_path)
    control = PAIR_TEXT["control.csv"]
    assert "\n1001L,XYZ," in control and "1001R,XY," in control
    control = control.replace("\n1001L,XYZ,", "\n1001l,XYZ,")  # the plates measure 1001L
    control = control.replace("1001R,XY,5000.0,4111.842105263158,,", "1001R,XY,5000.0,4111.842105263158,12.5,")
    control += "K9,check,1,2,3,0.1,,\n"
    (folder / "control.csv").write_text(control)
    photos = PAIR_TEXT["photos.csv"].replace("sigma_X0", "sigma_x0")
    photos += "1009,C1,1,7000,5000,1600,0,0,0,,,,,,\n"
    (folder / "photos.csv").write_text(photos)
    (folder / "cameras.csv").write_text(PAIR_TEXT["cameras.csv"] + "C9,88.0,0.0,0.0,,,\n")
    lonely = "".join(f"1001,T{k},{k}.5,1.25,0.005,0.005\n" for k in range(7))
    (folder / "image_points.csv").write_text(PAIR_TEXT["image_points.csv"] + lonely)
    (folder / "Control.CSV").write_text("x\n")
    (folder / "notes.txt").write_text("flown 1955\n")
    (folder / "old").mkdir()
    (folder / "README.md").write_text("pair\n")
    (folder / "striptri_ids.csv").write_text("table\n")
    (folder / ".hidden").write_text("")
    (folder / "truth").mkdir()

    notes = notes_of(folder)
    text = "\n".join(str(n) for n in notes)
    by_file = {}
    for n in notes:
        by_file.setdefault(Path(n.path).name, []).append(n)
    assert all(isinstance(n, Note) for n in notes)
    # the control point typed in another case: control.csv, its line, "did you mean"
    unmeasured = [n for n in by_file["control.csv"] if "measured on no photo" in n.text]
    assert len(unmeasured) == 1 and unmeasured[0].line == 2, text
    assert "'1001l'" in unmeasured[0].text and "did you mean '1001L'" in unmeasured[0].text
    # the check point K9 is measured on no photo either: the same note, with its own line
    k9_line = len(lines_of(control))
    assert unmeasured[0].text.startswith("2 control points") and f"'K9' (check) (line {k9_line})" in text
    # values the kind does not use: Z of the XY point, the sigma of the check point
    unused = [n for n in by_file["control.csv"] if "does not use" in n.text]
    assert len(unused) == 1 and "Z of XY point '1001R'" in unused[0].text and "sigma_X of check point 'K9'" in unused[0].text
    # tie points on one photo: one aggregated note, count, first few, "and 2 more"
    (single,) = [n for n in by_file["image_points.csv"] if "one photo only" in n.text]
    first_line = len(lines_of(PAIR_TEXT["image_points.csv"])) + 1
    assert single.line == first_line and single.text.startswith("7 tie points") and "and 2 more" in single.text
    # the photo without measurements, the camera no photo uses
    (photo,) = [n for n in by_file["photos.csv"] if "no measurements" in n.text]
    assert "'1009'" in photo.text and photo.line == len(lines_of(photos))
    (camera,) = by_file["cameras.csv"]
    assert "'C9'" in camera.text and camera.line == 3
    # a misspelt column: photos.csv's header line, did you mean
    (column,) = [n for n in by_file["photos.csv"] if "column" in n.text]
    assert column.line == 1 and "'sigma_x0' (did you mean 'sigma_X0'?)" in column.text
    # files striptri does not read, not the known ones
    (files,) = [n for n in notes if n.path == str(folder)]
    assert "'Control.CSV' (did you mean 'control.csv'?)" in files.text and "'notes.txt'" in files.text
    assert "'old/'" in files.text
    for known in ("README.md", "striptri_ids.csv", ".hidden", "truth", "cameras.csv"):
        assert f"'{known}" not in files.text


def test_notes_are_aggregated_per_kind_and_file(tmp_path):
    """Case 7: twenty unmeasured control points give one note with a count and the first few."""
    folder = pair(tmp_path)
    extra = "".join(f"Q{k},Z,,,{k}.0,,,\n" for k in range(20))
    (folder / "control.csv").write_text(PAIR_TEXT["control.csv"] + extra)
    notes = [n for n in notes_of(folder) if "measured on no photo" in n.text]
    assert len(notes) == 1
    assert notes[0].text.startswith("20 control points") and "'Q0' (Z) (line" in notes[0].text
    assert "and 15 more" in notes[0].text


def test_projects_striptri_writes_have_no_notes(tmp_path):
    """Case 7: the shipped projects, simulated ones and converted ones carry nothing unused."""
    for folder in sorted(p for p in DATA.iterdir() if p.is_dir()):
        assert read_project(folder).notes == (), folder
    sim = tmp_path / "sim"
    proc = run("simulate", "block", "--photos", "4", "--strips", "2", "--check-points", "2", "--extra-ties", "1",
               "--sigma-control", "0.05", "--gnss-sigma", "0.1", "--out", sim)
    assert proc.returncode == 0, proc.stderr
    assert read_project(sim).notes == ()
    conv = tmp_path / "conv"
    proc = run("convert", DATA / "strip8", "--to", "project", "--out", conv)
    assert proc.returncode == 0, proc.stderr
    assert "warning" not in proc.stderr and "converted project" not in proc.stderr, proc.stderr
    assert read_project(conv).notes == ()


# --------------------------------------------------------------------------- case 8


@pytest.mark.parametrize("cut", ["at a triple", "at half the bytes", "last line"])
def test_colmap_truncated_images_txt_fails_instead_of_losing_measurements(tmp_path, cut):
    """Case 8: a truncated images.txt lost half the measurements with exit status 0."""
    src = _colmap_folder(tmp_path)
    text = (src / "images.txt").read_text()
    images = lines_of(text)
    if cut == "at half the bytes":  # in the middle of a POINTS2D line
        short, words = text[: len(text) // 2], ["POINTS2D line must hold triples"]
    elif cut == "last line":  # the POINTS2D line of the last image lost
        short, words = "".join(images[:-1]), ["POINT2D_IDX", "has 0 2D points", "is images.txt complete?"]
    else:  # the POINTS2D line of the last image cut after half its triples
        triples = images[-1].split()
        kept = triples[: 3 * (len(triples) // 6)]
        short, words = "".join(images[:-1]) + " ".join(kept) + "\n", ["POINT2D_IDX", "is images.txt complete?"]
    (src / "images.txt").write_text(short)
    out = tmp_path / "out"
    where = f"{src}/images.txt, line" if cut == "at half the bytes" else f"{src}/points3D.txt, line"
    fails_cleanly(["convert", src, "--to", "project", "--out", out], src, out, where, words)


def test_colmap_tracks_must_agree_with_the_2d_points(tmp_path):
    """Case 8: a track naming a 2D point of another 3D point, or a 2D point no track names."""
    src = _colmap_folder(tmp_path)
    points = lines_of((src / "points3D.txt").read_text())
    data = [i for i, line in enumerate(points) if not line.startswith("#")]
    first, second = data[0], data[1]
    a, b = points[first].split(), points[second].split()
    a[8:10], b[8:10] = b[8:10], a[8:10]  # swap the first track entries of two points
    bad = list(points)
    bad[first], bad[second] = " ".join(a) + "\n", " ".join(b) + "\n"
    (src / "points3D.txt").write_text("".join(bad))
    out = tmp_path / "out"
    fails_cleanly(["convert", src, "--to", "project", "--out", out], src, out, f"{src}/points3D.txt, line {first + 1}",
                  ["whose POINT3D_ID in images.txt"])
    short = list(points)
    short[first] = " ".join(points[first].split()[:-2]) + "\n"  # drop its last track entry
    (src / "points3D.txt").write_text("".join(short))
    err = fails_cleanly(["convert", src, "--to", "project", "--out", out], src, out, f"{src}/images.txt, line",
                        ["does not name it"])
    assert f"POINT3D_ID {a[0]}" in err


# --------------------------------------------------------------------------- case 9


@pytest.mark.parametrize("text, words", [
    ("0 0 0\n", ["needs at least one camera, one point and one observation"]),
    ("1 1 0\n" + "0.1\n" * 12, ["needs at least one camera"]),
    ("1 1 1000000000000\n0 0 1 2\n" + "0.1\n" * 12, ["announces", "1000000000000 observations", "bytes"]),
    ("1000000000000 1 1\n0 0 1 2\n" + "0.1\n" * 12, ["announces 1000000000000 cameras", "bytes"]),
])
def test_bal_empty_problem_or_absurd_header_is_refused_on_line_1(tmp_path, text, words):
    """Case 9: "0 0 0" ended in a traceback, a header claiming 10^12 observations in MemoryError."""
    src = tmp_path / "problem.txt"
    src.write_text(text)
    out = tmp_path / "out"
    fails_cleanly(["convert", src, "--to", "project", "--out", out], tmp_path, out, f"{src}, line 1", words)


# --------------------------------------------------------------------------- case 10


BILLION_LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
                  + "".join(f' <!ENTITY lol{i} "{("&lol%s;" % ("" if i == 1 else i - 1)) * 10}">\n'
                            for i in range(1, 10))
                  + "]>\n<document><meta><name>&lol9;</name></meta></document>\n")


def test_dbat_billion_laughs_is_refused_at_once(tmp_path):
    """Case 10: a 1 KB "billion laughs" document ran past 300 s; it is refused at its first entity
    declaration (the subprocess timeout is the hang guard, no timing assertion)."""
    assert len(BILLION_LAUGHS) < 1024
    src = tmp_path / "bomb.xml"
    src.write_text(BILLION_LAUGHS)
    out = tmp_path / "out"
    fails_cleanly(["convert", src, "--to", "project", "--out", out], tmp_path, out, f"{src}, line 3",
                  ["declares the entity 'lol'"], timeout=60)
    external = tmp_path / "external.xml"
    external.write_text('<?xml version="1.0"?>\n<!DOCTYPE d [\n<!ENTITY e SYSTEM "file:///etc/passwd">\n]>\n'
                        "<document>&e;</document>\n")
    with pytest.raises(InputError, match="declares the entity 'e'") as info:
        read_dbat(external)
    assert info.value.line == 3


def test_dbat_huge_text_element_is_read_in_linear_time(tmp_path):
    """Case 10: character data arrives in chunks; concatenating them one by one was quadratic. A
    script with a 48 MB text element converts (in a subprocess with a generous timeout: a "does
    not hang" check; the quadratic reader took 46 s for 9.6 MB, some 20 minutes for this)."""
    script = _dbat_script(tmp_path)
    text = script.read_text()
    filler = ("all work and no play makes a long DBAT comment " * 2 + "\n") * 510_000
    assert len(filler) > 48_000_000
    script.write_text(text.replace("<document>\n", f"<document>\n<meta><description>{filler}</description></meta>\n"))
    proc = run("convert", script, "--to", "project", "--out", tmp_path / "out", timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out" / "cameras.csv").is_file()


# --------------------------------------------------------------------------- case 11


def test_convert_never_writes_a_project_that_adjust_rejects(tmp_path):
    """Case 11: a DBAT focal of -7.5 became c = -7.5. The DBAT reader refuses it (file, line); and
    convert validates the project it is about to write with the project reader's rules, in memory
    (here: two images with the same file name give two photos with one id)."""
    script = _dbat_script(tmp_path, focal="-7.5")
    out = tmp_path / "out"
    fails_cleanly(["convert", script, "--to", "project", "--out", out], script.parent, out,
                  f"{script}, line {_line_of(script, '<focal>')}",
                  ["<focal> (the principal distance) must be > 0", "'-7.5'"])
    script = _dbat_script(tmp_path, images="1, a/IMG1.JPG\n2, b/IMG1.JPG\n")
    fails_cleanly(["convert", script, "--to", "project", "--out", out], script.parent, out, str(script),
                  ["the converted project would be invalid", "photos.csv, line 3: duplicate photo_id 'IMG1.JPG'"])
    # values a project cannot hold are refused by the DBAT reader itself, with its file and line
    (script.parent / "pts.txt").write_text("# im,id,x,y,sxy\n1,7,500,400,0.5\n2,,600,300,0.5\n")
    with pytest.raises(InputError) as info:
        read_dbat(script)
    assert info.value.path.endswith("pts.txt") and info.value.line == 3 and "id is empty" in info.value.reason


def test_parse_project_in_memory_equals_the_folder_reader(tmp_path):
    """Case 11: parse_project (file contents in memory) applies exactly read_project's rules."""
    files = project_files(read_project(DATA / "strip8"))
    folder = tmp_path / "proj"
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_text(text)
    p, q = read_project(folder), parse_project(files)
    for name in ("xyz0", "angles", "sigma_xyz0", "sigma_angles", "R_ground_from_cam"):
        np.testing.assert_array_equal(getattr(q.photos, name), getattr(p.photos, name))
    np.testing.assert_array_equal(q.image_points.xy, p.image_points.xy)
    np.testing.assert_array_equal(q.points.xyz_given, p.points.xyz_given)
    assert q.points.ids == p.points.ids and q.settings == p.settings and q.notes == p.notes == ()
    files["cameras.csv"] = files["cameras.csv"].replace("152.0", "-152.0")
    with pytest.raises(InputError) as info:
        parse_project(files)
    assert info.value.path == "cameras.csv" and info.value.line == 2 and "> 0" in info.value.reason


# --------------------------------------------------------------------------- case 12


def test_messages_show_numbers_as_the_file_has_them_never_numpy_reprs(tmp_path):
    """Case 12: messages showed np.float64(-0.01)."""
    folder = pair(tmp_path)
    (folder / "image_points.csv").write_text(_set_field(PAIR_TEXT["image_points.csv"], 3, "sigma_y", "-0.010"))
    err = adjust_fails(folder, "image_points.csv, line 3", ["(got -0.010)"])
    assert "np." not in err
    (folder / "image_points.csv").write_text(PAIR_TEXT["image_points.csv"])
    (folder / "photos.csv").write_text(_set_field(PAIR_TEXT["photos.csv"], 2, "sigma_phi", "-1e-3"))
    err = adjust_fails(folder, "photos.csv, line 2", ["(got -1e-3)"])
    (folder / "photos.csv").write_text(PAIR_TEXT["photos.csv"])
    (folder / "cameras.csv").write_text(PAIR_TEXT["cameras.csv"].replace("C1,152.0,0.0,0.0", "C1,152.0,0.01,0.0"))
    out = tmp_path / "bal"
    err = fails_cleanly(["convert", folder, "--to", "bal", "--out", out], folder, out, f"{folder}/cameras.csv",
                        ["xp, yp = 0.01, 0.0"])
    assert "np." not in err
