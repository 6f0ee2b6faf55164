"""Helpers for tests that run the real ``striptri`` command in a subprocess: the command itself,
the shape of a clean failure (one message, the right exit status, no traceback) and snapshots of
folders that must not change."""

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


def run(*args, timeout: float = 300, cwd: Path | None = None, env: dict | None = None,
        stdin=subprocess.DEVNULL) -> subprocess.CompletedProcess:
    """Run ``striptri ARGS`` to completion; text output captured."""
    return subprocess.run([*command(), *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          cwd=cwd or REPO, env={**os.environ, "PYTHONWARNINGS": "ignore", **(env or {})},
                          stdin=stdin)


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
