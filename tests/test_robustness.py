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


# ============================================================================ property: mutated input

PROJECTS = ("pair", "pair_minimal", "strip8", "schmid_fig8", "strip_2_3", "block_3x6")
MUTABLE_FILES = ("cameras.csv", "photos.csv", "photos.csv", "image_points.csv", "image_points.csv", "control.csv",
                 "control.csv", "project.toml", "bases.csv", "approx_points.csv")  # weighted: the shipped ones
CELL_VALUES = ("", " ", "0", "-0", "1", "-1", "2", "1e-20", "1e300", "-1e300", "1e309", "nan", "inf", "-inf",
               "abc", "free", "XYZ", "check", "Z", "1001", "P1", "1.5.2", "0x10", "1_000", "\u00a0", "\"a,b\"",
               "'", "\"", "#", "\u00e9", "\U0001F600", "3" * 400)
TOML_VALUES = ('"bundle"', '"sequential"', '"cholmod"', '"gauss-seidel"', "0", "1", "-1", "true", "nan", "1e300",
               '"gon"', '"rad"', '"alpha-omega-chi"', '"inner"', "[1, 2]", '{a = 1}', '"x"')
EXTRA_OPTIONS = ((), ("--method", "bundle"), ("--method", "sequential"), ("--blunders", "snoop"),
                 ("--solver", "gauss-seidel"), ("--point-precision", "joint92"), ("--init", "sequential"))
PROPERTY_EXAMPLES = int(os.environ.get("STRIPTRI_PROPERTY_EXAMPLES", "120"))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return text.strip() != ""


def _mutate(data, text: str, name: str) -> str:
    """One random change of a file's text: bytes, a cell, a row, a column, a truncation."""
    from hypothesis import strategies as st

    lines = text.splitlines(keepends=True)
    kind = data.draw(st.sampled_from(["bytes", "cell", "perturb", "perturb", "rows", "row", "column", "truncate"]),
                     label="kind")
    if kind == "bytes" or not lines:
        raw = text.encode("utf-8", "surrogateescape")
        pos = data.draw(st.integers(0, len(raw)), label="pos")
        new = data.draw(st.binary(min_size=0, max_size=4), label="bytes")
        cut = data.draw(st.integers(0, 3), label="cut")
        return (raw[:pos] + new + raw[pos + cut:]).decode("utf-8", "surrogateescape")
    if kind == "truncate":
        return text[: data.draw(st.integers(0, len(text)), label="at")]
    if kind == "rows":  # keep the header and a random subset of the rows (control lost, photos cut off)
        keep = data.draw(st.lists(st.booleans(), min_size=len(lines) - 1, max_size=len(lines) - 1), label="keep")
        return "".join([lines[0], *(line for line, k in zip(lines[1:], keep) if k)])
    first = 1 if kind == "perturb" and len(lines) > 1 else 0  # numbers are in the data rows
    i = data.draw(st.integers(first, len(lines) - 1), label="line")
    if kind == "perturb" and not name.endswith(".toml"):  # a plausible number made wrong
        cells = lines[i].rstrip("\r\n").split(",")
        numeric = [j for j, c in enumerate(cells) if _is_number(c)]
        if numeric:
            j = data.draw(st.sampled_from(numeric), label="numeric column")
            change = data.draw(st.sampled_from(["*-1", "*10", "*1000", "*0.001", "+180", "+0.5", "*0"]), label="change")
            value = float(cells[j])
            value = value * float(change[1:]) if change[0] == "*" else value + float(change[1:])
            cells[j] = repr(value)
            lines[i] = ",".join(cells) + "\n"
            return "".join(lines)
        kind = "cell"
    if kind == "row":
        op = data.draw(st.sampled_from(["delete", "duplicate", "swap"]), label="row op")
        if op == "delete":
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[i])
        else:
            j = data.draw(st.integers(0, len(lines) - 1), label="with")
            lines[i], lines[j] = lines[j], lines[i]
        return "".join(lines)
    if name.endswith(".toml"):
        key_value = lines[i].split("=", 1)
        if len(key_value) == 2:
            lines[i] = f"{key_value[0]}= {data.draw(st.sampled_from(TOML_VALUES), label='value')}\n"
        else:
            lines[i] = data.draw(st.sampled_from(["[units]\n", "[adjustment]\n", "[nonsense]\n", "max_iterations = 1\n",
                                                  "cost_tolerance = 0.5\n", "x = \n"]), label="toml line")
        return "".join(lines)
    fields = [lines[i].rstrip("\r\n").split(",")]
    cells = fields[0]
    j = data.draw(st.integers(0, max(len(cells) - 1, 0)), label="column")
    if kind == "cell":
        value = data.draw(st.one_of(st.sampled_from(CELL_VALUES), st.text(max_size=6)), label="value")
        cells[j] = value.replace("\n", " ").replace("\r", " ")
        lines[i] = ",".join(cells) + "\n"
        return "".join(lines)
    # a whole column: removed, renamed in the header, or duplicated
    op = data.draw(st.sampled_from(["drop", "rename", "duplicate"]), label="column op")
    out = []
    for k, line in enumerate(lines):
        row = line.rstrip("\r\n").split(",")
        if j < len(row):
            if op == "drop":
                del row[j]
            elif op == "duplicate":
                row.insert(j, row[j])
            elif k == 0:
                row[j] = data.draw(st.sampled_from(["sigma_x0", "X", "kind", "", "photo_id", "c "]), label="name")
        out.append(",".join(row) + "\n")
    return "".join(out)


def test_mutated_projects_end_cleanly(tmp_path_factory):
    """Random changes of the shipped projects' files (bytes, cells, rows, columns): every run ends
    with exit status 0, 1 or 2, no traceback and no internal error; a failed run writes nothing,
    a successful one a whole output folder; the input folder is byte-identical afterwards. Case
    count: STRIPTRI_PROPERTY_EXAMPLES (120); derandomised, so CI runs the same cases every time."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    root = tmp_path_factory.mktemp("mutations")
    runner = CliRunner()
    counter = iter(range(10**9))
    seen_status: dict[int, int] = {}

    @settings(max_examples=PROPERTY_EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def check(data):
        case = root / f"case{next(counter)}"
        name = data.draw(st.sampled_from(PROJECTS), label="project")
        project = copy_project(name, case / "project")
        for _ in range(data.draw(st.integers(1, 3), label="changes")):
            file_name = data.draw(st.sampled_from(MUTABLE_FILES), label="file")
            path = project / file_name
            text = (path.read_bytes().decode("utf-8", "surrogateescape") if path.exists()
                    else "point_id,X,Y,Z\n1001C,1,2,3\n")
            path.write_bytes(_mutate(data, text, file_name).encode("utf-8", "surrogateescape"))
        extra = data.draw(st.sampled_from(EXTRA_OPTIONS), label="options")
        before = snapshot(project)
        out = case / "out"
        result = runner.invoke(main, ["adjust", str(project), "--out", str(out), *extra])
        output = result.output
        assert result.exit_code in (0, 1, 2), (result.exit_code, output, result.exception)
        assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
        assert "Traceback" not in output and "internal error" not in output, output
        assert snapshot(project) == before
        assert stray_siblings(out) == []
        if result.exit_code == 0:
            output_is_whole(out)
        else:
            assert not out.exists(), output
            assert output.count("striptri: error:") == 1, output
        seen_status[result.exit_code] = seen_status.get(result.exit_code, 0) + 1
        shutil.rmtree(case)

    check()
    # the mutations reach all three endings, so the property is not vacuous
    assert set(seen_status) == {0, 1, 2}, seen_status


# ============================================================================ faults at random moments


def _block_300(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("block300") / "block"
    proc = run("simulate", "block", "--photos", "20", "--strips", "15", "--seed", "7", "--out", folder)
    assert proc.returncode == 0, proc.stderr
    return folder


FAULT_SIGNALS = (signal.SIGKILL, signal.SIGTERM, signal.SIGINT)


@pytest.mark.parametrize("what", ["adjust", "convert"])
def test_signals_at_random_moments(tmp_path_factory, what):
    """SIGKILL, SIGTERM and SIGINT at random moments (fixed seed) of an adjustment of a 300-photo
    block and of a convert of it: after each, the input is unchanged and the output either absent
    or whole (never partial); after the next run no temporary folder is left."""
    import numpy as np
    import time

    project = _block_300(tmp_path_factory)
    before = snapshot(project)
    work = tmp_path_factory.mktemp(f"faults-{what}")
    out = work / "out"
    args = (["adjust", str(project), "--out", str(out)] if what == "adjust"
            else ["convert", str(project), "--to", "colmap", "--out", str(out)])
    t0 = time.perf_counter()
    first = subprocess.run([*command(), *args], capture_output=True, text=True, timeout=600)
    duration = time.perf_counter() - t0
    assert first.returncode == 0, first.stderr
    shutil.rmtree(out)
    rng = np.random.default_rng(20261124)
    moments = []
    for sig in FAULT_SIGNALS:
        for low, high in ((0.05, 0.5), (0.5, 0.9), (0.9, 1.1)):  # reading / computing / writing
            moments.append((sig, float(rng.uniform(low, high)) * duration))
    outcomes = []
    strays = stray_siblings(out)
    for sig, moment in moments:
        proc = subprocess.Popen([*command(), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            proc.wait(timeout=moment)
        except subprocess.TimeoutExpired:
            proc.send_signal(sig)
        status = proc.wait(timeout=600)
        err = proc.stderr.read()
        proc.stdout.close()
        proc.stderr.close()
        assert "Traceback" not in err, err
        assert status in (0, 128 + sig, -sig), (sig, status, err)
        assert snapshot(project) == before
        if out.exists():
            output_is_whole(out)
        if sig != signal.SIGKILL:  # it cleans up after itself (a killed run's temporary waits for the next run)
            assert set(stray_siblings(out)) <= set(strays), (sig, moment)
        strays = stray_siblings(out)
        outcomes.append(status)
    last = subprocess.run([*command(), *args], capture_output=True, text=True, timeout=600)
    assert last.returncode == 0, last.stderr
    assert stray_siblings(out) == []
    output_is_whole(out)
    assert snapshot(project) == before
    assert any(s != 0 for s in outcomes)  # some signal did strike a running command
