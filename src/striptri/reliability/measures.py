"""Reliability measures of one adjustment: redundancy numbers, w-test, MDB, bias-to-noise ratio.

Per plate coordinate i with a-priori standard deviation sigma_i (a-priori sigma0 = 1: the plate
sigmas are taken as known, as in precision.py):

* redundancy number ``r_i = qvv_i / q_i`` in [0, 1] (precision.residual_cofactors);
* normalised residual ``w_i = v_i / sqrt(qvv_i)`` of Baarda's w-test, N(0, 1) without a gross error;
* minimal detectable bias ``MDB_i = sigma_i delta0 / sqrt(r_i)`` (internal reliability): the
  smallest gross error the w-test of size alpha0 finds with probability beta0;
* bias-to-noise ratio ``delta0 sqrt((1 - r_i) / r_i)`` (external reliability): the effect of an
  undetected MDB_i on all estimated quantities (orientations and points together) in units of
  their own precision, ``sqrt(dx^T Qxx^-1 dx)``; its effect on the orientations alone is at most
  this.

``delta0`` is the non-centrality of the w-test, ``z(1 - alpha0/2) + z(beta0)``: 4.13 for Baarda's
alpha0 = 0.001 (two-sided) and beta0 = 0.80. The far tail of the two-sided test (the mean shifted
by delta0 yet w below -z(1 - alpha0/2), probability below 1e-9) is neglected, as in Baarda's tables.

A coordinate with ``r_i <= R_ZERO`` is checked by no condition (a tie point left in one photo, a
height point in one photo): w = nan and MDB = inf, a gross error there cannot be found. Small but
non-zero redundancy numbers are real and reported as they are: the x coordinate of a tie point in
two photos of a strip (r ~ 1e-4: the base is along x, only y-parallax is checked) has a finite w
and an MDB of hundreds of sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri  # the normal quantile; scipy.stats would cost 0.4 s of imports

from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult
from ..model import Project
from ..precision.residuals import residual_cofactors
from ..equations import weights

ALPHA0 = 0.001  # size of the w-test, two-sided (Baarda)
BETA0 = 0.80  # its power against a gross error of the minimal detectable size
R_ZERO = 1e-9  # a redundancy number at or below this is zero (the coordinate is not checked)


def critical_value(alpha0: float = ALPHA0) -> float:
    """Critical value of the two-sided w-test of size alpha0 (3.29 for 0.001)."""
    return float(-ndtri(alpha0 / 2))


def noncentrality(alpha0: float = ALPHA0, beta0: float = BETA0) -> float:
    """delta0 = z(1 - alpha0/2) + z(beta0): the mean of w at which the two-sided test of size alpha0
    rejects with probability beta0 (Baarda 1968; 4.13 for 0.001 and 0.80)."""
    return float(-ndtri(alpha0 / 2) + ndtri(beta0))


def minimal_detectable_bias(sigma: np.ndarray, r: np.ndarray, delta0: float) -> np.ndarray:
    """MDB = sigma delta0 / sqrt(r), in the units of sigma; inf where r <= R_ZERO."""
    r = np.asarray(r, dtype=float)
    ok = r > R_ZERO
    return np.where(ok, np.asarray(sigma) * delta0 / np.sqrt(np.where(ok, r, 1.0)), np.inf)


# magnitudes of w_x and w_y this close are one statistic (a point of two rays has one condition,
# and all its w are equal but for their signs): row_statistic then takes x's, whatever the round-off
SAME_MAGNITUDE = 1e-9


def row_statistic(w: np.ndarray) -> np.ndarray:
    """The signed w of the larger magnitude of x and y of every row, x's where the two agree to
    SAME_MAGNITUDE relative (a two-ray point's: the last bits of the arithmetic would otherwise
    choose the sign). w: (m, 2) -> (m,); nan where both are nan (the form of residuals.csv's w
    column)."""
    a = np.where(np.isnan(w), -1.0, np.abs(w))
    take_y = a[:, 1] > a[:, 0] * (1.0 + SAME_MAGNITUDE)
    return np.where(take_y, w[:, 1], w[:, 0])


def row_abs(w: np.ndarray) -> np.ndarray:
    """max(|w_x|, |w_y|) of every row. (m, 2) -> (m,); -inf where both are nan."""
    return np.max(np.where(np.isnan(w), -np.inf, np.abs(w)), axis=1, initial=-np.inf)


@dataclass
class PlateReliability:
    """Reliability of every plate coordinate of one adjustment; arrays (m, 2) (x, y) over the rows
    of the adjusted project's ImagePoints."""

    redundancy: np.ndarray  # r_i in [0, 1]; 0 for the rows of points without conditions
    w: np.ndarray  # normalised residuals; nan where r_i <= R_ZERO
    mdb: np.ndarray  # minimal detectable bias (plate units); inf where r_i <= R_ZERO
    bnr: np.ndarray  # bias-to-noise ratio (external reliability); inf where r_i <= R_ZERO
    critical: float
    delta0: float
    # with cofactor_blocks: precision.ResidualCofactors.plate_blocks (the w-tests' correlations)
    cofactor_blocks: list | None = None
    # w (r,) of distances.csv's rows (joint_groups; nan where r_i <= R_ZERO); empty without distances
    distance_w: np.ndarray = field(default_factory=lambda: np.zeros(0))


def plate_reliability(project: Project, result: AdjustmentResult, options: AdjustmentOptions = AdjustmentOptions(),
                      alpha0: float = ALPHA0, beta0: float = BETA0, cofactor_blocks: bool = False) -> PlateReliability:
    """Redundancy numbers, w, MDB and bias-to-noise ratios of the plate coordinates (module doc).
    For both methods: at convergence the bundle's solution is the conditions method's, and the
    cofactors are formed from the conditions at that solution. cofactor_blocks: also each point's
    plate block of Qvv (precision.residual_cofactors), for the w-tests' correlations."""
    cof = residual_cofactors(project, result, options, plate_blocks=cofactor_blocks)
    sigma = project.image_points.sigma_xy
    r = np.clip(weights.weigh(cof.plate, sigma), 0.0, 1.0)
    ok = r > R_ZERO
    safe_r = np.where(ok, r, 1.0)
    delta0 = noncentrality(alpha0, beta0)
    w = np.where(ok, result.plate_residuals / (sigma * np.sqrt(safe_r)), np.nan)
    bnr = np.where(ok, delta0 * np.sqrt((1.0 - r) / safe_r), np.inf)
    return PlateReliability(r, w, minimal_detectable_bias(sigma, r, delta0), bnr, critical_value(alpha0), delta0,
                            cof.plate_blocks, distance_tests(project, cof.distances, cof.distance_adjusted).w)


@dataclass(frozen=True)
class DistanceTests:
    """The w-test of every row of distances.csv (issue 17): v = adjusted - observed (m), qvv (m^2),
    redundancy number r = qvv / sigma^2, w = v / sqrt(qvv) (a-priori sigma0 = 1; nan where
    r <= R_ZERO), mdb (m), the minimal detectable bias (inf there)."""

    v: np.ndarray
    qvv: np.ndarray
    redundancy: np.ndarray
    w: np.ndarray
    mdb: np.ndarray


def distance_tests(project: Project, qvv: np.ndarray, adjusted: np.ndarray, alpha0: float = ALPHA0,
                   beta0: float = BETA0) -> DistanceTests:
    """DistanceTests from the distances' qvv and adjusted values (precision.distance_cofactors)."""
    if not len(qvv):
        z = np.zeros(0)
        return DistanceTests(z, z, z, z, z)
    sigma = project.distances.sigma
    v = adjusted - project.distances.distance
    r = np.clip(weights.weigh(qvv, sigma), 0.0, 1.0)
    ok = r > R_ZERO
    w = np.where(ok, v / (sigma * np.sqrt(np.where(ok, r, 1.0))), np.nan)
    return DistanceTests(v, qvv, r, w, minimal_detectable_bias(sigma, r, noncentrality(alpha0, beta0)))
