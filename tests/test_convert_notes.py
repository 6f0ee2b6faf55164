"""`striptri convert` says what an exchange format cannot hold of a project: map coordinates,
plate corrections and the GNSS model (BAL, COLMAP, DBAT), and that scanned film is written as plate
coordinates (formats.convert.what_the_target_leaves_out). The film note's claim is checked: the
converted project adjusts to the film project's result."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from striptri.cli import main
from striptri.formats.convert import convert
from striptri.io.project_reader import read_project

FILM = Path(__file__).resolve().parents[1] / "data" / "film_strip"


def _simulate(folder: Path, *extra: str) -> Path:
    res = CliRunner().invoke(main, ["simulate", "block", "--out", str(folder), "--photos", "4", "--strips", "2",
                                    *extra])
    assert res.exit_code == 0, res.output
    return folder


def test_film_is_written_as_plate_coordinates_and_adjusts_the_same(tmp_path):
    out = convert(FILM, tmp_path / "plate", "project")
    assert any(n.startswith("scanned film: the image points are written as plate coordinates") for n in out.notes)
    assert read_project(tmp_path / "plate").film is None
    summaries = []
    for i, folder in enumerate((FILM, tmp_path / "plate")):
        res = CliRunner().invoke(main, ["adjust", str(folder), "--out", str(tmp_path / f"out{i}"), "--quiet"])
        assert res.exit_code == 0, res.output
        summaries.append(json.loads((tmp_path / f"out{i}" / "summary.json").read_text()))
    assert summaries[1]["vtpv"] == pytest.approx(summaries[0]["vtpv"], rel=1e-9)
    assert summaries[1]["redundancy"] == summaries[0]["redundancy"]


@pytest.mark.parametrize("to", ["bal", "colmap", "dbat"])
def test_map_coordinates_to_an_exchange_format_are_said(tmp_path, to):
    src = _simulate(tmp_path / "p", "--crs", "EPSG:32633")
    notes = convert(src, tmp_path / to, to).notes
    said = [n for n in notes if n.startswith("map coordinates ([coordinates] crs = 'EPSG:32633'")]
    assert len(said) == 1 and "not a Cartesian frame" in said[0]


def test_a_project_target_keeps_the_coordinates_without_a_note(tmp_path):
    src = _simulate(tmp_path / "p", "--crs", "EPSG:32633")
    notes = convert(src, tmp_path / "copy", "project").notes
    assert not any("map coordinates" in n for n in notes)
    assert read_project(tmp_path / "copy").settings.coordinates.crs == "EPSG:32633"


def test_corrections_and_gnss_to_bal_are_said(tmp_path):
    src = _simulate(tmp_path / "p", "--gnss-sigma", "0.05", "--gnss-lever", "0,0,1")
    toml = src / "project.toml"
    toml.write_text(toml.read_text() + "\n[corrections]\nrefraction = true\n")
    notes = convert(src, tmp_path / "bal", "bal").notes
    assert any(n.startswith("[corrections] refraction: BAL gets the plate coordinates as measured") for n in notes)
    assert any(n.startswith("GNSS/IMU model") for n in notes)
    plain = convert(_simulate(tmp_path / "q"), tmp_path / "bal2", "bal").notes
    assert not any(n.startswith(("[corrections]", "GNSS", "map coordinates", "scanned film")) for n in plain)
