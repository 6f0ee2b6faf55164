"""GNSS input contract (io.gnss_reader): round trip, InputErrors naming file, line and reason;
outputs (cameras.csv columns, strips.csv, report section) and the simulator's GNSS block."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import replace

import numpy as np
import pytest
from test_gnss import ALL_FREE, ALL_OBSERVED, gnss_block

from striptri.adjustment import AdjustmentOptions, adjust
from striptri.errors import InputError
from striptri.io.project_reader import parse_project
from striptri.io.project_writer import project_files
from striptri.pipeline import adjust_products


def _files(gnss=ALL_FREE, seed=3):
    project, tables = gnss_block(seed, gnss)
    return project, project_files(project)


@pytest.mark.parametrize("gnss", [ALL_FREE, ALL_OBSERVED], ids=["free", "observed"])
def test_round_trip_gives_the_same_adjustment(gnss):
    project, files = _files(gnss)
    read = parse_project(files)
    g, h = project.gnss, read.gnss
    for name in ("lever", "sigma_lever", "boresight", "sigma_boresight", "time"):
        np.testing.assert_allclose(getattr(h, name), getattr(g, name), rtol=1e-12, atol=1e-15)
    assert (h.shift, h.drift, h.strip_ids) == (g.shift, g.drift, g.strip_ids)
    np.testing.assert_equal([h.sigma_shift, h.sigma_drift], [g.sigma_shift, g.sigma_drift])
    assert not read.notes  # every GNSS column was read
    assert adjust(read).vtpv == pytest.approx(adjust(project).vtpv, rel=1e-9)


def test_project_without_gnss_inputs_has_no_model():
    project, _ = _files()
    assert parse_project(project_files(replace(project, gnss=None))).gnss is None


def _edit(text: str, column: str, row: int, value: str) -> str:
    rows = list(csv.reader(io.StringIO(text)))
    j = rows[0].index(column)
    rows[1 + row][j] = value
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def _drop_column(text: str, column: str) -> str:
    rows = list(csv.reader(io.StringIO(text)))
    j = rows[0].index(column)
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([r[:j] + r[j + 1:] for r in rows])
    return out.getvalue()


def _error(files) -> InputError:
    with pytest.raises(InputError) as info:
        parse_project(files)
    return info.value


def test_drift_without_time_names_photos_csv():
    _, files = _files()
    e = _error({**files, "photos.csv": _drop_column(files["photos.csv"], "time")})
    assert "photos.csv" in str(e) and "time" in str(e)
    e = _error({**files, "photos.csv": _edit(files["photos.csv"], "time", 2, "")})
    assert "photos.csv" in str(e) and e.line == 4 and "time" in str(e)


def test_bad_mode_and_sigma_name_project_toml_and_line():
    _, files = _files()
    e = _error({**files, "project.toml": files["project.toml"].replace('drift = "free"', 'drift = "linear"')})
    assert "project.toml" in str(e) and "'linear'" in str(e) and e.line is not None
    e = _error({**files, "project.toml": files["project.toml"].replace('shift = "free"', 'shift = "observed"')})
    assert "sigma_shift" in str(e)
    e = _error({**files, "project.toml": files["project.toml"] + "sigma_drift = 0.01\n"})
    assert "sigma_drift" in str(e) and "observed" in str(e)
    e = _error({**files, "project.toml": files["project.toml"] + "drfit = 1\n"})
    assert "drfit" in str(e)


def test_bad_lever_arm_values_name_cameras_csv_line():
    _, files = _files()
    e = _error({**files, "cameras.csv": _edit(files["cameras.csv"], "sigma_lever_x", 0, "-1")})
    assert "cameras.csv" in str(e) and e.line == 2 and "negative" in str(e)
    e = _error({**files, "cameras.csv": _edit(files["cameras.csv"], "lever_z", 0, "1500")})
    assert "lever_z" in str(e) and e.line == 2
    e = _error({**files, "cameras.csv": _edit(files["cameras.csv"], "lever_y", 0, "abc")})
    assert "cameras.csv" in str(e) and e.line == 2


def test_estimated_lever_arm_needs_observed_centres():
    project, files = _files()
    photos = files["photos.csv"]
    for axis in ("X0", "Y0", "Z0"):
        for i in range(len(project.photos)):
            photos = _edit(photos, f"sigma_{axis}", i, "")
    e = _error({**files, "photos.csv": photos})
    assert "cameras.csv" in str(e) and "observed" in str(e)


def test_outputs_and_report():
    project, _ = gnss_block(3, ALL_FREE)
    products = adjust_products(project, AdjustmentOptions())
    cams = list(csv.DictReader(io.StringIO(products.files["cameras.csv"])))
    header = products.files["cameras.csv"].splitlines()[0].split(",")
    assert header[:11] == ["camera_id", "c", "xp", "yp", "k1", "k2", "sigma_c", "sigma_xp", "sigma_yp", "sigma_k1",
                           "sigma_k2"]
    assert header[-12:-6] == ["lever_x", "lever_y", "lever_z", "boresight_x", "boresight_y", "boresight_z"]
    result = products.result
    assert float(cams[0]["lever_z"]) == pytest.approx(result.state.gnss.lever[0, 2])
    assert float(cams[0]["sigma_lever_z"]) > 0
    strips = list(csv.DictReader(io.StringIO(products.files["strips.csv"])))
    assert [s["strip_id"] for s in strips] == list(project.gnss.strip_ids)
    assert float(strips[1]["drift_Y"]) == pytest.approx(result.state.gnss.drift[1, 1])
    # the mean error is the inverse normal matrix's: sigma0 sqrt(Qxx_ii)
    col = result.layout.gnss_cols.drift[1, 1]
    assert float(strips[1]["sigma_drift_Y"]) == pytest.approx(
        result.sigma0_for_precision * np.sqrt(result.Qxx[col, col]), rel=1e-9)
    summary = json.loads(products.files["summary.json"])["gnss"]
    assert summary["drift_sigma"][1][1] == pytest.approx(float(strips[1]["sigma_drift_Y"]))
    assert summary["shift"] == "free" and len(summary["lever_values"]) == 1
    html = products.files["report.html"]
    assert "id='gnss'" in html and "Lever arm" in html and "drift" in html and "Correlations among" in html


def test_plain_project_has_no_gnss_outputs():
    project, _ = gnss_block(3, ALL_FREE)
    products = adjust_products(replace(project, gnss=None), AdjustmentOptions())
    assert "strips.csv" not in products.files and "lever_x" not in products.files["cameras.csv"]
    assert "id='gnss'" not in products.files["report.html"]
    assert "gnss" not in json.loads(products.files["summary.json"])


def test_cli_simulates_and_adjusts_a_gnss_block(tmp_path):
    from cli_support import assert_clean_failure, run
    proj, out = tmp_path / "p", tmp_path / "o"
    proc = run("simulate", "block", "--out", proj, "--strips", "3", "--photos", "6", "--gnss-sigma", "0.05",
               "--gnss-lever", "0.1,-0.2,1.5", "--seed", "4")
    assert proc.returncode == 0, proc.stderr
    assert {"strips.csv", "cameras_gnss.csv"} <= {p.name for p in (proj / "truth").iterdir()}
    proc = run("adjust", proj, "--out", out)
    assert proc.returncode == 0, proc.stderr
    est = list(csv.DictReader((out / "strips.csv").open()))
    true = list(csv.DictReader((proj / "truth" / "strips.csv").open()))
    for e, t in zip(est, true):
        for name in ("shift_X", "shift_Y", "shift_Z", "drift_X", "drift_Y", "drift_Z"):
            assert abs(float(e[name]) - float(t[name])) < 4 * float(e[f"sigma_{name}"])
    # drift without times: exit 2 naming photos.csv, no output
    photos = (proj / "photos.csv").read_text()
    (proj / "photos.csv").write_text(_drop_column(photos, "time"))
    proc = run("adjust", proj, "--out", tmp_path / "o2")
    err = assert_clean_failure(proc, 2)
    assert "photos.csv" in err and "time" in err
    assert not (tmp_path / "o2").exists()


def test_boresight_needs_observed_angles_and_a_short_rotation_vector():
    from test_gnss import GnssOptions
    project, files = _files(GnssOptions(boresight_mode="free", sigma_imu=None))
    e = _error(files)
    assert "cameras.csv" in str(e) and e.line == 2 and "IMU" in str(e)
    _, files = _files(ALL_FREE)
    e = _error({**files, "cameras.csv": _edit(files["cameras.csv"], "boresight_x", 0, "200")})
    assert "cameras.csv" in str(e) and e.line == 2 and "180" in str(e)
