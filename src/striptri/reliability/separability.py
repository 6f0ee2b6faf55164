"""Separability of the w-tests: which plate coordinates a gross error can be told apart between.

The residuals of the rays of one point are correlated: their cofactor matrix is the point group's
block of Qvv (:func:`plate_cofactor_blocks`, the same ``K A Q`` products as
``precision.residual_cofactors``, whose diagonal it extends), and the correlation of the w-tests
of coordinates i and j is ``rho_ij = qvv_ij / sqrt(qvv_ii qvv_jj)``. A gross error nabla in i
moves w_i by ``nabla sqrt(qvv_ii) / q_i`` and w_j by rho_ij times that: when |rho_ij| is near 1 the
two w-tests see the same thing and the largest |w| may sit in either -- the gross error is
*detected but not localisable*. (The three x coordinates of a point seen by three photos of one
strip are checked by one scale transfer: |rho| ~ 1.)

Criterion (docs/reliability.md, "Separability"): under a gross error that moves w_i to delta,
E[w_j] = rho delta; the difference ``|w_i| - |w_j|`` has expectation ``delta (1 - |rho|)`` and
variance ``2 (1 - |rho|)``. The largest |w| picks the right coordinate reliably when that
expectation is k standard deviations of the difference (k = the critical value, 3.29):
``delta (1 - |rho|) >= k sqrt(2 (1 - |rho|))``, i.e. ``|rho| <= 1 - 2 k^2 / delta^2``. The test
uses delta = the candidate's own |w| (the error as observed): a 20-sigma error seen at |w| = 20 is
told from coordinates with |rho| below 1 - 2 (3.29/20)^2 = 0.946. The threshold is kept within
[RHO_MIN, RHO_MAX] = [0.9, 0.99]: just above the critical value the formula would put every ray
of a point in one group (an error of the MDB is never localised with certainty), which would throw
away well-checked points for a marginal w; pairs above 0.99 are never told apart. Within a point of
the blocks studied the correlations are either above 0.998 (the x of the rays of a three-ray
strip point; the four coordinates of a two-ray point) or below 0.7, so the groups do not depend on
where in [0.9, 0.99] the threshold falls.
Coupling beyond the point (through the orientations) is weaker by an order of magnitude in the
blocks studied and is not used.
"""

from __future__ import annotations

import numpy as np

from ..equations.linearise import At, Sweep, precision_options
from ..equations import ray_columns
from ..equations.observations import observations_of
from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult
from ..equations.groups import build_batches
from ..model import Project
from ..precision.residuals import group_inverse, group_slots


def plate_cofactor_blocks(project: Project, result: AdjustmentResult,
                          options: AdjustmentOptions = AdjustmentOptions()) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per chunk of point groups: (image_rows (m, k), Qvv (m, 2k, 2k)), the plate part of each
    group's residual cofactor matrix, coordinates ordered (x, y) per ray in chain order (plate
    units squared). The diagonal equals ``residual_cofactors(...).plate`` (tested)."""
    obs = observations_of(project, result.offset)
    sweep = Sweep(build_batches(project), At.of_result(result, obs), precision_options(options))
    out = []
    for chunk, s in sweep.systems():
        m, k = chunk.image_rows.shape
        AQ = s.A[:, :, : 2 * k] * s.Q[:, None, : 2 * k]
        AQfull = s.A * s.Q[:, None, :]
        M = AQfull @ np.swapaxes(s.A, 1, 2)
        Minv, bad = group_inverse(M, chunk)  # degenerate groups: untested, no block
        K = Minv @ (M - result.covariance.group_forms(group_slots(s.B, chunk, result, ray_columns.of_system(s)))) @ Minv
        good = ~bad
        if good.any():
            out.append((chunk.image_rows[good], np.swapaxes(AQ[good], 1, 2) @ K[good] @ AQ[good]))
    return out


def separability_threshold(abs_w: float | np.ndarray, critical: float) -> np.ndarray:
    """|rho| above which a coordinate cannot be told from one whose |w| is abs_w (module doc):
    ``1 - 2 (critical / abs_w)^2`` within [RHO_MIN, RHO_MAX]."""
    a = np.maximum(np.asarray(abs_w, dtype=float), 1e-300)
    return np.clip(1.0 - 2.0 * (critical / a) ** 2, RHO_MIN, RHO_MAX)


RHO_MAX = 0.99  # pairs correlated above this are never told apart, whatever the size of the error
RHO_MIN = 0.9  # pairs correlated below this are always told apart


class Correlations:
    """Correlations of the w-tests of the plate coordinates within each point group.

    Built from :func:`plate_cofactor_blocks` over the rows of ``project.image_points``.
    ``of_row(i)`` -> (rows (n,), rho (n, 2, 2)): the rows of i's point and the correlation of i's
    (x, y) w-tests with theirs (rho[a, c, d]: coordinate c of row i with coordinate d of rows[a])."""

    def __init__(self, blocks, m: int):
        self._where = np.full((m, 2), -1, dtype=int)  # (block, group) of every row
        self._pos = np.full(m, -1, dtype=int)
        self._blocks = []
        for b, (rows, qvv) in enumerate(blocks):
            d = np.sqrt(np.maximum(np.diagonal(qvv, axis1=1, axis2=2), 0.0))
            with np.errstate(invalid="ignore", divide="ignore"):
                rho = qvv / (d[:, :, None] * d[:, None, :])
            self._blocks.append((rows, rho))
            g, j = np.nonzero(rows >= 0)
            self._where[rows[g, j]] = np.stack([np.full(len(g), b), g], 1)
            self._pos[rows[g, j]] = j

    def of_row(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        b, g = self._where[i]
        if b < 0:
            return np.zeros(0, dtype=int), np.zeros((0, 2, 2))
        rows, rho = self._blocks[b]
        k = rows.shape[1]
        j = self._pos[i]
        r = rho[g].reshape(k, 2, k, 2)[j]  # (2, k, 2)
        return rows[g], np.nan_to_num(np.moveaxis(r, 1, 0), nan=0.0)


def inseparable_rows(corr: Correlations, i: int, w: np.ndarray, critical: float) -> np.ndarray:
    """The rows (i first) whose w-tests cannot be told from row i's largest one (module doc).
    w: (m, 2) normalised residuals of the rows of the adjusted project."""
    c = int(np.nanargmax(np.where(np.isnan(w[i]), -1.0, np.abs(w[i]))))
    rows, rho = corr.of_row(i)
    if not len(rows):
        return np.array([i])
    limit = separability_threshold(abs(w[i, c]), critical)
    close = np.max(np.abs(rho[:, c, :]), axis=1) > limit
    close &= rows != i
    return np.concatenate([[i], rows[close]]).astype(int)
