"""Reliability of the command line as a demanding user meets it (README "Safety"): every case a
hostile user reproduced is a test here, named after it.

The guarantee under test: striptri never deletes, replaces or changes a file it did not write,
never reads and writes the same folder, checks the output location before any computation,
leaves no temporary folder behind after any signal (SIGKILL: after the next run), and ends every
failure with one message and exit status 2 (input, output location) or 1 (numerical); an
adjustment that has not converged is a failure unless --keep-unconverged.

Most cases run the real console script in a subprocess (tests/cli_support.py), so that "no
traceback" and the exit status are proven on the real thing; faults that must strike at an exact
point (a full disk at the third file, a kill while writing) are injected into the same entry point.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli_support import DATA, assert_clean_failure, command, copy_project, run, snapshot, stray_siblings
from striptri.cli import main
from striptri.io.output import MARKER, foreign_content

# --------------------------------------------------------------------------------------- helpers


def adjust(project, out, *extra, **kw):
    return run("adjust", project, "--out", out, *extra, **kw)


def no_strays(out: Path) -> None:
    assert stray_siblings(out) == [], stray_siblings(out)


def output_is_whole(out: Path) -> None:
    """An output folder that exists is complete: the marker's manifest lists exactly its files,
    unchanged."""
    assert (out / MARKER).is_file()
    assert foreign_content(out) == ""
    listed = [line.split(" ", 2)[2] for line in (out / MARKER).read_text().splitlines()[3:]]
    present = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != MARKER)
    assert sorted(listed) == present


def set_toml(project: Path, text: str) -> None:
    (project / "project.toml").write_text(textwrap.dedent(text), encoding="utf-8")


def entry_point_with(preamble: str) -> list[str]:
    """The striptri entry point in a fresh interpreter, after ``preamble`` (fault injection)."""
    code = textwrap.dedent(preamble) + "\nimport sys\nsys.argv[0] = 'striptri'\nfrom striptri.cli import main\nmain()\n"
    return [sys.executable, "-c", code]


# ============================================================================ losing data


@pytest.mark.parametrize("target", ["colmap", "project", "bal", "dbat"])
def test_convert_output_equal_to_source_is_refused(tmp_path, target):
    """`striptri convert DIR --to colmap --out DIR` replaced the source project, truth/ included."""
    project = copy_project("strip8", tmp_path / "strip8", truth=True)
    before = snapshot(project)
    proc = run("convert", project, "--to", target, "--out", project)
    message = assert_clean_failure(proc, 2)
    assert "input" in message and "output folder" in message
    assert snapshot(project) == before
    no_strays(project)


def test_convert_output_inside_or_around_the_source_is_refused(tmp_path):
    project = copy_project("strip8", tmp_path / "strip8", truth=True)
    before = snapshot(project)
    for out in (project / "converted", project / "truth"):
        assert_clean_failure(run("convert", project, "--to", "colmap", "--out", out), 2)
    assert snapshot(project) == before
    # a converted project (it carries striptri's marker) converted onto itself
    first = tmp_path / "first"
    assert run("convert", project, "--to", "project", "--out", first).returncode == 0
    kept = snapshot(first)
    assert_clean_failure(run("convert", first, "--to", "project", "--out", first), 2)
    assert snapshot(first) == kept


def test_adjust_project_inside_an_earlier_output_is_kept(tmp_path):
    """`striptri adjust res/proj --out res`, res written by an earlier adjust, deleted res/proj."""
    res = tmp_path / "res"
    assert adjust(DATA / "pair", res).returncode == 0
    copy_project("pair", res / "proj")
    before = snapshot(res)
    message = assert_clean_failure(adjust(res / "proj", res), 2)
    assert "contains the input" in message
    assert snapshot(res) == before
    # the same with the project elsewhere: the folder holds a file striptri did not write
    message = assert_clean_failure(adjust(DATA / "pair", res), 2)
    assert "proj/ was added" in message
    assert snapshot(res) == before


def test_changed_earlier_output_is_not_replaced(tmp_path):
    out = tmp_path / "out"
    assert adjust(DATA / "pair", out).returncode == 0
    assert adjust(DATA / "pair", out).returncode == 0  # its own, unchanged output: replaced
    with open(out / "photos.csv", "a", encoding="utf-8") as f:
        f.write("# my note\n")
    before = snapshot(out)
    message = assert_clean_failure(adjust(DATA / "pair", out), 2)
    assert "photos.csv was changed" in message
    assert snapshot(out) == before


def test_output_through_a_link_into_the_project_is_refused(tmp_path):
    project = copy_project("pair", tmp_path / "project")
    os.symlink(project, tmp_path / "alias")
    before = snapshot(project)
    assert_clean_failure(adjust(project, tmp_path / "alias"), 2)
    assert_clean_failure(adjust(project, tmp_path / "alias" / "out"), 2)
    assert snapshot(project) == before


def test_linked_input_file_inside_the_output_is_refused(tmp_path):
    """A project file that is a link into the output folder would be deleted with it."""
    out = tmp_path / "out"
    assert adjust(DATA / "pair", out).returncode == 0
    project = copy_project("pair", tmp_path / "project")
    (project / "control.csv").unlink()
    os.symlink(out / "points.csv", project / "control.csv")
    before = snapshot(out)
    assert_clean_failure(adjust(project, out), 2)
    assert snapshot(out) == before


def _kill_self_while_writing(sig: int, at_file: int = 3) -> str:
    """Preamble: the process sends itself ``sig`` when it is about to write its at_file-th file."""
    return f"""
        import os, signal
        import striptri.io.output as output
        _write, _count = output.write_file, [0]
        def write_file(path, data):
            _count[0] += 1
            if _count[0] == {at_file}:
                os.kill(os.getpid(), {int(sig)})
            return _write(path, data)
        output.write_file = write_file
    """


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_signal_while_writing_leaves_nothing(tmp_path, sig):
    """SIGTERM or SIGHUP during the write left .out.tmp-* folders that no later run removed."""
    out = tmp_path / "res" / "out"
    proc = subprocess.run([*entry_point_with(_kill_self_while_writing(sig)), "adjust", str(DATA / "pair"),
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert_clean_failure(proc, 128 + sig)
    assert "interrupted" in proc.stderr
    assert not out.exists() and not out.parent.exists()  # the folder made for it is gone too
    # and over an earlier output: it stays as it was
    assert adjust(DATA / "pair", out).returncode == 0
    before = snapshot(out)
    proc = subprocess.run([*entry_point_with(_kill_self_while_writing(sig)), "adjust", str(DATA / "pair"),
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 128 + sig
    assert snapshot(out) == before
    no_strays(out)


def test_sigkill_while_writing_is_cleaned_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([*entry_point_with(_kill_self_while_writing(signal.SIGKILL)), "adjust",
                           str(DATA / "pair"), "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists()
    assert len(stray_siblings(out)) == 1  # what a kill cannot clean up
    unrelated = tmp_path / ".striptri-tmp-notours"  # not striptri's name pattern: never touched
    unrelated.mkdir()
    assert adjust(DATA / "pair", out).returncode == 0
    no_strays(out)
    assert unrelated.is_dir()
    output_is_whole(out)


def test_two_runs_writing_the_same_output(tmp_path):
    """Two runs writing the same --out could leave .out.old-* copies and end in a traceback."""
    out = tmp_path / "out"
    for _ in range(3):
        procs = [subprocess.Popen([*command(), "adjust", str(DATA / name), "--out", str(out)],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for name in ("pair", "strip8")]
        results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
        for status, err in results:
            assert status == 0, err
            assert "Traceback" not in err
        no_strays(out)
        output_is_whole(out)
        n_photos = json.loads((out / "summary.json").read_text())["n_photos"]
        assert n_photos in (2, 8)


# ============================================================================ failed adjustments


def _turn_kappa(project: Path, photo_line: int, degrees: float) -> None:
    lines = (project / "photos.csv").read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    row = lines[photo_line - 1].split(",")
    j = header.index("kappa")
    row[j] = repr(float(row[j]) + degrees)
    lines[photo_line - 1] = ",".join(row)
    (project / "photos.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_kappa_180_degrees_off_is_a_failure(tmp_path):
    """Kappa of one photo of strip8 off by 180 degrees: sigma0 about 10,000, exit 0 before."""
    project = copy_project("strip8", tmp_path / "strip8")
    _turn_kappa(project, 4, 180.0)
    out = tmp_path / "out"
    message = assert_clean_failure(adjust(project, out), 1)
    assert "converge" in message or "diverge" in message
    assert not out.exists()
    no_strays(out)


def test_c_in_micrometres_is_a_failure(tmp_path):
    project = copy_project("strip8", tmp_path / "strip8")
    text = (project / "cameras.csv").read_text(encoding="utf-8").replace(",152.0,", ",152000.0,")
    assert "152000.0" in text
    (project / "cameras.csv").write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    assert_clean_failure(adjust(project, out), 1)
    assert not out.exists()


def test_iteration_limit_is_a_failure_unless_kept(tmp_path):
    """`max_iterations = 1` gave exit 0 and a full output folder."""
    project = copy_project("strip8", tmp_path / "strip8")
    set_toml(project, """
        [adjustment]
        max_iterations = 1
    """)
    out = tmp_path / "out"
    message = assert_clean_failure(adjust(project, out), 1)
    assert "max_iterations" in message
    assert not out.exists()
    proc = adjust(project, out, "--keep-unconverged")
    assert proc.returncode == 0, proc.stderr
    assert "striptri: warning: kept although the adjustment did not converge" in proc.stderr
    assert "NOT converged" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is False
    assert summary["termination"] == "iteration_limit"
    assert summary["message"]
    assert any("did not converge" in w for w in summary["warnings"])
    assert "did not converge" in (out / "report.html").read_text(encoding="utf-8")
    # the command line's limit the same way
    assert_clean_failure(adjust(DATA / "strip8", tmp_path / "out2", "--max-iterations", "1"), 1)


def test_converged_summary_says_why(tmp_path):
    out = tmp_path / "out"
    assert adjust(DATA / "pair", out).returncode == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is True and summary["termination"] in ("converged", "cost_flat")
    assert summary["warnings"] == []


# ============================================================================ output problems


def test_output_below_a_file(tmp_path):
    (tmp_path / "afile").write_text("mine\n")
    message = assert_clean_failure(adjust(DATA / "pair", tmp_path / "afile" / "out"), 2)
    assert "afile" in message and "is a file" in message
    assert (tmp_path / "afile").read_text() == "mine\n"


def test_output_empty_path(tmp_path):
    """`--out ""` wrote into the current folder."""
    before = snapshot(tmp_path)
    message = assert_clean_failure(run("adjust", DATA / "pair", "--out", "", cwd=tmp_path), 2)
    assert "empty" in message
    assert snapshot(tmp_path) == before
    for args in (["simulate", "pair", "--out", ""], ["convert", DATA / "pair", "--to", "colmap", "--out", ""],
                 ["structure", DATA / "pair", "--out", ""], ["compare", "--out", "", "--photos", "4", "--trials", "1"]):
        assert_clean_failure(run(*args, cwd=tmp_path), 2)
    assert snapshot(tmp_path) == before


def test_output_in_an_unwritable_folder(tmp_path):
    if os.geteuid() == 0:
        target = Path("/sys/striptri-out")  # read-only even for root
    else:
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        target = locked / "out"
    message = assert_clean_failure(adjust(DATA / "pair", target), 2)
    assert "writ" in message or "permi" in message
    assert not target.exists()


def test_output_name_too_long(tmp_path):
    out = tmp_path / ("o" * 300)
    message = assert_clean_failure(adjust(DATA / "pair", out), 2)
    assert "name" in message
    out = tmp_path / "x" / ("o" * 250)  # fits, but its temporary sibling name would not: still written
    proc = adjust(DATA / "pair", out)
    assert proc.returncode == 0, proc.stderr
    output_is_whole(out)


def test_output_file_size_limit(tmp_path):
    """A file-size limit (ulimit -f) ended in a traceback."""
    out = tmp_path / "out"

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    proc = subprocess.run([*command(), "adjust", str(DATA / "strip8"), "--out", str(out)], capture_output=True,
                          text=True, timeout=300, preexec_fn=limit)
    message = assert_clean_failure(proc, 2)
    assert "file-size limit" in message
    assert not out.exists()
    no_strays(out)


def test_output_disk_full(tmp_path):
    """A full disk (ENOSPC at the third file) ends with exit 2 and nothing written."""
    preamble = """
        import errno, os
        import striptri.io.output as output
        _write, _count = output.write_file, [0]
        def write_file(path, data):
            _count[0] += 1
            if _count[0] == 3:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            return _write(path, data)
        output.write_file = write_file
    """
    out = tmp_path / "deep" / "out"
    proc = subprocess.run([*entry_point_with(preamble), "adjust", str(DATA / "pair"), "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    message = assert_clean_failure(proc, 2)
    assert "disk is full" in message
    assert not (tmp_path / "deep").exists()


def _forbid(monkeypatch, module, name):
    def fail(*args, **kwargs):
        raise AssertionError(f"{name} ran although the output location was unusable")

    monkeypatch.setattr(module, name, fail)


def test_unusable_output_is_found_before_the_adjustment(tmp_path, monkeypatch):
    """An unusable --out was found only after the whole adjustment (15-20 s on 320 photos)."""
    import striptri.pipeline as pipeline

    _forbid(monkeypatch, pipeline, "adjust_products")
    _forbid(monkeypatch, pipeline, "read_project")
    (tmp_path / "afile").write_text("x")
    runner = CliRunner()
    for out in (tmp_path / "afile" / "out", tmp_path / ("o" * 300), DATA / "pair"):
        result = runner.invoke(main, ["adjust", str(DATA / "pair"), "--out", str(out)])
        assert result.exit_code == 2, result.output
        assert "error" in result.output


def test_unusable_compare_output_is_found_before_the_trials(tmp_path, monkeypatch):
    """`compare` ran all its trials first."""
    import striptri.study.pipeline as study_pipeline

    _forbid(monkeypatch, study_pipeline, "run_study")
    (tmp_path / "afile").write_text("x")
    result = CliRunner().invoke(main, ["compare", "--out", str(tmp_path / "afile" / "out"), "--photos", "4",
                                       "--trials", "1", "--workers", "1"])
    assert result.exit_code == 2, result.output


def test_structure_does_not_overwrite_a_foreign_file(tmp_path):
    """`structure --out FILE` overwrote any file."""
    mine = tmp_path / "figure.png"
    mine.write_bytes(b"\x89PNG\r\n\x1a\nnot striptri's")
    message = assert_clean_failure(run("structure", DATA / "pair", "--out", mine), 2)
    assert "not written by this striptri command" in message
    assert mine.read_bytes() == b"\x89PNG\r\n\x1a\nnot striptri's"
    own = tmp_path / "structure.png"
    assert run("structure", DATA / "pair", "--out", own).returncode == 0
    assert run("structure", DATA / "strip8", "--out", own).returncode == 0  # its own figure: replaced
    assert_clean_failure(run("structure", DATA / "pair", "--out", DATA / "pair" / "s.png"), 2)
    assert not (DATA / "pair" / "s.png").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_simulate_refuses_zero_photos(tmp_path):
    """`simulate --photos 0` silently used the default."""
    for bad in (["--photos", "0"], ["--strips", "0"], ["--every-k", "0"], ["--flying-height", "nan"],
                ["--sigma-image", "-1"]):
        proc = run("simulate", "strip", "--out", tmp_path / "s", *bad)
        assert proc.returncode == 2, (bad, proc.stderr)
        assert "Traceback" not in proc.stderr
        assert not (tmp_path / "s").exists()


def test_command_line_clash_is_blamed_on_the_command_line(tmp_path):
    """A command-line clash was blamed on project.toml."""
    message = assert_clean_failure(adjust(DATA / "pair", tmp_path / "out", "--method", "bundle", "--datum", "inner"),
                                   2)
    assert "command line" in message and "project.toml" not in message
    project = copy_project("pair", tmp_path / "p")
    set_toml(project, """
        [adjustment]
        method = "bundle"
        [datum]
        mode = "inner"
    """)
    message = assert_clean_failure(adjust(project, tmp_path / "out"), 2)
    assert "project.toml" in message


# ============================================================================ the command itself


def test_internal_errors_are_one_line(tmp_path, monkeypatch):
    """A defect of striptri still ends with one message and exit 1, no traceback."""
    import striptri.pipeline as pipeline

    def broken(*args, **kwargs):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(pipeline, "adjust_products", broken)
    monkeypatch.delenv("STRIPTRI_DEBUG", raising=False)
    result = CliRunner().invoke(main, ["adjust", str(DATA / "pair"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert "internal error (ZeroDivisionError" in result.output
    assert not (tmp_path / "out").exists()
    assert stray_siblings(tmp_path / "out") == []
