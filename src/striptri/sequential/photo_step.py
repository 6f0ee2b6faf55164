"""One step of the sequential method: the orientation of a new photograph j with the preceding
photograph i held (Schut's procedures 1 and 2), by the general case of least squares.

Conditions, each a function of plate coordinates (the observations) and the unknowns of photo j:

* coplanarity of the rays of a point in i and j with the base (Schmid 20), one condition with the
  four plate coordinates x_i, y_i, x_j, y_j as observations;
* collinearity of a known (held) point with photo j (Schmid 14), two conditions, one per plate
  coordinate.

Unknowns (``mode``):

* ``"relative"`` (procedure 1, dependent relative orientation): the rotation vector of photo j
  (``R_j <- R_j Exp(d)``) and the two base components ``b_cam = R_i^T (O_j - O_i)`` other than
  ``held_axis``, which stays at its starting value (Schut's bx held at the approximate base);
* ``"full"`` (procedure 2, Schmid's "(20) & (14)", and the resection after a strip correction):
  the centre of photo j (3) and its rotation vector (3).

Linearised at the adjusted observations (Pope 1972, DESIGN section 4): ``A v + B dx + w = 0`` with
``w = g(l^, x^) + A (l - l^)``; the conditions share no observation, so ``M = A Q A^T`` is diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..geometry.camera import plate_vector
from ..equations.conditions import RayConditions, collinearity, coplanarity, ray_chain
from ..core.convergence import has_converged
from ..errors import NumericalFailure
from ..geometry.rotations import exp_so3
from ..core.termination import table

MODES = ("relative", "full")


class StepIteration(NamedTuple):
    """One iteration of a step: v^T P v and the largest correction in standard deviations (the
    fields of core.result.Iteration that termination.table reads)."""

    vtpv: float
    max_correction: float


@dataclass
class PhotoStep:
    """Result of one step. R_j, O_j: the new photo in the model frame; b_cam: the base in the frame
    of photo i (relative mode); plate_cop: (m, 4) adjusted plate coordinates of the coplanarity
    points (x_i, y_i, x_j, y_j); vtpv, n_conditions, n_unknowns, iterations, converged, max_correction;
    N: the normal matrix of the step (in its own unknowns); history: every iteration's v^T P v and
    largest correction (StepIteration), for the message of a step that did not converge."""

    R_j: np.ndarray
    O_j: np.ndarray
    b_cam: np.ndarray
    plate_cop: np.ndarray
    vtpv: float
    n_conditions: int
    n_unknowns: int
    iterations: int
    converged: bool
    max_correction: float
    N: np.ndarray
    history: list = field(default_factory=list)

    @property
    def redundancy(self) -> int:
        return self.n_conditions - self.n_unknowns


class Pose(NamedTuple):
    """A photograph in the model frame: R (3, 3) R_ground_from_cam, O (3,) its centre, interior (3,)
    c, xp, yp."""

    R: np.ndarray
    O: np.ndarray
    interior: np.ndarray


class StepMeasurements(NamedTuple):
    """What orients photo j: cop_xy, cop_sigma (m, 4) plate coordinates x_i, y_i, x_j, y_j of the
    points for coplanarity and their standard deviations; col_xy, col_sigma (n, 2) plate
    coordinates in photo j of the known points col_X (n, 3) (model frame)."""

    cop_xy: np.ndarray
    cop_sigma: np.ndarray
    col_xy: np.ndarray = np.zeros((0, 2))
    col_sigma: np.ndarray = np.zeros((0, 2))
    col_X: np.ndarray = np.zeros((0, 3))


def orient_photo(mode: str, held: Pose, start: Pose, measured: StepMeasurements, held_axis: int = 0,
                 tolerance: float = 1e-10, max_iterations: int = 30, label: str = "a photograph") -> PhotoStep:
    """Orient photo j to photo i (``held``) and to known points (held) by least squares.

    held, start: photo i and the approximate orientation of photo j (Pose, model frame);
    measured: the plate coordinates that orient j (StepMeasurements). Convergence: every
    correction below ``tolerance`` times its standard deviation with all other unknowns known, or
    the round-off floor (core.convergence.has_converged, as adjust()).
    label: the photograph in messages ("photo 1005").
    """
    R_i, O_i, interior_i = held
    R_j, O_j, interior_j = start
    cop_xy, cop_sigma, col_xy, col_sigma, col_X = measured
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}")
    m, n = len(cop_xy), len(col_xy)
    n_unknowns = 5 if mode == "relative" else 6
    n_conditions = m + 2 * n
    if n_conditions < n_unknowns:
        raise NumericalFailure(
            f"too few measurements to orient the photograph: {m} points shared with the preceding photograph "
            f"and {n} known points give {n_conditions} conditions for {n_unknowns} unknowns."
        )
    free_axes = [a for a in range(3) if a != held_axis]
    b_cam = R_i.T @ (O_j - O_i)
    R_j = R_j.copy()
    O_j = O_j.copy()
    l_cop = np.asarray(cop_xy, dtype=float)
    q_cop = np.asarray(cop_sigma, dtype=float) ** 2
    l_col = np.asarray(col_xy, dtype=float).reshape(n, 2)
    q_col = np.asarray(col_sigma, dtype=float).reshape(n, 2) ** 2
    lhat_cop, lhat_col = l_cop.copy(), l_col.copy()
    interior = np.stack([interior_i, interior_j])
    converged, crit, vtpv, N = False, np.inf, np.nan, np.zeros((n_unknowns, n_unknowns))
    iteration = 0
    history: list[StepIteration] = []
    for iteration in range(1, max_iterations + 1):
        B_rows, w_rows, M_rows = [], [], []
        if m:
            R = np.broadcast_to(np.stack([R_i, R_j]), (m, 2, 3, 3))
            p = plate_vector(lhat_cop.reshape(m, 2, 2), interior)
            r = np.einsum("mkij,mkj->mki", R, p)
            O_j_now = O_i + R_i @ b_cam if mode == "relative" else O_j
            b = np.broadcast_to(O_j_now - O_i, (m, 3))
            g, dg_b, dg_r1, dg_r2 = coplanarity(b, r[:, 0], r[:, 1])
            d_r = np.stack([dg_r1, dg_r2], 1)[:, None]
            lin = ray_chain(RayConditions(g[:, None], d_r, np.zeros_like(d_r), np.zeros((m, 1, 3))), R, p)
            a = lin.d_plate.reshape(m, 4)
            d_rot = lin.d_rot[:, 0, 1]
            if mode == "relative":
                d_b = (dg_b @ R_i)[:, free_axes]  # dg/db_cam = R_i^T dg/db
                B_rows.append(np.concatenate([d_rot, d_b], 1))
            else:
                B_rows.append(np.concatenate([dg_b, d_rot], 1))  # dg/dO_j = dg/db
            w_rows.append(g + np.einsum("mi,mi->m", a, l_cop - lhat_cop))
            M_rows.append(np.einsum("mi,mi->m", a * q_cop, a))
        if n:
            lc = collinearity(lhat_col[:, None], np.broadcast_to(R_j, (n, 1, 3, 3)), np.broadcast_to(O_j, (n, 1, 3)),
                              np.broadcast_to(interior_j, (n, 1, 3)), col_X)
            B_rows.append(np.concatenate([lc.d_centre[:, :, 0], lc.d_rot[:, :, 0]], 2).reshape(2 * n, 6))
            w_rows.append((lc.g + (l_col - lhat_col)).reshape(2 * n))  # A = I
            M_rows.append(q_col.reshape(2 * n))
        B, w, M = np.concatenate(B_rows), np.concatenate(w_rows), np.concatenate(M_rows)
        N = B.T @ (B / M[:, None])
        u = B.T @ (w / M)
        try:
            if not (np.isfinite(N).all() and np.isfinite(u).all()):
                raise np.linalg.LinAlgError("not finite")
            dx = -np.linalg.solve(N, u)
        except np.linalg.LinAlgError as exc:
            raise NumericalFailure(f"the orientation of {label} is not determined by its points (too few, or on a "
                                   "line), or its equations are not finite numbers", reason="singular") from exc
        k = -(w + B @ dx) / M
        vtpv = float(np.sum(k * k * M))
        if m:
            lhat_cop = l_cop + q_cop * a * k[:m, None]
        if n:
            lhat_col = l_col + q_col * k[m:].reshape(n, 2)
        if mode == "relative":
            R_j = R_j @ exp_so3(dx[:3])
            b_cam = b_cam.copy()
            b_cam[free_axes] += dx[3:]
            O_j = O_i + R_i @ b_cam
        else:
            O_j = O_j + dx[:3]
            R_j = R_j @ exp_so3(dx[3:])
        crit = float(np.max(np.abs(dx) * np.sqrt(np.diag(N))))
        history.append(StepIteration(vtpv, crit))
        if not (np.isfinite(crit) and np.isfinite(vtpv)):
            raise NumericalFailure(f"the orientation of {label} diverged at iteration {iteration}: its numbers became "
                                   "infinite or not a number.\n" + table(history, n_conditions - n_unknowns),
                                   reason="diverged")
        if has_converged(history, tolerance):  # the tolerance, or the round-off floor (as adjust())
            converged = True
            break
    return PhotoStep(R_j=R_j, O_j=O_j, b_cam=R_i.T @ (O_j - O_i), plate_cop=lhat_cop, vtpv=vtpv,
                     n_conditions=n_conditions, n_unknowns=n_unknowns, iterations=iteration,
                     converged=converged, max_correction=crit, N=N, history=history)
