"""No data loss at any moment of writing an output (issue 26; io.output, docs/file-formats.md
"Output safety"), shown with forced timing: a hook in io.output (STEP_HOOK) sends the process a
signal at each named step of reserving, writing and swapping, in a process that has a worker thread
besides the main one (as BLAS, tqdm and executors give a real run). After every such run:

* at --out stands either the earlier output or the new one, whole, never nothing and never a mix;
* a SIGTERM, SIGINT or SIGHUP leaves no temporary entry; a SIGKILL leaves one that the next run
  removes (or, for the journalled swap of file systems without an atomic exchange, puts back);
* the message says whether the output was complete when the signal came.

Also: the sweep of temporaries touches only what striptri marked, and convert never reads from the
folder it writes.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cli_support import DATA, assert_clean_failure, run, snapshot, stray_siblings
from striptri.io import output
from striptri.io.output import MARKER
from striptri.io.output_location import foreign_content

FOLDER_STEPS = ("reserve:parents", "reserve:made", "reserve:marked", "commit:written", "swap:checked",
                "swap:exchanged", "swap:old-removed", "commit:done")
JOURNAL_STEPS = ("swap:journal", "swap:aside", "swap:renamed")
AFTER_THE_SWAP = {"swap:exchanged", "swap:renamed", "swap:old-removed", "commit:done"}


def striptri_with_signal_at(step: str, sig: int, *args, env: dict | None = None) -> subprocess.CompletedProcess:
    """striptri ARGS in a fresh interpreter that has a second thread and sends itself ``sig`` when
    io.output reaches ``step``."""
    code = textwrap.dedent(f"""
        import os, sys, threading, time
        import striptri.io.output as output
        threading.Thread(target=time.sleep, args=(600,), daemon=True).start()
        def hook(name):
            if name == {step!r}:
                os.kill(os.getpid(), {int(sig)})
        output.STEP_HOOK = hook
        sys.argv = ["striptri", *{[str(a) for a in args]!r}]
        from striptri.cli import main
        main()
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONWARNINGS": "ignore", **(env or {})})


def whole_output(out: Path) -> dict:
    """The summary of the whole output folder at out (its manifest lists exactly its files, unchanged)."""
    assert out.is_dir(), f"{out} is missing"
    assert foreign_content(out) == "", foreign_content(out)
    listed = sorted(line.split(" ", 2)[2] for line in (out / MARKER).read_text().splitlines()[3:])
    present = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != MARKER)
    assert listed == present
    return json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def earlier(tmp_path_factory) -> Path:
    """An earlier output of the pair by the method of conditions (the new one is by the bundle method)."""
    out = tmp_path_factory.mktemp("earlier") / "out"
    proc = run("adjust", DATA / "pair", "--out", out)
    assert proc.returncode == 0, proc.stderr
    return out


def _new_outcome(proc, sig, step, out) -> str:
    """-> "old" or "new": what stands at out after the run; checks the exit and the message."""
    method = whole_output(out)["method"]
    outcome = "new" if method == "bundle" else "old"
    if sig == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL
    else:
        err = assert_clean_failure(proc, 128 + sig)
        if outcome == "new":
            assert "after the output was complete" in err and str(out) in err, err
        else:
            assert "no output was left half-written" in err, err
    return outcome


# every step with a signal that can be held back (SIGTERM) and one that cannot (SIGKILL); SIGINT and
# SIGHUP, held back the same way, at the two steps inside the swap
STEP_SIGNALS = ([(step, sig) for step in FOLDER_STEPS for sig in (signal.SIGTERM, signal.SIGKILL)]
                + [(step, sig) for step in ("swap:checked", "swap:exchanged") for sig in (signal.SIGINT, signal.SIGHUP)])


@pytest.mark.parametrize("step, sig", STEP_SIGNALS, ids=[f"{st}-{signal.Signals(sg).name}" for st, sg in STEP_SIGNALS])
def test_a_signal_at_any_step_of_the_swap_loses_nothing(tmp_path, earlier, step, sig):
    """Before: a signal between the two renames of the swap (received by a worker thread while the
    main thread held it back) left --out missing, the earlier output aside, deleted by the next run."""
    out = tmp_path / "out"
    shutil.copytree(earlier, out)
    before = snapshot(out)
    proc = striptri_with_signal_at(step, sig, "adjust", DATA / "pair", "--out", out, "--method", "bundle")
    outcome = _new_outcome(proc, sig, step, out)
    # a signal that can be held back waits for the end of the swap; SIGKILL cannot be
    held_through_the_swap = step == "swap:checked" and sig != signal.SIGKILL
    assert outcome == ("new" if step in AFTER_THE_SWAP or held_through_the_swap else "old"), (step, outcome)
    if outcome == "old":
        assert snapshot(out) == before  # exactly as it was
    if sig != signal.SIGKILL:
        assert stray_siblings(out) == []
    # the next run cleans up whatever a SIGKILL left, and nothing else
    proc = run("adjust", DATA / "pair", "--out", out, "--method", "bundle")
    assert proc.returncode == 0, proc.stderr
    assert stray_siblings(out) == []
    assert whole_output(out)["method"] == "bundle"


@pytest.mark.parametrize("sig", (signal.SIGTERM, signal.SIGKILL), ids=lambda s: signal.Signals(s).name)
@pytest.mark.parametrize("step", JOURNAL_STEPS)
def test_the_journalled_swap_puts_the_old_output_back(tmp_path, earlier, step, sig):
    """Where no atomic exchange exists (STRIPTRI_NO_RENAME_EXCHANGE stands in for such a file
    system), a run killed between the two renames leaves its journal; the next sweep reads it and
    puts the earlier output back, or deletes it when the new one is in place."""
    out = tmp_path / "out"
    shutil.copytree(earlier, out)
    before = snapshot(out)
    env = {output.NO_EXCHANGE_VARIABLE: "1"}
    proc = striptri_with_signal_at(step, sig, "adjust", DATA / "pair", "--out", out, "--method", "bundle", env=env)
    if sig == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL
        if step == "swap:aside":
            assert not out.exists()  # the one instant an exchange would have avoided
        output.remove_stale_temporaries(tmp_path)
        expected = "new" if step == "swap:renamed" else "old"
    else:  # held back until the swap is done
        expected = "new"
        assert _new_outcome(proc, sig, step, out) == expected
    assert stray_siblings(out) == []
    assert whole_output(out)["method"] == ("bundle" if expected == "new" else "conditions")
    if expected == "old":
        assert snapshot(out) == before


FIRST_OUTPUT_STEPS = ("reserve:parents", "reserve:made", "reserve:marked", "commit:written", "swap:checked",
                      "swap:renamed", "commit:done")


@pytest.mark.parametrize("step", FIRST_OUTPUT_STEPS)
def test_a_signal_at_any_step_of_a_first_output_leaves_nothing_or_all(tmp_path, step):
    """No earlier output: afterwards --out is absent (with the folders made for it) or whole."""
    out = tmp_path / "made" / "out"
    proc = striptri_with_signal_at(step, signal.SIGTERM, "adjust", DATA / "pair", "--out", out)
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    if step in AFTER_THE_SWAP or step == "swap:checked":
        whole_output(out)
        assert stray_siblings(out) == []
    else:
        assert not out.parent.exists(), list(out.parent.iterdir())


@pytest.mark.parametrize("step", ("commit:written", "swap:renamed", "commit:done"))
def test_a_kill_while_replacing_a_single_file_output(tmp_path, step):
    """striptri structure replaces its PNG by one rename: the old figure or the new one, whole."""
    png = tmp_path / "n.png"
    assert run("structure", DATA / "pair", "--out", png).returncode == 0
    old = png.read_bytes()
    proc = striptri_with_signal_at(step, signal.SIGKILL, "structure", DATA / "strip8", "--out", png)
    assert proc.returncode == -signal.SIGKILL
    new = png.read_bytes()
    assert new == old if step == "commit:written" else new != old
    assert new.startswith(b"\x89PNG") and new.endswith(b"IEND\xaeB`\x82")
    assert run("structure", DATA / "pair", "--out", png).returncode == 0
    assert stray_siblings(png) == []


# --------------------------------------------------------------------------- the sweep


def test_the_sweep_never_touches_a_users_entry_with_a_temporary_name(tmp_path):
    """Before: `echo notes > .striptri-tmp-0123456789ab; striptri adjust ... --out out` deleted it."""
    notes = tmp_path / ".striptri-tmp-0123456789ab"
    notes.write_text("notes\n")
    folder = tmp_path / ".striptri-old-abcdefabcdef"
    folder.mkdir()
    (folder / "mine.txt").write_text("mine\n")
    (folder / ".striptri-partial").write_text("")  # the name alone is no marker
    swap = tmp_path / ".striptri-swap-0123456789ab"
    swap.write_text("a user's file\nout\n")
    before = snapshot(tmp_path)
    proc = run("adjust", DATA / "pair", "--out", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    after = snapshot(tmp_path)
    assert {k: v for k, v in after.items() if k in before} == before


def test_the_sweep_removes_what_a_killed_run_marked(tmp_path):
    partial = tmp_path / ".striptri-tmp-0123456789ab"
    partial.mkdir()
    (partial / ".striptri-partial").write_bytes(output.PARTIAL_TEXT)
    (partial / "photos.csv").write_text("half\n")
    empty = tmp_path / ".striptri-tmp-abcdefabcdef"  # killed between mkdir and its mark
    empty.mkdir()
    removed = output.remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([partial.name, empty.name])
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- convert


def test_convert_never_reads_from_the_folder_it_writes(tmp_path):
    """Before: a DBAT script whose base_dir pointed into --out was read from there and its files
    replaced, exit 0."""
    source = DATA.parents[1].parent / "shared" / "data" / "real" / "dbat_camcal" / "script" / "camcaldemo.xml"
    if not source.exists():
        pytest.skip("../shared/data/real is not beside the repository")
    d = tmp_path / "d"
    proc = run("convert", source, "--to", "dbat", "--out", d)
    assert proc.returncode == 0, proc.stderr
    script = tmp_path / "x.xml"
    script.write_text((d / "project.xml").read_text().replace('base_dir="$HERE"', 'base_dir="$HERE/d"'))
    before = snapshot(d)
    proc = run("convert", script, "--to", "project", "--out", d)
    err = assert_clean_failure(proc, 2)
    assert "contains the input" in err and str(d) in err, err
    assert snapshot(d) == before


@pytest.mark.parametrize("sig", (signal.SIGTERM, signal.SIGINT), ids=lambda s: signal.Signals(s).name)
def test_a_signal_as_the_command_ends_says_the_output_is_complete(tmp_path, sig):
    """Before: a signal that came after the command had put its output in place, while it was
    ending, gave a traceback or no message at all."""
    out = tmp_path / "out"
    code = textwrap.dedent(f"""
        import os, sys
        import striptri.cli.base as cli
        restore = cli._restore_signals
        def restore_then_signal(previous):
            restore(previous)
            os.kill(os.getpid(), {int(sig)})
        cli._restore_signals = restore_then_signal
        from striptri._entry import main
        sys.argv = ["striptri", "adjust", {str(DATA / "pair")!r}, "--out", {str(out)!r}]
        main()
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    err = assert_clean_failure(proc, 128 + sig)
    assert f"{out} holds this run's whole result" in err, err
    whole_output(out)
