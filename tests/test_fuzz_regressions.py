"""The defects the fuzzing of issue 26 found in the inputs added by issues 14-17, as regression
tests: bad values end with exit status 2, the file, the line and the reason; extreme but valid
values are handled or refused in words; nothing hangs."""

from __future__ import annotations

import csv
import itertools
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from cli_support import DATA, REPO, assert_clean_failure, run, snapshot
from striptri.adjustment import adjust
from striptri.io import read_project
from striptri.pipeline import options_for

CLOSE_RANGE = REPO / "data" / "close_range"


# --------------------------------------------------------------------------- COLMAP


@pytest.fixture()
def colmap(tmp_path) -> Path:
    out = tmp_path / "colmap"
    proc = run("convert", DATA / "strip8", "--to", "colmap", "--out", out)
    assert proc.returncode == 0, proc.stderr
    return out


def _refused(src: Path, tmp_path: Path, where: str, words: list[str]) -> None:
    before = snapshot(src)
    out = tmp_path / "converted"
    err = assert_clean_failure(run("convert", src, "--to", "project", "--out", out), 2)
    assert where in err, err
    for word in words:
        assert word in err, (word, err)
    assert not out.exists() and snapshot(src) == before


@pytest.mark.parametrize("size", ["0 198", "210 -5"])
def test_colmap_image_size_must_be_positive(colmap, tmp_path, size):
    """Before: zero or negative image sizes were accepted (exit 0)."""
    path = colmap / "cameras.txt"
    lines = path.read_text().splitlines()
    i = next(k for k, line in enumerate(lines) if line and not line.startswith("#"))
    tokens = lines[i].split()
    tokens[2:4] = size.split()
    lines[i] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")
    _refused(colmap, tmp_path, f"cameras.txt, line {i + 1}", ["WIDTH HEIGHT must be positive"])


def test_colmap_duplicate_image_name_is_refused(colmap, tmp_path):
    path = colmap / "images.txt"
    lines = path.read_text().splitlines()
    data = [k for k, line in enumerate(lines) if line and not line.startswith("#")]
    first, second = data[0], data[2]  # the image lines (each followed by its POINTS2D line)
    name = lines[first].split()[9]
    tokens = lines[second].split()
    tokens[9] = name
    lines[second] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")
    _refused(colmap, tmp_path, f"images.txt, line {second + 1}", [f"NAME '{name}' occurs twice"])


def test_colmap_point_observed_twice_in_one_image_is_refused(colmap, tmp_path):
    path = colmap / "images.txt"
    lines = path.read_text().splitlines()
    data = [k for k, line in enumerate(lines) if line and not line.startswith("#")]
    k = data[1]  # the POINTS2D line of the first image
    triples = lines[k].split()
    triples[5] = triples[2]  # the second 2D point names the first one's 3D point
    lines[k] = " ".join(triples)
    path.write_text("\n".join(lines) + "\n")
    _refused(colmap, tmp_path, f"images.txt, line {k + 1}", ["observed twice"])


@pytest.mark.parametrize("change", ["same colmap id twice", "two points one striptri id"])
def test_colmap_conflicting_striptri_ids_are_refused(colmap, tmp_path, change):
    """Before: a striptri_ids.csv that listed an id twice, or gave two points one name (merging
    them), was accepted."""
    path = colmap / "striptri_ids.csv"
    rows = list(csv.reader(path.open()))
    header, body = rows[0], rows[1:]
    points = [k for k, r in enumerate(body) if r[header.index("table")] == "point"]
    a, b = points[0], points[1]
    if change == "same colmap id twice":
        body.append(list(body[a]))
        body[-1][header.index("striptri_id")] = "other"
        line, words = len(body) + 1, ["listed twice"]
    else:
        body[b][header.index("striptri_id")] = body[a][header.index("striptri_id")]
        line, words = b + 2, ["two points would become one"]
    with path.open("w", newline="") as f:
        csv.writer(f).writerows([header, *body])
    _refused(colmap, tmp_path, f"striptri_ids.csv, line {line}", words)


# --------------------------------------------------------------------------- distances, plan


def test_header_only_distances_file_means_no_distances(tmp_path):
    """Before: a distances.csv with only its header ended in an internal error."""
    project = tmp_path / "cr"
    shutil.copytree(CLOSE_RANGE, project, ignore=shutil.ignore_patterns("truth"))
    (project / "distances.csv").write_text("point_from,point_to,distance,sigma\n")
    proc = run("adjust", project, "--out", tmp_path / "out", "--method", "bundle")
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "out" / "distances.csv").exists()


@pytest.mark.parametrize("option, words", [
    (["--format", "1e300"], ["--format 1e300", "plausible"]),
    (["--format", "230", "--terrain-height", "1e300"], ["terrain height", "plausible"]),
])
def test_plan_numbers_beyond_any_camera_are_refused(tmp_path, option, words):
    """Before: plan formats and terrain heights of 1e300 ended as internal errors."""
    proc = run("plan", DATA / "block_3x6", "--out", tmp_path / "p", "--von-gruber", *option)
    err = assert_clean_failure(proc, 2)
    assert "command line" in err and all(w in err for w in words), err


def test_plan_overlap_that_no_camera_flies_is_refused_at_once(tmp_path):
    """Before: --overlap 0.99999 re-spaced the strips with 600,000 photos and did not finish."""
    t0 = time.perf_counter()
    proc = run("plan", DATA / "block_3x6", "--out", tmp_path / "p", "--format", "230", "--overlap", "0.99999")
    err = assert_clean_failure(proc, 2)
    assert "--overlap 0.99999" in err and "photographs" in err
    assert time.perf_counter() - t0 < 60  # generous: the refusal needs no adjustment


def test_a_distance_between_every_pair_of_targets(tmp_path):
    """Before: a close range with a distance between every pair of its targets did not finish with
    the method of conditions (one joint group of every target: its normal-equation product ran
    over every ray's columns; now over the distinct unknowns) and the bundle's correction looped
    over the points. 20 targets, 190 distances: both methods, the same result."""
    project = tmp_path / "cr"
    shutil.copytree(CLOSE_RANGE, project, ignore=shutil.ignore_patterns("truth"))
    truth = {r["point_id"]: np.array([float(r[a]) for a in "XYZ"])
             for r in csv.DictReader((CLOSE_RANGE / "truth" / "points.csv").open())}
    ids = sorted(truth)[:20]
    with (project / "distances.csv").open("w") as f:
        f.write("point_from,point_to,distance,sigma\n")
        for a, b in itertools.combinations(ids, 2):
            f.write(f"{a},{b},{float(np.linalg.norm(truth[a] - truth[b]))!r},0.0001\n")
    p = read_project(project)
    assert len(p.distances) == 190
    results = {m: adjust(p, options_for(p, method=m)) for m in ("conditions", "bundle")}
    assert all(r.converged for r in results.values())
    assert results["conditions"].vtpv == pytest.approx(results["bundle"].vtpv, rel=1e-7)


# --------------------------------------------------------------------------- sigmas beyond any meaning


def test_gnss_shift_sigma_beyond_the_limits_is_refused(tmp_path):
    """Before: [gnss] sigma_shift = 1e300 was accepted without a word."""
    project = tmp_path / "g"
    proc = run("simulate", "block", "--out", project, "--gnss-sigma", "0.05", "--gnss-lever", "0,0,1", "--seed", "2")
    assert proc.returncode == 0, proc.stderr
    toml = project / "project.toml"
    toml.write_text(toml.read_text().replace('shift = "free"', 'shift = "observed"\nsigma_shift = 1e300'))
    err = assert_clean_failure(run("adjust", project, "--out", tmp_path / "o"), 2)
    assert "project.toml" in err and "sigma_shift" in err and "plausible" in err, err


def test_film_sigma_beyond_the_limits_is_refused(tmp_path):
    """Before: [film] sigma_px = 1e300 was accepted without a word."""
    project = tmp_path / "film"
    shutil.copytree(REPO / "data" / "film_strip", project, ignore=shutil.ignore_patterns("truth"))
    toml = project / "project.toml"
    toml.write_text(toml.read_text().replace("sigma_px = 0.5", "sigma_px = 1e300"))
    err = assert_clean_failure(run("adjust", project, "--out", tmp_path / "o"), 2)
    assert "project.toml" in err and "sigma_px" in err and "plausible" in err, err


# --------------------------------------------------------------------------- the right cause named


def test_an_affinity_that_makes_x_vanish_is_named_in_cameras_csv(tmp_path):
    """Before: b1 = -1 (c (1 + b1) = 0, no x scale) ended in "give better k1..k3", exit 1."""
    project = tmp_path / "p"
    shutil.copytree(DATA / "pair", project, ignore=shutil.ignore_patterns("truth"))
    lines = (project / "cameras.csv").read_text().splitlines()
    lines[0] += ",b1"
    lines[1] += ",-1"
    (project / "cameras.csv").write_text("\n".join(lines) + "\n")
    err = assert_clean_failure(run("adjust", project, "--out", tmp_path / "o"), 2)
    assert f"{project}/cameras.csv, line 2" in err and "b1" in err and "scale of x" in err, err


def test_a_calibration_focal_length_beyond_the_limits_is_named_in_calibration_toml(tmp_path):
    """Before: a calibration.toml focal length of 1e12 was reported against cameras.csv."""
    project = tmp_path / "film"
    shutil.copytree(REPO / "data" / "film_strip", project, ignore=shutil.ignore_patterns("truth"))
    toml = project / "calibration.toml"
    toml.write_text(toml.read_text().replace("focal_length_mm = 152.847", "focal_length_mm = 1e12"))
    err = assert_clean_failure(run("adjust", project, "--out", tmp_path / "o"), 2)
    assert "calibration.toml" in err and "focal_length_mm" in err and "cameras.csv" not in err, err


def test_a_distance_in_the_wrong_unit_is_named_as_the_likely_cause(tmp_path):
    """Before: a 1e9 m distance (a scale bar typed in nanometres, say) was reported only as an
    undetermined datum."""
    project = tmp_path / "cr"
    shutil.copytree(CLOSE_RANGE, project, ignore=shutil.ignore_patterns("truth"))
    lines = (project / "distances.csv").read_text().splitlines()
    fields = lines[1].split(",")
    fields[2] = "1e9"
    lines[1] = ",".join(fields)
    (project / "distances.csv").write_text("\n".join(lines) + "\n")
    err = assert_clean_failure(run("adjust", project, "--out", tmp_path / "o"), 1)
    assert "Likely cause: distances.csv, line 2" in err and "check the value and its unit" in err, err
