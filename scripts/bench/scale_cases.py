"""The cases of bench_scale.py: project folders made by ``striptri simulate`` and close_range.py.

Blocks (the issue's benchmark data, /work/benchdata/b1k, b5k, b20k, are the raw folders)::

    striptri simulate block --photos P --strips S --extra-ties 6 --control perimeter --seed 11 --out RAW

then the perimeter layout's height points become tie points (their rows leave control.csv; their
measurements stay): pycolmap can hold a whole point constant but not one coordinate of it, so with
full control only both programs solve the same least-squares problem. The block keeps its full
(XYZ) control points around the perimeter, held fixed.

Close range: close_range.py (115 convergent photos, 150 targets, ~66 rays per target,
self-calibration of c, xp, yp, k1, k2, six full control points held fixed).

Each case is built once into ``DATA_DIR/<name>`` and reused while its recipe (``case.json``) is
unchanged. ``summarise`` counts what the benchmark documents (photos, points, measurements, rays).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SEED = 11  # the blocks' seed (the issue's benchmark data)
CLOSE_SEED = 3


@dataclass(frozen=True)
class ScaleCase:
    """kind "block": photos per strip x strips; kind "strip": photos, control every k models (full
    control, issue 12's long strips); kind "close": photos, targets (close_range.py)."""

    name: str
    kind: str
    photos: int
    strips_or_targets: int

    @property
    def n_photos(self) -> int:
        return self.photos * self.strips_or_targets if self.kind == "block" else self.photos

    def recipe(self) -> list[str]:
        """The command that makes the raw project (OUT for its folder)."""
        if self.kind == "strip":
            return ["striptri", "simulate", "strip", "--photos", str(self.photos), "--control", "every-k",
                    "--every-k", str(self.strips_or_targets), "--every-k-kind", "XYZ", "--seed", str(SEED),
                    "--out", "OUT"]
        if self.kind == "block":
            return ["striptri", "simulate", "block", "--photos", str(self.photos), "--strips",
                    str(self.strips_or_targets), "--extra-ties", "6", "--control", "perimeter", "--seed", str(SEED),
                    "--out", "OUT"]
        return ["python", "scripts/bench/close_range.py", "OUT", "--photos", str(self.photos), "--targets",
                str(self.strips_or_targets), "--seed", str(CLOSE_SEED)]


CASES = {
    "b1k": ScaleCase("b1k", "block", 50, 20),
    "b5k": ScaleCase("b5k", "block", 100, 50),
    "b20k": ScaleCase("b20k", "block", 200, 100),
    "b100k": ScaleCase("b100k", "block", 500, 200),  # issue 29: 200 strips of 500
    "close-range": ScaleCase("close-range", "close", 115, 150),
    # issue 12: long strips, full control every 20 models
    "s10k": ScaleCase("s10k", "strip", 10000, 20),
    "s100k": ScaleCase("s100k", "strip", 100000, 20),
    "s100k-50": ScaleCase("s100k-50", "strip", 100000, 50),  # issue 29's strip: full control every 50 models
    # quick mode (smoke run)
    "b100": ScaleCase("b100", "block", 20, 5),
    "close-small": ScaleCase("close-small", "close", 24, 40),
}
DEFAULT_CASES = ("b1k", "b5k", "b20k", "close-range")
QUICK_CASES = ("b100", "close-small")
BLOCK_SCALE = ("b1k", "b5k", "b20k", "b100k")  # the growth fit (those measured)

# What the built cases hold (measured by summarise; bench_scale.py prints it at every run and the
# smoke test checks the cheap ones): photos, points with rays, full control points, measurements.
DOCUMENTED = {
    "b1k": {"photos": 1000, "points": 7930, "full_control": 90, "measurements": 29213},
    "close-range": {"photos": 115, "points": 150, "full_control": 6, "measurements": 10022},
    "close-small": {"photos": 24, "points": 40, "full_control": 6},
}


def default_data_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "striptri-bench" / "scale"


def build_case(case: ScaleCase, data_dir: Path, env: dict | None = None) -> Path:
    """The case's project folder, made now unless it is there with the same recipe."""
    folder = Path(data_dir) / case.name
    stamp = folder / "case.json"
    recipe = {"case": asdict(case), "recipe": case.recipe(), "version": 1}
    if stamp.is_file():
        try:
            if json.loads(stamp.read_text()) == recipe:
                return folder / "project"
        except ValueError:
            pass
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    raw = folder / "raw"
    if case.kind in ("block", "strip"):
        cmd = [sys.executable, "-m", "striptri"] + case.recipe()[1:]
    else:
        cmd = [sys.executable, str(HERE / "close_range.py")] + case.recipe()[2:]
    cmd[cmd.index("OUT")] = str(raw)
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    project = folder / "project"
    if case.kind in ("block", "strip"):
        full_control_only(raw, project)
        shutil.rmtree(raw)
    else:
        raw.rename(project)
    stamp.write_text(json.dumps(recipe, indent=1) + "\n")
    return project


def full_control_only(raw: Path, out: Path) -> None:
    """A copy of the project folder ``raw`` whose control.csv keeps its XYZ rows only (module doc);
    truth/ is copied as it is."""
    out.mkdir(parents=True)
    for name in ("cameras.csv", "photos.csv", "image_points.csv", "project.toml"):
        shutil.copyfile(raw / name, out / name)
    shutil.copytree(raw / "truth", out / "truth")
    with open(raw / "control.csv", newline="") as src, open(out / "control.csv", "w", newline="") as dst:
        reader, writer = csv.reader(src), csv.writer(dst)
        header = next(reader)
        writer.writerow(header)
        kind = header.index("kind")
        writer.writerows(row for row in reader if row and row[kind].strip().upper() == "XYZ")


def read_columns(path: Path, names: list[str]) -> dict[str, list[str]]:
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    header = [h.strip() for h in rows[0]]
    idx = [header.index(n) for n in names]
    return {n: [r[i].strip() for r in rows[1:]] for n, i in zip(names, idx)}


def summarise(project: Path) -> dict:
    """Counts of a case's project folder: photos, measured points (and of them those on one photo
    only), the full control points among them, measurements, rays per point and measurements per photo."""
    photos = read_columns(project / "photos.csv", ["photo_id"])["photo_id"]
    ip = read_columns(project / "image_points.csv", ["photo_id", "point_id"])
    control = read_columns(project / "control.csv", ["point_id", "kind"])
    ids, rays = np.unique(np.array(ip["point_id"]), return_counts=True)
    full = {p for p, k in zip(control["point_id"], control["kind"]) if k.upper() == "XYZ"}
    per_photo = np.unique(np.array(ip["photo_id"]), return_counts=True)[1]
    return {
        "photos": len(photos),
        "points": len(ids),
        "points_on_one_photo": int((rays == 1).sum()),
        "full_control": int(sum(1 for p in ids if p in full)),
        "measurements": len(ip["photo_id"]),
        "rays_per_point": {"mean": round(float(rays.mean()), 2), "min": int(rays.min()), "max": int(rays.max())},
        "measurements_per_photo": round(float(per_photo.mean()), 1),
    }


def truth_centres(project: Path) -> dict[str, np.ndarray]:
    cols = read_columns(project / "truth" / "photos.csv", ["photo_id", "X0", "Y0", "Z0"])
    xyz = np.column_stack([np.array(cols[k], dtype=float) for k in ("X0", "Y0", "Z0")])
    return dict(zip(cols["photo_id"], xyz))


def rms_centres(photos_csv: Path, truth: dict[str, np.ndarray]) -> float:
    """RMS of the projection centres of an output photos.csv against the truth (m)."""
    cols = read_columns(photos_csv, ["photo_id", "X0", "Y0", "Z0"])
    xyz = np.column_stack([np.array(cols[k], dtype=float) for k in ("X0", "Y0", "Z0")])
    ref = np.array([truth[p] for p in cols["photo_id"]])
    return float(np.sqrt(np.mean(np.sum((xyz - ref) ** 2, axis=1))))
