"""Weak points never fail a converged adjustment, and never hide; real data through the command
(issue 26; docs/decisions.md "Undetermined points"): a point whose rays do not determine it at the adjusted values (nearly
parallel rays, one ray left, coordinates lost to rejected measurements) is flagged
``undetermined`` in points.csv, named in summary.json's warnings and the report, left out of the
check-point statistics (which count it), and everything else is computed."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cli_support import DATA, SHARED_DATA, run
from striptri.core.runs import RunOptions
from striptri.equations.triangulation import (WEAK_FACTOR, conditioning, far_weaker_than_the_rest)

LADYBUG = SHARED_DATA / "bal_ladybug49" / "problem-49-7776-pre.txt"


# --------------------------------------------------------------------------- the criteria


def test_conditioning_is_the_ratio_of_the_extreme_eigenvalues_over_the_free_coordinates():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(4, 3, 3))
    N = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    free = np.ones((4, 3), dtype=bool)
    ev = np.linalg.eigvalsh(N)
    np.testing.assert_allclose(conditioning(N, free), ev[:, 0] / ev[:, -1], rtol=1e-12)
    np.testing.assert_allclose(conditioning(1e6 * N, free), ev[:, 0] / ev[:, -1], rtol=1e-12)  # scale-free
    # Z held: the ratio of the X, Y block, whatever N holds in Z's row and column
    held = free.copy()
    held[:, 2] = False
    ev2 = np.linalg.eigvalsh(N[:, :2, :2])
    np.testing.assert_allclose(conditioning(N, held), ev2[:, 0] / ev2[:, -1], rtol=1e-12)
    assert conditioning(N, np.zeros((4, 3), dtype=bool)).tolist() == [1.0] * 4
    assert conditioning(np.full((1, 3, 3), np.nan), free[:1]).tolist() == [0.0]


def test_a_point_far_weaker_than_the_rest_is_weak_and_the_usual_spread_is_not():
    rng = np.random.default_rng(7)
    sig = rng.uniform(0.02, 0.1, size=(200, 3))  # the usual spread: edge points several times the best
    cov = np.einsum("ni,ij->nij", sig**2, np.eye(3))
    cov[17, 2, 2] = (WEAK_FACTOR * 1.2 * np.median(sig.max(axis=1))) ** 2
    weak = far_weaker_than_the_rest(cov, np.ones(200, dtype=bool))
    assert weak.tolist() == [i == 17 for i in range(200)]
    assert not far_weaker_than_the_rest(cov[:5], np.ones(5, dtype=bool)).any()  # too few to compare


# --------------------------------------------------------------------------- a rejected group


def _block_with_blunders(tmp_path: Path) -> Path:
    """The issue's design (simulate block --photos 20 --strips 5 --check-points 12 --seed 22) with 2 %
    of the measurements given 10-30 sigma errors in x or y (a fixed draw, numpy seed 8)."""
    proc = run("simulate", "block", "--photos", "20", "--strips", "5", "--check-points", "12", "--seed", "22",
               "--out", tmp_path / "sim")
    assert proc.returncode == 0, proc.stderr
    project = tmp_path / "project"
    shutil.copytree(tmp_path / "sim", project, ignore=shutil.ignore_patterns("truth"))
    path = project / "image_points.csv"
    rows = list(csv.DictReader(path.open()))
    rng = np.random.default_rng(8)
    for i in rng.choice(len(rows), int(round(0.02 * len(rows))), replace=False):
        axis = "x" if rng.random() < 0.5 else "y"
        error = rng.uniform(10, 30) * float(rows[i][f"sigma_{axis}"]) * rng.choice([-1, 1])
        rows[i][axis] = repr(float(float(rows[i][axis]) + error))
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return project


def test_a_point_left_undetermined_by_a_rejected_group_is_flagged_and_left_out(tmp_path):
    """Before: the x coordinates of a check point rejected as one inseparable group left it with
    a Z tens of metres off, a sigma_Z of 20 m and more, no flag, no warning, and the check-point RMS
    grew a hundredfold."""
    project = _block_with_blunders(tmp_path)
    out = tmp_path / "out"
    proc = run("adjust", project, "--out", out, "--blunders", "snoop")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    points = {r["point_id"]: r for r in csv.DictReader((out / "points.csv").open())}
    given = {r["point_id"]: r for r in csv.DictReader((project / "control.csv").open()) if r["kind"] == "check"}
    flagged = {pid for pid, r in points.items() if r["flag"] == "undetermined"}
    left_out = sorted(flagged & set(given))
    assert left_out, "the draw was chosen to leave check points undetermined"
    check = summary["check_points"]
    assert check["n_left_out"] == len(left_out) and check["n"] == len(given) - len(left_out)
    warning = next(w for w in summary["warnings"] if "not determined by" in w)
    assert all(pid in warning for pid in sorted(flagged)[:10])
    assert "undetermined" in proc.stderr
    # every check point that remains determined is within its usual error (4 sigma, its own sigmas)
    for pid in set(given) - flagged:
        r = points[pid]
        for a in "XYZ":
            assert abs(float(r[a]) - float(given[pid][a])) <= 4 * float(r[f"sigma_{a}"]), (pid, a)
    # and the statistics are those of a block without gross errors (the truth's check-point RMS
    # is about 0.04 m, 0.05 m, 0.07 m)
    assert max(check["rms_X"], check["rms_Y"], check["rms_Z"]) < 0.1, check
    # each flagged point is far weaker than the block's points, or its rays nearly parallel
    sigmas = np.array([[float(r[f"sigma_{a}"] or "nan") for a in "XYZ"] for r in points.values()])
    usual = np.nanmedian(np.nanmax(sigmas, axis=1))
    for pid in flagged:
        s = [float(points[pid][f"sigma_{a}"] or "inf") for a in "XYZ"]
        assert max(s) > 3 * usual, (pid, s, usual)
    # the report says which check points were left out
    html = (out / "report.html").read_text()
    for pid in left_out:
        assert pid in html
    assert "left out" in html


# --------------------------------------------------------------------------- real data


@pytest.mark.skipif(not LADYBUG.exists(), reason="../shared/data/real is not beside the repository")
def test_ladybug_through_the_command_reaches_ceres_cost(tmp_path):
    """Before: convert then adjust of BAL's ladybug exited 1 after converging ("the cofactors of the
    residuals cannot be computed: the rays of points 7070, 7076, ... do not determine it"). Now:
    exit 0, converged, at the cost Ceres reaches on the same observations (13308.4127: pycolmap's
    SPARSE_SCHUR, scripts/bench/bench_bal.py; the 31 observations behind their camera inactive, as
    COLMAP gives them no residual), the far points flagged and named."""
    lady = tmp_path / "lady"
    proc = run("convert", LADYBUG, "--to", "project", "--out", lady)
    assert proc.returncode == 0, proc.stderr
    assert "31 observations whose point lies behind its camera" in proc.stderr
    proc = run("adjust", lady, "--out", tmp_path / "out", timeout=600)  # the defaults: --blunders off
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["converged"] is True and summary["options"]["blunders"] == "off"
    assert summary["vtpv"] / 2 == pytest.approx(13308.4127, abs=0.01)
    points = list(csv.DictReader((tmp_path / "out" / "points.csv").open()))
    flagged = [r["point_id"] for r in points if r["flag"] == "undetermined"]
    # the points the old message named are among them, and they are few
    assert {"7070", "7076", "7099", "7125", "7126"} <= set(flagged) and len(flagged) < 0.03 * len(points)
    assert any(f"{len(flagged)} points are not determined by" in w and flagged[0] in w for w in summary["warnings"])
    assert summary["inactive"]["n"] == 31


ROMA = SHARED_DATA / "dbat_roma" / "script" / "romabundledemo.xml"
CAMCAL = SHARED_DATA / "dbat_camcal" / "script" / "camcaldemo.xml"


@pytest.mark.skipif(not ROMA.exists(), reason="../shared/data/real is not beside the repository")
def test_roma_through_the_command_reproduces_dbat(tmp_path):
    """DBAT's 60-image block through the real command with the defaults: sigma0 0.582769 px and
    redundancy 101,801 of DBAT's report (script/result/report.txt); a few far points flagged."""
    proc = run("convert", ROMA, "--to", "project", "--out", tmp_path / "roma")
    assert proc.returncode == 0, proc.stderr
    proc = run("adjust", tmp_path / "roma", "--out", tmp_path / "out", timeout=600)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["converged"] is True and summary["redundancy"] == 101801
    assert f"{summary['sigma0']:.6f}" == "0.582769"


@pytest.mark.skipif(not CAMCAL.exists(), reason="../shared/data/real is not beside the repository")
def test_camcal_through_the_command_reproduces_dbat(tmp_path):
    """DBAT's camera calibration through the real command (a subprocess) with the defaults: sigma0
    1.6148 and redundancy 3725 of DBAT's report."""
    proc = run("convert", CAMCAL, "--to", "project", "--out", tmp_path / "cc")
    assert proc.returncode == 0, proc.stderr
    proc = run("adjust", tmp_path / "cc", "--out", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["converged"] is True and summary["redundancy"] == 3725
    assert f"{summary['sigma0']:.4f}" == "1.6148"


def test_a_tie_point_left_undetermined_in_a_strip_is_flagged():
    """Before: in a copy of strip8 with one 0.1 mm y-error (tie point 1001C on photo 1002) snooping
    rejected the point's y coordinates, leaving it with a sigma_Y of 30 m, unflagged."""
    from dataclasses import replace

    from striptri.io import read_project
    from striptri.pipeline import adjust_products, options_for

    project = read_project(DATA / "strip8")
    ip = project.image_points
    row = next(i for i in range(len(ip)) if project.photos.ids[ip.photo_index[i]] == "1002"
               and project.points.ids[ip.point_index[i]] == "1001C")
    xy = ip.xy.copy()
    xy[row, 1] += 0.1
    project = replace(project, image_points=replace(ip, xy=xy))
    products = adjust_products(project, options_for(project), RunOptions(blunders="snoop"))
    rows = {r["point_id"]: r for r in csv.DictReader(products.files["points.csv"].splitlines())}
    assert rows["1001C"]["flag"] == "undetermined"
    assert float(rows["1001C"]["sigma_Y"]) > 1.0  # metres: its rays no longer fix it in Y
    assert any("1001C" in w and "not determined by" in w for w in products.summary["warnings"])
    assert sum(r["flag"] == "undetermined" for r in rows.values()) == 1  # the others stay as they were
