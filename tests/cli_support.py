"""Helpers for tests that run the real ``striptri`` command: the command itself, the shape of a
clean failure (one message, the right exit status, no traceback) and snapshots of folders that
must not change.

:func:`run` runs the command's own entry point (``striptri.cli.main``, with its error and signal
handling) in this process, through click's test runner: a fresh interpreter with numpy, scipy and
matplotlib costs 2-3 s of CPU per run, which over the suite's runs was a quarter of CI's time.
What a separate process would show is kept: the exit status, stdout and stderr apart, and an
exception that escaped the command turned into its traceback on stderr with exit status 1 (so
``assert_clean_failure`` still catches it). ``STRIPTRI_TEST_SUBPROCESS=1`` (or
``in_subprocess=True``) runs the real console script in a subprocess instead; the tests of signals,
interruptions and worker processes always do (they call :func:`command` themselves)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data" / "synthetic_strips"
SHARED_DATA = REPO.parent / "shared" / "data" / "real"


def command() -> list[str]:
    """The ``striptri`` console script of this interpreter (or the same entry point through -c)."""
    script = Path(sys.executable).parent / "striptri"
    if script.exists():
        return [str(script)]
    found = shutil.which("striptri")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; sys.argv[0] = 'striptri'; from striptri.cli import main; main()"]


IN_SUBPROCESS = bool(os.environ.get("STRIPTRI_TEST_SUBPROCESS"))
SUBPROCESS_COMMANDS = ("match",)  # commands that start worker processes of their own


def run(*args, timeout: float = 300, cwd: Path | None = None, env: dict | None = None,
        stdin=subprocess.DEVNULL, in_subprocess: bool = False) -> subprocess.CompletedProcess:
    """Run ``striptri ARGS`` to completion; text output captured (module doc: in this process
    unless ``in_subprocess`` or STRIPTRI_TEST_SUBPROCESS)."""
    args = [str(a) for a in args]
    if (in_subprocess or IN_SUBPROCESS or stdin is not subprocess.DEVNULL
            or args[:1] and args[0] in SUBPROCESS_COMMANDS):
        return subprocess.run([*command(), *args], capture_output=True, text=True, timeout=timeout, cwd=cwd or REPO,
                              env={**os.environ, "PYTHONWARNINGS": "ignore", **(env or {})}, stdin=stdin)
    return _in_this_process(args, cwd or REPO, env)


def _in_this_process(args: list[str], cwd: Path, env: dict | None) -> subprocess.CompletedProcess:
    import traceback
    import warnings

    from click.testing import CliRunner

    from striptri.cli import main

    before = os.getcwd()
    os.chdir(cwd)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # as PYTHONWARNINGS=ignore for the subprocess
            result = CliRunner().invoke(main, args, env=env, prog_name="striptri", catch_exceptions=True)
    finally:
        os.chdir(before)
    code, stderr = result.exit_code, result.stderr
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        # what the interpreter would print and return for an exception no handler caught
        stderr += "Traceback (most recent call last):\n" + "".join(traceback.format_exception(result.exception))
        code = 1
    return subprocess.CompletedProcess(["striptri", *args], code, result.stdout, stderr)


def assert_clean_failure(proc: subprocess.CompletedProcess, status: int) -> str:
    """Exit status, exactly one ``striptri: error:`` message first on stderr, no traceback, no
    internal error; returns stderr."""
    assert proc.returncode == status, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    assert "internal error" not in proc.stderr, proc.stderr
    assert proc.stderr.count("striptri: error:") == 1, proc.stderr
    assert proc.stderr.startswith("striptri: error:") or "\nstriptri: error:" in proc.stderr, proc.stderr
    return proc.stderr


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under folder, hidden ones too: for a file its bytes and mtime, for a folder or a
    link what it is, so that any change, addition or removal shows."""
    out: dict[str, tuple] = {}
    for p in sorted(Path(folder).rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = ("link", os.readlink(p))
        elif p.is_dir():
            out[rel] = ("dir",)
        elif p.is_file():
            st = p.stat()
            out[rel] = ("file", p.read_bytes(), st.st_mtime_ns)
        else:
            out[rel] = ("other",)
    return out


def copy_project(name: str, dest: Path, truth: bool = False) -> Path:
    """A copy of a shipped project of data/synthetic_strips (without its truth folder unless asked)."""
    ignore = None if truth else shutil.ignore_patterns("truth")
    shutil.copytree(DATA / name, dest, ignore=ignore)
    return dest


def stray_siblings(out: Path) -> list[str]:
    """Temporary or aside entries striptri may have left next to the output path ``out`` (its own
    ``.striptri-tmp-*`` / ``.striptri-old-*`` names, and the ``.<name>.tmp-*`` of earlier versions)."""
    parent = Path(out).parent
    if not parent.exists():
        return []
    pattern = re.compile(r"^\.striptri-(tmp|old|swap)-[0-9a-f]{12}(\.[A-Za-z0-9]+)?$")
    return sorted(p.name for p in parent.iterdir()
                  if pattern.match(p.name) or p.name.startswith(f".{Path(out).name}."))
