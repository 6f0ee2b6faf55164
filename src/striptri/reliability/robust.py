"""Robust re-weighting (iteratively reweighted least squares), then least squares of the survivors.

1. Adjust with weights p per row (all 1 at first; the row's sigmas become sigma / sqrt(p)).
2. For every coordinate, u = its studentised estimated gross error
   (:func:`studentised_gross_errors`); a row's u is the larger of its x and y.
3. Target weight ``robust_weight(u, c)``; the new weight is the geometric mean of the old weight
   and the target (damping: undamped, the rays of one point whose w are strongly correlated
   take turns being down-weighted and the weights cycle for ever).
4. Repeat from the last orientations until no weight changes by more than ``robust_tolerance``,
   or the rows whose u exceeds the critical value (the decision of step 5) have stayed the same
   over ``STABLE_ROUNDS`` re-weightings: the weights of the rows below it still creep towards 1
   then (the damping halves their logarithm each time), but they are re-adjusted at full weight
   anyway.
5. Reject the rows whose u exceeds the critical value of the w-test (the same alpha0 as data
   snooping), at most ``max_rejections`` (largest first), and adjust the rest at full weight. That
   adjustment's w, MDB and flags are reported ("suspect" where |w| still exceeds the critical
   value): reporting a least-squares adjustment of the survivors keeps sigma0, the precision and
   the w-test meaningful; the re-weighting only finds the rows.

The weight is per row, like the rejection: a gross error of identification spoils x and y.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..adjustment import AdjustmentOptions, AdjustmentResult, adjust
from ..errors import NumericalFailure
from ..model import TIE, Project
from ..precision.residuals import residual_cofactors
from .measures import R_ZERO, critical_value, plate_reliability, row_abs
from .outcome import (
    BlunderOptions,
    BlunderResult,
    Rejection,
    Round,
    FinalAdjustment,
    blunder_result,
    subset,
    succeeded,
    untested,
    warm_start,
)

DOWNWEIGHTED = 0.5  # Round.rejected of a re-weighting counts the rows with a weight below this
STABLE_ROUNDS = 3  # re-weighting stops when the rows above the critical value stay the same this often
START_ROUNDS = 10  # robust-snoop: re-weightings at most before snooping takes over


def robust_weight(u: np.ndarray, c: float) -> np.ndarray:
    """Danish-type weight function: 1 up to c, then an exponential decay,
    ``p(u) = 1`` for ``u <= c`` and ``p(u) = exp(1 - (u/c)^2)`` above (continuous at c; 0.05 at
    2c, 3e-4 at 3c). The exponential down-weighting is that of the Danish method (Krarup, Juhl &
    Kubik 1980); its exact exponent varies between implementations, this is striptri's. u >= 0 in
    units of its standard deviation; nan (untestable) -> 1."""
    u = np.nan_to_num(np.asarray(u, dtype=float), nan=0.0)
    return np.where(u <= c, 1.0, np.exp(1.0 - (u / c) ** 2))


def studentised_gross_errors(v: np.ndarray, qvv: np.ndarray, q_current: np.ndarray, q_prior: np.ndarray) -> np.ndarray:
    """|estimated gross error| / its standard deviation under the a-priori model, per coordinate.

    In an adjustment where the coordinate has cofactor q' (its a-priori cofactor q divided by its
    weight) and redundancy number r' = qvv / q', the estimated gross error is ``-v / r'`` (minus the
    residual the coordinate would have if left out), and the prediction from the other observations
    has cofactor ``q' (1 - r') / r'``; so ``u = |v / r'| / sqrt(q + q' (1 - r') / r')``. At full
    weight (q' = q) this is Baarda's |w|; for a down-weighted coordinate it stays what |w| would be
    at full weight given the rest, instead of shrinking with the weight (which would let a gross
    error win its weight back). All arrays alike; nan where r' <= R_ZERO.
    """
    r = np.clip(qvv / q_current, 0.0, 1.0)
    ok = r > R_ZERO
    safe = np.where(ok, r, 1.0)
    u = np.abs(v / safe) / np.sqrt(q_prior + q_current * (1.0 - safe) / safe)
    return np.where(ok, u, np.nan)


def _reweighted(project: Project, options: AdjustmentOptions, blunders: BlunderOptions,
                first: AdjustmentResult | None, t_start: float):
    """Steps 1-4 of the module doc: -> (weights p (m,), u (m, 2), row u (m,), the last state,
    rounds, converged), or the untested BlunderResult when an adjustment fails."""
    ip = project.image_points
    m = len(ip)
    q_prior = ip.sigma_xy**2
    crit = critical_value(blunders.alpha0)
    p = np.ones(m)
    state = None
    rounds: list[Round] = []
    u_row = np.zeros(m)
    u = np.zeros((m, 2))
    decisions, stable, converged = None, 0, False
    for _ in range(blunders.max_rounds):
        t0 = time.perf_counter()
        weighted = replace(project, image_points=replace(ip, sigma_xy=ip.sigma_xy / np.sqrt(p)[:, None]))
        if state is not None:
            weighted = warm_start(weighted, *state)
        result = first if state is None and first is not None else adjust(weighted, options)
        if not succeeded(result):  # no solution to judge residuals by: all rows at full weight, untested
            if state is not None:
                result = adjust(warm_start(project, *state), options)
            return untested(blunders.method, project, result, blunders, time.perf_counter() - t_start)
        state = (result.state, result.offset)
        cof = residual_cofactors(weighted, result, options)
        u = studentised_gross_errors(result.plate_residuals, cof.plate, weighted.image_points.sigma_xy**2, q_prior)
        u_row = np.maximum(row_abs(u), 0.0)
        target = np.maximum(robust_weight(u_row, blunders.robust_c), blunders.min_weight)
        if blunders.method == "robust-snoop":  # no redundancy left (u nan): no evidence to change the weight
            target = np.where(np.isnan(u_row), p, target)
        p_new = np.sqrt(p * target)
        change = float(np.max(np.abs(p_new - p), initial=0.0))
        p = p_new
        rounds.append(Round(int(np.count_nonzero(p < DOWNWEIGHTED)), float(u_row.max(initial=0.0)),
                            result.iterations, time.perf_counter() - t0))
        over = frozenset(np.flatnonzero(u_row > crit).tolist())
        stable = stable + 1 if over == decisions else 0
        decisions = over
        if change < blunders.robust_tolerance or stable >= STABLE_ROUNDS:
            converged = True
            break
    return p, u, u_row, state, rounds, converged


def robust_start(project: Project, options: AdjustmentOptions, blunders: BlunderOptions,
                 first: AdjustmentResult | None = None):
    """The re-weighting as the start of data snooping (``--blunders robust-snoop``): -> (the rows it
    would reject as Rejections, the last state, its rounds), or the untested BlunderResult.

    The rows whose studentised gross error exceeds the critical value (the largest first, at most
    the rejection limit) are the candidates, each a group of its own, and with it every other ray
    of its point that would be left without a partner: a tie point keeps its rays only while two or
    more of them remain. (A false ray of a two-ray point is a gross error of the pair: its partner,
    down-weighted or not, is its only check, and the re-weighting leaves both untestable, u nan.)
    Snooping then goes on from the survivors and re-tests these groups like its own
    (snooping.snoop), re-admitting those that pass. The start needs the large errors, not the
    converged weights: at most START_ROUNDS re-weightings (on the rendered block with 5 % false
    matches the weights had not settled after 100). A row left without redundancy (u nan) keeps
    its weight instead of returning to 1: without it the two rays of a point took turns being
    down-weighted for ever."""
    t_start = time.perf_counter()
    ip = project.image_points
    found = _reweighted(project, options, replace(blunders, max_rounds=min(blunders.max_rounds, START_ROUNDS)),
                        first, t_start)
    if isinstance(found, BlunderResult):
        return found
    p, u, u_row, state, rounds, converged = found
    crit = critical_value(blunders.alpha0)
    over = np.flatnonzero(u_row > crit)
    cand = over[np.argsort(-u_row[over], kind="stable")][: blunders.rejection_limit(len(ip))]
    out = np.zeros(len(ip), dtype=bool)
    out[cand] = True
    ground = project.points.kind[ip.point_index] != TIE  # control, check points: a ray of their own counts
    left = np.bincount(ip.point_index[~out], minlength=len(project.points.ids))
    rejections, group = [], 0
    for i in cand:  # a few rows: each with the partners its point would leave alone
        partners = [] if ground[i] or left[ip.point_index[i]] >= 2 else \
            np.flatnonzero((ip.point_index == ip.point_index[i]) & ~out).tolist()
        for row in [int(i), *partners]:
            out[row] = True
            rejections.append(Rejection(row, int(ip.photo_index[row]), int(ip.point_index[row]), len(rounds),
                                        u[row].copy(), np.full(2, np.nan), group))
        left = np.bincount(ip.point_index[~out], minlength=len(project.points.ids))
        group += 1
    return rejections, state, rounds


def robust(project: Project, options: AdjustmentOptions = AdjustmentOptions(),
           blunders: BlunderOptions = BlunderOptions(), first: AdjustmentResult | None = None) -> BlunderResult:
    """Re-weighting to convergence, rejection, final adjustment at full weight (module doc).

    If the final adjustment of the survivors fails (or does not converge), all rows are adjusted
    at full weight instead, the candidates are flagged "suspect" and ``stopped`` says why. Raises
    NumericalFailure when the first adjustment fails; when it, or the re-weighting, does not
    converge, nothing is tested (outcome.untested) on the adjustment of all rows at full weight.
    first: the adjustment of all rows at full weight (the first round's) when the caller has made it.
    """
    t_start = time.perf_counter()
    ip = project.image_points
    m = len(ip)
    crit = critical_value(blunders.alpha0)
    found = _reweighted(project, options, blunders, first, t_start)
    if isinstance(found, BlunderResult):
        return found
    p, u, u_row, state, rounds, converged = found
    over = np.flatnonzero(u_row > crit)
    cand = over[np.argsort(-u_row[over], kind="stable")][: blunders.rejection_limit(m)]
    stopped = "limit" if len(over) > len(cand) else "clean" if converged else "rounds"
    keep = np.ones(m, dtype=bool)
    keep[cand] = False
    t0 = time.perf_counter()
    try:
        current = warm_start(subset(project, keep), *state)
        result = adjust(current, options)
        if not succeeded(result):
            raise NumericalFailure(result.termination_message.splitlines()[0])
    except NumericalFailure as exc:
        stopped, keep[:], cand = f"failure: {exc}", True, cand[:0]
        current = warm_start(project, *state)
        result = adjust(current, options)
        if not succeeded(result):
            return untested("robust", project, result, blunders, time.perf_counter() - t_start)
    rel = plate_reliability(current, result, options, blunders.alpha0, blunders.beta0)
    rounds.append(Round(0, float(max(row_abs(rel.w).max(initial=0.0), 0.0)), result.iterations,
                        time.perf_counter() - t0))
    rejected = [
        Rejection(int(i), int(ip.photo_index[i]), int(ip.point_index[i]), len(rounds) - 1, u[i].copy(),
                  np.full(2, np.nan))
        for i in cand
    ]
    final = FinalAdjustment(current, result, rel, np.flatnonzero(keep))
    return blunder_result("robust", project, final, rejected, rounds, stopped, time.perf_counter() - t_start,
                          weights=np.repeat(p[:, None], 2, axis=1))
