"""Reliability of the plate measurements and gross-error (blunder) detection (DESIGN section 6).

* :mod:`.measures` -- of one adjustment: redundancy numbers, Baarda's w-test, minimal detectable
  bias (MDB) and bias-to-noise ratio of every plate coordinate (:func:`plate_reliability`);
* :mod:`.snooping` -- data snooping with iterative rejection (:func:`snoop`): inseparable groups
  rejected together, rejected groups re-tested and re-admitted (procedure "separable");
* :mod:`.separability` -- the point groups' blocks of Qvv and the correlations of the w-tests;
* :mod:`.rejections` -- per rejected group its w, MDB, bias-to-noise ratio and ground effect;
* :mod:`.robust` -- iteratively reweighted least squares with a Danish-type weight function,
  then the survivors adjusted at full weight (:func:`robust`);
* :mod:`.outcome` -- :class:`BlunderOptions`, :class:`BlunderResult` and what both share.

:func:`detect_blunders` runs the method ``BlunderOptions.method`` names: "snoop", "robust", or
"off" (one adjustment; rows with |w| above the critical value are flagged "suspect").

The unit rejected is the *image point*, one row of ImagePoints (x and y of one point on one
photo): a gross error of identification or transcription spoils both coordinates. The test
statistic of a row is the larger |w| of its two coordinates. Rejected rows are removed (a new
Project through dataclasses.replace) and each re-adjustment starts from the previous adjusted
orientations (outcome.warm_start; observed elements keep their observed values), so it takes
few iterations. A point that loses so many rays
that no condition is left drops out; its remaining rows are flagged "dropped".
Both adjustment methods ("conditions", "bundle") are served alike. docs/reliability.md has the
choices and the measured detection rates.
"""

from __future__ import annotations

from dataclasses import replace

from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult
from ..model import Project
from .measures import (
    ALPHA0,
    BETA0,
    R_ZERO,
    PlateReliability,
    critical_value,
    minimal_detectable_bias,
    noncentrality,
    plate_reliability,
    row_statistic,
)
from .outcome import (
    BLUNDER_METHODS,
    FLAG_DROPPED,
    FLAG_INSEPARABLE,
    FLAG_OK,
    FLAG_REJECTED,
    FLAG_SUSPECT,
    FLAGS,
    PER_ROUND,
    PROCEDURES,
    BlunderOptions,
    BlunderResult,
    Rejection,
    Round,
    blunder_options,
    predicted_residuals,
    subset,
    triangulate_adjusted,
    warm_start,
)
from .robust import robust, robust_start, robust_weight, studentised_gross_errors
from .snooping import select_rejections, snoop


def detect_blunders(project: Project, options: AdjustmentOptions = AdjustmentOptions(),
                    blunders: BlunderOptions = BlunderOptions(), first: AdjustmentResult | None = None) -> BlunderResult:
    """The blunder procedure ``blunders.method`` (module doc) on ``project``; first: the adjustment
    of all rows, ``adjust(project, options)``, when the caller has made it (the pipeline does, as
    its own step), else it is made here. Method "off" tests that adjustment and rejects nothing.
    Raises NumericalFailure when the adjustment of all rows fails."""
    if blunders.method == "snoop":
        return snoop(project, options, blunders, first)
    if blunders.method == "robust":
        return robust(project, options, blunders, first)
    if blunders.method == "robust-snoop":
        start = robust_start(project, options, blunders, first)
        if isinstance(start, BlunderResult):
            return start
        out = snoop(project, options, blunders, None, start)
        out.method = "robust-snoop"
        return out
    out = snoop(project, options, replace(blunders, max_rejections=0), first)
    out.method, out.stopped = "off", "off"
    return out


__all__ = [
    "ALPHA0", "BETA0", "BLUNDER_METHODS", "FLAGS", "FLAG_DROPPED", "FLAG_INSEPARABLE", "FLAG_OK", "FLAG_REJECTED", "FLAG_SUSPECT",
    "PER_ROUND", "PROCEDURES", "R_ZERO", "BlunderOptions", "BlunderResult", "PlateReliability", "Rejection", "Round", "blunder_options",
    "critical_value", "detect_blunders", "minimal_detectable_bias", "noncentrality", "plate_reliability",
    "predicted_residuals", "robust", "robust_weight", "row_statistic", "select_rejections", "snoop",
    "studentised_gross_errors", "subset", "triangulate_adjusted", "warm_start",
]
