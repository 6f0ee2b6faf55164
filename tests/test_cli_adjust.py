"""`striptri adjust` end to end (DESIGN section 10): the output folder and its columns, summary.json,
agreement with the simulator's truth, bad input (exit 2), datum defects (exit 1), the atomic
output rule and large national-grid coordinates.

Most cases run the real console script in a subprocess, so that "no traceback reaches stderr" is
proven on the real thing.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data" / "synthetic_strips"

OUTPUT_FILES = {"photos.csv", "cameras.csv", "points.csv", "residuals.csv", "summary.json", "report.html"}
MARKER = ".striptri-output"
COLUMNS = {
    "photos.csv": ["photo_id", "X0", "Y0", "Z0", "omega", "phi", "kappa",
                   "sigma_X0", "sigma_Y0", "sigma_Z0", "sigma_omega", "sigma_phi", "sigma_kappa"],
    "cameras.csv": ["camera_id", "c", "xp", "yp", "k1", "k2"],  # "and their sigmas (when estimated)"
    "points.csv": ["point_id", "kind", "X", "Y", "Z", "sigma_X", "sigma_Y", "sigma_Z", "rays", "flag"],
    "residuals.csv": ["photo_id", "point_id", "vx", "vy", "w", "flag"],
}
SUMMARY_KEYS = ["method", "solver", "sigma0", "redundancy", "vtpv", "iterations", "converged",
                "n_photos", "n_points", "n_observations", "n_conditions", "n_unknowns",
                "check_points", "timings_s"]
CHECK_KEYS = ["n", "rms_X", "rms_Y", "rms_Z"]

DIRECTIONS = {
    "tX": "translation in X",
    "tY": "translation in Y",
    "tZ": "translation in Z",
    "rX": "rotation about the X axis",
    "rY": "rotation about the Y axis",
    "rZ": "rotation about the Z axis",
    "s": "scale",
}


# --------------------------------------------------------------------------------------- helpers


def _command() -> list[str]:
    """The `striptri` console script of this interpreter (striptri.cli has no __main__ guard, so
    `python -m striptri.cli` would do nothing)."""
    script = Path(sys.executable).parent / "striptri"
    if script.exists():
        return [str(script)]
    found = shutil.which("striptri")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; sys.argv[0] = 'striptri'; from striptri.cli import main; main()"]


def run(*args, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*_command(), *map(str, args)], capture_output=True, text=True, timeout=120,
                          cwd=REPO, env={**os.environ, "PYTHONWARNINGS": "ignore", **(env or {})})


def adjust(project, out, *extra) -> subprocess.CompletedProcess:
    return run("adjust", project, "--out", out, *extra)


def read_table(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def by_id(rows, key):
    return {r[key]: r for r in rows}


def num(text: str) -> float:
    return float(text) if text != "" else math.nan


def copy_project(name: str, dest: Path) -> Path:
    """A copy of a shipped project, without its truth folder."""
    shutil.copytree(DATA / name, dest, ignore=shutil.ignore_patterns("truth"))
    return dest


def edit_line(path: Path, line: int, fn) -> str:
    """Replace physical line ``line`` (1-based) of a text file by fn(old line); returns the old line."""
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    old = lines[line - 1]
    end = "\n" if old.endswith("\n") else ""
    lines[line - 1] = fn(old.rstrip("\n")) + end
    path.write_text("".join(lines), encoding="utf-8")
    return old


def set_field(path: Path, line: int, column: str, value: str) -> None:
    """Set one field of a CSV row (physical line ``line``; header on line 1)."""
    header = path.read_text(encoding="utf-8").splitlines()[0].split(",")
    j = header.index(column)

    def fn(text):
        fields = next(csv.reader([text]))
        fields[j] = value
        buf = io.StringIO()
        csv.writer(buf, lineterminator="").writerow(fields)
        return buf.getvalue()

    edit_line(path, line, fn)


def write_rows(path: Path, header: list[str], rows: list[dict]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=header, lineterminator="\n", extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def assert_clean_failure(proc, status: int) -> str:
    """Exit status, exactly one `striptri: error:` message, no traceback; returns the message."""
    assert proc.returncode == status, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stdout, proc.stdout
    assert proc.stderr.count("striptri: error:") == 1, proc.stderr
    assert proc.stderr.startswith("striptri: error:"), proc.stderr
    return proc.stderr


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under folder (hidden ones too): bytes and mtime."""
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*")) if p.is_file()
    }


def no_leftovers(parent: Path, name: str) -> None:
    """No temporary or aside siblings of the output folder are left behind."""
    from cli_support import stray_siblings

    left = stray_siblings(parent / name)
    assert left == [], left


# --------------------------------------------------------------------------- successful runs


@pytest.fixture(scope="module")
def strip8_run(tmp_path_factory):
    """strip8 adjusted by the command, its progress lines held back however slow the machine (they
    start after 2 s; on a loaded 2-core machine the run can take longer), so that stderr holds
    exactly the warnings and errors: none."""
    out = tmp_path_factory.mktemp("strip8") / "out"
    proc = run("adjust", DATA / "strip8", "--out", out, env={"STRIPTRI_PROGRESS_AFTER": "1e9"})
    return proc, out


def test_strip8_exits_0_and_writes_exactly_the_files(strip8_run):
    proc, out = strip8_run
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr == ""
    names = {p.name for p in out.iterdir()}
    assert names - {MARKER} == OUTPUT_FILES
    assert (out / MARKER).is_file()
    no_leftovers(out.parent, out.name)


@pytest.mark.parametrize("name", sorted(COLUMNS))
def test_strip8_columns_in_design_order(strip8_run, name):
    _, out = strip8_run
    header, rows = read_table(out / name)
    want = COLUMNS[name]
    assert header[: len(want)] == want, header
    extra = header[len(want):]
    if name == "cameras.csv":
        # the sigmas of the contract's elements, then the other additional parameters (docs/camera-model.md)
        assert extra == ["sigma_c", "sigma_xp", "sigma_yp", "sigma_k1", "sigma_k2", "k3", "p1", "p2", "b1", "b2",
                         "distortion", "sigma_k3", "sigma_p1", "sigma_p2", "sigma_b1", "sigma_b2"], extra
    elif name == "residuals.csv":
        # the minimal detectable biases follow the contract's columns
        assert extra == ["mdb_x", "mdb_y"], extra
    else:
        # at present no extra columns are written; any would have to come after the listed ones
        assert extra == [], extra
    assert rows, name


def test_strip8_summary_keys_and_consistency(strip8_run):
    _, out = strip8_run
    s = json.loads((out / "summary.json").read_text())
    for key in SUMMARY_KEYS:
        assert key in s, key
    assert list(s)[: len(SUMMARY_KEYS)] == SUMMARY_KEYS
    assert set(CHECK_KEYS) <= set(s["check_points"])
    assert isinstance(s["timings_s"], dict) and s["timings_s"]
    assert all(isinstance(v, (int, float)) and v >= 0 for v in s["timings_s"].values())

    assert s["method"] == "conditions"
    assert isinstance(s["solver"], str) and s["solver"]
    assert s["converged"] is True
    # what made the result (DESIGN, third wave): striptri's version and the time the run started
    from datetime import datetime

    from striptri import __version__

    assert s["version"] == __version__
    started = datetime.fromisoformat(s["started"])
    assert started.tzinfo is not None and abs((datetime.now(started.tzinfo) - started).total_seconds()) < 3600
    assert s["options"]["method"] == "conditions" and s["project"].endswith("strip8")
    assert 1 <= s["iterations"] <= 30

    _, photos_in = read_table(DATA / "strip8" / "photos.csv")
    _, image_in = read_table(DATA / "strip8" / "image_points.csv")
    _, control_in = read_table(DATA / "strip8" / "control.csv")
    _, photos = read_table(out / "photos.csv")
    _, points = read_table(out / "points.csv")
    _, residuals = read_table(out / "residuals.csv")
    _, cameras = read_table(out / "cameras.csv")

    assert s["n_photos"] == len(photos) == len(photos_in) == 8
    assert [r["photo_id"] for r in photos] == [r["photo_id"] for r in photos_in]
    assert len(cameras) == 1
    measured = {r["point_id"] for r in image_in}
    assert s["n_points"] == len(points) == len(measured | {r["point_id"] for r in control_in})
    assert len(residuals) == len(image_in)
    # control is held fixed, so the observations are the plate coordinates only
    assert s["n_observations"] == 2 * len(image_in)
    # all photo elements free, camera fixed, no observed elements
    assert s["n_unknowns"] == 6 * len(photos)
    assert s["redundancy"] == s["n_conditions"] - s["n_unknowns"] > 0
    assert s["sigma0"] == pytest.approx(math.sqrt(s["vtpv"] / s["redundancy"]), rel=1e-12)
    # sigma0 a posteriori near 1 (stated plate sigma is the simulated noise)
    assert 0.5 < s["sigma0"] < 1.5

    # v^T P v from residuals.csv
    sig = {(r["photo_id"], r["point_id"]): (num(r["sigma_x"]), num(r["sigma_y"])) for r in image_in}
    vtpv = sum((num(r["vx"]) / sig[r["photo_id"], r["point_id"]][0]) ** 2
               + (num(r["vy"]) / sig[r["photo_id"], r["point_id"]][1]) ** 2 for r in residuals)
    assert vtpv == pytest.approx(s["vtpv"], rel=1e-6)

    # rays = number of plate measurements of the point
    counts: dict[str, int] = {}
    for r in image_in:
        counts[r["point_id"]] = counts.get(r["point_id"], 0) + 1
    for r in points:
        assert int(r["rays"]) == counts.get(r["point_id"], 0), r

    # check points: n and RMS recomputed from points.csv and control.csv
    checks = [r for r in control_in if r["kind"].lower() == "check"]
    cp = s["check_points"]
    assert cp["n"] == len(checks) == 4
    pts = by_id(points, "point_id")
    for axis in "XYZ":
        diffs = [num(pts[c["point_id"]][axis]) - num(c[axis]) for c in checks]
        rms = math.sqrt(sum(d * d for d in diffs) / len(diffs))
        assert cp[f"rms_{axis}"] == pytest.approx(rms, rel=1e-9, abs=1e-12)
        assert cp[f"rms_{axis}"] < 0.5
    # kinds carried over
    for c in control_in:
        assert pts[c["point_id"]]["kind"].lower() == c["kind"].lower()


def test_strip8_report_html(strip8_run):
    _, out = strip8_run
    text = (out / "report.html").read_text(encoding="utf-8")
    assert "<html" in text.lower() and "</html>" in text.lower()


def _compare_photos_with_truth(out: Path, truth: Path, n_sigma: float, max_pos: float):
    _, photos = read_table(out / "photos.csv")
    _, true = read_table(truth / "photos.csv")
    true = by_id(true, "photo_id")
    assert set(true) == {r["photo_id"] for r in photos}
    for r in photos:
        t = true[r["photo_id"]]
        for col in ("X0", "Y0", "Z0", "omega", "phi", "kappa"):
            d = num(r[col]) - num(t[col])
            sigma = num(r[f"sigma_{col}"])
            assert sigma > 0, (r["photo_id"], col)
            assert abs(d) <= n_sigma * sigma, (r["photo_id"], col, d, sigma)
            if col in ("X0", "Y0", "Z0"):
                assert abs(d) < max_pos, (r["photo_id"], col, d)


def _compare_points_with_truth(out: Path, truth: Path, n_sigma: float):
    _, points = read_table(out / "points.csv")
    _, true = read_table(truth / "points.csv")
    true = by_id(true, "point_id")
    assert set(true) == {r["point_id"] for r in points}
    for r in points:
        t = true[r["point_id"]]
        for axis in "XYZ":
            d = num(r[axis]) - num(t[axis])
            sigma = num(r[f"sigma_{axis}"])
            assert abs(d) <= n_sigma * sigma + 1e-6, (r["point_id"], axis, d, sigma)


def test_strip8_close_to_truth(strip8_run):
    _, out = strip8_run
    # sigma 0.005 mm at 1:10,000: a few decimetres for the centres; every element within 5 sigma
    _compare_photos_with_truth(out, DATA / "strip8" / "truth", n_sigma=5.0, max_pos=0.5)
    _compare_points_with_truth(out, DATA / "strip8" / "truth", n_sigma=5.0)


def test_strip8_fixed_control_kept(strip8_run):
    _, out = strip8_run
    _, control = read_table(DATA / "strip8" / "control.csv")
    pts = by_id(read_table(out / "points.csv")[1], "point_id")
    for c in control:
        kind = c["kind"].upper()
        axes = {"XYZ": "XYZ", "XY": "XY", "Z": "Z"}.get(kind, "")
        for axis in axes:
            assert num(pts[c["point_id"]][axis]) == pytest.approx(num(c[axis]), abs=1e-6)


def test_pair_noisy(tmp_path):
    out = tmp_path / "out"
    proc = adjust(DATA / "pair", out)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert {p.name for p in out.iterdir()} - {MARKER} == OUTPUT_FILES
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] is True
    assert s["n_photos"] == 2
    assert s["redundancy"] == s["n_conditions"] - s["n_unknowns"] > 0
    assert s["sigma0"] == pytest.approx(math.sqrt(s["vtpv"] / s["redundancy"]), rel=1e-12)
    assert s["check_points"]["n"] == 0
    _compare_photos_with_truth(out, DATA / "pair" / "truth", n_sigma=5.0, max_pos=1.0)
    _compare_points_with_truth(out, DATA / "pair" / "truth", n_sigma=5.0)


def test_pair_minimal_no_redundancy_recovers_truth(tmp_path):
    out = tmp_path / "out"
    proc = adjust(DATA / "pair_minimal", out)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert {p.name for p in out.iterdir()} - {MARKER} == OUTPUT_FILES
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] is True
    assert s["redundancy"] == 0
    assert s["n_conditions"] == s["n_unknowns"] == 12
    assert s["sigma0"] is None  # JSON null
    assert '"sigma0": null' in (out / "summary.json").read_text()

    _, photos = read_table(out / "photos.csv")
    true = by_id(read_table(DATA / "pair_minimal" / "truth" / "photos.csv")[1], "photo_id")
    for r in photos:
        for col in ("X0", "Y0", "Z0"):
            assert num(r[col]) == pytest.approx(num(true[r["photo_id"]][col]), abs=1e-6)
        for col in ("omega", "phi", "kappa"):  # degrees; 1e-6 m at 1500 m is 4e-8 deg
            assert num(r[col]) == pytest.approx(num(true[r["photo_id"]][col]), abs=4e-8)
    _, points = read_table(out / "points.csv")
    true_pts = by_id(read_table(DATA / "pair_minimal" / "truth" / "points.csv")[1], "point_id")
    assert set(true_pts) == {r["point_id"] for r in points}
    for r in points:
        for axis in "XYZ":
            assert num(r[axis]) == pytest.approx(num(true_pts[r["point_id"]][axis]), abs=1e-6)
    # noise-free: every plate residual vanishes
    for r in read_table(out / "residuals.csv")[1]:
        assert abs(num(r["vx"])) < 1e-9 and abs(num(r["vy"])) < 1e-9


# --------------------------------------------------------------------------------- bad input


def _damage_missing_file(p: Path):
    (p / "photos.csv").unlink()
    return "photos.csv", None, ["not found"]


def _damage_missing_column(p: Path):
    header, rows = read_table(p / "photos.csv")
    write_rows(p / "photos.csv", [h for h in header if h != "Z0"], rows)
    return "photos.csv", 1, ["missing column", "Z0"]


def _damage_non_numeric(p: Path):
    set_field(p / "image_points.csv", 4, "x", "12.5mm")
    return "image_points.csv", 4, ["'x'", "12.5mm", "not a number"]


def _damage_nan(p: Path):
    set_field(p / "photos.csv", 3, "Z0", "nan")
    return "photos.csv", 3, ["'Z0'", "nan"]


def _damage_unknown_photo(p: Path):
    set_field(p / "image_points.csv", 6, "photo_id", "9999")
    return "image_points.csv", 6, ["9999", "photo_id"]


def _damage_unknown_camera(p: Path):
    set_field(p / "photos.csv", 2, "camera_id", "C7")
    return "photos.csv", 2, ["C7", "camera"]


def _damage_duplicate_photo(p: Path):
    _, rows = read_table(p / "photos.csv")
    set_field(p / "photos.csv", 3, "photo_id", rows[0]["photo_id"])
    return "photos.csv", 3, ["duplicate", rows[0]["photo_id"], "line 2"]


def _damage_duplicate_control(p: Path):
    _, rows = read_table(p / "control.csv")
    set_field(p / "control.csv", 4, "point_id", rows[0]["point_id"])
    return "control.csv", 4, ["duplicate", rows[0]["point_id"]]


def _damage_unknown_kind(p: Path):
    set_field(p / "control.csv", 3, "kind", "XYZW")
    return "control.csv", 3, ["XYZW", "kind"]


def _damage_c_zero(p: Path):
    set_field(p / "cameras.csv", 2, "c", "0")
    return "cameras.csv", 2, ["c", "> 0"]


def _damage_c_negative(p: Path):
    set_field(p / "cameras.csv", 2, "c", "-152.0")
    return "cameras.csv", 2, ["c", "> 0"]


def _damage_undecodable(p: Path):
    path = p / "image_points.csv"
    lines = path.read_bytes().split(b"\n")
    lines[4] = lines[4] + b"\xff\xfe junk"  # physical line 5
    path.write_bytes(b"\n".join(lines))
    return "image_points.csv", 5, ["UTF-8"]


def _damage_toml_bad_value(p: Path):
    path = p / "project.toml"
    text = path.read_text(encoding="utf-8")
    assert 'method = "conditions"' in text
    path.write_text(text.replace('method = "conditions"', 'method = "magic"'), encoding="utf-8")
    line = 1 + path.read_text(encoding="utf-8").splitlines().index('method = "magic"')
    return "project.toml", line, ["method", "magic"]


def _damage_toml_bad_iterations(p: Path):
    path = p / "project.toml"
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace("max_iterations = 30", "max_iterations = 0"), encoding="utf-8")
    line = 1 + path.read_text(encoding="utf-8").splitlines().index("max_iterations = 0")
    return "project.toml", line, ["max_iterations"]


def _damage_toml_bad_plate_unit(p: Path):
    path = p / "project.toml"
    text = path.read_text(encoding="utf-8")
    assert 'rotation = "omega-phi-kappa"\n' in text
    path.write_text(text.replace('rotation = "omega-phi-kappa"\n', 'rotation = "omega-phi-kappa"\nplate = "pixels"\n'),
                    encoding="utf-8")
    line = 1 + path.read_text(encoding="utf-8").splitlines().index('plate = "pixels"')
    return "project.toml", line, ["[units] plate", "'pixels'", "'mm', 'px'"]


BAD_INPUT = {
    "missing_file": _damage_missing_file,
    "missing_column": _damage_missing_column,
    "non_numeric": _damage_non_numeric,
    "nan_value": _damage_nan,
    "unknown_photo_id": _damage_unknown_photo,
    "unknown_camera_id": _damage_unknown_camera,
    "duplicate_photo_id": _damage_duplicate_photo,
    "duplicate_control_id": _damage_duplicate_control,
    "unknown_control_kind": _damage_unknown_kind,
    "c_zero": _damage_c_zero,
    "c_negative": _damage_c_negative,
    "undecodable_bytes": _damage_undecodable,
    "toml_bad_value": _damage_toml_bad_value,
    "toml_bad_max_iterations": _damage_toml_bad_iterations,
    "toml_bad_plate_unit": _damage_toml_bad_plate_unit,
}


@pytest.mark.parametrize("case", sorted(BAD_INPUT))
def test_bad_input_exit_2(tmp_path, case):
    project = copy_project("pair", tmp_path / "project")
    file_name, line, words = BAD_INPUT[case](project)
    before = snapshot(project)
    out = tmp_path / "results" / "out"  # parents do not exist either
    proc = adjust(project, out)
    message = assert_clean_failure(proc, 2)
    assert file_name in message, message
    if line is not None:
        assert f"{file_name}, line {line}:" in message, message
    for word in words:
        assert word in message, (word, message)
    assert not out.exists()
    assert not (tmp_path / "results").exists()
    assert snapshot(project) == before  # the reader writes nothing


@pytest.mark.parametrize("key, value", [("method", "simplex"), ("solver", "magic")])
def test_toml_value_not_implemented(tmp_path, key, value):
    """A method or solver striptri does not have is bad input: exit 2, and like every project.toml
    error the message names the file and the line of the key."""
    project = copy_project("pair", tmp_path / "project")
    path = project / "project.toml"
    lines = path.read_text(encoding="utf-8").splitlines()
    line = next(i for i, text in enumerate(lines, start=1) if text.startswith(f"{key} ="))
    lines[line - 1] = f'{key} = "{value}"'
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "out"
    message = assert_clean_failure(adjust(project, out), 2)
    assert "project.toml" in message and value in message, message
    assert not out.exists()
    assert f"project.toml, line {line}:" in message, message


def test_output_folder_equal_to_project_folder(tmp_path):
    project = copy_project("pair", tmp_path / "project")
    before = snapshot(project)
    for out in (project, tmp_path / "project" / ".." / "project"):
        proc = adjust(project, out)
        message = assert_clean_failure(proc, 2)
        assert "project" in message and "output folder" in message, message
        assert snapshot(project) == before
    no_leftovers(tmp_path, "project")


def test_output_folder_not_written_by_striptri(tmp_path):
    out = tmp_path / "precious"
    out.mkdir()
    (out / "thesis.tex").write_text("do not delete\n")
    before = snapshot(out)
    proc = adjust(DATA / "pair", out)
    message = assert_clean_failure(proc, 2)
    assert str(out) in message and "not written by striptri" in message, message
    assert snapshot(out) == before
    no_leftovers(tmp_path, "precious")


def test_output_path_is_a_file(tmp_path):
    out = tmp_path / "out"
    out.write_text("a file\n")
    proc = adjust(DATA / "pair", out)
    # click's own usage error (file_okay=False on --out) or striptri's: either way status 2
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "is a file" in proc.stderr or "not a folder" in proc.stderr, proc.stderr
    assert out.read_text() == "a file\n"


def test_project_folder_missing(tmp_path):
    out = tmp_path / "out"
    proc = adjust(tmp_path / "nowhere", out)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "nowhere" in proc.stderr
    assert not out.exists()


# ------------------------------------------------------------------------------- datum defects


@pytest.fixture(scope="module")
def simulated_pair(tmp_path_factory):
    """A simulated pair with full control at the four model corners, and one without control."""
    base = tmp_path_factory.mktemp("datum")
    corners, none = base / "corners", base / "none"
    for folder, layout in ((corners, "corners"), (none, "none")):
        proc = run("simulate", "pair", "--out", folder, "--control", layout, "--extra-ties", "4", "--seed", "7")
        assert proc.returncode == 0, proc.stderr
    return corners, none


def _with_control(source: Path, dest: Path, spec: dict[str, str]) -> Path:
    """Copy project source and give it the control spec {point_id: kind} with the true coordinates."""
    shutil.copytree(source, dest)
    truth = by_id(read_table(source / "truth" / "points.csv")[1], "point_id")
    rows = []
    for pid, kind in spec.items():
        t = truth[pid]
        rows.append({"point_id": pid, "kind": kind,
                     "X": t["X"] if "X" in kind else "", "Y": t["Y"] if "Y" in kind else "",
                     "Z": t["Z"] if "Z" in kind else ""})
    write_rows(dest / "control.csv", ["point_id", "kind", "X", "Y", "Z", "sigma_X", "sigma_Y", "sigma_Z"], rows)
    return dest


def _named(message: str) -> set[str]:
    return {key for key, words in DIRECTIONS.items() if words in message}


def _datum_failure(project: Path, out: Path) -> str:
    proc = adjust(project, out)
    message = assert_clean_failure(proc, 1)
    assert "datum" in message, message
    assert not out.exists()
    no_leftovers(out.parent, out.name)
    return message


def _defect_count(message: str) -> int | None:
    m = re.search(r"(\d+) similarity element", message)
    return int(m.group(1)) if m else None


def test_corner_control_works(simulated_pair, tmp_path):
    corners, _ = simulated_pair
    proc = adjust(corners, tmp_path / "out")
    assert proc.returncode == 0, proc.stderr


def test_datum_plan_control_only(simulated_pair, tmp_path):
    """Three plan points (not on a line): the height of the model is free; the relief of the
    plan points fixes its tilts (weakly)."""
    corners, _ = simulated_pair
    project = _with_control(corners, tmp_path / "plan", {"1001L": "XY", "1001R": "XY", "1002R": "XY"})
    message = _datum_failure(project, tmp_path / "out")
    assert _named(message) == {"tZ"}, message
    assert _defect_count(message) in (None, 1), message


def test_datum_three_height_points(simulated_pair, tmp_path):
    """Three height points: translations in X and Y and the rotation about Z are free, and so is
    the scale: three heights fix only three of (translation in Z, tilt about X, tilt about Y,
    scale), since any change of scale moves the three heights by amounts that one plane (a tilt and
    a translation in Z) absorbs exactly. Four defects, one of them naming the scale."""
    corners, _ = simulated_pair
    project = _with_control(corners, tmp_path / "height", {"1001L": "Z", "1001R": "Z", "1002R": "Z"})
    message = _datum_failure(project, tmp_path / "out")
    assert _defect_count(message) in (None, 4), message
    named = _named(message)
    assert {"tX", "tY", "rZ", "s"} <= named, message


def test_datum_four_height_points(simulated_pair, tmp_path):
    """Four height points (model corners, with relief): translations in X and Y and the rotation
    about Z are free; the scale is fixed (weakly) by the relief."""
    corners, _ = simulated_pair
    project = _with_control(corners, tmp_path / "height4",
                            {"1001L": "Z", "1001R": "Z", "1002L": "Z", "1002R": "Z"})
    message = _datum_failure(project, tmp_path / "out")
    assert _defect_count(message) in (None, 3), message
    assert _named(message) == {"tX", "tY", "rZ"}, message


_VEC = r"\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)"


def test_datum_two_full_points_only(simulated_pair, tmp_path):
    """Two full points on a diagonal of the model: one free rotation, about the line through them.
    The message may say it with the elementary directions (the line is oblique in plan, so a
    rotation about X and one about Y, with translations as the rotation is stated about the
    centroid of the projection centres) or as a rotation about an axis with a direction through a
    ground point: then the axis must be the line through the two points."""
    corners, _ = simulated_pair
    pids = ("1001L", "1002R")
    project = _with_control(corners, tmp_path / "two", {pid: "XYZ" for pid in pids})
    message = _datum_failure(project, tmp_path / "out")
    assert _defect_count(message) in (None, 1), message
    assert "rotation" in message, message
    named = _named(message)
    assert not named & {"rZ", "s", "tZ"}, message
    axis = re.search(r"rotation about an axis with direction " + _VEC + r" through the ground point " + _VEC,
                     message)
    if axis is None:
        assert {"rX", "rY"} <= named, message
        return
    direction = [float(axis.group(k)) for k in (1, 2, 3)]
    point = [float(axis.group(k)) for k in (4, 5, 6)]
    given = by_id(read_table(project / "control.csv")[1], "point_id")
    a, b = ([num(given[pid][c]) for c in "XYZ"] for pid in pids)
    line = [bb - aa for aa, bb in zip(a, b)]
    length = math.sqrt(sum(x * x for x in line))
    unit = [x / length for x in line]
    norm = math.sqrt(sum(x * x for x in direction))
    cos = abs(sum(u * d for u, d in zip(unit, direction))) / norm
    assert cos > 0.99, (message, unit)  # the direction is printed to one decimal
    rel = [p - aa for p, aa in zip(point, a)]
    along = sum(r * u for r, u in zip(rel, unit))
    off = math.sqrt(max(sum(r * r for r in rel) - along * along, 0.0))
    assert off < 5.0, (message, off)  # the ground point lies on the line through the two points


def test_datum_no_control(simulated_pair, tmp_path):
    """No control at all: all seven similarity elements are free."""
    _, none = simulated_pair
    assert read_table(none / "control.csv")[1] == []
    message = _datum_failure(none, tmp_path / "out")
    assert _defect_count(message) in (None, 7), message
    assert _named(message) == set(DIRECTIONS), message


# ---------------------------------------------------------------------- atomic output folder


def test_failed_run_leaves_earlier_output_unchanged(simulated_pair, tmp_path):
    corners, none = simulated_pair
    out = tmp_path / "out"
    proc = adjust(corners, out)
    assert proc.returncode == 0, proc.stderr
    before = snapshot(out)
    assert MARKER in before

    proc = adjust(none, out)  # datum defect
    assert_clean_failure(proc, 1)
    assert snapshot(out) == before
    no_leftovers(tmp_path, "out")

    broken = copy_project("pair", tmp_path / "broken")  # bad input
    set_field(broken / "photos.csv", 2, "X0", "east")
    proc = adjust(broken, out)
    assert_clean_failure(proc, 2)
    assert snapshot(out) == before
    no_leftovers(tmp_path, "out")

    # and a successful run replaces it whole
    proc = adjust(DATA / "pair", out)
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in out.iterdir()} - {MARKER} == OUTPUT_FILES
    assert snapshot(out)["summary.json"] != before["summary.json"]
    no_leftovers(tmp_path, "out")


# -------------------------------------------------------------------- national-grid coordinates

SHIFT = {"X": 500000.0, "Y": 5000000.0}


def _shift_project(source: Path, dest: Path, back: bool) -> Path:
    """source with SHIFT added to X and Y of control.csv and of the centres in photos.csv.

    back=True: the same numbers shifted and shifted back, (v + d) - d, which is exact; the shifted
    and the back-shifted project then describe the same geometry bit for bit (v + d itself is
    rounded to the ulp of 5e6 m, about 1e-9 m, so the plain project would differ from the shifted
    one by that much)."""
    shutil.copytree(source, dest, ignore=shutil.ignore_patterns("truth"))

    def shifted(text: str, d: float) -> str:
        v = float(text) + d
        return repr(v - d if back else v)

    header, rows = read_table(dest / "control.csv")
    for r in rows:
        for axis, d in SHIFT.items():
            if r[axis] != "":
                r[axis] = shifted(r[axis], d)
    write_rows(dest / "control.csv", header, rows)
    header, rows = read_table(dest / "photos.csv")
    for r in rows:
        for axis, d in SHIFT.items():
            r[f"{axis}0"] = shifted(r[f"{axis}0"], d)
    write_rows(dest / "photos.csv", header, rows)
    return dest


@pytest.mark.parametrize("name", ["pair", "pair_minimal", "strip8"])
def test_large_grid_coordinates(tmp_path, name):
    plain_out, shifted_out = tmp_path / "plain_out", tmp_path / "shifted_out"
    plain = _shift_project(DATA / name, tmp_path / "plain", back=True)
    shifted = _shift_project(DATA / name, tmp_path / "shifted", back=False)
    for project, out in ((plain, plain_out), (shifted, shifted_out)):
        proc = adjust(project, out)
        assert proc.returncode == 0, proc.stderr

    s0 = json.loads((plain_out / "summary.json").read_text())
    s1 = json.loads((shifted_out / "summary.json").read_text())
    if s0["sigma0"] is None:
        assert s1["sigma0"] is None
    else:
        assert s1["sigma0"] == pytest.approx(s0["sigma0"], rel=1e-9)
    assert s1["redundancy"] == s0["redundancy"]
    assert s1["converged"] is True

    p0 = by_id(read_table(plain_out / "photos.csv")[1], "photo_id")
    p1 = by_id(read_table(shifted_out / "photos.csv")[1], "photo_id")
    assert p0.keys() == p1.keys()
    for pid in p0:
        for col, d in (("X0", SHIFT["X"]), ("Y0", SHIFT["Y"]), ("Z0", 0.0)):
            assert num(p1[pid][col]) - d == pytest.approx(num(p0[pid][col]), abs=1e-6), (pid, col)
        for col in ("omega", "phi", "kappa"):  # degrees: 4e-8 deg is 1e-6 m at 1500 m
            assert num(p1[pid][col]) == pytest.approx(num(p0[pid][col]), abs=4e-8), (pid, col)
        for col in ("sigma_X0", "sigma_Y0", "sigma_Z0", "sigma_omega", "sigma_phi", "sigma_kappa"):
            assert num(p1[pid][col]) == pytest.approx(num(p0[pid][col]), rel=1e-6), (pid, col)

    q0 = by_id(read_table(plain_out / "points.csv")[1], "point_id")
    q1 = by_id(read_table(shifted_out / "points.csv")[1], "point_id")
    assert q0.keys() == q1.keys()
    for pid in q0:
        for axis, d in (("X", SHIFT["X"]), ("Y", SHIFT["Y"]), ("Z", 0.0)):
            assert num(q1[pid][axis]) - d == pytest.approx(num(q0[pid][axis]), abs=1e-6), (pid, axis)
            assert num(q1[pid][f"sigma_{axis}"]) == pytest.approx(num(q0[pid][f"sigma_{axis}"]), rel=1e-6, abs=1e-9)


def test_blunders_snoop_rejects_a_gross_error(tmp_path):
    """A gross error of 40 sigma on the y coordinate (across the base, well checked) of one plate
    measurement: --blunders snoop rejects exactly that measurement (flag "rejected" in residuals.csv,
    its predicted residual about minus the error) and summary.json says so; --blunders off only
    flags it as suspect."""
    project = copy_project("block_3x6", tmp_path / "project")
    path = project / "image_points.csv"
    lines = path.read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    row = 40  # a measurement in the middle of the block
    fields = lines[row].split(",")
    fields[header.index("y")] = repr(float(fields[header.index("y")]) + 0.2)  # 40 x 0.005 mm
    lines[row] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    target = (fields[header.index("photo_id")], fields[header.index("point_id")])
    clean = run("adjust", DATA / "block_3x6", "--out", tmp_path / "clean")
    assert clean.returncode == 0, clean.stderr
    # the clean data have their own measurements above the critical value (the test's size alpha0)
    baseline = {(r["photo_id"], r["point_id"]) for r in read_table(tmp_path / "clean" / "residuals.csv")[1]
                if r["flag"] == "suspect"}
    assert target not in baseline
    for mode, flag in (("snoop", "rejected"), ("off", "suspect")):
        out = tmp_path / mode
        proc = run("adjust", project, "--out", out, "--blunders", mode)
        assert proc.returncode == 0, proc.stderr
        _, rows = read_table(out / "residuals.csv")
        flagged = {(r["photo_id"], r["point_id"]) for r in rows if r["flag"] == flag}
        summary = json.loads((out / "summary.json").read_text())
        assert summary["blunders"]["method"] == mode
        assert target in flagged
        if mode == "snoop":
            assert flagged - baseline == {target}
            bad = next(r for r in rows if (r["photo_id"], r["point_id"]) == target)
            assert abs(float(bad["vy"]) + 0.2) < 0.02


def test_sequential_method_and_init_from_the_command_line(tmp_path):
    """--method sequential writes the same files (method "sequential" in summary.json); forward and
    backward differ; --init sequential gives the simultaneous solution; a block and --blunders
    snoop are refused with explanations."""
    photos = {}
    for direction in ("forward", "backward"):
        out = tmp_path / direction
        proc = run("adjust", DATA / "strip8", "--out", out, "--method", "sequential", "--direction", direction)
        assert proc.returncode == 0, proc.stderr
        assert json.loads((out / "summary.json").read_text())["method"] == "sequential"
        photos[direction] = np.array([[num(r[c]) for c in ("X0", "Y0", "Z0")] for r in read_table(out / "photos.csv")[1]])
    assert np.abs(photos["forward"] - photos["backward"]).max() > 1e-4
    plain = run("adjust", DATA / "strip8", "--out", tmp_path / "plain")
    init = run("adjust", DATA / "strip8", "--out", tmp_path / "init", "--init", "sequential")
    assert plain.returncode == 0 and init.returncode == 0, init.stderr
    a = np.array([[num(r[c]) for c in ("X0", "Y0", "Z0")] for r in read_table(tmp_path / "plain" / "photos.csv")[1]])
    b = np.array([[num(r[c]) for c in ("X0", "Y0", "Z0")] for r in read_table(tmp_path / "init" / "photos.csv")[1]])
    np.testing.assert_allclose(b, a, atol=1e-6)
    block = run("adjust", DATA / "block_3x6", "--out", tmp_path / "block", "--method", "sequential")
    # the method refused for this input is bad input (issue 26: it was exit status 1)
    assert block.returncode == 2 and "one strip" in block.stderr and "Traceback" not in block.stderr
    snoop = run("adjust", DATA / "strip8", "--out", tmp_path / "s", "--method", "sequential", "--blunders", "snoop")
    assert snoop.returncode == 2 and "simultaneous" in snoop.stderr
