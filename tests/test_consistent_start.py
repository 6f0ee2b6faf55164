"""The first linearisation of the method of conditions (conditions_method.adjust.consistent_start):
the plate coordinates moved onto the rays of each point intersected at the approximate orientation,
so that every condition holds there and the first misclosure is A (l - l^) alone; with the lens
model of either convention active. The adjustment's result does not depend on the start (the
conditions method still equals the bundle method: test_conditions_vs_bundle, test_bundle)."""

from __future__ import annotations

import numpy as np
import pytest
from test_self_calibration import calibration_project

from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.conditions_method.adjust import consistent_start
from striptri.equations.groups import build_batches
from striptri.equations.linearise import evaluate
from striptri.equations.observations import observations_of
from striptri.equations.parameters import build_layout, initial_state, reduction_offset
from striptri.geometry.lens import IMAGE, PLATE
from striptri.io import read_project
from striptri.model import TIE

from cli_support import DATA

NOISE = sim.NoiseOptions()  # approximations 10 m and 1 degree off


def _project(case: str):
    if case == "block":
        return read_project(DATA / "block_3x6")
    project, _, _ = calibration_project(PLATE if case == "plate lens" else IMAGE, NOISE, free=())
    return project  # the true lens held: the distortion is active at the approximations


@pytest.mark.parametrize("case", ["block", "plate lens", "image lens"])
def test_the_conditions_hold_at_the_first_linearisation_point(case):
    project = _project(case)
    offset = reduction_offset(project)
    state, layout, obs = initial_state(project, offset), build_layout(project), observations_of(project, offset)
    plate_hat, control_hat = consistent_start(project, state, layout, obs)
    moved = (plate_hat != obs.plate).any(axis=1)
    assert moved.mean() > 0.9, moved.mean()  # noisy approximations: almost every ray is moved
    n_checked = 0
    for batch in build_batches(project):
        own = moved[batch.image_rows].all(axis=1)  # groups whose point was intersected
        before = evaluate(batch, state, obs.plate, obs.control, plate_measured=obs.plate).g[own]
        after = evaluate(batch, state, plate_hat, control_hat, plate_measured=obs.plate).g[own]
        scale = np.abs(before).max(axis=0)  # per condition of the shape: its misclosure at l
        assert np.all(scale > 0)
        assert np.all(np.abs(after) <= 1e-11 * scale), np.abs(after / scale).max()
        n_checked += own.sum()
    assert n_checked > 0.9 * len(project.points)


def test_points_the_approximations_do_not_determine_keep_their_measurements():
    """A tie point seen twice along the base at the approximations: its rays are not intersected,
    and l^ stays l for them."""
    project = read_project(DATA / "pair")
    offset = reduction_offset(project)
    state, layout, obs = initial_state(project, offset), build_layout(project), observations_of(project, offset)
    # the second photo's centre on the first: every pair of rays meets at the centre or not at all
    state.xyz0[1] = state.xyz0[0]
    plate_hat, control_hat = consistent_start(project, state, layout, obs)
    ip = project.image_points
    tie = project.points.kind == TIE
    rows = tie[ip.point_index]
    assert rows.any()
    np.testing.assert_array_equal(plate_hat[rows], obs.plate[rows])
    np.testing.assert_array_equal(control_hat, obs.control)


def test_a_rough_start_converges_to_the_same_solution_in_fewer_iterations(monkeypatch):
    """On a block with rough approximations the consistent start saves iterations (the first step
    is the bundle method's Gauss-Newton step) and reaches the same vTPv."""
    import striptri.conditions_method.adjust as conditions_adjust

    project, _, _ = calibration_project(PLATE, sim.NoiseOptions(approx_position_error=30.0, approx_angle_error=3.0),
                                        free=())
    consistent = adjust(project, AdjustmentOptions())
    monkeypatch.setattr(conditions_adjust, "consistent_start",
                        lambda project, state, layout, obs: (obs.plate.copy(), obs.control.copy()))
    at_l = adjust(project, AdjustmentOptions())
    assert consistent.converged and at_l.converged
    assert consistent.vtpv == pytest.approx(at_l.vtpv, rel=1e-10)
    assert consistent.iterations < at_l.iterations, (consistent.iterations, at_l.iterations)
