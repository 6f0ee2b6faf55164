"""striptri plan (issue 15): the pre-analysis of a planned block.

* the a-priori mean errors equal those ``striptri adjust`` reports for a simulated (noise-free)
  flight of the plan, divided by its sigma0, to 1e-9 relative; and its MDBs those of adjust's
  reliability module (residuals.csv mdb_x, mdb_y);
* the mean errors equal the empirical scatter of a Monte Carlo on the plan, within the chi-square
  tolerance of the trial count;
* the control ranking equals brute force: each control point turned into a check point in the
  files, the project adjusted by ``adjust``;
* the command's contract: exit codes, nothing written on failure, never into the input.
"""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from cli_support import assert_clean_failure, run, snapshot
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.io.project_writer import write_project
from striptri.model import CHECK, FULL, HEIGHT, PLAN, TIE
from striptri.pipeline import run_adjust
from striptri.plan import ranking, whatif
from striptri.plan.analysis import analyse, external_bound, precision_only
from striptri.plan.external import own_point_shifts
from striptri.plan.design import planned_points, predicted_plates
from striptri.plan.pipeline import PlanOptions, run_plan
from striptri.simulate.design import SyntheticDesign
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.pipeline import SimulateOptions, simulate_project
from striptri.simulate.truth import make_truth

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("plan")

REL = 1e-9


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def by_id(rows, key):
    return {r[key]: r for r in rows}


def small_design(n_photos=6, n_strips=2) -> SyntheticDesign:
    d = SyntheticDesign()
    return SyntheticDesign(flight=replace(d.flight, n_photos=n_photos, n_strips=n_strips),
                           control=replace(d.control, layout="perimeter"))


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A noise-free simulated flight (approximations 10 m / 1 deg off) and its plan: the same
    folder with the true orientations in photos.csv."""
    root = tmp_path_factory.mktemp("plan")
    noise = NoiseOptions(sigma_image=0.0)
    project, truth = simulate_project("block", SimulateOptions(small_design(), noise), seed=7)
    sim = write_project(root / "sim", project, truth_tables=truth)
    plan = root / "plan"
    shutil.copytree(sim, plan, ignore=shutil.ignore_patterns("truth"))
    rows = read_rows(plan / "photos.csv")
    true = by_id(read_rows(sim / "truth" / "photos.csv"), "photo_id")
    for r in rows:
        for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa"):
            r[k] = true[r["photo_id"]][k]
    with open(plan / "photos.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    adj = run_adjust(sim, root / "adjusted")
    planned = run_plan(plan, root / "planned")
    return {"root": root, "sim": sim, "plan": plan, "adjust": adj, "planned": planned}


def test_plan_mean_errors_equal_adjust_of_a_simulated_flight(flight):
    s0 = flight["adjust"].summary["sigma0"]
    assert 0 < s0 < 1e-6  # noise-free: the adjusted values are the truth, the plan
    adj_ph = by_id(read_rows(flight["root"] / "adjusted" / "photos.csv"), "photo_id")
    pl_ph = by_id(read_rows(flight["root"] / "planned" / "photos.csv"), "photo_id")
    assert adj_ph.keys() == pl_ph.keys()
    cols = [f"sigma_{k}" for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
    a = np.array([[float(adj_ph[i][c]) for c in cols] for i in adj_ph]) / s0
    p = np.array([[float(pl_ph[i][c]) for c in cols] for i in adj_ph])
    assert np.all(p > 0)
    np.testing.assert_allclose(p, a, rtol=REL, atol=0)
    adj_pt = by_id(read_rows(flight["root"] / "adjusted" / "points.csv"), "point_id")
    pl_pt = by_id(read_rows(flight["root"] / "planned" / "points.csv"), "point_id")
    assert adj_pt.keys() == pl_pt.keys()
    tie = [i for i in adj_pt if adj_pt[i]["kind"] in ("tie", "check")]
    assert len(tie) > 10
    a = np.array([[float(adj_pt[i][f"sigma_{c}"]) for c in "XYZ"] for i in tie]) / s0
    p = np.array([[float(pl_pt[i][f"sigma_{c}"]) for c in "XYZ"] for i in tie])
    np.testing.assert_allclose(p, a, rtol=REL, atol=0)
    # the planned coordinates are the truth the flight was simulated from
    true = by_id(read_rows(flight["sim"] / "truth" / "points.csv"), "point_id")
    xyz = np.array([[float(pl_pt[i][c]) for c in "XYZ"] for i in tie])
    np.testing.assert_allclose(xyz, [[float(true[i][c]) for c in "XYZ"] for i in tie], rtol=0, atol=1e-6)
    summary = json.loads((flight["root"] / "planned" / "summary.json").read_text())
    assert summary["sigma0"] == 1.0
    assert set(flight["adjust"].summary) - {"blunders"} <= set(summary)


def test_plan_mdb_equal_reliability_module(flight):
    adj = read_rows(flight["root"] / "adjusted" / "residuals.csv")
    pl = read_rows(flight["root"] / "planned" / "reliability.csv")
    assert [(r["photo_id"], r["point_id"]) for r in adj] == [(r["photo_id"], r["point_id"]) for r in pl]
    for c in ("x", "y"):
        a = np.array([float(r[f"mdb_{c}"]) for r in adj])
        p = np.array([float(r[f"mdb_{c}"]) for r in pl])
        assert np.array_equal(np.isfinite(a), np.isfinite(p))
        ok = np.isfinite(a)
        assert ok.sum() > 50
        np.testing.assert_allclose(p[ok], a[ok], rtol=REL, atol=0)


TRIALS = 300
ALPHA = 1e-3  # probability that the whole test fails although the prediction is right


def test_plan_mean_errors_equal_monte_carlo_scatter():
    """The mean square error of T adjustments of noisy flights about the truth, per quantity, is
    sigma^2 chi2(T) / T (the estimates are unbiased to first order); every predicted sigma^2 must
    lie within the two-sided chi-square interval, Bonferroni over all K quantities tested."""
    design = small_design(5, 2)
    truth = make_truth(design, np.random.default_rng(11))
    exact = NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0)
    plan = perturb(truth, exact, np.random.default_rng(0))
    a = analyse(plan)
    sig_centres, _ = a.result.photo_mean_errors("omega-phi-kappa")
    new = (plan.points.kind == TIE) | (plan.points.kind == CHECK)
    predicted = np.concatenate([sig_centres.ravel(), a.sigma_points[new].ravel()])
    assert np.all(predicted > 0)
    noise = NoiseOptions(sigma_image=0.005)
    rng = np.random.default_rng(2024)
    err = np.empty((TRIALS, predicted.size))
    options = AdjustmentOptions()
    for t in range(TRIALS):
        project = perturb(truth, noise, rng)
        result = adjust(project, options)
        pts = triangulate_adjusted(project, result)
        d_centres = result.state.xyz0 + result.offset - truth.xyz0
        d_points = pts.xyz[new] + result.offset - truth.xyz_ground[new]
        err[t] = np.concatenate([d_centres.ravel(), d_points.ravel()])
    ratio = np.mean(err**2, axis=0) / predicted**2
    K = predicted.size
    lo = stats.chi2.ppf(ALPHA / (2 * K), TRIALS) / TRIALS
    hi = stats.chi2.isf(ALPHA / (2 * K), TRIALS) / TRIALS
    assert lo > 0.6 and hi < 1.5  # the test has teeth: a 40 % error in sigma^2 fails it
    assert np.all((ratio > lo) & (ratio < hi)), (ratio.min(), ratio.max(), lo, hi)


def test_control_ranking_equals_brute_force(flight, tmp_path):
    """Each control point turned into a check point in control.csv, the flight adjusted by
    ``adjust``: the worst 3D mean error of the tie and check points (divided by sigma0) is the
    ranking's, to 1e-9 relative, and the ranking orders by its increase."""
    ranking = read_rows(flight["root"] / "planned" / "control_ranking.csv")
    control = read_rows(flight["sim"] / "control.csv")
    truth = by_id(read_rows(flight["sim"] / "truth" / "points.csv"), "point_id")
    ids = [r["point_id"] for r in control if r["kind"] in ("XYZ", "XY", "Z")]
    assert sorted(r["point_id"] for r in ranking) == sorted(ids) and len(ids) >= 4
    base = flight["planned"].whatifs[0]["worst_sigma_P"]
    brute = {}
    for pid in ids:
        folder = tmp_path / f"drop_{pid}"
        shutil.copytree(flight["sim"], folder, ignore=shutil.ignore_patterns("truth"))
        rows = [dict(r) for r in control]
        for r in rows:
            if r["point_id"] == pid:
                r.update(kind="check", **{c: truth[pid][c] for c in "XYZ"})
        with open(folder / "control.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        out = run_adjust(folder, tmp_path / f"out_{pid}")
        pts = read_rows(tmp_path / f"out_{pid}" / "points.csv")
        sig = np.array([[float(r[f"sigma_{c}"]) for c in "XYZ"] for r in pts if r["kind"] in ("tie", "check")])
        brute[pid] = float(np.sqrt(np.sum(sig**2, axis=1)).max()) / out.summary["sigma0"]
    for r in ranking:
        assert r["status"] == "ok"
        assert float(r["worst_sigma_P"]) == pytest.approx(brute[r["point_id"]], rel=REL)
        assert float(r["loss_sigma_P"]) == pytest.approx(brute[r["point_id"]] - base, rel=1e-6, abs=1e-12)
    losses = [brute[r["point_id"]] for r in ranking]
    assert losses == sorted(losses, reverse=True)
    assert losses[0] > losses[-1]


def test_whatifs(flight, tmp_path):
    """A what-if row is the plan with that change: half the plate sigma halves every mean error
    (fixed control: all weights scale alike); dropping one control point is its ranking row;
    turning a dropped point back into control restores the plan."""
    ranking = flight["planned"].ranking
    first = ranking[0]["point_id"]
    out = run_plan(flight["plan"], tmp_path / "w",
                   PlanOptions(drop_control=[first], sigma_image=["0.0025"], rank_control=False))
    plan, dropped, half = out.whatifs
    assert plan["case"] == "plan" and dropped["case"] == f"drop control {first}"
    assert dropped["worst_sigma_P"] == pytest.approx(ranking[0]["worst_sigma_P"], rel=REL)
    for k in ("worst_sigma_XY", "rms_sigma_XY", "worst_sigma_Z", "rms_sigma_Z", "worst_sigma_P"):
        assert half[k] == pytest.approx(plan[k] / 2, rel=REL)
    assert not (tmp_path / "w" / "control_ranking.csv").exists()
    rows = read_rows(tmp_path / "w" / "whatifs.csv")
    assert [r["case"] for r in rows] == ["plan", f"drop control {first}", "sigma image 0.0025"]


def test_plan_command_contract(flight, tmp_path):
    """The command: exit 0 and the files; bad input exit 2 naming file and line; a plan whose control
    leaves a datum defect exit 1; an output inside the input exit 2; nothing written on failure and
    the input never touched."""
    plan = flight["plan"]
    before = snapshot(plan)
    pts = flight["planned"].analysis.project.points
    tie = pts.ids[int(np.flatnonzero(pts.kind == TIE)[0])]
    ok = run("plan", plan, "--out", tmp_path / "ok", "--drop-control", "XYZ", "--add-control", f"{tie}=XYZ")
    assert ok.returncode == 0, ok.stderr
    names = {"photos.csv", "cameras.csv", "points.csv", "reliability.csv", "whatifs.csv", "control_ranking.csv",
             "summary.json", "report.html"}
    assert names <= {p.name for p in (tmp_path / "ok").iterdir()}
    rows = read_rows(tmp_path / "ok" / "whatifs.csv")
    assert rows[1]["status"] == "datum defect"  # every full control point dropped: a what-if, not a failure
    assert rows[2]["status"] == "ok" and float(rows[2]["worst_sigma_P"]) <= float(rows[0]["worst_sigma_P"])
    html = (tmp_path / "ok" / "report.html").read_text()
    assert html.count("<img") == 3 and "What-ifs" in html
    # the points.csv of adjust's columns first
    header = next(csv.reader(open(tmp_path / "ok" / "points.csv")))
    assert header[:9] == ["point_id", "kind", "X", "Y", "Z", "sigma_X", "sigma_Y", "sigma_Z", "rays"]
    assert snapshot(plan) == before
    err = assert_clean_failure(run("plan", plan, "--out", plan / "out"), 2)
    assert "input" in err
    bad = tmp_path / "bad"
    shutil.copytree(plan, bad)
    lines = (bad / "photos.csv").read_text().splitlines()
    lines[2] = lines[2].replace(lines[2].split(",")[3], "abc", 1)
    (bad / "photos.csv").write_text("\n".join(lines) + "\n")
    err = assert_clean_failure(run("plan", bad, "--out", tmp_path / "bad_out"), 2)
    assert "photos.csv, line 3" in err
    assert not (tmp_path / "bad_out").exists()
    err = assert_clean_failure(run("plan", plan, "--out", tmp_path / "x", "--drop-control", "nope"), 2)
    assert "nope" in err and not (tmp_path / "x").exists()
    free = tmp_path / "free"
    shutil.copytree(plan, free)
    (free / "control.csv").write_text((free / "control.csv").read_text().splitlines()[0] + "\n")
    err = assert_clean_failure(run("plan", free, "--out", tmp_path / "free_out"), 1)
    assert "datum" in err and not (tmp_path / "free_out").exists()


def test_planned_points_from_approx_points_or_rays():
    """approx_points.csv gives the planned points: image_points.csv's x, y then only say which photo
    sees which point (noisy x, y give the same mean errors); without it the rays are intersected
    (noisy x, y move the points and, a little, the mean errors); the predicted plates of the
    planned points are image_points' x, y for exact measurements."""
    truth = make_truth(small_design(4, 2), np.random.default_rng(3))
    exact = perturb(truth, NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0),
                    np.random.default_rng(0))
    np.testing.assert_allclose(planned_points(exact)[exact.points.kind == TIE],
                               truth.xyz_ground[exact.points.kind == TIE], rtol=0, atol=1e-7)
    np.testing.assert_allclose(predicted_plates(exact, truth.xyz_ground), exact.image_points.xy, rtol=0, atol=1e-10)
    noisy = perturb(truth, NoiseOptions(sigma_image=0.05, stated_sigma_image=0.005, approx_position_error=0.0,
                                        approx_angle_error=0.0),
                    np.random.default_rng(1))
    with_approx = replace(noisy, points=replace(noisy.points, xyz_approx=truth.xyz_ground.copy()))
    base = analyse(exact).sigma_points
    np.testing.assert_allclose(analyse(with_approx).sigma_points, base, rtol=REL, atol=1e-15)
    moved = analyse(noisy).sigma_points
    tie = exact.points.kind == TIE
    assert np.max(np.abs(moved[tie] / base[tie] - 1)) > 1e-6


def _fast_and_brute(project):
    options = AdjustmentOptions()
    xyz = planned_points(project)
    plan, result, _, sigma = precision_only(project, options, xyz)
    assert ranking.applicable(result, options)
    base = {"worst_sigma_P": whatif.worst_sigma_p(plan, sigma)}
    return (whatif.ranked(project, ranking.rank_control_fast(plan, result, sigma), base),
            whatif.rank_control(project, options, xyz, base))


def test_rank3_update_equals_brute_force_with_weighted_partial_control_and_defects():
    """The rank-3 update (plan.ranking) against brute force (whatif.rank_control, one adjustment per
    control point) on a block with held and weighted full control, plan and height control, and on
    one whose every full control point is indispensable (a drop leaves a datum defect)."""
    truth = make_truth(small_design(5, 2), np.random.default_rng(5))
    exact = NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0)
    project = perturb(truth, exact, np.random.default_rng(0))
    pts = project.points
    control = np.flatnonzero(np.isin(pts.kind, (FULL, PLAN, HEIGHT)))
    assert len(control) >= 8
    kind, sigma, given = pts.kind.copy(), pts.sigma_given.copy(), pts.xyz_given.copy()
    kind[control[1]], kind[control[2]] = PLAN, HEIGHT
    given[control[1], 2] = np.nan
    given[control[2], :2] = np.nan
    sigma[control[3]] = (0.05, 0.05, 0.08)  # weighted full control
    sigma[control[4], 2] = 0.1  # held in X, Y, weighted in Z
    varied = replace(project, points=replace(pts, kind=kind, sigma_given=sigma, xyz_given=given))
    fast, brute = _fast_and_brute(varied)
    assert [r["point_id"] for r in fast] == [r["point_id"] for r in brute]
    for f, b in zip(fast, brute):
        assert f["status"] == b["status"] == "ok"
        assert f["worst_sigma_P"] == pytest.approx(b["worst_sigma_P"], rel=REL)
    # three control points only (two full, one height): dropping a full one leaves a datum defect
    xy = truth.xyz_ground[control, :2]
    a = 0
    b = int(np.argmax(np.linalg.norm(xy - xy[a], axis=1)))
    u = (xy[b] - xy[a]) / np.linalg.norm(xy[b] - xy[a])
    d = xy - xy[a]
    c = int(np.argmax(np.abs(u[0] * d[:, 1] - u[1] * d[:, 0])))  # farthest from the line a-b
    keep = [int(control[a]), int(control[b]), int(control[c])]
    kind = np.where(np.isin(np.arange(len(pts)), control) & ~np.isin(np.arange(len(pts)), keep), TIE, pts.kind)
    kind[keep[2]] = HEIGHT
    given = np.where((kind == TIE)[:, None], np.nan, pts.xyz_given)
    given[keep[2], :2] = np.nan
    minimal = replace(project, points=replace(pts, kind=kind, xyz_given=given))
    fast, brute = _fast_and_brute(minimal)
    by_id = {r["point_id"]: r for r in brute}
    statuses = {r["point_id"]: r["status"] for r in fast}
    assert statuses == {pid: by_id[pid]["status"] for pid in statuses}
    assert "datum defect" in statuses.values()
    for f in fast:
        if f["status"] == "ok":
            assert f["worst_sigma_P"] == pytest.approx(by_id[f["point_id"]]["worst_sigma_P"], rel=REL)


def test_overlap_whatif_equals_a_thinned_plan(flight, tmp_path):
    """--keep-every 2 is the plan with every other photo of each strip removed from photos.csv and
    image_points.csv."""
    out = run_plan(flight["plan"], tmp_path / "w", PlanOptions(keep_every=[2], rank_control=False))
    thinned = tmp_path / "thinned"
    shutil.copytree(flight["plan"], thinned)
    photos = read_rows(thinned / "photos.csv")
    position: dict[str, int] = {}
    kept = set()
    for r in photos:
        i = position.get(r["strip_id"], 0)
        position[r["strip_id"]] = i + 1
        if i % 2 == 0:
            kept.add(r["photo_id"])
    for name, key in (("photos.csv", "photo_id"), ("image_points.csv", "photo_id")):
        rows = [r for r in read_rows(thinned / name) if r[key] in kept]
        with open(thinned / name, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    assert 0 < len(kept) < len(photos)
    alone = run_plan(thinned, tmp_path / "t", PlanOptions(rank_control=False))
    row, ref = out.whatifs[1], alone.whatifs[0]
    assert row["case"] == "every 2-th photo" and row["status"] == "ok"
    for k in ("n_points", "worst_sigma_XY", "rms_sigma_XY", "worst_sigma_Z", "rms_sigma_Z", "worst_sigma_P"):
        assert row[k] == pytest.approx(ref[k], rel=REL)


def test_external_reliability_is_the_shift_of_a_blunder():
    """The exact external reliability (plan.external): a blunder of MDB/100 put into one plate
    coordinate of the noise-free plan and the plan adjusted moves that coordinate's point by
    1/100 of the predicted shift (the adjustment is linear to a relative 1e-3 at that size), for
    tie points and for held control (its free axes only); the shift never exceeds the bound
    bnr sigma."""
    truth = make_truth(small_design(5, 2), np.random.default_rng(8))
    exact = NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0)
    project = perturb(truth, exact, np.random.default_rng(0))
    options = AdjustmentOptions()
    a = analyse(project, options)
    assert a.external_method == "exact"
    shifts = own_point_shifts(a.project, a.result, a.reliability)
    base = triangulate_adjusted(a.project, adjust(a.project, options)).xyz
    rel = a.reliability
    finite = np.flatnonzero(np.isfinite(rel.mdb).all(axis=1) & (rel.redundancy.min(axis=1) > 0.05))
    rows = np.random.default_rng(1).choice(finite, 6, replace=False)
    moved = 0
    for row in rows:
        for axis in range(2):
            xy = a.project.image_points.xy.copy()
            xy[row, axis] += rel.mdb[row, axis] / 100
            blundered = replace(a.project, image_points=replace(a.project.image_points, xy=xy))
            xyz = triangulate_adjusted(blundered, adjust(blundered, options)).xyz
            j = a.project.image_points.point_index[row]
            np.testing.assert_allclose((xyz[j] - base[j]) * 100, shifts[row, axis], rtol=2e-3,
                                       atol=2e-3 * np.abs(shifts[row, axis]).max())
            moved += np.abs(shifts[row, axis]).max() > 0
    assert moved >= 6
    bound = external_bound(a.project, rel, a.sigma_points)
    ok = np.isfinite(bound)
    assert np.all(a.external[ok] <= bound[ok] * (1 + 1e-9))


def test_conditions_and_bundle_predict_alike():
    """The method of conditions and the bundle are the same least squares: the same a-priori mean
    errors, MDBs and external reliability of the plan (1e-9 relative)."""
    truth = make_truth(small_design(5, 2), np.random.default_rng(4))
    exact = NoiseOptions(sigma_image=0.0, approx_position_error=0.0, approx_angle_error=0.0)
    project = perturb(truth, exact, np.random.default_rng(0))
    c = analyse(project, AdjustmentOptions(method="conditions"))
    b = analyse(project, AdjustmentOptions(method="bundle"))
    np.testing.assert_allclose(b.sigma_points, c.sigma_points, rtol=REL, atol=1e-15)
    ok = np.isfinite(c.reliability.mdb)
    assert np.array_equal(ok, np.isfinite(b.reliability.mdb)) and ok.sum() > 50
    np.testing.assert_allclose(b.reliability.mdb[ok], c.reliability.mdb[ok], rtol=REL)
    fin = np.isfinite(c.external)
    np.testing.assert_allclose(b.external[fin], c.external[fin], rtol=REL, atol=1e-15)
