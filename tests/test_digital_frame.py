"""Digital frame cameras (issue 28): cameras.csv's width_px, height_px, pixel_size and the pixel
convention of docs/file-formats.md (striptri.geometry.pixels)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest

from striptri.errors import InputError
from striptri.geometry.pixels import pixel_from_plate, plate_from_pixel
from striptri.io import read_project
from striptri.io.project_writer import write_project

STRIP8 = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8"


def test_the_pixel_convention():
    size, s = np.array([4000, 3000]), 0.005
    # the centre of the top-left pixel, the image centre, the bottom-right corner
    xy = plate_from_pixel(np.array([[0.5, 0.5], [2000.0, 1500.0], [4000.0, 3000.0]]), size, s)
    np.testing.assert_allclose(xy, [[(0.5 - 2000) * s, (1500 - 0.5) * s], [0.0, 0.0], [10.0, -7.5]])
    rng = np.random.default_rng(1)
    colrow = rng.uniform(0, 4000, (50, 2))
    np.testing.assert_allclose(pixel_from_plate(plate_from_pixel(colrow, size, s), size, s), colrow, rtol=0, atol=1e-9)


def _with_columns(tmp_path, header, values):
    folder = tmp_path / "p"
    shutil.copytree(STRIP8, folder)
    rows = list(csv.reader((folder / "cameras.csv").open()))
    rows[0] += header
    for r in rows[1:]:
        r += values
    with (folder / "cameras.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    return folder


def test_cameras_csv_reads_and_writes_a_digital_frame_camera(tmp_path):
    folder = _with_columns(tmp_path, ["width_px", "height_px", "pixel_size"], ["11310", "17310", "0.0133"])
    project = read_project(folder)
    np.testing.assert_array_equal(project.cameras.size_px, [[11310, 17310]])
    np.testing.assert_array_equal(project.cameras.pixel_size, [0.0133])
    write_project(tmp_path / "q", project)
    again = read_project(tmp_path / "q")
    np.testing.assert_array_equal(again.cameras.size_px, project.cameras.size_px)
    np.testing.assert_array_equal(again.cameras.pixel_size, project.cameras.pixel_size)
    assert read_project(STRIP8).cameras.size_px is None  # a film camera: none


@pytest.mark.parametrize("header, values, message", [
    (["width_px", "height_px"], ["100", "80"], "pixel_size missing"),
    (["width_px", "height_px", "pixel_size"], ["100", "", "0.01"], "all three or none"),
    (["width_px", "height_px", "pixel_size"], ["100.5", "80", "0.01"], "whole number of pixels"),
    (["width_px", "height_px", "pixel_size"], ["100", "80", "-0.01"], "must be > 0"),
])
def test_a_bad_digital_frame_is_an_error_naming_the_line(tmp_path, header, values, message):
    folder = _with_columns(tmp_path, header, values)
    with pytest.raises(InputError, match=message) as err:
        read_project(folder)
    assert Path(err.value.path).name == "cameras.csv"
    assert err.value.line in (1, 2)  # the header (a column missing) or the camera's line
