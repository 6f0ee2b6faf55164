"""From rendered images to a triangulated block (issue 28), with known truth.

`striptri simulate block --images` renders a block of 3 strips x 8 photos from a textured terrain
(simulate.render); `striptri match` finds the tie points; `striptri adjust --blunders snoop`
adjusts. The adjusted orientations and check points are compared with the truth in units of their
reported mean errors, and 5 % of the automatic measurements are then made false to see the
adjustment find them.

Tolerances (the normalised errors z = (adjusted - true) / reported mean error are standard normal
when the reported precision is honest):
* of all 144 orientation elements, at most 3 beyond 3 (the expected number is 0.39; 4 or more has
  probability 8e-4) and none beyond 4.5 (probability 1e-3);
* the check points' 18 coordinates: none beyond 4, at most 1 beyond 3 (expected 0.05);
* each element's 24 values: RMS z within the two-sided 99.9 % chi-square bounds for 24 degrees of
  freedom, [0.56, 1.46]. Measured 1.12 to 1.36 here (and 0.97 to 1.30 with seed 1): the
  reported precision is still somewhat optimistic (docs/matching.md), within these bounds.

The renders carry noise of 2 grey levels, as real photographs do.
"""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("cv2")

from striptri.cli import main  # noqa: E402
from striptri.core.runs import RunOptions  # noqa: E402
from striptri.pipeline import run_adjust  # noqa: E402

SIZE = 500  # pixels: a small image keeps the test quick; the texture scales with the pixel


def _run(args):
    run = CliRunner().invoke(main, [str(a) for a in args])
    assert run.exit_code == 0, run.output
    return run


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("rendered")
    _run(["simulate", "block", "--photos", 8, "--strips", 3, "--images", "--image-size", SIZE, "--image-noise", 2,
          "--check-points", 6, "--seed", 2, "--out", root / "p"])
    _run(["match", root / "p", "--images", root / "p" / "images", "--out", root / "m", "--scale", 1,
          "--features", 2000])
    adjusted = run_adjust(root / "m", root / "a", RunOptions(blunders="snoop"))
    assert adjusted.result.converged
    return root


def _table(path, key="photo_id"):
    return {r[key]: r for r in csv.DictReader(path.open())}


def _normalised_orientation_errors(block) -> np.ndarray:
    """(24, 6): (adjusted - true) / reported mean error of X0, Y0, Z0, omega, phi, kappa."""
    truth, adjusted = _table(block / "p" / "truth" / "photos.csv"), _table(block / "a" / "photos.csv")
    assert len(adjusted) == 24
    return np.array([[(float(r[a]) - float(truth[pid][a])) / float(r[f"sigma_{a}"])
                      for a in ("X0", "Y0", "Z0", "omega", "phi", "kappa")] for pid, r in adjusted.items()])


@pytest.mark.xdist_group("rendered_block")  # one worker renders and matches the block for both tests
def test_the_matched_block_adjusts_to_the_truth(block):
    z = _normalised_orientation_errors(block)
    assert np.sum(np.abs(z) > 3.0) <= 3, z
    assert np.all(np.abs(z) < 4.5), z
    points, reference = _table(block / "a" / "points.csv", "point_id"), _table(block / "p" / "control.csv", "point_id")
    check = [pid for pid, r in points.items() if r["kind"] == "check"]
    assert len(check) == 6
    zc = np.array([[(float(points[p][a]) - float(reference[p][a])) / float(points[p][f"sigma_{a}"]) for a in "XYZ"]
                   for p in check])
    assert np.all(np.abs(zc) < 4.0) and np.sum(np.abs(zc) > 3.0) <= 1, zc
    # every tie point is an automatic one, and they cover every photo
    rows = list(csv.DictReader((block / "m" / "image_points.csv").open()))
    assert {r["source"] for r in rows} == {"manual", "auto"}
    assert {r["photo_id"] for r in rows if r["source"] == "auto"} == set(_table(block / "a" / "photos.csv"))


@pytest.mark.xdist_group("rendered_block")
def test_the_reported_orientation_precision_is_honest(block):
    rms = np.sqrt(np.mean(_normalised_orientation_errors(block) ** 2, axis=0))
    assert np.all((rms > 0.56) & (rms < 1.46)), rms


@pytest.mark.xdist_group("rendered_block")
@pytest.mark.parametrize("method", ["snoop", "robust-snoop"])
def test_five_percent_false_matches_are_found_and_the_check_points_hold(block, tmp_path, method):
    """5 % of the automatic measurements moved by 1.5 to 15 pixels in a random direction (a wrong
    feature taken for the right one): data snooping, alone or started by robust re-weighting,
    removes at least 95 % of them (a false ray of a two-ray point is an inseparable pair: both rays
    go), and the check points' RMS stays within 10 % of the clean run's. (Measured on the 500 px
    block of seed 2: snoop removed 116 of 117 false rays and 91 true ones; robust-snoop 116 and
    67, in as many seconds; robust alone stopped after 100 re-weightings with 11 false rays left.)"""
    bad = tmp_path / "bad"
    shutil.copytree(block / "m", bad)
    rows = list(csv.DictReader((bad / "image_points.csv").open()))
    header = list(rows[0])
    pixel = float(next(csv.DictReader((bad / "cameras.csv").open()))["pixel_size"])
    rng = np.random.default_rng(7)
    auto = [k for k, r in enumerate(rows) if r["source"] == "auto"]
    wrong = rng.choice(auto, int(round(0.05 * len(auto))), replace=False)
    for k in wrong:
        angle, size = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(1.5, 15.0) * pixel
        rows[k]["x"] = repr(float(rows[k]["x"]) + float(size * np.cos(angle)))
        rows[k]["y"] = repr(float(rows[k]["y"]) + float(size * np.sin(angle)))
    with (bad / "image_points.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, header, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    result = run_adjust(bad, tmp_path / "out", RunOptions(blunders=method))
    assert result.result.converged and result.summary["blunders"]["method"] == method
    assert result.summary["blunders"]["stopped"] == "clean"
    flags = {(r["photo_id"], r["point_id"]): r["flag"] for r in csv.DictReader((tmp_path / "out" / "residuals.csv").open())}
    removed = sum(flags[(rows[k]["photo_id"], rows[k]["point_id"])] in ("rejected", "inseparable", "dropped")
                  for k in wrong)
    assert removed >= 0.95 * len(wrong), (removed, len(wrong))
    # the adjustment says how many automatic rays it removed, and how well the rest fit (pixels)
    auto = result.summary["automatic_tie_points"]
    out_rows = list(csv.DictReader((tmp_path / "out" / "residuals.csv").open()))
    gone = [r["flag"] in ("rejected", "inseparable", "dropped") for r in out_rows]
    is_auto = [r["source"] == "auto" for r in rows]
    assert auto["rays"] == sum(is_auto) and auto["removed"] == sum(g and a for g, a in zip(gone, is_auto))
    v = np.array([[float(r["vx"]), float(r["vy"])] for r, g, a in zip(out_rows, gone, is_auto) if a and not g]) / pixel
    assert auto["rms_px"] == pytest.approx(np.sqrt(np.mean(v**2)), rel=1e-9)
    assert "Automatic tie points" in (tmp_path / "out" / "report.html").read_text()

    def rms(summary):
        c = summary["check_points"]
        return np.sqrt((c["rms_X"] ** 2 + c["rms_Y"] ** 2 + c["rms_Z"] ** 2) / 3.0)

    clean = json.loads((block / "a" / "summary.json").read_text())
    assert rms(result.summary) <= 1.10 * rms(clean), (result.summary["check_points"], clean["check_points"])


def test_automatic_tie_points_on_noise_free_renders_fit_to_a_few_hundredths_of_a_pixel(tmp_path):
    """A strip of 3 noise-free 400-pixel renders: the automatic tie points' image residuals after
    the adjustment (RMS over x and y, in pixels) are at most 0.3 px (issue 28); measured about 0.03."""
    _run(["simulate", "strip", "--photos", 3, "--images", "--image-size", 400, "--seed", 5, "--out", tmp_path / "p"])
    _run(["match", tmp_path / "p", "--images", tmp_path / "p" / "images", "--out", tmp_path / "m", "--scale", 1,
          "--features", 2000])
    run_adjust(tmp_path / "m", tmp_path / "a", RunOptions(blunders="snoop"))
    pixel = float(next(csv.DictReader((tmp_path / "p" / "cameras.csv").open()))["pixel_size"])
    source = {(r["photo_id"], r["point_id"]): r["source"] for r in csv.DictReader((tmp_path / "m" / "image_points.csv").open())}
    v = np.array([[float(r["vx"]), float(r["vy"])] for r in csv.DictReader((tmp_path / "a" / "residuals.csv").open())
                  if source[(r["photo_id"], r["point_id"])] == "auto" and not r["flag"]]) / pixel
    assert len(v) > 100
    assert np.sqrt(np.mean(v**2)) <= 0.3
