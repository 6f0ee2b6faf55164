"""AdjustmentOptions: one options object with one object per method inside, validated where made
(issue 13), and the flat form the command line and project.toml use."""

from __future__ import annotations

import pytest

from striptri.adjustment import AdjustmentOptions, BundleOptions, ConditionsOptions, SequentialOptions


def test_flat_keywords_go_to_the_object_they_belong_to():
    flat = AdjustmentOptions.of(method="bundle", max_iterations=12, cost_tolerance=1e-9, scale_form="xz",
                                procedure=2, direction="backward", polynomial_degree=2)
    assert flat == AdjustmentOptions(method="bundle", max_iterations=12, bundle=BundleOptions(cost_tolerance=1e-9),
                                     conditions=ConditionsOptions(scale_form="xz"),
                                     sequential=SequentialOptions(procedure=2, direction="backward",
                                                                  polynomial_degree=2))
    assert AdjustmentOptions.of() == AdjustmentOptions()


def test_a_keyword_no_object_has_is_an_error():
    with pytest.raises(TypeError, match="no option 'cost_tolerence'"):
        AdjustmentOptions.of(cost_tolerence=1e-9)


@pytest.mark.parametrize("make, words", [
    (lambda: ConditionsOptions(scale_form="2d"), "unknown scale form"),
    (lambda: BundleOptions(cost_tolerance=-1.0), "cost_tolerance"),
    (lambda: SequentialOptions(procedure=3), "unknown procedure"),
    (lambda: AdjustmentOptions.of(direction="sideways"), "unknown direction"),
    (lambda: AdjustmentOptions(datum="inner", datum_points=("a", "b", "c")), "for the point datum"),
    (lambda: AdjustmentOptions(datum="inner-points", datum_points=("a", "b")), "at least three"),
    (lambda: AdjustmentOptions(method="sequential", datum="inner"), "datum from control"),
    (lambda: AdjustmentOptions(max_iterations=0), "at least 1"),
])
def test_each_object_is_validated_where_it_is_made(make, words):
    with pytest.raises(ValueError, match=words):
        make()


def test_the_sequential_steps_limit_is_the_larger_of_the_two():
    options = AdjustmentOptions(method="sequential", max_iterations=50)
    assert SequentialOptions.from_adjustment_options(options).max_iterations == 50
    options = AdjustmentOptions(method="sequential", max_iterations=1)
    assert SequentialOptions.from_adjustment_options(options).max_iterations == 30
    options = AdjustmentOptions(method="sequential", max_iterations=1, sequential=SequentialOptions(max_iterations=2))
    assert SequentialOptions.from_adjustment_options(options).max_iterations == 2


def test_run_options_hold_every_option_of_the_adjust_command():
    """The command line builds one RunOptions (runs.py): each option of ``striptri adjust`` is a
    field of it, except the covariance flags (one CovarianceRequest), --quiet (the terminal) and
    --threads (the machine: how many cores compute, never what is computed)."""
    from dataclasses import fields

    from striptri.cli import main
    from striptri.core.runs import ADJUSTMENT_FIELDS, RunOptions

    names = {f.name for f in fields(RunOptions)}
    given = {p.name for p in main.commands["adjust"].params} - {"project_dir", "out_dir", "quiet", "threads"}
    covariance = {n for n in given if n.startswith("covariance")}
    assert given - covariance <= names
    run = RunOptions(method="bundle", datum_points=["P1", 2])
    assert run.adjustment == {"method": "bundle", "datum_points": ("P1", "2")}
    assert set(run.adjustment) <= set(ADJUSTMENT_FIELDS)
    assert RunOptions().corrections == {"earth_curvature": None, "refraction": None}


def test_run_summary_is_what_summary_json_holds(tmp_path):
    """runs.RunSummary types summary.json: the file is its as_dict, the contract's keys first in
    DESIGN's order, an optional section only when the project has it, and the mapping reads the
    same keys."""
    import json
    from pathlib import Path

    from striptri.pipeline import run_adjust
    from striptri.core.runs import OPTIONAL_SECTIONS, RunOptions

    folder = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8"
    products = run_adjust(folder, tmp_path / "out", RunOptions(blunders="snoop"))
    written = json.loads((tmp_path / "out" / "summary.json").read_text())
    summary = products.summary
    assert written == json.loads(json.dumps(summary.as_dict())) and list(written) == list(summary)
    contract = ["method", "solver", "sigma0", "redundancy", "vtpv", "iterations", "converged", "n_photos",
                "n_points", "n_observations", "n_conditions", "n_unknowns", "check_points", "timings_s"]
    assert list(written)[: len(contract)] == contract
    assert summary["sigma0"] == summary.sigma0 and summary.blunders["method"] == "snoop"
    assert not any(key in written for key in OPTIONAL_SECTIONS)  # strip8: no free network, GNSS, film ...
    with pytest.raises(KeyError):
        summary["film"]
    assert summary.get("film") is None and "film" not in summary
