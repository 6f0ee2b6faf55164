"""Precision and the cofactors of the residuals (DESIGN section 6).

Mean errors of the unknowns and of functions of them live on AdjustmentResult
(``mean_error``, ``photo_mean_errors``); this module adds what needs one more pass over the
groups: the cofactor matrix of the residuals of each group,

    Qvv = Q A^T M^-1 (M - B Qxx B^T) M^-1 A Q,

its diagonal gives the redundancy numbers ``r_i = qvv_i / q_i`` (they add up to the redundancy)
and the normalised residuals ``w_i = v_i / (sigma_prior sqrt(qvv_i))`` of Baarda's w-test, with
the a-priori sigma0 = 1 (the plate sigmas are taken as known).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .adjustment import AdjustmentOptions, AdjustmentResult, Sweep, observations_of
from .model import Project
from .parameter_observations import build_parameter_observations

W_CRITICAL = 3.29  # two-sided, alpha0 = 0.001 (Baarda)


@dataclass
class ResidualCofactors:
    plate: np.ndarray  # (m_ip, 2) qvv of the plate coordinates
    control: np.ndarray  # (n_pt, 3) qvv of weighted control coordinates (0 elsewhere)
    parameters: np.ndarray  # (p,) qvv of observed elements

    def redundancy_numbers(self, project: Project, result: AdjustmentResult) -> dict:
        obs = observations_of(project, result.offset)
        pobs = build_parameter_observations(project, result.offset)
        return {
            "plate": self.plate / obs.q_plate,
            "control": np.where(obs.q_control > 0, self.control / np.where(obs.q_control > 0, obs.q_control, 1), 0),
            "parameters": self.parameters / pobs.sigma**2 if len(pobs) else np.zeros(0),
        }


def residual_cofactors(project: Project, result: AdjustmentResult, options: AdjustmentOptions = AdjustmentOptions()) -> ResidualCofactors:
    """Diagonal of Qvv for every observation, at the converged solution."""
    obs = observations_of(project, result.offset)
    from .groups import build_batches

    sweep = Sweep(build_batches(project), result.state, result.layout, obs, result.plate_adjusted,
                  result.control_adjusted, options)
    cov = result.covariance
    q_plate = np.zeros_like(obs.plate)
    q_control = np.zeros_like(obs.control)
    for chunk, s in sweep.systems():
        M = np.einsum("mco,mo,mdo->mcd", s.A, s.Q, s.A)
        Minv = np.linalg.inv(M)
        Qloc = cov.entries(s.cols[:, :, None], s.cols[:, None, :])
        C = M - np.einsum("mcu,muv,mdv->mcd", s.B, Qloc, s.B)
        AQ = s.A * s.Q[:, None, :]  # (m, nc, no): A Q
        K = Minv @ C @ Minv
        qvv = np.einsum("mco,mcd,mdo->mo", AQ, K, AQ)
        m, k = chunk.image_rows.shape
        q_plate[chunk.image_rows] = qvv[:, : 2 * k].reshape(m, k, 2)
        if chunk.has_control:
            q_control[chunk.point_index] = qvv[:, 2 * k :]
    pobs = build_parameter_observations(project, result.offset)
    q_par = np.zeros(len(pobs))
    if len(pobs):
        _, grad, cols = pobs.evaluate(result.state, result.layout, sweep.T)
        Qloc = cov.entries(cols[:, :, None], cols[:, None, :])
        q_par = pobs.sigma**2 - np.einsum("pi,pij,pj->p", grad, Qloc, grad)
    return ResidualCofactors(plate=q_plate, control=q_control, parameters=q_par)


def normalised_residuals(v: np.ndarray, qvv: np.ndarray) -> np.ndarray:
    """w = v / sqrt(qvv) (a-priori sigma0 = 1); nan where the observation has no redundancy."""
    ok = qvv > 1e-12 * np.max(np.abs(qvv), initial=1.0)
    return np.where(ok, v / np.sqrt(np.where(ok, qvv, 1.0)), np.nan)
