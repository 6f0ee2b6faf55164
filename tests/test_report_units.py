"""The plate unit of a project ([units] plate = "mm" | "px", docs/file-formats.md) reaches every
label of report.html: a project in mm shows its residuals in micrometres of the plate, one in
pixels (BAL, COLMAP at one plate unit per pixel) in pixels, without the factor 1000. The converters
write the unit into the project.toml they generate; a value outside the list is bad input (exit 2,
naming project.toml, the line and the key)."""

from __future__ import annotations

import functools
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from striptri.report import figures, html as report, page
from striptri import pipeline
from striptri.cli import main
from striptri.formats import convert
from striptri.io import read_project
from striptri.io.project_reader import parse_settings
from striptri.io.project_writer import settings_toml
from striptri.model import PLATE_UNITS, ProjectSettings
from test_formats import synthetic_bal_text

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


def _bal_project(folder: Path):
    """A BAL problem converted by `striptri convert` to a project folder (pinhole: the synthetic
    problem is too small to estimate k1, k2 of four cameras)."""
    folder.mkdir(parents=True)
    (folder / "problem.txt").write_text(synthetic_bal_text(k1=-0.1))
    convert(folder / "problem.txt", folder / "project", "project", drop_distortion=True)
    return folder / "project"


@pytest.fixture(scope="module")
def bal_folder(tmp_path_factory):
    return _bal_project(tmp_path_factory.mktemp("bal") / "units")


@functools.lru_cache(maxsize=None)
def _products(folder: Path):
    project = read_project(folder)
    return pipeline.adjust_products(project, pipeline.options_for(project))


class _Drawn:
    """The labels report.html gives its residual figures (figures.plate_residuals_* wrapped)."""

    def __init__(self, monkeypatch):
        self.per_photo, self.stacked = [], []
        per_photo, stacked = figures.plate_residuals_per_photo, figures.plate_residuals_stacked

        def record_per_photo(*args, **kwargs):
            self.per_photo.append({"titles": args[4], "bar_label": args[6].label})
            return per_photo(*args, **kwargs)

        def record_stacked(*args, **kwargs):
            self.stacked.append({"bar_label": args[4].label, "field": kwargs.get("field"),
                                 "plate_unit": kwargs.get("plate_unit", "mm")})
            return stacked(*args, **kwargs)

        monkeypatch.setattr(figures, "plate_residuals_per_photo", record_per_photo)
        monkeypatch.setattr(figures, "plate_residuals_stacked", record_stacked)


def _report(products, monkeypatch, large: bool = False) -> tuple[str, _Drawn]:
    drawn = _Drawn(monkeypatch)
    if large:  # the residual field of large projects: a raster of the RMS per cell
        monkeypatch.setattr(page, "MAX_VECTORS", 10)
        monkeypatch.setattr(page, "WORST_VECTORS", 4)
    w = products.blunders.w[products.blunders.rows]
    text = report.html_report(products.project, products.result, products.summary, w, points=products.points)
    return text, drawn


def _rms_line(text: str) -> str:
    return re.search(r"RMS of the plate residuals:.*?\)", text).group(0)


# --------------------------------------------------------------------------- the plate unit of a project


def test_bal_conversion_writes_pixels_into_project_toml(bal_folder):
    toml = (bal_folder / "project.toml").read_text(encoding="utf-8")
    assert 'plate = "px"' in toml.split("[defaults]")[0]  # in [units]
    assert read_project(bal_folder).settings.plate_unit == "px"


def test_default_plate_unit_is_mm_and_not_written():
    """Projects without the key (every project before it existed) are in mm; the writer leaves the
    default out, so the simulator's project.toml files stay as they were."""
    assert read_project(DATA / "strip8").settings.plate_unit == "mm"
    assert "plate" not in settings_toml(ProjectSettings())
    px = settings_toml(ProjectSettings(plate_unit="px"))
    assert parse_settings("project.toml", px).plate_unit == "px"


@pytest.mark.parametrize("pixel_size, unit", [(None, "px"), (1.0, "px"), (0.012, "mm")])
def test_colmap_conversion_names_the_plate_unit(tmp_path, bal_folder, pixel_size, unit):
    """From COLMAP the plate coordinates are pixels at one plate unit per pixel, otherwise
    --pixel-size is the pixel pitch in mm."""
    convert(bal_folder, tmp_path / "colmap", "colmap")
    convert(tmp_path / "colmap", tmp_path / "project", "project", pixel_size=pixel_size)
    assert read_project(tmp_path / "project").settings.plate_unit == unit


def test_mm_round_trips_through_colmap_and_dbat(tmp_path):
    """strip8 (mm) -> COLMAP at 12 um pixels -> project, and -> DBAT -> project: still mm."""
    convert(DATA / "strip8", tmp_path / "colmap", "colmap", pixel_size=0.012)
    convert(tmp_path / "colmap", tmp_path / "from_colmap", "project", pixel_size=0.012)
    assert read_project(tmp_path / "from_colmap").settings.plate_unit == "mm"
    convert(DATA / "strip8", tmp_path / "dbat", "dbat", pixel_size=0.012)
    convert(tmp_path / "dbat" / "project.xml", tmp_path / "from_dbat", "project")
    assert read_project(tmp_path / "from_dbat").settings.plate_unit == "mm"


def test_pixel_size_that_does_not_fit_the_plate_unit_is_noted(tmp_path, bal_folder):
    """A project in mm written at 1 mm per pixel, or one in pixels at another pixel size: a note."""
    mm = convert(DATA / "strip8", tmp_path / "a", "colmap")
    assert any("in mm and the pixel size is 1" in n for n in mm.notes), mm.notes
    px = convert(bal_folder, tmp_path / "b", "colmap", pixel_size=0.005)
    assert any('plate = "px"' in n and "0.005" in n for n in px.notes), px.notes
    fitting = convert(bal_folder, tmp_path / "c", "colmap")
    assert not any("pixel size" in n for n in fitting.notes), fitting.notes


def test_bad_plate_unit_is_bad_input(tmp_path):
    """exit 2, the message naming project.toml, the line of the key, the key and the allowed values."""
    project = tmp_path / "strip8"
    shutil.copytree(DATA / "strip8", project)
    toml = project / "project.toml"
    text = toml.read_text(encoding="utf-8").replace('rotation = "omega-phi-kappa"\n',
                                                     'rotation = "omega-phi-kappa"\nplate = "um"\n')
    toml.write_text(text, encoding="utf-8")
    line = 1 + text.splitlines().index('plate = "um"')
    result = CliRunner().invoke(main, ["adjust", str(project), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert f"project.toml, line {line}: [units] plate: 'um' is not one of 'mm', 'px'" in result.output
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- the report


@pytest.mark.parametrize("large", [False, True])
def test_report_of_a_bal_project_is_in_pixels(bal_folder, monkeypatch, large):
    products = _products(bal_folder)
    text, drawn = _report(products, monkeypatch, large)
    v = products.result.plate_residuals
    rms = np.sqrt(np.mean(v**2, axis=0))
    assert "µm" not in text and "(mm)" not in text
    # no factor 1000: the RMS in px as computed from the residuals
    assert _rms_line(text) == (f"RMS of the plate residuals: v<sub>x</sub> {rms[0]:.2f} px, v<sub>y</sub> "
                               f"{rms[1]:.2f} px over {len(v)} measurements (plate coordinates in pixels)")
    assert "<th>x (px)</th><th>y (px)</th><th>v<sub>x</sub> (px)</th><th>v<sub>y</sub> (px)</th>" in text
    assert "RMS in px" in text and "about the principal point" in text and " px about the principal" in text
    # the photos table: the RMS of each photo in px
    ip = products.project.image_points
    first = ip.photo_index == 0
    rms0 = np.sqrt(np.mean(v[first] ** 2, axis=0))
    assert f"<td>{rms0[0]:.2f}</td><td>{rms0[1]:.2f}</td>" in text
    # the figures: titles, scale bars, axes and the field grid in px
    assert all(t.endswith(" px)") for t in drawn.per_photo[0]["titles"])
    assert drawn.per_photo[0]["bar_label"].endswith(" px")
    (stacked,) = drawn.stacked
    assert stacked["bar_label"].endswith(" px") and stacked["plate_unit"] == "px"
    if large:
        assert stacked["field"][1] == "px" and "grid over the format (px; white" in text


@pytest.mark.parametrize("large", [False, True])
def test_report_of_a_project_in_mm_is_in_micrometres(monkeypatch, large):
    products = _products(DATA / "strip8")
    text, drawn = _report(products, monkeypatch, large)
    v = products.result.plate_residuals
    rms = 1000.0 * np.sqrt(np.mean(v**2, axis=0))
    assert _rms_line(text) == (f"RMS of the plate residuals: v<sub>x</sub> {rms[0]:.1f} µm, v<sub>y</sub> "
                               f"{rms[1]:.1f} µm over {len(v)} measurements (plate coordinates in mm)")
    assert "<th>x (mm)</th><th>y (mm)</th><th>v<sub>x</sub> (µm)</th><th>v<sub>y</sub> (µm)</th>" in text
    assert "RMS in µm" in text and " mm about the principal point" in text
    assert "(px)" not in text and " px" not in text
    assert all(t.endswith(" µm)") for t in drawn.per_photo[0]["titles"])
    assert drawn.per_photo[0]["bar_label"].endswith(" µm")
    (stacked,) = drawn.stacked
    assert stacked["bar_label"].endswith(" µm") and stacked["plate_unit"] == "mm"
    if large:
        assert stacked["field"][1] == "µm" and "grid over the format (µm; white" in text


def test_residual_unit_is_one_helper():
    """(factor, label) of the residuals per plate unit, and the plate unit named in words."""
    mm, px = page.RESIDUAL_UNITS["mm"], page.RESIDUAL_UNITS["px"]
    assert (mm.factor, mm.label, mm.plate_words) == (1000.0, "µm", "mm")
    assert (px.factor, px.label, px.plate_words) == (1.0, "px", "pixels")
    assert mm(0.0042) == "4.2" and px(0.42) == "0.42" and mm(None) == px(float("nan")) == "&ndash;"
    assert mm.length(0.005) == "5 µm" and px.length(0.5) == "0.5 px"
    assert set(page.RESIDUAL_UNITS) == set(PLATE_UNITS)
