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
from striptri.adjusted_points import triangulate_adjusted
from striptri.io.project_writer import write_project
from striptri.model import CHECK, FULL, HEIGHT, PLAN, TIE
from striptri.pipeline import run_adjust
from striptri.plan.analysis import analyse
from striptri.plan.design import planned_points, predicted_plates
from striptri.plan.pipeline import run_plan
from striptri.simulate.design import SyntheticDesign
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.pipeline import SimulateOptions, simulate_project
from striptri.simulate.truth import make_truth

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
