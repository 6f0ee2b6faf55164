"""Levenberg-Marquardt damping of the bundle adjustment (docs/solvers.md): taken only when a
Gauss-Newton step fails, grown after every failed step, relaxed by Nielsen's rule after a good one."""

from __future__ import annotations

import copy

import numpy as np
import scipy.sparse as sp

from .reduced import ReducedNormals

LM_START = 1e-4  # first Levenberg-Marquardt factor after a failed step
LM_MAX = 1e8  # beyond this the step is a gradient step of nothing; give up
LM_FLOOR = 1e-9  # below this the damping is dropped (plain Gauss-Newton again)
ROUND_OFF = 1e-10  # a rise of the sum of squares below this fraction is round-off, not a worse step
COST_ROUND_OFF = 1e-20  # and below this per observation (whitened residuals of 1e-10 sigma)


class Damping:
    """The Levenberg-Marquardt factor ``lam`` (0: plain Gauss-Newton) and its growth ``nu``:
    ``more`` after a failed step (from LM_START, doubling the growth each time), Nielsen's rule on
    the ratio of the actual to the predicted reduction after a good one, back to 0 below LM_FLOOR."""

    def __init__(self):
        self.lam, self.nu = 0.0, 2.0

    def exhausted(self) -> bool:
        return self.lam * self.nu > LM_MAX

    def more(self) -> None:
        self.lam, self.nu = max(self.lam * self.nu, LM_START), 2.0 * self.nu

    def after_good_step(self, actual: float, predicted: float, round_off: float = 0.0) -> None:
        """Nielsen's rule on rho = actual / predicted reduction of the sum of squares. A predicted
        reduction within ``round_off`` (the rise of the sum that counts as round-off, bundle.adjust)
        is a step at the minimum, where both numbers are round-off and their ratio means nothing:
        rho is taken as 1 there. (Their ratio had multiplied the damping by 2e11 in one step at the
        minimum of a free network, 4.7e-9 -> 1.1e3, and every step after it failed.)"""
        if self.lam > 0.0:
            rho = actual / predicted if predicted > round_off else 1.0
            self.lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            self.lam = self.lam if self.lam >= LM_FLOOR else 0.0
        self.nu = 2.0

    def applied(self, normals: ReducedNormals) -> ReducedNormals:
        """The normals with lam * max(diag of J^T J, diag of N) added to the reduced camera system."""
        if self.lam == 0.0:
            return normals
        damped = copy.copy(normals)
        damped.N = (normals.N + self.lam * sp.diags(np.maximum(normals.d, normals.N.diagonal()))).tocsr()
        return damped
