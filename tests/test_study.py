"""striptri compare: the method-comparison study (DESIGN section 9; docs/study.md)."""

from __future__ import annotations

import csv
import dataclasses
import io
import math

import numpy as np
import pytest

from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.study import (
    METHOD_LABELS,
    ROW_COLUMNS,
    StudyOptions,
    fit_power_law,
    growth_table,
    run_compare,
    simulate_task,
    tasks_of,
)
from striptri.study.growth import label_of

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("study")

SMALL = StudyOptions(methods=METHOD_LABELS, photos=(4, 5), layouts=("cantilever", "ends"), trials=1, seed=7)


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _without_seconds(path) -> str:
    rows = _read(path)
    out = io.StringIO()
    writer = csv.writer(out)
    for r in rows:
        writer.writerow([v for k, v in r.items() if k != "seconds"])
    return out.getvalue()


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("study") / "serial"
    run_compare(out, SMALL, workers=1)
    return out


def test_study_csv_has_the_columns_and_one_row_per_method_configuration_trial(serial):
    rows = _read(serial / "study.csv")
    assert tuple(rows[0].keys()) == ROW_COLUMNS
    n_expected = len(SMALL.methods) * len(SMALL.photos) * len(SMALL.layouts) * len(SMALL.sigma_images) * SMALL.trials
    assert len(rows) == n_expected
    keys = {(r["method"], r["procedure"], r["direction"], r["n_photos"], r["layout"], r["sigma_image"], r["trial"])
            for r in rows}
    assert len(keys) == n_expected
    assert all(r["status"] == "ok" for r in rows)
    # one seed per (configuration, trial), shared by the methods: they see the same data
    seeds = {(r["n_photos"], r["layout"], r["trial"]): r["seed"] for r in rows}
    assert len(set(seeds.values())) == len(SMALL.photos) * len(SMALL.layouts) * SMALL.trials
    for name in ("growth.csv", "precision.csv", "along.csv", "report.html"):
        assert (serial / name).stat().st_size > 0
    assert "data:image/png;base64," in (serial / "report.html").read_text()


def test_two_workers_give_the_same_study_csv(serial, tmp_path):
    run_compare(tmp_path / "pool", SMALL, workers=2)
    assert _without_seconds(tmp_path / "pool" / "study.csv") == _without_seconds(serial / "study.csv")


def test_a_dask_cluster_gives_the_same_study_csv(serial, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        run_compare(tmp_path / "dask", SMALL, scheduler=client)
    assert _without_seconds(tmp_path / "dask" / "study.csv") == _without_seconds(serial / "study.csv")


def test_trial_seeds_do_not_depend_on_the_rest_of_the_study():
    one = {t.key: t.seed for t in tasks_of(StudyOptions(photos=(8,), layouts=("ends",), trials=3))}
    many = {t.key: t.seed for t in tasks_of(StudyOptions(photos=(4, 8), layouts=("cantilever", "ends"), trials=5))}
    assert all(many[k] == s for k, s in one.items())


def test_fit_power_law_recovers_a_known_law_exactly():
    n = np.array([4, 8, 16, 32])
    fit = fit_power_law(n, 0.03 * n**1.5)
    assert fit["b"] == pytest.approx(1.5, abs=1e-12)
    assert fit["a"] == pytest.approx(0.03, rel=1e-12)
    assert fit["se_b"] < 1e-12 and fit["se_log_a"] < 1e-12
    assert math.isnan(fit_power_law([4, 8], [1.0, 2.0])["se_b"])  # two sizes: no scatter to estimate


def test_growth_table_fits_a_known_law_per_method_and_layout():
    laws = {("seq1-forward", "cantilever"): (0.02, 1.5), ("conditions", "cantilever"): (0.05, 1.0),
            ("conditions", "ends"): (0.2, 0.0)}
    specs = {"seq1-forward": ("sequential", 1, "forward"), "conditions": ("conditions", None, None)}
    rows = [
        {"method": specs[label][0], "procedure": specs[label][1], "direction": specs[label][2], "layout": layout,
         "n_photos": n, "sigma_image": 0.005, "trial": t, "centre_last": a * n**b, "status": "ok"}
        for (label, layout), (a, b) in laws.items() for n in (4, 8, 16, 32) for t in range(3)
    ]
    g = growth_table(rows)
    for i in range(len(g["method"])):
        label = label_of({"method": g["method"][i], "procedure": g["procedure"][i], "direction": g["direction"][i]})
        a, b = laws[(label, g["layout"][i])]
        assert g["a"][i] == pytest.approx(a, rel=1e-10) and g["b"][i] == pytest.approx(b, abs=1e-10)
        assert g["trials"][i] == 3 and g["n_sizes"][i] == 4


def test_noise_free_every_method_recovers_the_truth(tmp_path):
    options = StudyOptions(photos=(6,), layouts=("cantilever", "ends", "every-k"), sigma_images=(0.0,), trials=1)
    result = run_compare(tmp_path / "exact", options, workers=2)
    assert len(result.rows) == 6 * 1 * 3 and result.n_failed == 0
    for r in result.rows:
        assert r["centre_rms"] < 1e-5, r
        assert max(r["check_rms_X"], r["check_rms_Y"], r["check_rms_Z"]) < 1e-5, r


def test_with_noise_the_sequential_methods_are_not_more_accurate_than_the_simultaneous(tmp_path):
    # Least squares over the whole strip is the minimum-variance estimator (Gauss-Markov, linearised), so
    # in expectation no sequential method beats it. Every method sees the same noise in a trial (paired
    # samples), which keeps the ratio's scatter small; 0.9 allows for what scatter is left in 4 trials.
    options = StudyOptions(photos=(8,), layouts=("ends",), trials=4, seed=3)
    rows = run_compare(tmp_path / "noisy", options, workers=2).rows
    mse = {}
    for r in rows:
        mse.setdefault(label_of(r), []).append(r["centre_rms"] ** 2 + r["check_rms_X"] ** 2
                                               + r["check_rms_Y"] ** 2 + r["check_rms_Z"] ** 2)
    simultaneous = math.sqrt(np.mean(mse["conditions"]))
    assert math.sqrt(np.mean(mse["bundle"])) == pytest.approx(simultaneous, rel=1e-6)
    for label in ("seq1-forward", "seq1-backward", "seq2-forward", "seq2-backward"):
        assert math.sqrt(np.mean(mse[label])) >= 0.9 * simultaneous, label


def _reversed_photos(project: model.Project) -> model.Project:
    """The same project with its photos (photos.csv rows) in reverse order."""
    ph, ip = project.photos, project.image_points
    n = len(ph)
    rev = slice(None, None, -1)
    photos = dataclasses.replace(
        ph, ids=ph.ids[rev], camera_index=ph.camera_index[rev], strip_ids=ph.strip_ids[rev], xyz0=ph.xyz0[rev],
        R_ground_from_cam=ph.R_ground_from_cam[rev], angles=ph.angles[rev], sigma_xyz0=ph.sigma_xyz0[rev],
        sigma_angles=ph.sigma_angles[rev])
    photo_index = n - 1 - ip.photo_index
    order = np.argsort(photo_index, kind="stable")
    image_points = dataclasses.replace(ip, photo_index=photo_index[order], point_index=ip.point_index[order],
                                       xy=ip.xy[order], sigma_xy=ip.sigma_xy[order])
    return dataclasses.replace(project, photos=photos, image_points=image_points)


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_the_simultaneous_result_does_not_depend_on_the_photo_order(method):
    task = tasks_of(StudyOptions(photos=(6,), layouts=("ends",), trials=1, seed=11))[0]
    _, project = simulate_task(task)
    options = AdjustmentOptions(method=method)
    a = adjust(project, options)
    b = adjust(_reversed_photos(project), options)
    xyz_a = a.state.xyz0 + a.offset
    xyz_b = (b.state.xyz0 + b.offset)[::-1]
    np.testing.assert_allclose(xyz_b, xyz_a, rtol=0, atol=1e-6)


def test_the_compare_command_takes_lists_after_one_flag(tmp_path):
    from click.testing import CliRunner

    from striptri.cli import main

    out = tmp_path / "cli"
    res = CliRunner().invoke(main, ["compare", "--out", str(out), "--methods", "seq1-forward", "conditions",
                                    "--photos", "4", "5", "--layouts", "cantilever", "--trials", "1", "--workers", "1"])
    assert res.exit_code == 0, res.output
    rows = _read(out / "study.csv")
    assert sorted({(r["method"], r["n_photos"]) for r in rows}) == [
        ("conditions", "4"), ("conditions", "5"), ("sequential", "4"), ("sequential", "5")]


def test_a_scheduler_without_dask_is_a_clear_input_error(tmp_path, monkeypatch):
    import sys

    from click.testing import CliRunner

    from striptri.cli import main

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import fails as if not installed
    res = CliRunner().invoke(main, ["compare", "--out", str(tmp_path / "x"), "--photos", "4", "--trials", "1",
                                    "--scheduler", "tcp://127.0.0.1:1"])
    assert res.exit_code == 2
    assert "dask.distributed" in res.output and not (tmp_path / "x").exists()
