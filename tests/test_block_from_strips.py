"""Approximate orientations of a block from its strips (striptri.sequential.block), for photos
that come without any (issue 28, striptri match on unoriented photos).

A simulated block of 3 strips x 8 photos (no image noise beyond the simulator's 5 um), its
photos.csv with the middle strip listed backwards; the given approximations are not used.
Tolerance: centres within 0.1 % of the flying height (1.6 m; measured 0.70 m largest) and angles
within 0.05 degrees (measured 0.027): a strip triangulation's quality, far inside the few degrees
the adjustment needs."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from striptri.cli import main
from striptri.errors import NumericalFailure
from striptri.geometry.rotations import R_from_angles
from striptri.io.project_reader import read_project
from striptri.sequential.block import block_from_strips


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("strips")
    run = CliRunner().invoke(main, ["simulate", "block", "--strips", "3", "--photos", "8", "--check-points", "4",
                                    "--seed", "5", "--out", str(root / "b")])
    assert run.exit_code == 0, run.output
    path = root / "b" / "photos.csv"
    lines = path.read_text().splitlines()
    strip2 = [ln for ln in lines[1:] if ln.split(",")[2] == "2"]
    path.write_text("\n".join([lines[0]] + [ln for ln in lines[1:] if ln.split(",")[2] == "1"] + strip2[::-1]
                              + [ln for ln in lines[1:] if ln.split(",")[2] == "3"]) + "\n")
    return root / "b"


def _truth(folder, ids):
    t = {r["photo_id"]: r for r in csv.DictReader((folder / "truth" / "photos.csv").open())}
    O = np.array([[float(t[i][k]) for k in ("X0", "Y0", "Z0")] for i in ids])
    R = R_from_angles(np.radians([[float(t[i][k]) for k in ("omega", "phi", "kappa")] for i in ids]),
                      "omega-phi-kappa")
    return O, R


def test_the_strips_are_built_and_placed_on_the_control_and_on_one_another(folder):
    project = read_project(folder)
    block = block_from_strips(project)
    O, R = _truth(folder, project.photos.ids)
    assert np.abs(block.xyz0 - O).max() < 0.001 * 1600.0
    angle = np.degrees(np.arccos(np.clip((np.einsum("nij,nij->n", block.R_ground_from_cam, R) - 1) / 2, -1, 1)))
    assert angle.max() < 0.05, angle
    assert [s.strip for s in block.strips][0] in {"1", "3"}  # a strip with control goes first
    assert all(s.points >= 3 for s in block.strips)


def test_a_strip_that_cannot_be_placed_is_named(folder, tmp_path):
    """Strip 3's measurements of points seen elsewhere (and of control) renamed: it keeps its
    models but shares nothing with the ground."""
    for f in folder.iterdir():
        if f.is_file():
            (tmp_path / f.name).write_bytes(f.read_bytes())
    strip_of = {r["photo_id"]: r["strip_id"] for r in csv.DictReader((folder / "photos.csv").open())}
    rows = list(csv.DictReader((folder / "image_points.csv").open()))
    control = {r["point_id"] for r in csv.DictReader((folder / "control.csv").open())}
    elsewhere = {r["point_id"] for r in rows if strip_of[r["photo_id"]] != "3"} | control
    with (tmp_path / "image_points.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            if strip_of[r["photo_id"]] == "3" and r["point_id"] in elsewhere:
                r = {**r, "point_id": r["point_id"] + "_apart"}
            w.writerow(r)
    with pytest.raises(NumericalFailure) as e:
        block_from_strips(read_project(tmp_path))
    text = str(e.value)
    assert "strip 3 (8 photos): 0 full control points and 0 points of strips already placed" in text
    assert "Give approximate orientations" in text
