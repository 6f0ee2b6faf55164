"""``striptri compare --project DIR`` (issue 15): the method-comparison study on a project's own
strip and control, with the outputs of today's study."""

from __future__ import annotations

import csv
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from cli_support import assert_clean_failure, run, snapshot
from striptri.io.project_reader import read_project
from striptri.io.project_writer import write_project
from striptri.plan.analysis import analyse
from striptri.plan.design import noise_free_project
from striptri.simulate.design import SyntheticDesign
from striptri.simulate.pipeline import SimulateOptions, simulate_project
from striptri.study.project import noisy_project, project_tasks
from striptri.study.project_pipeline import ProjectStudyOptions, run_compare_project

METHODS = ("seq1-forward", "conditions", "bundle")
TRIALS = 6


def rows_of(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def strip_design(n_photos: int = 6) -> SyntheticDesign:
    d = SyntheticDesign()
    return SyntheticDesign(flight=replace(d.flight, n_photos=n_photos), control=replace(d.control, layout="ends"))


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    project, truth = simulate_project("strip", SimulateOptions(strip_design()), seed=5)
    return write_project(tmp_path_factory.mktemp("cmp") / "strip", project, truth_tables=truth)


def test_compare_project_writes_the_study_of_the_project(strip, tmp_path):
    before = snapshot(strip)
    result = run_compare_project(tmp_path / "out", strip, ProjectStudyOptions(METHODS, trials=TRIALS, seed=3), workers=1)
    assert snapshot(strip) == before
    assert {p.name for p in (tmp_path / "out").iterdir()} >= {"study.csv", "growth.csv", "precision.csv",
                                                               "along.csv", "report.html"}
    rows = rows_of(tmp_path / "out" / "study.csv")
    assert len(rows) == TRIALS * len(METHODS) and result.n_failed == 0
    assert {r["layout"] for r in rows} == {"project"} and {r["n_photos"] for r in rows} == {"6"}
    # the predicted precision of the last centre is the plan's a-priori one (at the adjusted values,
    # which differ from the plan by the noise: 1e-3 relative is far above that effect)
    plan = analyse(read_project(strip))
    sig, _ = plan.result.photo_mean_errors("omega-phi-kappa")
    for r in rows:
        if r["method"] in ("conditions", "bundle"):
            assert float(r["predicted_last"]) == pytest.approx(float(np.linalg.norm(sig[-1])), rel=1e-3)
    # conditions and bundle are the same least squares: the same errors
    cond = [float(r["centre_last"]) for r in rows if r["method"] == "conditions"]
    bund = [float(r["centre_last"]) for r in rows if r["method"] == "bundle"]
    np.testing.assert_allclose(cond, bund, rtol=1e-6)
    # the same seed gives the same study
    again = run_compare_project(tmp_path / "again", strip, ProjectStudyOptions(METHODS, trials=TRIALS, seed=3),
                                workers=1)
    key = [(r["method"], r["trial"], r["centre_last"]) for r in result.rows]
    assert key == [(r["method"], r["trial"], r["centre_last"]) for r in again.rows]


def test_trial_noise_is_the_plans():
    """A trial's plates scatter about the plan's predictions with the plan's sigma (chi-square
    bound over all coordinates of many trials), the held control is exact."""
    project, _ = simulate_project("strip", SimulateOptions(strip_design()), seed=1)
    plan = noise_free_project(project)
    tasks = project_tasks(plan, ("conditions",), (), 40, 0)
    d = np.concatenate([(noisy_project(t).image_points.xy - plan.image_points.xy).ravel() for t in tasks])
    s = plan.image_points.sigma_xy[0, 0]
    n = d.size
    ratio = np.sum(d**2) / s**2
    assert stats.chi2.ppf(1e-4, n) < ratio < stats.chi2.isf(1e-4, n)
    t0 = noisy_project(tasks[0])
    held = np.isfinite(plan.points.xyz_given) & ~(np.nan_to_num(plan.points.sigma_given) > 0)
    assert np.array_equal(t0.points.xyz_given[held], plan.points.xyz_given[held])


def test_compare_project_command(strip, tmp_path):
    ok = run("compare", "--project", strip, "--out", tmp_path / "o", "--trials", "2", "--workers", "1",
             "--methods", "conditions")
    assert ok.returncode == 0, ok.stderr
    assert "2 adjustments" in ok.stdout
    err = assert_clean_failure(run("compare", "--project", strip, "--out", tmp_path / "x", "--photos", "8"), 2)
    assert "--project" in err and not (tmp_path / "x").exists()
    err = assert_clean_failure(run("compare", "--project", strip, "--out", strip / "inside"), 2)
    assert "input" in err


def test_compare_project_on_a_block_runs_the_sequential_method_strip_by_strip(tmp_path):
    """On a block of two strips the sequential method adjusts each strip on its own (it extends
    one strip) and its row pools them: the centre RMS over all photos, the last centre and the
    check points equal those of adjusting each strip's photos, measurements and control by hand
    (photos.csv rows of the strip); the simultaneous methods adjust the whole block."""
    from striptri.adjustment import AdjustmentOptions, adjust
    from striptri.pipeline import check_point_statistics, triangulate_result
    from striptri.study.project import run_project_task, strip_project, strip_rows

    d = SyntheticDesign()
    design = SyntheticDesign(flight=replace(d.flight, n_photos=6, n_strips=2),
                             control=replace(d.control, layout="perimeter", n_check=4))
    project, truth = simulate_project("block", SimulateOptions(design), seed=2)
    folder = write_project(tmp_path / "block", project, truth_tables=truth)
    plan = noise_free_project(read_project(folder))
    task = project_tasks(plan, METHODS, (), 1, seed=7)[0]
    rows, along = run_project_task(task)
    assert [r["method"] for r in rows] == ["sequential", "conditions", "bundle"]
    assert all(r["status"] == "ok" for r in rows), [r["status"] for r in rows]
    noisy = noisy_project(task)
    strips = strip_rows(noisy.photos.strip_ids)
    assert len(strips) == 2 and sorted(np.concatenate(strips).tolist()) == list(range(len(noisy.photos)))
    errors, checks = np.zeros((len(noisy.photos), 3)), []
    for photos in strips:
        part = strip_project(noisy, photos)
        assert part.photos.ids == [noisy.photos.ids[i] for i in photos]
        assert np.all(np.isin(noisy.image_points.photo_index[np.isin(noisy.image_points.photo_index, photos)],
                              photos))
        result = adjust(part, AdjustmentOptions.of(method="sequential", procedure=1, direction="forward"))
        errors[photos] = result.state.xyz0 + result.offset - plan.photos.xyz0[photos]
        checks.append(check_point_statistics(part, result, triangulate_result(part, result)))
    seq = rows[0]
    norms = np.linalg.norm(errors, axis=1)
    assert seq["centre_rms"] == pytest.approx(float(np.sqrt(np.mean(norms**2))), rel=1e-9)
    assert seq["centre_last"] == pytest.approx(float(norms[-1]), rel=1e-9)
    np.testing.assert_allclose(along["seq1-forward"], norms, rtol=1e-9)
    n = sum(c["n"] for c in checks)
    assert seq["check_n"] == n > 0
    rms_z = np.sqrt(sum(c["n"] * c["rms_Z"] ** 2 for c in checks if c["n"]) / n)
    assert seq["check_rms_Z"] == pytest.approx(float(rms_z), rel=1e-9)
    assert seq["predicted_last"] is None and rows[1]["predicted_last"] is not None
