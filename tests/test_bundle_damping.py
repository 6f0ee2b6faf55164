"""The bundle method's Levenberg-Marquardt damping rule (bundle.damping.Damping)."""

from __future__ import annotations

import pytest

from striptri.bundle.damping import LM_FLOOR, LM_START, Damping


def _damped(lam: float) -> Damping:
    damping = Damping()
    damping.lam = lam
    return damping


def test_nielsens_rule_on_a_measurable_step():
    """rho = actual / predicted: a step that did what the model predicted divides the factor by 3;
    one that did half of it keeps it; one that made things worse by as much as predicted multiplies
    it by 28 (1 - (2 rho - 1)^3)."""
    for rho, factor in ((1.0, 1.0 / 3.0), (0.5, 1.0), (-1.0, 28.0)):
        damping = _damped(1e-3)
        damping.after_good_step(rho * 2.0, 2.0, round_off=1e-9)
        assert damping.lam == pytest.approx(1e-3 * factor, rel=1e-12)
        assert damping.nu == 2.0


def test_a_step_at_the_minimum_is_not_judged_by_its_round_off():
    """At the minimum the predicted and the actual reduction are both round-off, and their ratio
    means nothing: -3e-12 against a predicted 1e-14 gave rho = -300 and multiplied the factor by
    2e8 (a damped run in a free network then failed with 'damping grew past 1e8'). A predicted
    reduction within the round-off of the sum counts as rho = 1: the factor falls, as after a
    good step, down to plain Gauss-Newton."""
    damping = _damped(6e-8)
    damping.after_good_step(-3e-12, 1e-14, round_off=8e-9)
    assert damping.lam == pytest.approx(2e-8, rel=1e-12)
    unguarded = _damped(6e-8)
    unguarded.after_good_step(-3e-12, 1e-14)  # no round-off given: the ratio as it is
    assert unguarded.lam / 6e-8 > 1e8
    for _ in range(5):
        damping.after_good_step(-3e-12, 1e-14, round_off=8e-9)
    assert damping.lam == 0.0  # below LM_FLOOR: Gauss-Newton again
    assert LM_FLOOR < LM_START


def test_more_damping_after_a_failed_step():
    damping = Damping()
    damping.more()
    assert damping.lam == LM_START and damping.nu == 4.0
    damping.more()
    assert damping.lam == 4.0 * LM_START and damping.nu == 8.0
