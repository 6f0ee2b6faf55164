"""Progress of long runs on stderr (striptri.progress): plain lines in a log, one rewritten status
line on a terminal, nothing for short runs, with --quiet or without a reporter."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import pytest

from cli_support import run
from striptri import progress
from striptri.solvers import SolverInfo
from striptri.pipeline import run_adjust

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


def _adjust(tmp_path, *extra, after="0"):
    out = tmp_path / f"out{after}{''.join(extra)}"
    proc = run("adjust", DATA / "block_3x6", "--out", out, *extra, env={"STRIPTRI_PROGRESS_AFTER": after})
    assert proc.returncode == 0, proc.stderr
    return proc, json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_each_iteration_and_phase_is_a_plain_line_on_a_pipe(tmp_path, method):
    proc, summary = _adjust(tmp_path, "--method", method)
    lines = proc.stderr.splitlines()
    iterations = [line for line in lines if f"{method} iteration" in line]
    assert len(iterations) == summary["iterations"] == len(summary["history"])
    for number, (line, h) in enumerate(zip(iterations, summary["history"]), start=1):
        assert line.startswith(f"striptri: {method} iteration {number}: vTPv {h['vtpv']:.6g}, "
                               f"correction {h['max_correction']:.3g} sigma, ")
    phases = [line.split(":")[1].strip() for line in lines if "iteration" not in line]
    assert phases == ["reliability measures (gross errors)", "point precision", "tables (CSV)", "report"]
    assert "\r" not in proc.stderr


def test_quiet_and_short_runs_print_nothing(tmp_path):
    proc, _ = _adjust(tmp_path, "--quiet")
    assert proc.stderr == ""
    proc, _ = _adjust(tmp_path, after="1000")
    assert proc.stderr == ""


def test_a_terminal_gets_one_status_line_rewritten_in_place(tmp_path):
    stream = io.StringIO()
    with progress.reporting(progress.StderrProgress(stream, after=0.0, tty=True)):
        products = run_adjust(DATA / "strip8", tmp_path / "out")
    text = stream.getvalue()
    n = products.summary["iterations"]
    assert "\r" in text and f"conditions iteration {n}:" in text
    # the finished phases are written above the status line, one line each
    for name in ("point precision", "tables (CSV)", "report"):
        assert f"striptri: {name}: " in text


def test_the_silent_start_is_shown_once_the_run_is_long():
    stream = io.StringIO()
    reporter = progress.StderrProgress(stream, after=0.3, tty=False)
    with progress.reporting(reporter):
        progress.iteration("conditions", 1, 10.0, 5.0, 0.1)
        assert stream.getvalue() == ""
        time.sleep(0.35)
        progress.iteration("conditions", 2, 9.0, 0.5, 0.1, SolverInfo(inner_iterations=17))
    lines = stream.getvalue().splitlines()
    assert [line.split(":")[1] for line in lines] == [" conditions iteration 1", " conditions iteration 2"]
    assert lines[1].endswith(", 17 inner sweeps")


def test_without_a_reporter_the_library_is_silent(tmp_path, capsys):
    run_adjust(DATA / "strip8", tmp_path / "out")
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_inner_sweeps_of_an_iterative_solver_are_shown_while_it_runs(tmp_path, monkeypatch):
    """A relaxation solver announces its inner iterations (progress.inner) during a solve; the
    reporter shows them throttled (here: every call, the intervals set to zero), after the silent
    start only, and in a log as plain lines naming the solver, the iteration and the residual."""
    monkeypatch.setattr(progress, "INNER_LINE_EVERY_S", 0.0)
    stream = io.StringIO()
    from striptri.adjustment import AdjustmentOptions, adjust
    from striptri.io import read_project

    with progress.reporting(progress.StderrProgress(stream, after=0.0, tty=False)):
        result = adjust(read_project(DATA / "block_3x6"), AdjustmentOptions(solver="pcg"))
    lines = [line for line in stream.getvalue().splitlines() if "inner iteration" in line]
    total = sum(h.solver_info.inner_iterations for h in result.history)
    assert total >= 25 and len(lines) >= 1
    for line in lines:
        name, rest = line.removeprefix("striptri: ").split(": ", 1)
        assert name == "pcg" and rest.startswith("inner iteration ") and "relative residual" in rest
    # throttled by time: with the default interval a short solve writes at most one line per 10 s
    monkeypatch.setattr(progress, "INNER_LINE_EVERY_S", 10.0)
    stream = io.StringIO()
    with progress.reporting(progress.StderrProgress(stream, after=0.0, tty=False)):
        for k in range(100):
            progress.inner("strip-pcg", 25 * (k + 1), 1e-3)
    assert len(stream.getvalue().splitlines()) == 1
    # before the silent start is over nothing is shown, and nothing is queued for later
    stream = io.StringIO()
    with progress.reporting(progress.StderrProgress(stream, after=1000.0, tty=False)) as reporter:
        progress.inner("pcg", 25, 1e-3)
        assert reporter.pending == []
    assert stream.getvalue() == ""
