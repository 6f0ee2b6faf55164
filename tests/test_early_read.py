"""The project read by a forked child while the command loads (striptri.io.early_read).

Each case runs in a fresh interpreter: the reader is a fork of the console script before it starts
any thread, which a pytest worker is not. EARLY_READ_BYTES is lowered there so that the small
shipped projects take the child's path (the benchmark blocks take it at their own size)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the early reader forks (Linux)")

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"

# the console script's main with the threshold lowered; take() reports whether the child's project came
COMMAND = """
import sys
import striptri.io.early_read as early
early.EARLY_READ_BYTES = int(sys.argv[1])
taken = early.take
def take(folder):
    project = taken(folder)
    sys.stderr.write(f"early read: {project is not None}\\n")
    return project
early.take = take
sys.argv = ["striptri", *sys.argv[2:]]
from striptri._entry import main
main()
"""


def command(threshold: int, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", COMMAND, str(threshold), *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def tables(folder: Path) -> dict[str, str]:
    out = {p.name: p.read_text() for p in sorted(folder.glob("*.csv"))}
    summary = json.loads((folder / "summary.json").read_text())
    for key in ("timings_s", "started"):
        summary.pop(key, None)
    out["summary.json"] = json.dumps(summary, sort_keys=True)
    return out


def test_the_child_reads_the_project_and_the_command_writes_the_same_files(tmp_path):
    early = command(0, "adjust", DATA / "strip8", "--out", tmp_path / "early", "--quiet")
    assert early.returncode == 0, early.stderr
    assert "early read: True" in early.stderr
    plain = command(10**15, "adjust", DATA / "strip8", "--out", tmp_path / "plain", "--quiet")
    assert plain.returncode == 0 and "early read: False" in plain.stderr
    assert tables(tmp_path / "early") == tables(tmp_path / "plain")


def test_bad_input_is_reported_as_without_the_child(tmp_path):
    """The child sends nothing when the project is bad: the command reads it itself and says what it
    always said (file, line, reason), exit status 2, no output."""
    bad = tmp_path / "bad"
    shutil.copytree(DATA / "strip8", bad)
    lines = (bad / "image_points.csv").read_text().splitlines()
    fields = lines[3].split(",")
    fields[2] = "x1.5"
    lines[3] = ",".join(fields)
    (bad / "image_points.csv").write_text("\n".join(lines) + "\n")
    early = command(0, "adjust", bad, "--out", tmp_path / "out1")
    plain = command(10**15, "adjust", bad, "--out", tmp_path / "out2")
    assert early.returncode == plain.returncode == 2
    assert "early read: False" in early.stderr
    message = [line for line in early.stderr.splitlines() if line.startswith("striptri: error:")]
    assert message and message == [line for line in plain.stderr.splitlines() if line.startswith("striptri: error:")]
    assert "image_points.csv" in message[0] and "line 4" in message[0]
    assert not (tmp_path / "out1").exists()


UNIT = """
import os, sys
import striptri.io.early_read as early
early.EARLY_READ_BYTES = 0
strip8, block = sys.argv[1], sys.argv[2]
# no reader: another command, an option first, a folder without image_points.csv, a large threshold
assert not early.start(["convert", strip8])
assert not early.start(["adjust", "--out", "x", strip8])
assert not early.start(["adjust", os.path.dirname(strip8)])
early.EARLY_READ_BYTES = 10**15
assert not early.start(["adjust", strip8])
early.EARLY_READ_BYTES = 0
# a reader for one folder is not taken for another, and is gone after
assert early.start(["adjust", strip8]) and not early.start(["adjust", strip8])
pid = early._pending[0][1]
assert early.take(block) is None and not early._pending
try:
    os.waitpid(pid, 0)
    raise SystemExit("the child was left running")
except ChildProcessError:
    pass
# nothing to wait for without a reader
assert early.ready() and not early.waiting_for(strip8)
# taken for its folder: the project read_project reads; waited for (its folder only) until the
# child has sent it, then ready
from striptri.io import read_project
import time
assert early.start(["adjust", strip8])
assert not early.waiting_for(block)
deadline = time.monotonic() + 60
while not early.ready():
    assert early.waiting_for(strip8)
    assert time.monotonic() < deadline, "the child never sent its project"
    time.sleep(0.001)
assert not early.waiting_for(strip8)
project = early.take(strip8)
ref = read_project(strip8)
assert project is not None and project.photos.ids == ref.photos.ids
assert (project.image_points.xy == ref.image_points.xy).all()
# discard stops a reader not taken
assert early.start(["adjust", block])
pid = early._pending[0][1]
early.discard()
assert not early._pending
try:
    os.waitpid(pid, 0)
    raise SystemExit("discard left the child running")
except ChildProcessError:
    pass
print("ok")
"""


def test_start_take_and_discard():
    done = subprocess.run([sys.executable, "-c", UNIT, str(DATA / "strip8"), str(DATA / "block_3x6")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr
