"""The structure of the normal matrix (Schmid Fig. 10) and its figure."""

import subprocess
from pathlib import Path

import numpy as np

from striptri.adjustment import normal_matrix_at_approximations
from striptri.report.figures import normal_matrix_structure
from striptri.io import read_project

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_strip_normal_matrix_is_filled_within_two_photos_of_the_diagonal():
    """Photos in flight order, 60 % overlap: a photo shares points with the two before and the two
    after it, so its 6x6 blocks are nonzero exactly within two photos of the diagonal."""
    project = read_project(DATA / "strip8")
    N, layout = normal_matrix_at_approximations(project)
    n = len(project.photos)
    blocks = np.abs(N.toarray()).reshape(n, 6, n, 6).sum(axis=(1, 3)) > 0
    i, j = np.indices((n, n))
    np.testing.assert_array_equal(blocks, np.abs(i - j) <= 2)


def test_structure_figure_is_a_png():
    project = read_project(DATA / "strip8")
    N, layout = normal_matrix_at_approximations(project)
    png = normal_matrix_structure(N, layout.block_starts(), len(project.photos))
    assert png.startswith(PNG_SIGNATURE) and len(png) > 2000


def test_structure_command(tmp_path):
    out = tmp_path / "fig" / "structure.png"
    done = subprocess.run(["striptri", "structure", str(DATA / "pair"), "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert out.read_bytes().startswith(PNG_SIGNATURE)
    bad = subprocess.run(["striptri", "structure", str(tmp_path / "nope"), "--out", str(tmp_path / "x.png")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and not (tmp_path / "x.png").exists()
