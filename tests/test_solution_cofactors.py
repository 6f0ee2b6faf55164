"""The residual cofactors from the whitened groups that the method of conditions' final checks keep
(ConditionsOptions.keep_solution_systems, core.result.SolutionSystems) against the conditions form
that linearises every group again at the result (precision.residuals): the same Qvv to round-off,
with weighted control, with the plate blocks of the w-tests' correlations, with groups of long
tracks (kept without their systems) and with groups whose M = A Q A^T is not clearly regular
(formed by the conditions form, which tells the degenerate ones)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri.adjustment import adjust
from striptri.core.options import AdjustmentOptions, ConditionsOptions
from striptri.equations import normal_equations
from striptri.equations.observations import observations_of
from striptri.io import read_project
from striptri.precision import collinearity_form, residuals
from striptri.precision.residuals import residual_cofactors

ROOT = Path(__file__).resolve().parents[1]
KEEP = AdjustmentOptions(conditions=ConditionsOptions(keep_solution_systems=True))
# Qvv formed as Gt^T (I - Bw Qxx Bw^T) Gt or as Q A^T M^-1 (M - B Qxx B^T) M^-1 A Q: the same
# products in another order, so they agree to a few units of the last digit of the largest terms
TOLERANCE = 1e-11


def _weighted_block():
    """block_3x6 with the full control points weighted (0.05 m in X and Y, 0.08 m in Z): groups
    with control observations besides their rays."""
    project = read_project(ROOT / "data" / "synthetic_strips" / "block_3x6")
    points = project.points
    sigma = np.array(points.sigma_given, dtype=float).reshape(len(points), 3)
    full = points.given_axes.all(axis=1)
    sigma[full] = [0.05, 0.05, 0.08]
    return replace(project, points=replace(points, sigma_given=sigma))


@pytest.fixture(scope="module")
def weighted_block():
    return _weighted_block()


@pytest.fixture(autouse=True)
def conditions_form(monkeypatch):
    """These small projects would take the collinearity form (collinearity_form.applies), and the
    method of conditions would then keep nothing: its limit lowered, they take the conditions form."""
    monkeypatch.setattr(collinearity_form, "DENSE_UNKNOWNS", 0)


def _assert_same(kept, swept):
    for name in ("plate", "control"):
        a, b = getattr(kept, name), getattr(swept, name)
        np.testing.assert_allclose(a, b, rtol=0, atol=TOLERANCE * abs(b).max())
    np.testing.assert_array_equal(kept.undetermined, swept.undetermined)
    if swept.plate_blocks is not None:
        ours = {tuple(r): q for rows, Q in kept.plate_blocks for r, q in zip(rows, Q)}
        theirs = {tuple(r): q for rows, Q in swept.plate_blocks for r, q in zip(rows, Q)}
        assert ours.keys() == theirs.keys()
        for key, q in theirs.items():
            np.testing.assert_allclose(ours[key], q, rtol=0, atol=TOLERANCE * abs(q).max())


@pytest.mark.parametrize("datum", ["control", "inner"])
def test_the_kept_systems_give_the_conditions_form(weighted_block, datum):
    """The same cofactors, with the datum by control and in a free network (Qxx under its inner
    constraints)."""
    keep = replace(KEEP, datum=datum)
    result = adjust(weighted_block, keep)
    assert result.solution_systems is not None
    swept = residual_cofactors(weighted_block, adjust(weighted_block, replace(keep, conditions=ConditionsOptions())),
                               plate_blocks=True)
    kept = residual_cofactors(weighted_block, result, keep, plate_blocks=True)
    assert (swept.control > 0).any()  # the weighted control is tested
    _assert_same(kept, swept)
    q_control = observations_of(weighted_block, result.offset).q_control
    np.testing.assert_array_equal(kept.control[q_control == 0], 0.0)  # held or free: no observation, no qvv
    assert not np.signbit(kept.control).any()


def test_the_kept_systems_are_used_once_and_only_for_their_project(monkeypatch, weighted_block):
    """The first pass takes them; a second pass (and a pass for another project, even an equal
    one) linearises as before, and the systems are let go either way."""
    used = []
    solution = residuals._solution_cofactors
    monkeypatch.setattr(residuals, "_solution_cofactors", lambda *a: used.append(1) or solution(*a))
    result = adjust(weighted_block, KEEP)
    first = residual_cofactors(weighted_block, result, KEEP)
    assert used == [1]
    second = residual_cofactors(weighted_block, result, KEEP)
    assert used == [1]
    _assert_same(first, second)
    other = adjust(weighted_block, KEEP)
    residual_cofactors(replace(weighted_block), other, KEEP)
    assert used == [1]
    assert other.solution_systems.take(weighted_block) is None  # let go by the pass that could not use them


def test_nothing_is_kept_where_it_would_not_serve(monkeypatch, weighted_block):
    """Not without the option, not in chunks larger than the precision passes' and not where the
    collinearity form gives the cofactors."""
    assert adjust(weighted_block, AdjustmentOptions()).solution_systems is None
    assert adjust(weighted_block, replace(KEEP, chunk_size=4096)).solution_systems is None
    monkeypatch.setattr(collinearity_form, "DENSE_UNKNOWNS", 2048)
    assert adjust(weighted_block, KEEP).solution_systems is None


def test_groups_not_clearly_regular_are_formed_again(monkeypatch, weighted_block):
    """With the threshold of clearly_regular raised so that no group passes, every point goes to
    the conditions form: the same numbers as the pass that linearises, to the last bit."""
    monkeypatch.setattr(normal_equations, "CLEARLY_REGULAR", 1.0)  # the adjustment's own inverses too: both
    swept = residual_cofactors(weighted_block, adjust(weighted_block, AdjustmentOptions()), plate_blocks=True)
    result = adjust(weighted_block, KEEP)
    kept = residual_cofactors(weighted_block, result, KEEP, plate_blocks=True)
    np.testing.assert_array_equal(kept.plate, swept.plate)
    np.testing.assert_array_equal(kept.control, swept.control)


@pytest.fixture(scope="module")
def close_range_project(tmp_path_factory):
    sys.path.insert(0, str(ROOT / "scripts" / "bench"))
    import close_range

    net = close_range.make_close_range(20, 30, seed=5)  # 6 to 17 rays per target
    return read_project(close_range.write_close_range(tmp_path_factory.mktemp("cr") / "p", net))


def test_long_tracks_are_formed_by_the_conditions_form(monkeypatch, close_range_project):
    """Targets of 12 rays and more are whitened by ray (ray_columns): their chunks are kept
    without their systems and formed again; the shorter ones come from the kept systems."""
    swept = residual_cofactors(close_range_project, adjust(close_range_project, AdjustmentOptions()))
    result = adjust(close_range_project, KEEP)
    chunks = result.solution_systems._chunks
    assert any(c.Bw is None for c in chunks) and any(c.Bw is not None for c in chunks)
    again = []
    form = residuals._conditions_form_of
    monkeypatch.setattr(residuals, "_conditions_form_of", lambda *a: again.append(a[3].sum()) or form(*a))
    kept = residual_cofactors(close_range_project, result, KEEP)
    assert again and 0 < again[0] < len(close_range_project.points)
    _assert_same(kept, swept)
