"""Baarda's data snooping with iterative rejection of image points.

Adjust; compute w of every plate coordinate; while the largest row |w| (the larger of x and y)
exceeds the critical value, reject rows (:func:`select_rejections`) and re-adjust the rest,
starting from the adjusted orientations.

Data snooping is one-at-a-time in theory: the w-test assumes a single gross error. Rejecting
several rows per round is safe when they do not disturb each other, so a "separated" round takes
a row only if

* its |w| exceeds the critical value and is at least half the largest |w| of the round
  (``SEPARATED_FRACTION``): a large gross error raises the |w| of clean rows around it, which
  therefore wait until the large ones are gone;
* it has the largest |w| of its point: the rays of one point share its conditions, so a gross
  error in one raises the w of the others most;
* no row already taken shares its point or its photo (a gross error also shifts the orientation
  of its photo, and through it the residuals of the photo's other points).

Procedure "separable" (the default): the rows of the taken row's point whose w-tests correlate
with its own beyond separability (separability.inseparable_rows) are rejected with it as one group
(flag "inseparable": detected, not located); once the rest is clean the rejected groups are
re-tested against it and those that pass are re-admitted (:func:`retest`); then the rejected rows
get their other coordinate back where it passes the same test (:func:`readmit_coordinates`: a gross
error spoils x or y; a group is inseparable in one coordinate). Procedure "classic":
rows of the taken row's point whose |w| equals its own to ``TWIN_TOLERANCE`` (the two rays of a
tie point in two photos share a single condition) are rejected with it, and nothing is re-tested.
docs/reliability.md shows that this meets the same detection and false-alarm figures as one row
per round, in about half the rounds.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..adjustment import AdjustmentOptions, AdjustmentResult, adjust
from ..errors import InputError, NumericalFailure
from ..model import Project
from ..core.result import sigma0_of
from ..precision.residuals import plate_blocks_of, residual_cofactors
from .measures import critical_value, plate_reliability, row_abs
from .robust import studentised_gross_errors
from .separability import Correlations, inseparable_rows
from .outcome import (
    FLAG_INSEPARABLE,
    FLAG_REJECTED,
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
from ..equations import weights

SEPARATED_FRACTION = 0.5  # a "separated" round rejects rows with |w| >= this times the largest
TWIN_TOLERANCE = 1e-6  # rows of one point whose |w| agree to this (relative) are not told apart


def select_rejections(point_index: np.ndarray, photo_index: np.ndarray, row_abs_w: np.ndarray, critical: float,
                      per_round: str = "separated", expand=None) -> np.ndarray:
    """Rows to reject after one adjustment (module doc), largest |w| first.

    point_index, photo_index, row_abs_w: (m,) per row (row_abs_w = max(|w_x|, |w_y|), -inf when
    untestable). per_round: "separated" or "single". expand: None (the rows of the taken row's
    point whose |w| equals its own, ``TWIN_TOLERANCE``) or a function row -> the rows that cannot
    be told from it (separability.inseparable_rows, the taken row first). -> (k,) row indices.
    """
    cand = np.flatnonzero(row_abs_w > critical)
    if not len(cand):
        return cand
    order = cand[np.argsort(-row_abs_w[cand], kind="stable")]
    if per_round == "separated":
        order = order[row_abs_w[order] >= SEPARATED_FRACTION * row_abs_w[order[0]]]
    else:
        order = order[:1]
    group_max = np.full(int(point_index.max()) + 1, -np.inf)
    np.maximum.at(group_max, point_index, row_abs_w)
    taken: list[int] = []
    points: set[int] = set()
    photos: set[int] = set()
    for i in order:
        pt, ph = int(point_index[i]), int(photo_index[i])
        if row_abs_w[i] < group_max[pt] or pt in points or ph in photos:
            continue
        if expand is None:
            twins = np.flatnonzero((point_index == pt) & (row_abs_w >= (1.0 - TWIN_TOLERANCE) * row_abs_w[i]))
        else:
            twins = np.asarray(expand(int(i)), dtype=int)
        taken.extend(int(j) for j in twins)
        points.add(pt)
        photos.update(int(p) for p in photo_index[twins])
    return np.array(taken, dtype=int)


def snoop(project: Project, options: AdjustmentOptions = AdjustmentOptions(),
          blunders: BlunderOptions = BlunderOptions(), first: AdjustmentResult | None = None,
          start: tuple | None = None) -> BlunderResult:
    """Data snooping (module doc) until no row |w| exceeds the critical value, ``max_rejections``
    rows are rejected or ``max_rounds`` adjustments are made.

    procedure "separable" (the default): each taken row brings the rows whose w-tests cannot be told
    from it (separability.inseparable_rows), rejected together as one group; once the rest is
    clean, the rejected groups are re-tested (:func:`retest`) and those that pass are re-admitted,
    and snooping goes on (each group is re-admitted at most once). "classic": the twins rule and no
    re-test (the procedure before issue 18).

    If a re-adjustment fails (a photo or the datum lost too much) or does not converge, the rows
    rejected in that round are taken back (flagged "suspect") and the previous adjustment is the
    result. Raises NumericalFailure when the first adjustment, of all rows, fails; when it does not
    converge, nothing is tested (outcome.untested). first: that adjustment of all rows when the
    caller has made it (``adjust(project, options)``), else it is made here. start: (rejections,
    state, rounds) to start from instead of all rows, robust.robust_start's (``robust-snoop``):
    those rows are left out of the first adjustment (warm-started from the state) and re-tested
    with the groups snooping rejects itself.
    """
    t_start = time.perf_counter()
    m = len(project.image_points)
    keep = np.ones(m, dtype=bool)
    rejected: list[Rejection] = []
    rounds: list[Round] = []
    separable = blunders.procedure == "separable"
    current, before = None, []
    if start is not None:  # the re-weighting's rounds are reported first, but not counted against max_rounds
        initial, state, before = start
        rejected += initial
        keep[[rej.row for rej in initial]] = False
        current, first = warm_start(subset(project, keep), *state), None
    out = _snoop_rounds(project, options, blunders, keep, rejected, rounds, current, first)
    if isinstance(out, BlunderResult):
        return out
    stopped, last = out
    readmitted: set[int] = set()
    while separable and stopped == "clean" and rejected:
        back = retest(project, options, blunders, keep, rejected, last[1], readmitted)
        if not len(back):
            break
        readmitted.update(rejected[i].group for i in back)
        gone = {rejected[i].row for i in back}
        keep[list(gone)] = True
        rejected[:] = [rej for rej in rejected if rej.row not in gone]
        start = warm_start(subset(project, keep), last[1].state, last[1].offset)
        stopped, last = _snoop_rounds(project, options, blunders, keep, rejected, rounds, start)
    factor = np.ones((m, 2))
    for _ in range(READMIT_PASSES if separable else 0):
        out_now = [rej for rej in rejected if not keep[rej.row]]
        back = readmit_coordinates(project, options, blunders, out_now, last[1], factor) \
            if stopped == "clean" and out_now else None
        if back is None:
            break
        saved = (keep.copy(), list(rejected), len(rounds), factor.copy())
        factor[back[0], back[1]] = RETEST_SIGMA_FACTOR
        weighted = _scaled(project, factor)
        keep[back[0]] = True
        start = warm_start(subset(weighted, keep), last[1].state, last[1].offset)
        try:
            stopped, last = _snoop_rounds(weighted, options, blunders, keep, rejected, rounds, start)
        except NumericalFailure:
            keep[:], rejected[:], factor = saved[0], saved[1], saved[3]
            del rounds[saved[2]:]
            break
        latest = {rej.row: k for k, rej in enumerate(rejected)}  # a row rejected again: its last rejection
        rejected[:] = [rej for k, rej in enumerate(rejected) if latest[rej.row] == k]
        factor[~keep] = 1.0
    partial = bool(np.any(factor > 1.0))
    if partial:
        last = _without_coordinates(*last, factor)
    rounds[:0] = before
    det = blunder_result("snoop", project, FinalAdjustment(*last), rejected, rounds, stopped,
                         time.perf_counter() - t_start, weights=weights.weight(factor) if partial else None)
    if partial:
        _flag_rejected(det, rejected)
    return det


def _scaled(project: Project, factor: np.ndarray) -> Project:
    """The project with the sigmas of its image points times factor (m, 2)."""
    ip = project.image_points
    return replace(project, image_points=replace(ip, sigma_xy=ip.sigma_xy * factor))


def _without_coordinates(current, result, rel, rows, factor):
    """The last adjustment (current, result, rel, rows) with the coordinates kept at
    ``RETEST_SIGMA_FACTOR`` times their sigma (factor (m, 2) over the original rows) taken out of its
    redundancy and v^T P v (each adds about 1 to the redundancy and nothing to v^T P v), and their w,
    redundancy, MDB and BNR nan, like a rejected row's."""
    i, j = np.nonzero(factor[rows] > 1.0)
    for name in ("w", "redundancy", "mdb", "bnr"):
        getattr(rel, name)[i, j] = np.nan
    sigma = current.image_points.sigma_xy[i, j]
    vtpv = result.vtpv - float(np.sum(weights.whiten(result.plate_residuals[i, j], sigma) ** 2))
    redundancy = result.redundancy - len(i)
    result = replace(result, vtpv=vtpv, redundancy=redundancy, sigma0=sigma0_of(vtpv, redundancy))
    return current, result, rel, rows


def _flag_rejected(det: BlunderResult, rejected: list[Rejection]) -> None:
    """Flags of rejected rows kept for one coordinate (readmit_coordinates): "rejected", or
    "inseparable" for the members of a group of several, as blunder_result flags rejected rows."""
    sizes: dict[int, int] = {}
    for rej in rejected:
        sizes[rej.group] = sizes.get(rej.group, 0) + 1
    for rej in rejected:
        det.flag[rej.row] = FLAG_INSEPARABLE if rej.group >= 0 and sizes[rej.group] > 1 else FLAG_REJECTED


def rejected_axes(rejected: list[Rejection]) -> np.ndarray:
    """(len(rejected),) the coordinate (0 x, 1 y) each rejected row was rejected for: that of the
    larger |w| of its group's lead row (the first rejected of the group), the row tested; the
    members of an inseparable group are inseparable in that coordinate."""
    lead: dict[int, int] = {}
    axes = np.zeros(len(rejected), dtype=int)
    for k, rej in enumerate(rejected):
        key = rej.group if rej.group >= 0 else -1 - k
        if key not in lead:
            lead[key] = int(np.argmax(np.nan_to_num(np.abs(rej.w), nan=-np.inf)))
        axes[k] = lead[key]
    return axes


def readmit_coordinates(project: Project, options: AdjustmentOptions, blunders: BlunderOptions,
                        rejected: list[Rejection], result, factor: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The rejected rows whose other coordinate comes back (snoop, procedure "separable"): a gross
    error spoils x or y, and a group is inseparable in one coordinate (x along the strip,
    docs/reliability.md); removing whole rows also removes clean coordinates, which costs ground
    accuracy.

    Once snooping is clean: one adjustment of all rows with the rejected ones at
    ``RETEST_SIGMA_FACTOR`` times their sigma gives every rejected coordinate its studentised gross
    error u (as :func:`retest`); the other coordinate (rejected_axes) of each rejected row whose u
    is finite and below the critical value comes back at full weight, while the rejected one stays at
    ``RETEST_SIGMA_FACTOR`` times its sigma (1e-6 of its weight) and the snooping rounds go on
    (:func:`snoop`). -> (rows (k,), their rejected axis (k,)) or None (none passes, or the adjustment
    failed)."""
    ip = project.image_points
    gone = np.array([rej.row for rej in rejected], dtype=int)
    axes = rejected_axes(rejected)
    factor = factor.copy()
    factor[gone] = RETEST_SIGMA_FACTOR
    weighted = _scaled(project, factor)
    try:
        res = adjust(warm_start(weighted, result.state, result.offset), options)
        if not succeeded(res):
            return None
        cof = residual_cofactors(weighted, res, options)
    except NumericalFailure:
        return None
    u = studentised_gross_errors(res.plate_residuals, cof.plate, weighted.image_points.sigma_xy**2, ip.sigma_xy**2)
    other = u[gone, 1 - axes]
    ok = np.isfinite(other) & (other <= critical_value(blunders.alpha0))
    return (gone[ok], axes[ok]) if np.any(ok) else None


RETEST_SIGMA_FACTOR = 1e3  # the rejected rows are re-tested at this many times their sigma
READMIT_PASSES = 3  # readmit_coordinates and further rounds at most this many times


def retest(project: Project, options: AdjustmentOptions, blunders: BlunderOptions, keep: np.ndarray,
           rejected: list[Rejection], result, readmitted: set[int]) -> np.ndarray:
    """Indices into ``rejected`` of the rows of the groups that pass a re-test against the clean rest.

    One adjustment of all rows with the rejected ones at ``RETEST_SIGMA_FACTOR`` times their
    sigma (so they hardly pull the solution) gives every rejected coordinate its studentised gross
    error u (robust.studentised_gross_errors): the |w| it would have at full weight among the clean
    rows. A group passes when every coordinate of every member has a finite u below the critical
    value; groups already re-admitted once are not re-tested. Members of one inseparable group are
    re-tested with the others still out, so a group that took its point's conditions with it
    (u nan) stays rejected."""
    ip = project.image_points
    gone = np.flatnonzero(~keep)
    factor = np.ones(len(ip))
    factor[gone] = RETEST_SIGMA_FACTOR
    weighted = replace(project, image_points=replace(ip, sigma_xy=ip.sigma_xy * factor[:, None]))
    try:
        res = adjust(warm_start(weighted, result.state, result.offset), options)
        if not succeeded(res):
            return np.zeros(0, dtype=int)
        cof = residual_cofactors(weighted, res, options)
    except NumericalFailure:
        return np.zeros(0, dtype=int)
    u = studentised_gross_errors(res.plate_residuals, cof.plate, weighted.image_points.sigma_xy**2, ip.sigma_xy**2)
    crit = critical_value(blunders.alpha0)
    ok_row = np.all(np.isfinite(u) & (u <= crit), axis=1)
    groups: dict[int, list[int]] = {}
    for k, rej in enumerate(rejected):
        groups.setdefault(rej.group, []).append(k)
    back = [k for g, ks in groups.items() if g not in readmitted and all(ok_row[rejected[k].row] for k in ks)
            for k in ks]
    return np.array(back, dtype=int)


STOPPED_DISTANCE = "distance: a row of distances.csv has the largest |w| (flagged suspect there, not rejected)"


def _distance_leads(distance_w: np.ndarray, row_abs_w: np.ndarray, crit: float) -> bool:
    """Whether a distance's |w| exceeds the critical value and every plate row's |w|."""
    a = np.abs(distance_w[np.isfinite(distance_w)])
    return bool(len(a) and a.max() > crit and a.max() >= row_abs_w.max(initial=0.0))


def _snoop_rounds(project, options, blunders, keep, rejected, rounds, current, first=None):
    """Snooping rounds from the rows ``keep`` (updated in place, as ``rejected`` and ``rounds``);
    first: the adjustment of the first round when already made (of all rows, current None).
    -> (stopped, last) with last = (project, result, reliability, rows) of the last adjustment that
    succeeded, or a BlunderResult when the first adjustment of all rows did not converge."""
    t_start = time.perf_counter()
    separable = blunders.procedure == "separable"
    ip = project.image_points
    limit = blunders.rejection_limit(len(ip))
    crit = critical_value(blunders.alpha0)
    current = subset(project, keep) if current is None else current
    stopped = "clean"
    last = None
    taken_rows = np.zeros(0, dtype=int)
    while True:
        t0 = time.perf_counter()
        try:
            result = first if last is None and first is not None else adjust(current, options)
            if not succeeded(result):
                if last is None and not rejected:
                    return untested("snoop", project, result, blunders, time.perf_counter() - t_start)
                raise NumericalFailure(result.termination_message.splitlines()[0])
        except (NumericalFailure, InputError) as exc:  # InputError: a distance point left with one ray
            if last is None:
                raise
            keep[taken_rows] = True
            del rejected[len(rejected) - len(taken_rows):]
            rounds[-1].rejected = 0
            stopped = f"failure: {exc}"
            break
        rel = plate_reliability(current, result, options, blunders.alpha0, blunders.beta0)
        rows = np.flatnonzero(keep)
        last = (current, result, rel, rows)
        abs_w = row_abs(rel.w)
        if _distance_leads(rel.distance_w, abs_w, crit):
            # a distance has the largest |w| above the critical value: the plate rows whose w it
            # raises are not rejected for it, and the distance itself is flagged, not rejected
            # (docs/decisions.md, "Distances between object points")
            rounds.append(Round(0, float(np.nanmax(np.abs(rel.distance_w))), result.iterations,
                                time.perf_counter() - t0))
            stopped = STOPPED_DISTANCE
            break
        sub = current.image_points
        expand, members = None, {}
        may_take = limit - len(rejected) > 0 and len(rounds) + 1 < blunders.max_rounds  # as below
        if separable and may_take and np.any(abs_w > crit):
            # the w-tests' correlations of the points of the rows that may be taken (select_rejections
            # expands only those): their blocks of Qvv, formed now (a clean round forms none, nor
            # one whose picks are dropped at the limits)
            suspects = np.zeros(len(current.points), dtype=bool)
            suspects[sub.point_index[abs_w > crit]] = True
            corr = Correlations(plate_blocks_of(current, result, options, suspects), len(sub))

            def expand(i):
                members[i] = inseparable_rows(corr, i, rel.w, crit)
                return members[i]
        picks = select_rejections(sub.point_index, sub.photo_index, abs_w, crit, blunders.per_round, expand)
        room = limit - len(rejected)
        if len(picks) and room <= 0:
            stopped, picks = "limit", picks[:0]
        elif len(picks) and len(rounds) + 1 >= blunders.max_rounds:
            stopped, picks = "rounds", picks[:0]
        picks = picks[:room]
        rounds.append(Round(len(picks), float(max(abs_w.max(initial=0.0), 0.0)), result.iterations,
                            time.perf_counter() - t0))
        if not len(picks):
            break
        taken_rows = rows[picks]
        group_of = {}
        next_group = max((rej.group for rej in rejected), default=-1) + 1
        for lead, mem in members.items():
            for j in mem:
                group_of[int(j)] = next_group
            next_group += 1
        for i, row in zip(picks, taken_rows):
            g = group_of.get(int(i))
            if g is None:
                g, next_group = next_group, next_group + 1
            rejected.append(Rejection(int(row), int(ip.photo_index[row]), int(ip.point_index[row]), len(rounds),
                                      rel.w[i].copy(), rel.mdb[i].copy(), group=g))
        keep[taken_rows] = False
        current = warm_start(subset(project, keep), result.state, result.offset)
    return stopped, last
