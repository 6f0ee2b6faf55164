"""Map coordinates: a block on the curved Earth adjusted naively in UTM grid coordinates, with its
CRS set, and in the local frame it was simulated in (docs/decisions.md, "Map coordinates").

    PYTHONPATH=src python scripts/demo_crs.py [--size-km 20] [--seeds 3]

Prints, per adjustment, the check points' mean error and RMS per axis (metres, local-frame
differences adjusted - true; for the naive run grid differences converted with the local scale).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from striptri.core.runs import RunOptions
from striptri import simulate as sim
from striptri.io.project_writer import write_project
from striptri.model import CoordinateSettings
from striptri.pipeline import run_adjust
from striptri.simulate.map_coordinates import central_meridian, to_map_coordinates


def block_design(size_km: float, flying_height: float, layout: str = "perimeter", every_k: int = 2) -> sim.SyntheticDesign:
    """A block of about size_km x size_km with 60 % overlap and 30 % sidelap (23 cm format, c = 152 mm)."""
    footprint = 230.0 * flying_height / 152.0 / 1000.0
    base, spacing = 0.4 * footprint, 0.7 * footprint
    n_photos = int(np.ceil(size_km / base)) + 1
    n_strips = int(np.ceil(size_km / spacing)) + 1
    return sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=n_photos, n_strips=n_strips, flying_height=flying_height,
                                attitude_std_deg=(0.5,) * 3, position_std_m=(20.0,) * 3),
        terrain=sim.TerrainDesign(relief=100.0),
        points=sim.PointDesign(extra_ties_per_model=4),
        control=sim.ControlDesign(layout=layout, every_k=every_k, n_check=2 * n_strips * 4),
    )


def check_errors(out: Path, truth: dict) -> np.ndarray:
    """adjusted - true of the check points in points.csv (the files' coordinates). -> (n, 3)."""
    import csv

    rows = list(csv.DictReader((out / "points.csv").open()))
    true = {pid: np.array([truth["points.csv"][a][k] for a in "XYZ"], dtype=float)
            for k, pid in enumerate(truth["points.csv"]["point_id"])}
    return np.array([[float(r[a]) for a in "XYZ"] - true[r["point_id"]] for r in rows if r["kind"] == "check"])


def run(size_km: float, seed: int, crs: str, lat: float, offset_deg: float, heights: str, undulation: float | None,
        flying_height: float, folder: Path, layout: str = "perimeter", every_k: int = 2) -> dict:
    design = block_design(size_km, flying_height, layout, every_k)
    noise = sim.NoiseOptions(sigma_image=0.005, approx_position_error=10.0, approx_angle_error=0.5)
    local, truth_local = sim.simulate_project("block", sim.SimulateOptions(design, noise), seed)
    coordinates = CoordinateSettings(crs=crs, heights=heights, geoid_undulation=undulation)
    grid, truth_grid = to_map_coordinates(local, truth_local, coordinates, lat, central_meridian(crs) + offset_deg)
    naive = replace(grid, settings=replace(grid.settings, coordinates=None))
    out = {}
    for name, project, truth in (("local frame", local, truth_local), ("CRS set", grid, truth_grid),
                                 ("naive grid", naive, truth_grid)):
        src, dst = folder / f"{name}-{seed}".replace(" ", "_"), folder / f"out-{name}-{seed}".replace(" ", "_")
        write_project(src, project, truth_tables=truth)
        run_adjust(src, dst, RunOptions(method="bundle"))
        out[name] = check_errors(dst, truth)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-km", type=float, default=20.0)
    ap.add_argument("--flying-height", type=float, default=3000.0)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--crs", default="EPSG:32633")
    ap.add_argument("--lat", type=float, default=48.0)
    ap.add_argument("--control", default="perimeter", help="control layout (striptri simulate --control)")
    ap.add_argument("--every-k", type=int, default=2)
    ap.add_argument("--offset-deg", type=float, default=3.0, help="east of the central meridian")
    args = ap.parse_args()
    errors: dict[str, list] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            for name, e in run(args.size_km, seed, args.crs, args.lat, args.offset_deg, "ellipsoidal", None,
                               args.flying_height, Path(tmp), args.control, args.every_k).items():
                errors.setdefault(name, []).append(e)
    print(f"{args.size_km:g} km block, {args.crs}, lat {args.lat:g}, {args.offset_deg:g} deg east of the central "
          f"meridian, flying height {args.flying_height:g} m, control {args.control} every {args.every_k}")
    print(f"{'adjustment':<12} {'n':>4} {'mean dX':>9} {'mean dY':>9} {'mean dZ':>9} {'rms X':>8} {'rms Y':>8} "
          f"{'rms Z':>8} {'max |d|':>8}")
    for name, es in errors.items():
        e = np.concatenate(es)
        m, r = e.mean(axis=0), np.sqrt((e**2).mean(axis=0))
        print(f"{name:<12} {len(e):>4} {m[0]:9.3f} {m[1]:9.3f} {m[2]:9.3f} {r[0]:8.3f} {r[1]:8.3f} {r[2]:8.3f} "
              f"{np.abs(e).max():8.3f}")


if __name__ == "__main__":
    main()
