"""Scanned film input files (striptri.io.film_reader) and the worked example data/film_strip (issue 16)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_support import assert_clean_failure, run

from striptri.core.runs import RunOptions
from striptri.errors import InputError
from striptri.simulate.film import FilmOptions, film_project_files
from striptri.io.csvtable import format_csv
from striptri.io.project_reader import parse_project, read_project
from striptri.pipeline import run_adjust

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "film_strip"


def example_files() -> dict:
    return {p.name: p.read_text(encoding="utf-8") for p in EXAMPLE.iterdir() if p.is_file()}


def test_the_example_is_what_the_script_writes():
    """data/film_strip is scripts/make_film_strip.py's output (seed 16): nothing edited by hand."""
    files, truth = film_project_files(FilmOptions(), seed=16)
    assert files == example_files()
    for name, columns in truth.items():
        assert (EXAMPLE / "truth" / name).read_text(encoding="utf-8") == format_csv(columns)


def test_example_reads_to_plate_millimetres_close_to_the_truth():
    """The image points are carried to the plate: within a few sigma of the true ideal plate points
    (the simulator's exact plates, through the same projection)."""
    project = read_project(EXAMPLE)
    film = project.film
    assert film.transformation == "affine" and len(film.photo_ids) == 30
    assert np.all(np.abs(project.image_points.xy) < 120)  # mm, no longer pixels
    # 0.5 px at 50 px/mm = 0.01 mm, inflated a little by the transformation's uncertainty
    assert np.all((project.image_points.sigma_xy > 0.0099) & (project.image_points.sigma_xy < 0.013))
    assert len(film.calibrations) == 1 and film.calibrations[0].fit.rms_um < 0.5


@pytest.mark.parametrize("method", ["sequential", "conditions"])
def test_example_adjusts_and_reports_the_fiducials(tmp_path, method):
    out = tmp_path / method
    products = run_adjust(EXAMPLE, out, RunOptions(method=method))
    assert products.result.converged
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "Fiducial marks and calibration report" in html and "largest |v| px" in html
    summary = json.loads((out / "summary.json").read_text())
    assert summary["film"]["n_photos"] == 30 and summary["film"]["flagged_fiducials"] == []
    rows = (out / "fiducial_residuals.csv").read_text().splitlines()
    assert rows[0] == "photo_id,fiducial_id,v_col,v_row,w_col,w_row,flag" and len(rows) == 1 + 240


def test_a_20_pixel_fiducial_error_is_flagged_in_the_report(tmp_path):
    folder = tmp_path / "film"
    shutil.copytree(EXAMPLE, folder)
    path = folder / "fiducial_measurements.csv"
    lines = path.read_text().splitlines()
    photo, fid, col, row = lines[5 * 8 + 3].split(",")  # photo 1006, fiducial 3
    lines[5 * 8 + 3] = ",".join([photo, fid, f"{float(col) + 20.0:.2f}", row])
    path.write_text("\n".join(lines) + "\n")
    run_adjust(folder, tmp_path / "out")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["film"]["flagged_fiducials"] == [[photo, fid]]
    html = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    # the photo's row names the fiducial (left-aligned photo id, flagged list marked bad)
    assert f"<td class='l'>{photo}</td>" in html and f"<td class='bad'>{fid}</td>" in html
    assert "<td class='bad'>flagged</td>" in html


BAD = [
    ("project.toml", lambda t: t.replace('transformation = "affine"', 'transformation = "helmert"'),
     "project.toml", "[film] transformation: 'helmert' is not one of"),
    ("project.toml", lambda t: t.replace('image_points = "scan_px"', 'image_points = "pixels"'),
     "project.toml", "[film] image_points"),
    ("project.toml", lambda t: t.replace("sigma_px = 0.5", "sigma_px = -1"), "project.toml", "[film] sigma_px"),
    ("fiducial_measurements.csv", lambda t: t.replace("1001,3,", "1001,9,", 1), "fiducial_measurements.csv",
     "fiducial '9' is not in fiducials.csv"),
    ("fiducial_measurements.csv", lambda t: t.replace("1002,1,", "1099,1,", 1), "fiducial_measurements.csv",
     "unknown photo_id '1099'"),
    ("fiducial_measurements.csv", lambda t: t.replace("1001,2,", "1001,1,", 1), "fiducial_measurements.csv",
     "measured twice"),
    ("fiducial_measurements.csv", lambda t: "\n".join(l for l in t.splitlines() if not l.startswith(("1003,1,", "1003,2,", "1003,3,", "1003,4,", "1003,5,", "1003,6,"))),
     "fiducial_measurements.csv", "photo '1003' has 2 measured fiducials; the affine transformation needs at least 3"),
    ("fiducial_measurements.csv", lambda t: t.replace("col,row", "col,row,sigma").replace("\n", ",\n").replace(
        "col,row,sigma,", "col,row,sigma").replace(",\n1002,1,", ",0\n1002,1,", 1), "fiducial_measurements.csv",
     "column 'sigma': must be > 0"),
    ("fiducials.csv", lambda t: t.replace("RC,8,", "RC,7,"), "fiducials.csv", "given twice"),
    ("fiducials.csv", lambda t: t.replace("RC,8,", "XX,8,"), "fiducials.csv", "unknown camera_id 'XX'"),
    ("calibration.toml", lambda t: t.replace("[camera.RC]", "[camera.XX]"), "calibration.toml", "unknown camera 'XX'"),
    ("calibration.toml", lambda t: t.replace("focal_length_mm", "focal_lenght_mm"), "calibration.toml", "unknown key"),
    ("calibration.toml", lambda t: t.replace("radial_distortion_um = [", "radial_distortion_um = [1, "),
     "calibration.toml", "expected 6 numbers"),
    ("calibration.toml", lambda t: t + "radius_mm = [1, 2]\n", "calibration.toml", "one of them"),
    ("calibration.toml", lambda t: t.replace("= [", "= ((", 1), "calibration.toml", "not valid TOML"),
]


@pytest.mark.parametrize("name, edit, where, reason", BAD)
def test_bad_film_input_names_file_line_and_reason(name, edit, where, reason):
    files = example_files()
    files[name] = edit(files[name])
    with pytest.raises(InputError) as info:
        parse_project(files, "film")
    message = str(info.value)
    assert where in message and reason in message, message
    if name != "fiducial_measurements.csv" or "needs at least" not in reason:
        assert info.value.line is not None, message


def test_missing_fiducial_file_and_cli_exit_2(tmp_path):
    folder = tmp_path / "film"
    shutil.copytree(EXAMPLE, folder)
    (folder / "fiducials.csv").unlink()
    proc = run("adjust", folder, "--out", tmp_path / "out")
    err = assert_clean_failure(proc, 2)
    assert "fiducials.csv" in err and "scan_px" in err
    assert not (tmp_path / "out").exists()


def test_collinear_fiducials_and_unused_columns():
    """Photo 1002 keeps only fiducials 5 and 7, enough for a similarity, but 7 is moved onto 5 in
    fiducials.csv: an InputError naming the photo, not a singular matrix. An extra column is a Note."""
    files = example_files()
    lines = files["fiducial_measurements.csv"].splitlines()
    keep = [l for l in lines if not l.startswith("1002,") or l.split(",")[1] in ("5", "7")]
    files["fiducial_measurements.csv"] = "\n".join(keep) + "\n"
    files["project.toml"] = files["project.toml"].replace('"affine"', '"similarity"')
    files["fiducials.csv"] = files["fiducials.csv"].replace("RC,7,-0.002,113.003", "RC,7,0.001,-112.998")
    with pytest.raises(InputError) as info:
        parse_project(files, "film")
    assert "photo '1002'" in str(info.value) and "lie on a line or coincide" in str(info.value)
    files = example_files()
    files["fiducials.csv"] = files["fiducials.csv"].replace("camera_id,fiducial_id,x,y", "camera_id,fiducial_id,x,y,z")
    files["fiducials.csv"] = "\n".join(l + ",0" if l.startswith("RC,") else l
                                       for l in files["fiducials.csv"].splitlines()) + "\n"
    project = parse_project(files, "film")
    assert any("fiducials.csv" in n.path and "'z'" in n.text for n in project.notes)


def test_a_calibration_report_alone_sets_the_camera():
    """calibration.toml in a project with plate coordinates (no [film]): the camera's c, xp, yp, k1,
    k2 come from the fitted report (K0 folded into c), a Note says so; the image points are untouched."""
    strip8 = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8"
    files = {p.name: p.read_text(encoding="utf-8") for p in strip8.iterdir() if p.is_file()}
    before = parse_project(files, "strip8")
    files["calibration.toml"] = ("[camera.C1]\nfocal_length_mm = 153.247\npbs_mm = [0.006, -0.001]\n"
                                 "field_angle_deg = [7.5, 15, 22.7, 30, 35, 40]\n"
                                 "radial_distortion_um = [-1, -1, -1, 0, 1, 1]\n")
    project = parse_project(files, "strip8")
    cal = project.film.calibrations[0]
    c, xp, yp, k1, k2 = project.cameras.interior[0, :5]
    assert abs(c - 153.247 / (1 + cal.fit.k0)) < 1e-12 and (xp, yp) == (0.006, -0.001)
    assert (k1, k2) == tuple(cal.fit.k[:2] / (1 + cal.fit.k0))
    assert project.film.fit is None and np.array_equal(project.image_points.xy, before.image_points.xy)
    assert any("calibration.toml" in n.path for n in project.notes)
