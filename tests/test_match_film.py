"""From film scans to a triangulated strip (issue 28): ``striptri simulate strip --film --images``
renders scans turned by up to 2 degrees and shifted on the scanner, with noise; ``striptri match``
finds their fiducial marks (within 0.2 px of the truth) and the tie points, and ``striptri adjust``
triangulates the strip with control at one end only: every orientation element within 3 of its
reported mean errors of the truth, every check point within 3 sigma.

The seed: over seeds 1 to 8 the largest normalised orientation error was 1.68, 2.22, 2.00, 4.39,
2.90, 2.17, 1.62 and 1.26 (RMS 0.7 to 1.5). Seed 4 is the one beyond 3: with the automatic tie
points replaced by exact ones its control measurements' noise alone puts photo 1002's Y0 and omega
2.4 a-priori sigma off, and the adjustment's sigma0 of 0.76 (the estimated tie sigma is about twice
the ties' true error) shrinks the reported mean errors by that factor (the issue's note)."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

cv2 = pytest.importorskip("cv2")

from striptri.cli import main  # noqa: E402

pytestmark = pytest.mark.xdist_group("film_strip")

SIZE = 1000  # scan side (px): 260 mm of film at 260 um, coarse enough to be quick
MATCH = ["--scale", "1", "--features", "3000", "--scan-pixel-size", "260"]


def _run(args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    return result


def _rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    root = tmp_path_factory.mktemp("film")
    made = _run(["simulate", "strip", "--film", "--images", "--photos", 5, "--image-size", SIZE, "--image-noise", 2,
                 "--check-points", 3, "--seed", 1, "--out", root / "scans"])
    assert made.exit_code == 0, made.output
    matched = _run(["match", root / "scans", "--images", root / "scans" / "images", *MATCH, "--out", root / "matched"])
    assert matched.exit_code == 0, matched.output
    adjusted = _run(["adjust", root / "matched", "--blunders", "snoop", "--out", root / "adjusted"])
    assert adjusted.exit_code == 0, adjusted.output
    return root, matched.output


def test_the_fiducial_marks_of_turned_shifted_scans_are_found_within_a_fifth_of_a_pixel(strip):
    root, _ = strip
    scans = _rows(root / "scans" / "truth" / "scans.csv")
    turn = np.degrees([np.arctan2(float(r["b1"]), float(r["a1"])) for r in scans])
    assert np.abs(turn).max() > 1.0  # the scans lie turned on the scanner (up to 2 degrees)
    assert not (root / "scans" / "fiducial_measurements.csv").exists()
    truth = {(r["photo_id"], r["fiducial_id"]): (float(r["col"]), float(r["row"]))
             for r in _rows(root / "scans" / "truth" / "fiducial_marks.csv")}
    found = {(r["photo_id"], r["fiducial_id"]): (float(r["col"]), float(r["row"]))
             for r in _rows(root / "matched" / "fiducial_measurements.csv")}
    assert set(found) == set(truth) and len(truth) == 5 * 8
    error = np.array([np.subtract(found[k], truth[k]) for k in truth])
    assert np.abs(error).max() < 0.2


def test_the_strip_matched_from_scans_equals_the_truth_within_its_precision(strip):
    root, _ = strip
    control = [r for r in _rows(root / "scans" / "control.csv") if r["kind"] != "check"]
    photos = {r["photo_id"]: r for r in _rows(root / "scans" / "truth" / "photos.csv")}
    centres = sorted(float(r["X0"]) for r in photos.values())
    # control at one end only: every control point lies before the third photo's centre
    assert len(control) == 4 and max(float(r["X"]) for r in control) < centres[2]
    summary = json.loads((root / "adjusted" / "summary.json").read_text())
    assert summary["converged"]
    normalised = []
    for r in _rows(root / "adjusted" / "photos.csv"):
        t = photos[r["photo_id"]]
        normalised += [(float(r[k]) - float(t[k])) / float(r[f"sigma_{k}"])
                       for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
    assert np.abs(normalised).max() < 3.0
    points = {r["point_id"]: r for r in _rows(root / "scans" / "truth" / "points.csv")}
    checks = [r for r in _rows(root / "adjusted" / "points.csv") if r["kind"] == "check"]
    assert len(checks) == 3
    z = [(float(r[k]) - float(points[r["point_id"]][k])) / float(r[f"sigma_{k}"]) for r in checks for k in "XYZ"]
    assert np.abs(z).max() < 3.0
    auto = summary["automatic_tie_points"]
    assert auto["points_left"] >= 60 and auto["rms_px"] < 0.3  # in scan pixels, through each scan's fiducials


def test_the_automatic_rows_are_scan_pixels_like_the_users(strip):
    root, _ = strip
    rows = _rows(root / "matched" / "image_points.csv")
    auto = [r for r in rows if r["source"] == "auto"]
    manual = [r for r in rows if r["source"] == "manual"]
    assert len(manual) == len(_rows(root / "scans" / "image_points.csv")) and len(auto) > 200
    xy = np.array([[float(r["x"]), float(r["y"])] for r in auto])
    assert (xy > 0).all() and (xy < SIZE).all()
    # none on the frame or the marks: every automatic ray lies inside the exposed image, 110 mm
    # about the plate centre (which the fiducials put near the scan's centre)
    assert np.abs(xy - SIZE / 2).max() < 110 / 0.26 + 12 / 0.26
    # one ray per place: SIFT's twin keypoints (one per orientation) joined into one track
    places = {(r["photo_id"], r["x"], r["y"]) for r in auto}
    assert len(places) == len(auto)


def test_a_mark_that_is_not_found_is_listed_and_never_guessed(strip, tmp_path):
    root, _ = strip
    project = tmp_path / "scans"
    shutil.copytree(root / "scans", project)
    truth = {(r["photo_id"], r["fiducial_id"]): (float(r["col"]), float(r["row"]))
             for r in _rows(project / "truth" / "fiducial_marks.csv")}
    image = cv2.imread(str(project / "images" / "1003.png"), cv2.IMREAD_GRAYSCALE)
    col, row = truth[("1003", "6")]
    disc = np.zeros_like(image)
    cv2.circle(disc, (int(col), int(row)), 30, 1, -1)
    base = np.clip(np.rint(np.random.default_rng(0).normal(20.0, 2.0, image.shape)), 0, 255).astype(image.dtype)
    image[disc == 1] = base[disc == 1]  # the mark under film base with the scan's noise: gone
    cv2.imwrite(str(project / "images" / "1003.png"), image)
    result = _run(["match", project, "--images", project / "images", *MATCH, "--out", tmp_path / "out"])
    assert result.exit_code == 0, result.output
    assert "fiducial marks: 7 of 8, not found: 6 (no mark" in result.output
    found = {(r["photo_id"], r["fiducial_id"]) for r in _rows(tmp_path / "out" / "fiducial_measurements.csv")}
    assert ("1003", "6") not in found and len(found) == 39
    report = (tmp_path / "out" / "match_report.html").read_text()
    assert "Fiducial marks" in report and "6: no mark" in report


def test_fiducial_measurements_of_the_project_are_taken_as_they_are(strip, tmp_path):
    root, _ = strip
    project = tmp_path / "scans"
    shutil.copytree(root / "scans", project)
    shutil.copy(root / "matched" / "fiducial_measurements.csv", project)
    given = (project / "fiducial_measurements.csv").read_bytes()
    result = _run(["match", project, "--images", project / "images", "--scale", "1", "--features", "3000",
                   "--out", tmp_path / "out"])
    assert result.exit_code == 0, result.output  # no --scan-pixel-size needed
    assert (tmp_path / "out" / "fiducial_measurements.csv").read_bytes() == given
    assert "fiducial marks:" not in result.output


def test_without_the_scan_pixel_size_or_fiducials_the_command_says_what_is_missing(strip, tmp_path):
    root, _ = strip
    result = _run(["match", root / "scans", "--images", root / "scans" / "images", "--out", tmp_path / "out"])
    assert result.exit_code == 2 and "--scan-pixel-size" in result.output
    assert "fiducial_measurements.csv" in result.output and "Traceback" not in result.output
    project = tmp_path / "scans"
    shutil.copytree(root / "scans", project, ignore=shutil.ignore_patterns("images", "fiducials.csv"))
    result = _run(["match", project, "--images", root / "scans" / "images", *MATCH, "--out", tmp_path / "out"])
    assert result.exit_code == 2 and "fiducials.csv" in result.output
    assert not (tmp_path / "out").exists()


def test_a_scan_pixel_size_far_off_finds_too_few_marks_and_names_the_scan(strip, tmp_path):
    root, _ = strip
    args = [a if a != "260" else "130" for a in MATCH]
    result = _run(["match", root / "scans", "--images", root / "scans" / "images", *args, "--out", tmp_path / "out"])
    assert result.exit_code == 2 and "fiducial marks found" in result.output and ".png" in result.output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, words", [
    (["block", "--film", "--images"], "strip"),
    (["strip", "--film"], "strip"),
    (["strip", "--film", "--images", "--relief", "10"], "--relief"),
])
def test_simulate_film_takes_only_what_the_film_strip_honours(tmp_path, args, words):
    result = _run(["simulate", *args, "--out", tmp_path / "out"])
    assert result.exit_code == 2 and words in result.output
    assert not (tmp_path / "out").exists()


def test_least_squares_matching_makes_a_half_resolution_match_precise(strip, tmp_path):
    """Matched at half resolution, the scans' tie points refined at full resolution (--refine):
    their image residual RMS after the adjustment falls by more than 3 times (measured on this
    strip: 0.048 -> 0.007 px, rays removed as gross errors 21 -> 3), the sigma the matcher
    estimates from the matching's closures fits them (0.073 -> 0.007 px; the adjustment's sigma0
    1.00 -> 0.90), and the orientations stay within 3 of their (now smaller) mean errors."""
    root, _ = strip
    photos = {r["photo_id"]: r for r in _rows(root / "scans" / "truth" / "photos.csv")}
    runs = {}
    for refine in ([], ["--refine"]):
        out, adjusted = tmp_path / f"m{len(refine)}", tmp_path / f"a{len(refine)}"
        matched = _run(["match", root / "scans", "--images", root / "scans" / "images", "--scale", "0.5",
                        "--features", "3000", "--scan-pixel-size", "260", *refine, "--out", out])
        assert matched.exit_code == 0, matched.output
        result = _run(["adjust", out, "--blunders", "snoop", "--out", adjusted])
        assert result.exit_code == 0, result.output
        sigma = float(next(r for r in _rows(out / "image_points.csv") if r["source"] == "auto")["sigma_x"])
        runs[len(refine)] = (json.loads((adjusted / "summary.json").read_text()), sigma, adjusted, matched.output)
    (plain, plain_sigma, _, _), (fine, fine_sigma, adjusted, output) = runs[0], runs[1]
    assert "least-squares matching:" in output and "closures" in output
    assert fine["automatic_tie_points"]["rms_px"] < plain["automatic_tie_points"]["rms_px"] / 3
    assert fine_sigma < plain_sigma / 3
    assert 0.6 < fine["sigma0"] < 1.4
    normalised = []
    for r in _rows(adjusted / "photos.csv"):
        t = photos[r["photo_id"]]
        normalised += [(float(r[k]) - float(t[k])) / float(r[f"sigma_{k}"])
                       for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
    assert np.abs(normalised).max() < 3.0
