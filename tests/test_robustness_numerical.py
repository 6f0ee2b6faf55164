"""Numerical robustness (the reliability issue's numerical part): every way an adjustment stops is
named truthfully (AdjustmentResult.termination / termination_message), numerical trouble ends in
one NumericalFailure in a photogrammetrist's words that names the likely cause, and a project
without unknowns works end to end.

One test (or one parametrised test) per case the user reproduced; the data are the shipped
synthetic projects (data/synthetic_strips, fixed seeds) changed the way the user changed them.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from cli_support import DATA, assert_clean_failure, copy_project, run
from striptri import diagnosis, termination
from striptri.adjustment import SUCCESSFUL_TERMINATIONS, TERMINATIONS, AdjustmentOptions, Iteration, adjust, stop_if_diverging
from striptri.errors import NumericalFailure
from striptri.figures import normal_matrix_structure
from striptri.io.project_reader import read_project
from striptri.rotations import R_from_opk

METHODS = ("conditions", "bundle")
NO_TRACE = ("Traceback", "SingularNormalMatrix", "LinAlgError")


# ----------------------------------------------------------------------------------------- helpers


@pytest.fixture(scope="module")
def strip8():
    return read_project(DATA / "strip8")


@pytest.fixture(scope="module")
def block():
    return read_project(DATA / "block_3x6")


def turned(project, photo: int, degrees: float):
    """The project with the approximate kappa of one photo turned by ``degrees`` (as a user who
    typed kappa + 180 in photos.csv)."""
    angles = project.photos.angles.copy()
    angles[photo, 2] += np.radians(degrees)
    return replace(project, photos=replace(project.photos, angles=angles, R_ground_from_cam=R_from_opk(angles)))


def with_c(project, c: float):
    interior = project.cameras.interior.copy()
    interior[:, 0] = c
    return replace(project, cameras=replace(project.cameras, interior=interior))


def photo_index(project, photo_id: str) -> int:
    return project.photos.ids.index(photo_id)


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def write_rows(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def assert_figures_of_last_iterations(message: str, history, redundancy: int) -> None:
    """The message carries the last three iterations' v^T P v, sigma0 and largest correction."""
    for k in range(max(len(history) - 3, 0), len(history)):
        h = history[k]
        assert f"{h.vtpv:.6g}" in message, (h.vtpv, message)
        assert f"{math.sqrt(h.vtpv / redundancy):.5g}" in message, message
        assert f"{h.max_correction:.3g} sd" in message, message


def no_traceback(text: str) -> None:
    for word in NO_TRACE:
        assert word not in text, text


# ------------------------------------------------------------- case 1: termination in every method


@pytest.mark.parametrize("method", ("conditions", "bundle", "sequential"))
def test_case1_every_method_says_converged_without_a_message(strip8, method):
    result = adjust(strip8, AdjustmentOptions(method=method))
    assert result.termination == "converged" and result.converged
    assert result.termination_message == ""
    assert set(TERMINATIONS) >= {"converged", "cost_flat", "iteration_limit", "diverged"}


@pytest.mark.parametrize("method", METHODS)
def test_case1_max_iterations_1_is_iteration_limit_still_shrinking(strip8, method):
    """project.toml max_iterations = 1 on strip8: the limit, reached while the corrections were
    still shrinking (the next correction, from the final checks, is smaller): raise the limit."""
    result = adjust(strip8, AdjustmentOptions(method=method, max_iterations=1, keep_unconverged=True))
    assert result.termination == "iteration_limit" and not result.converged
    assert result.termination not in SUCCESSFUL_TERMINATIONS
    msg = result.termination_message
    assert_figures_of_last_iterations(msg, result.history, result.redundancy)
    assert "max_iterations = 1" in msg and "(next)" in msg
    assert "still shrinking" in msg and "Raise [adjustment] max_iterations" in msg
    assert "Likely cause" not in msg  # clean data: nothing else is wrong
    # the same data converge with the default limit, so the advice is right
    assert adjust(strip8, AdjustmentOptions(method=method)).termination == "converged"


@pytest.mark.parametrize("method", METHODS)
def test_case1_unconverged_is_a_failure_unless_kept(strip8, method):
    """adjust() raises NumericalFailure with the termination message for an adjustment that stopped
    at its limit; keep_unconverged returns it, marked."""
    with pytest.raises(NumericalFailure) as info:
        adjust(strip8, AdjustmentOptions(method=method, max_iterations=1))
    kept = adjust(strip8, AdjustmentOptions(method=method, max_iterations=1, keep_unconverged=True))
    assert not kept.converged and kept.termination == "iteration_limit"
    assert str(info.value) == kept.termination_message


@pytest.mark.parametrize("method", METHODS)
def test_case1_and_2_kappa_180_off_names_the_photo(strip8, method):
    """kappa of photo 1006 of strip8 typed 180 deg off: sigma0 in the thousands, 30 iterations not
    converged; the message gives the figures and names photo 1006 and the corrected kappa."""
    j = photo_index(strip8, "1006")
    project = turned(strip8, j, 180.0)
    result = adjust(project, AdjustmentOptions(method=method, keep_unconverged=True))
    assert result.termination == "iteration_limit"
    assert result.sigma0 > 1000  # what the user saw
    msg = result.termination_message
    assert_figures_of_last_iterations(msg, result.history, result.redundancy)
    assert "photo 1006: its approximate kappa is probably 180 deg off" in msg
    given = np.degrees(strip8.photos.angles[j, 2])
    assert f"kappa = {given:.4f} deg" in msg  # the value to type back
    assert msg.count("photo 10") == 1  # no other photo is blamed


@pytest.mark.parametrize("method", ("conditions", "bundle", "sequential"))
def test_case1_and_2_c_in_micrometres_names_the_unit(strip8, method):
    """c = 152000 with plate coordinates in mm: not converged (or no relative orientation); the
    message names camera C1 and micrometres."""
    project = with_c(strip8, 152000.0)
    try:
        result = adjust(project, AdjustmentOptions(method=method, keep_unconverged=True))
        assert result.termination == "iteration_limit"
        msg = result.termination_message
        assert_figures_of_last_iterations(msg, result.history, result.redundancy)
    except NumericalFailure as exc:  # the sequential method fails in its first relative orientation
        assert method == "sequential"
        msg = str(exc)
        assert "largest correction" in msg  # the figures of its closest start
    assert "camera C1: c = 152000" in msg and "micrometres" in msg


def test_case1_cost_flat_is_a_result_with_a_message(strip8):
    """The bundle's cost tolerance met before the corrections: "cost_flat", a success, explained."""
    result = adjust(strip8, AdjustmentOptions(method="bundle", cost_tolerance=0.5))
    assert result.termination == "cost_flat" and result.termination in SUCCESSFUL_TERMINATIONS
    assert result.history[-1].max_correction > 1e-8
    msg = result.termination_message
    assert "cost_tolerance = 0.5" in msg and "This is a result" in msg
    assert_figures_of_last_iterations(msg, result.history, result.redundancy)


def test_case1_divergence_raises_with_the_history_and_the_cause(strip8):
    """Divergence stays a NumericalFailure, in the same words: the figures and the likely cause."""
    history = [Iteration(vtpv=10.0 ** (3 + k), max_correction=10.0 ** (3 + 2 * k), seconds=0.0) for k in range(5)]
    with pytest.raises(NumericalFailure) as info:
        stop_if_diverging(history, "conditions", 62, lambda: ["the stated cause."])
    msg = str(info.value)
    assert msg.startswith("the adjustment by conditions diverged at iteration 5")
    assert_figures_of_last_iterations(msg, history, 62)
    assert "Likely cause: the stated cause." in msg
    history.append(Iteration(vtpv=float("nan"), max_correction=float("inf"), seconds=0.0))
    with pytest.raises(NumericalFailure, match="infinite or not a number"):
        stop_if_diverging(history, "bundle", 62, lambda: [])


def test_case1_sequential_step_that_does_not_converge_is_iteration_limit(strip8):
    """The sequential method's steps have their own iterations: a step that stops at its limit makes
    the result "iteration_limit", and the message names the step's photo with its figures; a
    relative orientation without any converging start fails with the figures of the closest."""
    from striptri.sequential import SequentialOptions, adjust_sequential
    from striptri.sequential.result import result_of
    from striptri.sequential.strip import distortion_free, triangulate_strip

    project = distortion_free(strip8)
    sol = triangulate_strip(project, SequentialOptions(procedure=2))
    step = sol.steps[3]
    sol.steps[3] = replace(step, converged=False)  # as if it had stopped at its limit
    result = result_of(project, sol)
    assert result.termination == "iteration_limit" and not result.converged
    msg = result.termination_message
    assert "the orientation (procedure 2) of photo 1005 to photo 1004" in msg
    for h in step.history[-3:]:
        assert f"{h.max_correction:.3g} sd" in msg
    assert "still shrinking: raise [adjustment] max_iterations" in msg and "Likely cause" not in msg
    with pytest.raises(NumericalFailure) as info:
        adjust_sequential(strip8, SequentialOptions(max_iterations=2))
    msg = str(info.value)
    assert "the relative orientation of photographs 1001 and 1002 did not converge" in msg
    assert "largest correction" in msg and "still shrinking: raise [adjustment] max_iterations" in msg


@pytest.mark.parametrize("method", ("off", "snoop", "robust"))
def test_case1_blunder_detection_keeps_the_termination_and_tests_nothing(strip8, method):
    """Gross-error detection on an adjustment that did not converge: its residuals describe no
    solution, so nothing is tested or rejected, and the termination reaches the caller unchanged."""
    from striptri.reliability import BlunderOptions, detect_blunders

    det = detect_blunders(strip8, AdjustmentOptions(max_iterations=1, keep_unconverged=True),
                          BlunderOptions(method=method))
    assert det.result.termination == "iteration_limit"
    assert "max_iterations = 1" in det.result.termination_message
    assert det.stopped.startswith("not tested") or method == "off"
    assert det.rejected == [] and np.isnan(det.w).all() and set(det.flag) == {""}


# ------------------------------------------------------------------ case 2: name the likely cause


@pytest.mark.parametrize("name", ("strip8", "block_3x6"))
def test_case2_a_turned_photo_is_found_for_every_photo_and_quarter_turn(name):
    project = read_project(DATA / name)
    assert diagnosis.find_turns(project) == []
    for j in range(len(project.photos)):
        for degrees in (90, 180, 270):
            found = diagnosis.find_turns(turned(project, j, degrees))
            assert [(t.photo, t.degrees) for t in found] == [(j, 360 - degrees)], (j, degrees, found)
            assert found[0].turned_deg < diagnosis.GROSS_DEG < found[0].given_deg


def test_case1_and_2_block_with_one_photo_turned_diverges_naming_it(block):
    """block_3x6 with the kappa of photo 2003 typed 90 deg off: the adjustment by conditions diverges
    (corrections growing to 5e9 sd), a NumericalFailure with the figures and the photo. (The bundle
    method's damped steps recover from this one: it converges to the same solution as without.)"""
    j = photo_index(block, "2003")
    project = turned(block, j, 90.0)
    with pytest.raises(NumericalFailure) as info:
        adjust(project, AdjustmentOptions(method="conditions"))
    msg = str(info.value)
    assert msg.startswith("the adjustment by conditions diverged at iteration")
    assert "largest correction" in msg and "e+09 sd" in msg
    assert "photo 2003: its approximate kappa is probably 90 deg off" in msg
    assert msg.count("photo 2") == 1
    recovered = adjust(project, AdjustmentOptions(method="bundle"))
    assert recovered.termination == "converged"
    assert recovered.vtpv == pytest.approx(adjust(block, AdjustmentOptions(method="bundle")).vtpv, rel=1e-9)


@pytest.mark.parametrize("name", ("strip8", "block_3x6", "strip_2_3"))
def test_case2_no_photo_blamed_for_rough_approximations(name):
    """Approximate attitudes off by 5 deg and centres by 50 m (std, fixed seed): nothing is blamed,
    while a photo turned by 180 deg among them is still found."""
    project = read_project(DATA / name)
    rng = np.random.default_rng(20240611)
    for _ in range(10):
        angles = project.photos.angles + np.radians(5.0) * rng.standard_normal(project.photos.angles.shape)
        xyz0 = project.photos.xyz0 + 50.0 * rng.standard_normal(project.photos.xyz0.shape)
        rough = replace(project, photos=replace(project.photos, angles=angles, R_ground_from_cam=R_from_opk(angles),
                                                xyz0=xyz0))
        assert diagnosis.find_turns(rough) == []
        assert [t.photo for t in diagnosis.find_turns(turned(rough, 2, 180.0))] == [2]


def test_case2_whole_block_turned_and_a_photo_upside_down(strip8):
    every = strip8
    for j in range(len(strip8.photos)):
        every = turned(every, j, 180.0)
    found = diagnosis.find_turns(every)
    assert [(t.photo, t.degrees) for t in found] == [(-1, 180)]
    assert "kappa of all photos is probably 180 deg off" in diagnosis.wrong_orientations(every)[0]
    angles = strip8.photos.angles.copy()
    angles[4, 0] += np.pi  # omega 180 deg off: no kappa turn explains it
    upside = replace(strip8, photos=replace(strip8.photos, angles=angles, R_ground_from_cam=R_from_opk(angles)))
    words = diagnosis.wrong_orientations(upside)
    assert len(words) == 1 and words[0].startswith("photo 1005: its approximate orientation does not fit")


def test_case2_unit_of_c_judged_by_the_field_angle(strip8):
    assert diagnosis.camera_units(strip8) == []
    for name in ("pair", "block_3x6", "schmid_fig8", "strip_2_3"):
        assert diagnosis.camera_units(read_project(DATA / name)) == []
    long = diagnosis.camera_units(with_c(strip8, 152000.0))
    assert len(long) == 1 and "micrometres" in long[0] and "1.6e+03 times too large" in long[0]
    short = diagnosis.camera_units(with_c(strip8, 0.152))
    assert len(short) == 1 and "c is probably in metres" in short[0]
    assert diagnosis.camera_units(with_c(strip8, 88.0)) == []  # super wide angle
    assert diagnosis.camera_units(with_c(strip8, 610.0)) == []  # long focal length


# ---------------------------------------------------------- case 3: diagnoses that named the wrong cause


@pytest.mark.parametrize("method,datum", (("conditions", "control"), ("bundle", "control"), ("conditions", "inner")))
def test_case3a_a_sigma_of_1e20_is_named_not_a_datum_defect(strip8, method, datum):
    ip = strip8.image_points
    row = 10
    sigma = ip.sigma_xy.copy()
    sigma[row, 0] = 1e-20
    project = replace(strip8, image_points=replace(ip, sigma_xy=sigma))
    point, photo = strip8.points.ids[ip.point_index[row]], strip8.photos.ids[ip.photo_index[row]]
    # refused before iterating: with the round-off floor of the corrections the conditions method
    # with an inner datum would otherwise "converge" to sigma0 28,858 and centres 38 m off
    with pytest.raises(NumericalFailure) as info:
        adjust(project, AdjustmentOptions(method=method, datum=datum, keep_unconverged=True))
    msg = str(info.value)
    assert f"point {point} on photo {photo} (sigma_x = 1e-20)" in msg
    assert "double precision" in msg
    assert "leaves the datum undetermined" not in msg


def test_case3a_every_kind_of_weight_is_checked_within_its_kind(strip8):
    assert diagnosis.extreme_weights(strip8) == []
    sx = np.full_like(strip8.photos.sigma_xyz0, 0.05)
    sx[3, 2] = 1e-9  # a GNSS height 5e7 times sharper than the others
    sa = np.full_like(strip8.photos.sigma_angles, np.radians(0.01))
    sa[1, 0] = np.radians(1.0)  # 100 times looser: an ordinary range of sigmas
    project = replace(strip8, photos=replace(strip8.photos, sigma_xyz0=sx, sigma_angles=sa))
    words = diagnosis.extreme_weights(project)
    assert len(words) == 1 and "observed centre" in words[0] and "photo 1004 (sigma_Z0 = 1e-09)" in words[0]


def _cut_strip8(tmp_path: Path, control_in_second_part: bool) -> Path:
    """strip8 cut in two between photos 1004 and 1005 (no point measured in both parts); the
    second part keeps its control or loses it (as do both without control)."""
    folder = copy_project("strip8", tmp_path / "cut")
    rows = read_rows(folder / "image_points.csv")
    photos_of: dict[str, set] = {}
    for r in rows:
        photos_of.setdefault(r["point_id"], set()).add(r["photo_id"])
    kept = [r for r in rows if not (r["photo_id"] >= "1005" and min(photos_of[r["point_id"]]) <= "1004")]
    write_rows(folder / "image_points.csv", kept)
    if not control_in_second_part:
        control = read_rows(folder / "control.csv")
        write_rows(folder / "control.csv", [r for r in control if r["point_id"][:4] < "1005"])
    return folder


@pytest.mark.parametrize("method,datum", (("conditions", "control"), ("bundle", "control"), ("conditions", "inner")))
def test_case3b_a_strip_cut_in_two_names_the_groups(tmp_path, method, datum):
    project = read_project(_cut_strip8(tmp_path, control_in_second_part=False))
    with pytest.raises(NumericalFailure) as info:
        adjust(project, AdjustmentOptions(method=method, datum=datum))
    msg = str(info.value)
    assert "although the control fixes the datum" not in msg
    assert "the photos form 2 groups that share no points" in msg
    assert "group 1: photos 1001, 1002, 1003, 1004 (4 photos): its datum is fixed" in msg
    assert "group 2: photos 1005, 1006, 1007, 1008 (4 photos): no datum" in msg


def test_case3b_both_parts_with_control_adjust_and_without_any_the_groups_are_named(tmp_path):
    both = read_project(_cut_strip8(tmp_path / "a", control_in_second_part=True))
    assert adjust(both).termination == "converged"  # two blocks, each with its datum: legitimate
    folder = _cut_strip8(tmp_path / "b", control_in_second_part=False)
    write_rows(folder / "control.csv", [r for r in read_rows(folder / "control.csv") if r["kind"] == "check"])
    with pytest.raises(NumericalFailure) as info:
        adjust(read_project(folder))
    msg = str(info.value)
    assert "leaves the datum undetermined" in msg and "the photos form 2 groups" in msg


def test_case3_groups_are_connected_components(block):
    groups = diagnosis.photo_groups(block)
    assert groups.count == 1 and groups.lacking() == [] and groups.explain() == []


# --------------------------------------------------------- case 4: nothing escapes as a traceback


def _wild(project, what: str):
    if what == "X0":
        xyz0 = project.photos.xyz0.copy()
        xyz0[2, 0] = 1e300
        return replace(project, photos=replace(project.photos, xyz0=xyz0)), "photo 1003 (1e+300"
    if what == "x":
        xy = project.image_points.xy.copy()
        xy[7, 0] = 1e300
        return replace(project, image_points=replace(project.image_points, xy=xy)), "on photo 1001 (1e+300"
    return with_c(project, 1e9), "camera C1: c = 1e+09"


@pytest.mark.parametrize("method", ("conditions", "bundle", "sequential"))
@pytest.mark.parametrize("what", ("X0", "x", "c"))
def test_case4_wild_values_end_in_one_explained_failure(strip8, method, what):
    """X0 or x = 1e300, c = 1e9: a NumericalFailure (or a kept failure) naming the value, never a
    SingularNormalMatrix, LinAlgError or ValueError."""
    project, named = _wild(strip8, what)
    try:
        result = adjust(project, AdjustmentOptions(method=method))
    except NumericalFailure as exc:
        msg = str(exc)
    else:
        assert result.termination == "iteration_limit"
        msg = result.termination_message
    assert named in msg
    no_traceback(msg)


def test_case4_precision_reliability_and_points_of_a_singular_result(strip8):
    """c = 1e9 leaves N singular at the end: precision, selected inversion, reliability and the
    joint (92) point precision say so as NumericalFailure; triangulation leaves points undetermined."""
    from striptri.pipeline import triangulate_result
    from striptri.precision import joint_point_covariance, residual_cofactors
    from striptri.reliability import plate_reliability
    from striptri.triangulation import Triangulated

    project = with_c(strip8, 1e9)
    result = adjust(project, AdjustmentOptions(keep_unconverged=True))
    assert result.termination == "iteration_limit"
    for compute in (lambda: result.covariance, lambda: result.photo_mean_errors("omega-phi-kappa"),
                    lambda: residual_cofactors(project, result), lambda: plate_reliability(project, result),
                    lambda: triangulate_result(project, result)):
        with pytest.raises(NumericalFailure) as info:
            compute()
        assert "the precision of the result cannot be computed" in str(info.value)
        assert "did not converge" in str(info.value)  # with the adjustment's own failure
    points = Triangulated(np.zeros((len(project.points), 3)), np.zeros((len(project.points), 3, 3)),
                          np.zeros((len(project.points), 3, 3)), np.ones(len(project.points), dtype=bool))
    with pytest.raises(NumericalFailure):
        joint_point_covariance(project, result, points)


def test_case4_parallel_rays_leave_a_point_undetermined():
    from striptri.triangulation import intersect_rays, safe_inverse

    O = np.array([[[0.0, 0, 0], [1.0, 0, 0]], [[0.0, 0, 0], [1.0, 0, 0]]])
    r = np.array([[[0.0, 0, -1], [0.0, 0, -1]], [[0.1, 0, -1], [-0.1, 0, -1]]])
    X = intersect_rays(O, r, safe=True)
    assert np.isnan(X[0]).all() and np.allclose(X[1], [0.5, 0, -5])
    with pytest.raises(np.linalg.LinAlgError):
        intersect_rays(O, r)  # the sequential method's form keeps raising (its caller explains)
    inv, ok = safe_inverse(np.array([np.eye(3), np.diag([1.0, 1.0, 0.0]), np.full((3, 3), np.nan)]))
    assert ok.tolist() == [True, False, False] and np.allclose(inv[0], np.eye(3)) and np.isnan(inv[1:]).all()


@pytest.mark.parametrize("what,file,field,value,named", (
    ("X0", "photos.csv", "X0", "1e300", "photo 1003"),
    ("x", "image_points.csv", "x", "1e300", "point T1001_02 on photo 1001"),
    ("c", "cameras.csv", "c", "1e9", "camera C1"),
))
@pytest.mark.parametrize("method", ("conditions", "bundle", "sequential"))
def test_case4_command_line_one_message_no_traceback(tmp_path, what, file, field, value, named, method):
    """The real command on the user's edits: one message, exit 1 (or 2 if the reader's plausibility
    limits refuse the value first), no traceback, nothing written."""
    folder = copy_project("strip8", tmp_path / "p")
    rows = read_rows(folder / file)
    rows[{"X0": 2, "x": 7, "c": 0}[what]][field] = value
    write_rows(folder / file, rows)
    proc = run("adjust", folder, "--out", tmp_path / "out", "--method", method)
    assert proc.returncode in (1, 2), proc.stderr
    stderr = assert_clean_failure(proc, proc.returncode)
    no_traceback(stderr)
    if proc.returncode == 1:
        assert named in stderr
    assert not (tmp_path / "out").exists()


def test_case4_structure_command_on_a_wild_centre(tmp_path):
    folder = copy_project("strip8", tmp_path / "p")
    rows = read_rows(folder / "photos.csv")
    rows[2]["X0"] = "1e300"
    write_rows(folder / "photos.csv", rows)
    proc = run("structure", folder, "--out", tmp_path / "s.png")
    stderr = assert_clean_failure(proc, proc.returncode)
    assert proc.returncode in (1, 2)
    if proc.returncode == 1:
        assert "photo 1003 (1e+300" in stderr
    assert not (tmp_path / "s.png").exists()


# --------------------------------------------------------------- case 5: zero unknowns end to end


def _fixed_at_truth(tmp_path: Path) -> Path:
    """strip8 with every photo held (sigma 0 for every element) at its true orientation."""
    folder = copy_project("strip8", tmp_path / "fixed")
    truth = {r["photo_id"]: r for r in read_rows(DATA / "strip8" / "truth" / "photos.csv")}
    rows = read_rows(folder / "photos.csv")
    for r in rows:
        for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa"):
            r[k] = truth[r["photo_id"]][k]
            r[f"sigma_{k}"] = "0"
    write_rows(folder / "photos.csv", rows)
    return folder


def test_case5_zero_unknowns_conditions_equal_bundle(tmp_path):
    """A pure forward intersection: no unknowns; sigma0 from the intersections' redundancy (the
    2k - (3 - d) conditions of every point), the same by conditions and by the bundle method."""
    project = read_project(_fixed_at_truth(tmp_path))
    results = [adjust(project, AdjustmentOptions(method=m)) for m in METHODS]
    for r in results:
        assert r.n_unknowns == 0 and r.termination == "converged"
        assert r.redundancy == r.n_conditions == 110
    assert results[0].vtpv == pytest.approx(results[1].vtpv, rel=1e-9)
    # sigma0 against the simulated noise: inside the chi-square interval of 99.9 %
    lo, hi = (math.sqrt(chi2.ppf(q, 110) / 110) for q in (0.0005, 0.9995))
    assert lo < results[0].sigma0 < hi


def test_case5_zero_unknowns_through_the_real_commands(tmp_path):
    """striptri adjust and striptri structure on photos.csv with sigma 0 for every element."""
    folder = _fixed_at_truth(tmp_path)
    out = tmp_path / "out"
    proc = run("adjust", folder, "--out", out)
    assert proc.returncode == 0, proc.stderr
    no_traceback(proc.stderr)
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_unknowns"] == 0 and summary["converged"] is True and summary["redundancy"] == 110
    assert (out / "report.html").stat().st_size > 0  # with the figure of the empty normal matrix
    truth = {r["point_id"]: r for r in read_rows(DATA / "strip8" / "truth" / "points.csv")}
    worst = 0.0
    for r in read_rows(out / "points.csv"):
        for a in "XYZ":
            s = float(r[f"sigma_{a}"])
            if s > 0:
                worst = max(worst, abs(float(r[a]) - float(truth[r["point_id"]][a])) / s)
    assert 0 < worst < 4.5  # 114 coordinates: beyond 4.5 sigma with probability below 1e-3
    png = tmp_path / "structure.png"
    proc = run("structure", folder, "--out", png)
    assert proc.returncode == 0, proc.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_case5_the_empty_normal_matrix_is_drawn_as_such():
    import scipy.sparse as sp

    png = normal_matrix_structure(sp.csr_matrix((0, 0)), np.zeros(0, dtype=int), 8)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------------- the words themselves


def test_trend_of_the_corrections():
    h = lambda *c: [Iteration(vtpv=1.0, max_correction=x, seconds=0.0) for x in c]  # noqa: E731
    assert termination.trend(h(100.0, 10.0))[0] == "shrinking"
    assert termination.trend(h(100.0), 1.0)[0] == "shrinking"
    assert termination.trend(h(100.0, 99.0, 100.0))[0] == "stalled"
    assert termination.trend(h(10.0, 20.0, 40.0))[0] == "growing"
    assert termination.trend(h(10.0))[0] == "unknown"
    assert re.search(r"\(next\)\s+5 sd", termination.table(h(100.0), 10, 5.0))
