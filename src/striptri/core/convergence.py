"""The convergence test of the adjustments, its round-off floors and the divergence rule
(docs/decisions.md "A convergence test that means the same at every size").

Converged: the correction is below ``tolerance`` times the standard deviation in every function of
the unknowns, ``sqrt(dx^T N dx) < tolerance`` with N in units of the a-priori weights
(:func:`correction_in_sigma`): the largest change of any element, distance or angle, each in units
of its own standard deviation. It means the same on a 10-photo strip and a 100,000-photo one.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from . import termination
from ..errors import NumericalFailure
from ..equations.parameters import State, UnknownLayout
from .result import Iteration

ROUNDING_FLOOR = 1e-6  # corrections below this (in standard deviations) that stop shrinking are round-off
# the same per unknown for the measure of the simultaneous adjustments (energy_floor), measured: a
# 10,000-photo strip held at its ends stalls at 2e-9 per unknown, a 100,000-photo strip (coordinates
# of 5e7 m in the reduced frame) at 2e-8
ROUND_OFF_PER_UNKNOWN = 1e-7


ROUND_OFF_ULPS = 64.0  # a correction below this many units in the last place of its element's value is round-off


def round_off_floor(state: State, layout: UnknownLayout) -> np.ndarray:
    """(n_unknowns,) the smallest correction each unknown can meaningfully take in double precision:
    ROUND_OFF_ULPS units in the last place of its value (a centre's largest coordinate in the
    reduced frame; 1 rad for a rotation; a camera element's value). A correction below it is
    round-off however small the element's standard deviation: an element held by a very heavy
    weight (an angle observed with sigma 1e-10 rad) otherwise never shows convergence."""
    eps = ROUND_OFF_ULPS * np.finfo(float).eps
    floor = np.zeros(layout.n_unknowns + 1)  # the last slot takes the -1 columns of held elements
    centre = eps * np.max(np.abs(state.xyz0), axis=1)
    floor[layout.photo_cols[:, :3]] = centre[:, None]
    floor[layout.photo_cols[:, 3:]] = eps
    floor[layout.camera_cols] = eps * np.abs(state.interior)
    return floor[:-1]


def largest_correction(dx: np.ndarray, n_diag: np.ndarray, floor: np.ndarray) -> float:
    """The largest |dx_i| sqrt(N_ii): a correction in units of the standard deviation its element
    would have if all others were known, over the corrections above their element's round-off
    floor (round_off_floor). The sequential method's measure; the simultaneous adjustments use
    :func:`correction_in_sigma`."""
    if not len(dx):
        return 0.0
    size = np.abs(dx)
    return float(np.max(np.where(size > floor, size * np.sqrt(np.maximum(n_diag, 0.0)), 0.0)))


def correction_in_sigma(dx: np.ndarray, N: sp.spmatrix) -> float:
    """The convergence measure of the simultaneous adjustments: ``sqrt(d^T N d)``, the largest
    correction of any function of the unknowns in units of that function's standard deviation.

    For a function ``f^T x`` the correction is ``f^T d`` and the standard deviation (a-priori
    weights) ``sqrt(f^T N^-1 f)``; by the Cauchy-Schwarz inequality in the metric of N
    ``max_f |f^T d| / sqrt(f^T N^-1 f) = sqrt(d^T N d)``, reached for ``f = N d``. So the measure
    bounds every element's correction in units of its true standard deviation, ``sqrt(Qxx_ii)``,
    however strongly the elements are correlated: unlike ``|dx_i| sqrt(N_ii)`` (the standard
    deviation if all other elements were known), which on a long strip is thousands of times
    smaller than the true one and demands corrections along its weak directions far below their
    precision - beyond double precision at 10,000 photos. It is also the decrease of v^T P v (in
    units of sigma0^2) the linearised step brings, its square one matrix-vector product.

    Round-off is a small vector of its own in every direction; it is not masked element by
    element (setting the small corrections of correlated elements to zero breaks the cancellation
    between them and raises the measure tenfold, measured on a 10,000-photo strip), but accepted as
    a whole by has_converged below energy_floor. For a free network (singular N, dx with inner
    constraints) the measure covers the estimable functions."""
    if not len(dx):
        return 0.0
    return float(np.sqrt(max(float(dx @ (N @ dx)), 0.0)))


def chord_correction(dx: np.ndarray, u: np.ndarray) -> float:
    """:func:`correction_in_sigma` of a step that solved ``N dx = -u`` exactly, without N:
    ``dx^T N dx = -dx^T u``. The method of conditions' chord steps (conditions_method.adjust) solve
    on the factor of an earlier N, which they do not keep; this is their correction in its metric."""
    if not len(dx):
        return 0.0
    return float(np.sqrt(max(-float(dx @ u), 0.0)))


def energy_floor(n_unknowns: int, element_floor: np.ndarray | None = None, n_diag: np.ndarray | None = None) -> float:
    """The round-off floor of :func:`correction_in_sigma`, below which a correction that no longer
    halves is accepted as converged (has_converged): ROUND_OFF_PER_UNKNOWN standard deviations in
    each of the n unknowns, independent, so added in quadrature; or, when larger, the largest
    round-off floor of one element (round_off_floor) in units of its standard deviation if all
    others were known, ``max_i floor_i sqrt(N_ii)``: an element held by a very heavy weight (an
    angle observed with sigma 1e-10 rad) cannot be computed to better than that."""
    floor = ROUND_OFF_PER_UNKNOWN * float(np.sqrt(max(n_unknowns, 1)))
    if element_floor is not None and len(element_floor):
        floor = max(floor, float(np.max(element_floor * np.sqrt(np.maximum(n_diag, 0.0)))))
    return floor


CONTRACTION_MAX = 0.5  # the rate below which the next correction is predicted from the last two
STALLED = 0.5  # a correction below the round-off floor that shrinks by less than this factor has stalled


def has_converged(history: list[Iteration], tolerance: float, floor: float = ROUNDING_FLOOR) -> bool:
    """The stated criterion: the last correction is below ``tolerance`` (in the history's measure:
    standard deviations); or the correction the next iteration would make, predicted as the last
    one times the slower of the last two rates of contraction (``c_k max(c_k / c_(k-1),
    c_(k-1) / c_(k-2))``, both below CONTRACTION_MAX), is below it, so that the iteration that
    would only confirm convergence is saved (the final checks still form that correction and
    report it); or the iteration has reached the round-off floor of double precision (below
    ``floor``, by default ROUNDING_FLOOR, and no longer halving), which for very long strips with
    coordinates of thousands of kilometres lies above the tolerance.

    The slower of two rates, not the last one alone: Gauss-Newton contracts quadratically at first
    and linearly near a solution with residuals (measured: a strip with GNSS centres and no
    control went 2.2 -> 2.8e-5 -> 1.2e-7 -> 1.4e-9 sd, where the last rate alone predicted 4e-10
    after 2.8e-5)."""
    c = history[-1].max_correction
    if c < tolerance:
        return True
    if len(history) < 2:
        return False
    previous = history[-2].max_correction
    if len(history) >= 3 and 0.0 < c < CONTRACTION_MAX * previous:
        before = history[-3].max_correction
        if 0.0 < previous < CONTRACTION_MAX * before and c * max(c / previous, previous / before) < tolerance:
            return True
    return c < floor and c > STALLED * previous


# Chord steps (docs/decisions.md "Chord steps on the last factor", "Chord steps in the bundle"):
# the next iteration solves on the factor the solver holds (an earlier N's) while the last
# correction is below REUSE_FACTOR_BELOW standard deviations and shrank by CHORD_RATE or more
# against the one before (or lies below the round-off floor); else N is factorised anew.
REUSE_FACTOR_BELOW = 100.0
CHORD_RATE = 0.01


def keeps_factor(history: list[Iteration], floor: float) -> bool:
    """Whether the next iteration may solve on the factor the solver holds (a chord step). A chord
    step's rate of contraction is about the change of N since its factor, which near the solution
    is what the last Gauss-Newton step's contraction shows: so the last correction must be below
    REUSE_FACTOR_BELOW sd and below CHORD_RATE times the one before it (a first iteration, e.g. a
    re-adjustment from a solution, has none before it). A correction below the round-off floor
    ``floor`` (energy_floor) no longer shows a rate: it keeps the factor too. Both methods use it."""
    last = history[-1].max_correction
    if not last < REUSE_FACTOR_BELOW:
        return False
    return len(history) < 2 or last < floor or last < CHORD_RATE * history[-2].max_correction


# The divergence rule (stop_if_diverging): corrections that grow by more than DIVERGENCE_GROWTH in
# each of DIVERGENCE_RUN iterations in a row and end above DIVERGENCE_SIZE standard deviations.
# Gauss-Newton near a solution shrinks its corrections; a start far from one may grow them for an
# iteration or two, but four doublings in a row to a correction of a million standard deviations
# are a walk away from any solution, and more iterations only make the numbers overflow. A
# correction that grows less, or stays small, is left to the iteration limit, whose message says
# whether it was still shrinking (termination.iteration_limit).
DIVERGENCE_RUN = 4
DIVERGENCE_GROWTH = 2.0
DIVERGENCE_SIZE = 1e6


def stop_if_diverging(history: list[Iteration], method: str, redundancy: int = 0, causes=None) -> None:
    """Raise NumericalFailure, explained (termination.diverged: the last figures of the history and
    the likely cause, ``causes()`` called only then), when the iteration diverges: non-finite
    numbers, or corrections growing for four iterations in a row far beyond a first step (in
    Iteration.element_correction where it is known, else max_correction)."""
    last = history[-1]
    n = DIVERGENCE_RUN + 1
    c = [h.max_correction if math.isnan(h.element_correction) else h.element_correction for h in history[-n:]]
    growing = (len(c) == n and all(b > DIVERGENCE_GROWTH * a for a, b in zip(c, c[1:]))
               and c[-1] > DIVERGENCE_SIZE)
    if np.isfinite(last.max_correction) and np.isfinite(last.vtpv) and not growing:
        return
    raise NumericalFailure(termination.diverged(method, history, redundancy, causes or (lambda: [])),
                           reason="diverged")
