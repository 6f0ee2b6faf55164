"""The termination reason of every method, on cases that end each way (issue 13): converged, the
iteration limit, divergence and a datum defect. A result carries it as ``termination`` (with
``termination_message``); a failure as NumericalFailure.reason; summary.json, the report and the
command line show it."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri.adjustment import METHODS, AdjustmentOptions, SequentialOptions, adjust
from striptri.core.result import SUCCESSFUL_TERMINATIONS, TERMINATIONS
from striptri.errors import InputError, NumericalFailure
from striptri.io import read_project
from striptri.model import CHECK, TIE
from striptri.geometry.rotations import R_from_opk

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


@pytest.fixture(scope="module")
def strip8():
    return read_project(DATA / "strip8")


def without_control(project):
    """Every control point made a tie point (check points stay): nothing fixes the datum."""
    kind = project.points.kind
    return replace(project, points=replace(project.points, kind=np.where(kind == CHECK, CHECK, TIE)))


def turned(project, photo_id: str, degrees: float):
    angles = project.photos.angles.copy()
    angles[project.photos.ids.index(photo_id), 2] += np.radians(degrees)
    return replace(project, photos=replace(project.photos, angles=angles, R_ground_from_cam=R_from_opk(angles)))


def failure(project, options) -> NumericalFailure:
    with pytest.raises(NumericalFailure) as info:
        adjust(project, options)
    return info.value


@pytest.mark.parametrize("method", METHODS)
def test_converged(strip8, method):
    result = adjust(strip8, AdjustmentOptions(method=method))
    assert result.termination == "converged" and result.converged and result.termination_message == ""


@pytest.mark.parametrize("method", METHODS)
def test_iteration_limit_is_a_failure_with_its_reason(strip8, method):
    """The limit reached before convergence: NumericalFailure "iteration_limit" with the history's
    figures (the sequential method: its steps' own limit, which [adjustment] max_iterations can only
    raise, here lowered through its options)."""
    options = AdjustmentOptions(method=method, max_iterations=1, sequential=SequentialOptions(max_iterations=2))
    exc = failure(strip8, options)
    assert exc.reason == "iteration_limit"
    assert "did not converge" in str(exc) and "largest correction" in str(exc)


@pytest.mark.parametrize("method", ("conditions", "bundle"))
def test_iteration_limit_kept_is_a_result_that_says_so(strip8, method):
    result = adjust(strip8, AdjustmentOptions(method=method, max_iterations=1, keep_unconverged=True))
    assert result.termination == "iteration_limit" and not result.converged
    assert "still shrinking" in result.termination_message


@pytest.mark.parametrize("method", METHODS)
def test_datum_defect(strip8, method):
    """No control: the simultaneous methods find the seven free directions of a similarity; the
    sequential method cannot orient its strip model absolutely."""
    exc = failure(without_control(strip8), AdjustmentOptions(method=method))
    assert exc.reason == "datum_defect"
    assert ("datum" if method != "sequential" else "absolute orientation") in str(exc)


@pytest.mark.parametrize("method", METHODS)
def test_divergence(method):
    """block_3x6 with the approximate kappa of photo 3003 typed 180 deg off. The method of
    conditions diverges (its corrections double for four iterations in a row: the divergence rule,
    core.convergence.stop_if_diverging). The bundle's Levenberg-Marquardt damping does not recover
    from it either: its corrections stall at the iteration limit. The sequential method triangulates
    single strips and refuses the block before iterating: bad input for that method (an InputError,
    exit status 2; issue 26), not a termination of an iteration. (Until issue 29 this case was photo
    2003 turned 90 deg, from which both methods now recover: test_a_quarter_turn_is_recovered.)"""
    block = turned(read_project(DATA / "block_3x6"), "3003", 180.0)
    expected = {"conditions": "diverged", "bundle": "iteration_limit", "sequential": "refused"}[method]
    if expected == "refused":
        with pytest.raises(InputError, match="one strip"):
            adjust(block, AdjustmentOptions(method=method))
    else:
        exc = failure(block, AdjustmentOptions(method=method))
        assert exc.reason == expected
        if expected == "diverged":
            assert "diverged at iteration" in str(exc)
        assert "photo 3003: its approximate kappa is probably 180 deg off" in str(exc)


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_a_quarter_turn_is_recovered(method):
    """block_3x6 with the approximate kappa of photo 2003 typed 90 deg off: both methods reach the
    solution of the right approximations, the bundle by its damped steps, the method of conditions
    since its first linearisation is at observations where its conditions hold
    (conditions_method.adjust.consistent_start; before, it diverged here)."""
    block = read_project(DATA / "block_3x6")
    result = adjust(turned(block, "2003", 90.0), AdjustmentOptions(method=method))
    assert result.termination == "converged"
    reference = adjust(block, AdjustmentOptions(method=method))
    assert result.vtpv == pytest.approx(reference.vtpv, rel=1e-9)
    np.testing.assert_allclose(result.state.xyz0, reference.state.xyz0, atol=1e-6)


def test_every_reason_is_named():
    assert set(TERMINATIONS) >= {"converged", "cost_flat", "iteration_limit", "diverged", "datum_defect"}
    assert set(SUCCESSFUL_TERMINATIONS) == {"converged", "cost_flat"}


def cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "striptri", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def test_summary_report_and_command_line_show_a_kept_iteration_limit(tmp_path):
    out = tmp_path / "out"
    proc = cli("adjust", DATA / "strip8", "--out", out, "--max-iterations", "1", "--keep-unconverged", "--quiet")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["termination"] == "iteration_limit" and summary["converged"] is False
    assert "did not converge" in summary["message"]
    assert "iteration_limit" in (out / "report.html").read_text()
    assert "NOT converged (iteration_limit; kept)" in proc.stdout
    assert summary["plate_unit"] == "mm"


def test_report_names_the_termination_of_a_converged_run(tmp_path):
    out = tmp_path / "out"
    proc = cli("adjust", DATA / "strip8", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "summary.json").read_text())["termination"] == "converged"
    report = (out / "report.html").read_text()
    assert "termination (why the iteration stopped)" in report
    assert "converged: every correction below the tolerance" in report


def test_command_line_names_the_reason_of_a_failure(tmp_path):
    project = tmp_path / "project"
    project.mkdir()
    for f in (p for p in (DATA / "strip8").iterdir() if p.is_file()):
        (project / f.name).write_bytes(f.read_bytes())
    control = (project / "control.csv").read_text().splitlines()
    header = control[0].split(",")
    kind = header.index("kind")
    rows = [line.split(",") for line in control[1:] if line and not line.startswith("#")]
    checks = [row for row in rows if row[kind] == "check"]  # the control points become tie points
    assert len(checks) < len(rows)
    (project / "control.csv").write_text("\n".join([control[0]] + [",".join(r) for r in checks]) + "\n")
    proc = cli("adjust", project, "--out", tmp_path / "out", "--quiet")
    assert proc.returncode == 1
    assert proc.stderr.count("striptri: error:") == 1
    assert "(termination: datum_defect; nothing was written)" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_normal_matrix_singular_after_regular_ones_is_a_divergence(monkeypatch):
    """A singular normal matrix at a later iteration, with the same control as the regular first
    ones, is not a datum defect of the input: it is reported as the iteration's divergence, with
    its figures and the likely causes. At the first iteration it stays the datum defect it is."""
    import striptri.conditions_method.adjust as conditions_adjust
    from striptri.errors import NumericalFailure

    real = conditions_adjust._iteration
    calls = []

    def singular_at_third(problem, solver, now, history, timings, *held):
        calls.append(len(history))
        if len(history) == 2:
            raise NumericalFailure("the control leaves the datum undetermined", reason="datum_defect")
        return real(problem, solver, now, history, timings, *held)

    monkeypatch.setattr(conditions_adjust, "_iteration", singular_at_third)
    exc = failure(read_project(DATA / "strip8"), AdjustmentOptions())
    assert exc.reason == "diverged" and calls == [0, 1, 2]
    msg = str(exc)
    assert msg.startswith("the adjustment by conditions diverged at iteration 3: its normal matrix became singular")
    assert "regular in the 2 iterations before" in msg and "largest correction" in msg

    def singular_at_first(problem, solver, now, history, timings, *held):
        raise NumericalFailure("the control leaves the datum undetermined", reason="datum_defect")

    monkeypatch.setattr(conditions_adjust, "_iteration", singular_at_first)
    assert failure(read_project(DATA / "strip8"), AdjustmentOptions()).reason == "datum_defect"
