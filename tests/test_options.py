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
