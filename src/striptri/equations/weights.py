"""Where a standard deviation becomes a weight: the only place (issue 27).

An observation l with standard deviation sigma (a priori, sigma0 = 1) has the weight
``p = 1 / sigma^2``; a least-squares method either multiplies its normal-equation terms by p or
*whitens* the observation equation, dividing its row and misclosure by sigma, so that the whitened
residuals have unit variance and ``v^T P v`` is their sum of squares. Every method, the precision,
the reliability measures, the pre-analysis and the fiducial transformation turn sigmas into weights
through these functions, so that the rule is written once.

Each function keeps the exact floating-point operations its callers used before (``1 / sigma^2``
is not ``(1 / sigma)^2`` in the last bit): outputs stay the same byte for byte. Arrays broadcast;
nothing here checks that sigma > 0 (the readers do, core.diagnosis judges the sizes).
"""

from __future__ import annotations

import numpy as np


def weight(sigma):
    """``p = 1 / sigma^2`` of observations with standard deviations ``sigma``."""
    return 1.0 / sigma**2


def weigh(x, sigma):
    """``x p = x / sigma^2``: a quantity (a cofactor, a row of the design matrix) times the weight
    of the observation with standard deviation ``sigma``."""
    return x / sigma**2


def variance_weight(q, observed):
    """``1 / q`` where ``observed``, 0 elsewhere: the weights of the coordinates of object points
    (q their variances; held or not given coordinates have no weight, whatever q holds there)."""
    return np.where(observed, 1.0 / np.where(observed, q, 1.0), 0.0)


def inverse_variance(q):
    """``p = 1 / q``: the weights of observations with variances q (of the plate coordinates,
    core.observations' q_plate)."""
    return 1.0 / q


def whiten(x, sigma):
    """``x / sigma``: a misclosure, a residual or a row of the design matrix whitened by the
    standard deviation of its observation."""
    return x / sigma


def whitening(q):
    """The standard deviations ``sigma = sqrt(q)`` (of variances q, (..., 2) for plate
    coordinates) and the factors ``1 / sigma`` with a trailing axis, (..., 2, 1), that whiten the
    rows of Jacobians (..., 2, n)."""
    sigma = np.sqrt(q)
    return sigma, (1.0 / sigma)[..., None]


def inverse_sigma(q):
    """``1 / sqrt(q)``: the whitening factor of a condition from its propagated variance q
    (Schmid's conditions carry the plate-coordinate errors of their rays, ``q = A Q A^T``)."""
    return 1.0 / np.sqrt(q)
