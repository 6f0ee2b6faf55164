"""striptri plan without image_points.csv (issue 15): von Gruber points per model, the overlap
what-if for any overlap, weighted added control.

The plans here are ideal: vertical photos (angles 0), c = 152 mm, flying height 1520 m above a
flat terrain at Z = 0 (scale 1 : 10,000), format 230 mm: a ground footprint of 2300 m, so that a
forward overlap p is a base of (1 - p) 2300 m and the sightings can be checked by hand (a photo
sees a ground point when |X - X0| <= 1150 m and |Y - Y0| <= 1150 m).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from cli_support import assert_clean_failure, run
from dataclasses import replace

from striptri.core.adjusted_points import triangulate_adjusted
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io.project_reader import read_project
from striptri.model import TIE
from striptri.plan.analysis import analyse
from striptri.plan.pipeline import PlanOptions, run_plan
from striptri.plan.vongruber import von_gruber_project
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.truth import make_truth
from test_plan import small_design

REL = 1e-9
C, H, FOOT = 152.0, 1520.0, 2300.0
FIGURES = ("n_points", "worst_sigma_XY", "rms_sigma_XY", "worst_sigma_Z", "rms_sigma_Z", "worst_sigma_P")


def write_plan(folder: Path, overlap=0.6, sidelap=0.3, n_photos=6, n_strips=2, toml_plan=True) -> Path:
    """An ideal plan (module doc) with full control beside the four corners of the block, and
    full control in the middle of the block and a check point; no image_points.csv."""
    folder.mkdir(parents=True)
    base, spacing = (1 - overlap) * FOOT, (1 - sidelap) * FOOT
    (folder / "cameras.csv").write_text(f"camera_id,c,xp,yp\nC1,{C},0,0\n")
    rows = ["photo_id,camera_id,strip_id,X0,Y0,Z0,omega,phi,kappa"]
    for s in range(n_strips):
        for i in range(n_photos):
            rows.append(f"{s + 1}{i + 1:02d},C1,{s + 1},{i * base!r},{s * spacing!r},{H},0,0,0")
    (folder / "photos.csv").write_text("\n".join(rows) + "\n")
    L, W = (n_photos - 1) * base, (n_strips - 1) * spacing
    (folder / "control.csv").write_text(
        "point_id,kind,X,Y,Z,sigma_X,sigma_Y,sigma_Z\n"
        f"A,XYZ,0,{-0.4 * FOOT!r},0,,,\nB,XYZ,{L!r},{-0.4 * FOOT!r},0,,,\n"
        f"C,XYZ,0,{W + 0.4 * FOOT!r},0,,,\nD,XYZ,{L!r},{W + 0.4 * FOOT!r},0,,,\n"
        f"E,XYZ,{L / 2!r},{W / 2!r},0,,,\nK,check,{L / 2!r},{-0.4 * FOOT!r},0,,,\n")
    (folder / "project.toml").write_text("[defaults]\nsigma_image = 0.005\n"
                                         + ("[plan]\nformat = 230\nterrain_height = 0.0\n" if toml_plan else ""))
    return folder


def generated(folder: Path):
    project = read_project(folder, plate_measurements_optional=True)
    return von_gruber_project(project, np.array([230.0, 230.0]), 0.0)[0]


def test_von_gruber_pattern_and_sightings(tmp_path):
    """Six von Gruber positions per model: every nadir point, and abreast it the middle of the
    sidelap (half the strip spacing: 805 m, one point for both strips) or, on an outer side, 0.4 of
    the footprint (920 m); each point measured on exactly the photos whose format contains it, its
    plate coordinates those of a vertical photo at 1 : 10,000."""
    plan = generated(write_plan(tmp_path / "p"))
    pts, ip, ph = plan.points, plan.image_points, plan.photos
    tie = np.flatnonzero(pts.kind == TIE)
    xyz = pts.xyz_approx
    xs = np.arange(6) * 920.0
    expected = [(x, y) for x in xs for y in (0.0, 1610.0, -920.0, 805.0, 1610.0 + 920.0)]
    got = sorted(map(tuple, np.round(xyz[tie, :2], 6)))
    assert got == sorted(set(expected))  # 6 x 5 = 30 points: the shared middle line once
    assert np.all(xyz[tie, 2] == 0.0)
    # sightings: by hand, every photo whose 2300 m square contains the point
    dx = np.abs(xyz[:, None, 0] - ph.xyz0[None, :, 0])
    dy = np.abs(xyz[:, None, 1] - ph.xyz0[None, :, 1])
    seen = (dx <= 1150.0 + 1e-6) & (dy <= 1150.0 + 1e-6)
    measured = np.zeros_like(seen)
    measured[ip.point_index, ip.photo_index] = True
    assert np.array_equal(measured, seen)
    middle = np.flatnonzero((np.abs(xyz[:, 1] - 805.0) < 1e-6) & (np.abs(xyz[:, 0] - 1840.0) < 1e-6))
    assert len(middle) == 1 and np.sum(ip.point_index == middle[0]) == 6  # 3 photos of each strip
    d = ph.xyz0[ip.photo_index] - xyz[ip.point_index]
    np.testing.assert_allclose(ip.xy, -C * d[:, :2] / d[:, 2:3], rtol=0, atol=1e-9)
    assert np.all(ip.sigma_xy == 0.005)
    # control: measured on every photo that sees it, also on one photo
    assert pts.ids[:6] == ["A", "B", "C", "D", "E", "K"]


def test_plan_from_von_gruber_points_equals_the_plan_with_their_image_points(tmp_path):
    """Without image_points.csv the plan is analysed on its von Gruber points: the same figures as
    the same folder with those sightings written into image_points.csv (file column contract)."""
    folder = write_plan(tmp_path / "p")
    out = run_plan(folder, tmp_path / "o", PlanOptions(rank_control=False))
    assert out.summary["plan"]["tie_points"].startswith("von Gruber points: 30 tie points")
    assert "von Gruber points: 30 tie points" in (tmp_path / "o" / "report.html").read_text()
    header = next(csv.reader(open(tmp_path / "o" / "points.csv")))
    assert header[-3:] == ["ext_photos_X", "ext_photos_Y", "ext_photos_Z"]
    write_image_points(folder, out.analysis.project)
    ref = run_plan(folder, tmp_path / "r", PlanOptions(rank_control=False))
    assert ref.summary["plan"]["tie_points"] == "image_points.csv"
    for k in FIGURES:
        assert out.whatifs[0][k] == pytest.approx(ref.whatifs[0][k], rel=REL)
    a, b = out.analysis, ref.analysis
    order = [b.project.points.ids.index(p) for p in a.project.points.ids]
    np.testing.assert_allclose(a.sigma_points, b.sigma_points[order], rtol=REL)
    # --von-gruber replaces image_points.csv's tie points by the generated ones
    again = run_plan(folder, tmp_path / "v", PlanOptions(von_gruber=True, rank_control=False))
    np.testing.assert_allclose(again.analysis.sigma_points, a.sigma_points, rtol=REL)


def test_overlap_whatif_equals_a_plan_flown_at_that_overlap(tmp_path):
    """--overlap P re-spaces each strip (base (1 - P) x footprint from the same first photo): at the
    plan's own overlap it is the plan; at 80 % it is the plan written at 80 % (11 photos a strip)."""
    p60 = write_plan(tmp_path / "p60")
    p80 = write_plan(tmp_path / "p80", overlap=0.8, n_photos=11)
    out = run_plan(p60, tmp_path / "o", PlanOptions(overlap=[0.6, 0.8], keep_every=[2], rank_control=False))
    plan, kept, same, eighty = out.whatifs
    assert kept["case"] == "every 2-th photo" and same["case"] == "overlap 0.6 (12 photos)"
    assert eighty["case"] == "overlap 0.8 (22 photos)"
    ref = run_plan(p80, tmp_path / "r", PlanOptions(rank_control=False)).whatifs[0]
    for k in FIGURES:
        assert same[k] == pytest.approx(plan[k], rel=REL)
        assert eighty[k] == pytest.approx(ref[k], rel=REL)
    assert eighty["worst_sigma_P"] < plan["worst_sigma_P"]


def write_image_points(folder: Path, plan) -> None:
    """The plan's sightings as image_points.csv."""
    ip = plan.image_points
    with open(folder / "image_points.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["photo_id", "point_id", "x", "y"])
        for i, j, (x, y) in zip(ip.photo_index, ip.point_index, ip.xy):
            w.writerow([plan.photos.ids[i], plan.points.ids[j], repr(float(x)), repr(float(y))])


def test_add_control_with_a_sigma_is_weighted_control(tmp_path):
    """--add-control ID=KIND:SIGMA equals the point written into control.csv with that sigma (1e-9);
    held fixed (no SIGMA) it helps more, weighted less; a bad SIGMA is exit 2."""
    folder = write_plan(tmp_path / "p")
    plan = generated(folder)
    write_image_points(folder, plan)
    pid = "vg_103_r"
    X, Y, Z = map(float, plan.points.xyz_approx[plan.points.ids.index(pid)])
    out = run_plan(folder, tmp_path / "o",
                   PlanOptions(add_control=[f"{pid}=XYZ:0.05", f"{pid}=XYZ", f"{pid}=Z:0.05"], rank_control=False))
    base, weighted, held, height = out.whatifs
    assert weighted["case"] == f"add control {pid}=XYZ:0.05"
    for kind, sigmas, row in (("XYZ", "0.05,0.05,0.05", weighted), ("Z", ",,0.05", height)):
        ref = tmp_path / f"ref_{kind}"
        ref.mkdir()
        for name in ("cameras.csv", "photos.csv", "project.toml", "image_points.csv", "control.csv"):
            (ref / name).write_bytes((folder / name).read_bytes())
        with open(ref / "control.csv", "a") as f:
            f.write(f"{pid},{kind},{X!r},{Y!r},{Z!r},{sigmas}\n")
        expect = run_plan(ref, tmp_path / f"r_{kind}", PlanOptions(rank_control=False)).whatifs[0]
        for k in FIGURES:
            assert row[k] == pytest.approx(expect[k], rel=REL)
    assert held["worst_sigma_P"] < weighted["worst_sigma_P"] < base["worst_sigma_P"]
    err = assert_clean_failure(run("plan", folder, "--out", tmp_path / "x", "--add-control", f"{pid}=XYZ:-1"), 2)
    assert "SIGMA" in err and not (tmp_path / "x").exists()


def test_von_gruber_needs_the_format_and_positions(tmp_path):
    """Without image_points.csv the format must be given (option or project.toml); a Z control
    point needs its planned X, Y; bad values are exit 2 naming the option or file."""
    folder = write_plan(tmp_path / "p", toml_plan=False)
    err = assert_clean_failure(run("plan", folder, "--out", tmp_path / "x"), 2)
    assert "--format" in err and not (tmp_path / "x").exists()
    ok = run("plan", folder, "--out", tmp_path / "ok", "--format", "230x230", "--terrain-height", "0",
             "--overlap", "0.7")
    assert ok.returncode == 0, ok.stderr
    for bad in (("--format", "0"), ("--format", "abc"), ("--format", "230", "--overlap", "1.5")):
        err = assert_clean_failure(run("plan", folder, "--out", tmp_path / "y", *bad), 2)
        assert "command line" in err and not (tmp_path / "y").exists()
    with open(folder / "control.csv", "a") as f:
        f.write("Z1,Z,,,0,,,\n")
    err = assert_clean_failure(run("plan", folder, "--out", tmp_path / "z", "--format", "230"), 2)
    assert "control.csv" in err and "Z1" in err


def test_external_reliability_on_the_points_of_the_photos_involved():
    """ext_photos (external.photos_bound) bounds the shift of every point by an undetected MDB-sized
    blunder in any measurement of the photos that see it: a blunder of MDB/100 put into one plate
    coordinate a and the plan adjusted moves each point k of that photo by at most 1/100 of
    bnr_a sigma_k (the adjustment linear to 1e-3 at that size), which ext_photos covers; the bound
    covers the exact own-point shift; bnr_a sigma_k is reached to within a factor 10 somewhere."""
    truth = make_truth(small_design(5, 2), np.random.default_rng(8))
    exact = NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0)
    project = perturb(truth, exact, np.random.default_rng(0))
    options = AdjustmentOptions()
    a = analyse(project, options)
    ip, rel, bound = a.project.image_points, a.reliability, a.external_photos
    assert np.all(a.external[np.isfinite(bound)] <= bound[np.isfinite(bound)] * (1 + 1e-9))
    base = triangulate_adjusted(a.project, adjust(a.project, options)).xyz
    finite = np.flatnonzero(np.isfinite(rel.mdb).all(axis=1) & (rel.redundancy.min(axis=1) > 0.05))
    ratio = []
    for row in np.random.default_rng(2).choice(finite, 5, replace=False):
        for axis in range(2):
            xy = ip.xy.copy()
            xy[row, axis] += rel.mdb[row, axis] / 100
            blundered = replace(a.project, image_points=replace(ip, xy=xy))
            xyz = triangulate_adjusted(blundered, adjust(blundered, options)).xyz
            on_photo = np.unique(ip.point_index[ip.photo_index == ip.photo_index[row]])
            on_photo = on_photo[np.isfinite(bound[on_photo]).all(axis=1) & (bound[on_photo] > 0).all(axis=1)]
            shift = np.abs(xyz[on_photo] - base[on_photo]) * 100
            own = rel.bnr[row, axis] * a.sigma_points[on_photo]  # Baarda's bound for this coordinate
            assert np.all(shift <= own * (1 + 2e-3) + 1e-12)
            assert np.all(own <= bound[on_photo] * (1 + 1e-12))
            ratio.append(np.max(shift / own))
    assert max(ratio) > 0.1  # the bound of the blunder's own coordinate is not slack everywhere


def test_single_strip_lateral_points_at_the_classical_position(tmp_path):
    """A strip without neighbours: its lateral points at 0.4 of the footprint (920 m, y = +-92 mm on
    the plate); a format 230 x 180 (1800 m across track) puts them at 0.4 x 1800 = 720 m."""
    folder = write_plan(tmp_path / "p", n_strips=1)
    project = read_project(folder, plate_measurements_optional=True)
    plan = von_gruber_project(project, np.array([230.0, 230.0]), 0.0)[0]
    tie = plan.points.kind == TIE
    assert sorted(set(np.round(plan.points.xyz_approx[tie, 1], 6))) == [-920.0, 0.0, 920.0]
    ip = plan.image_points
    lateral = np.flatnonzero(tie & (plan.points.xyz_approx[:, 1] == 920.0))
    np.testing.assert_allclose(np.abs(ip.xy[np.isin(ip.point_index, lateral), 1]), 92.0, rtol=0, atol=1e-9)
    narrow = von_gruber_project(project, np.array([230.0, 180.0]), 0.0)[0]  # 1800 m across: |y| 920 > 900
    assert sorted(set(np.round(narrow.points.xyz_approx[narrow.points.kind == TIE, 1], 6))) == [-720.0, 0.0, 720.0]


SHIPPED = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


@pytest.mark.parametrize("name", ["pair", "strip8", "strip_2_3", "block_3x6", "schmid_fig8"])
def test_overlap_whatif_on_every_shipped_project(tmp_path, name):
    """Before: `striptri plan data/synthetic_strips/block_3x6 --out p --overlap 0.8 --format 230`
    said "a plan without image_points.csv needs its planned X, Y" though image_points.csv is there:
    the height points' X, Y now come from their measured rays (plan.design.planned_points)."""
    products = run_plan(SHIPPED / name, tmp_path / "p", PlanOptions(overlap=(0.8,), plate_format="230"))
    assert any("overlap 0.8" in case for case in products.files["summary.json"].split('"'))


def test_von_gruber_on_a_simulated_project(tmp_path):
    """Before: --von-gruber failed the same way on simulate's output (height points without X, Y)."""
    proc = run("simulate", "block", "--out", tmp_path / "sim", "--seed", "3")
    assert proc.returncode == 0, proc.stderr
    products = run_plan(tmp_path / "sim", tmp_path / "p", PlanOptions(von_gruber=True, plate_format="230"))
    assert (tmp_path / "p" / "points.csv").is_file() and products.files["points.csv"]
