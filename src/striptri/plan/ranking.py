"""The control ranking by rank-3 updates of the normal matrix (Woodbury) instead of one adjustment
per control point (whatif.rank_control, the brute force it is checked against).

With the points eliminated, each point contributes to the normal matrix N of the orientation
unknowns ``A_o^T P A_o - U_f^T (M_ff + W_f)^-1 U_f`` (Schmid's reduction; the bundle's Schur
complement): ``M = sum A_p^T P A_p`` (3 x 3) and ``U = sum A_p^T P A_o`` over the point's rays,
f its free axes, W_f the weights of its weighted control coordinates. Dropping a control point
(it becomes a check point: all three axes free, no weight) changes only its own term:
``dB = -U^T M^-1 U + U_f^T (M_ff + W_f)^-1 U_f``, negative semidefinite of rank <= 3 on the
columns C of the photos that see it (E_C selects them). With ``dB = -V V^T``,
``XV = N^-1 E_C V`` and ``K = I - V^T (XV)_C`` (Woodbury)::

    N_new^-1 = N^-1 + XV K^-1 XV^T

(K singular: the drop leaves a datum defect). A point's covariance is ``M^-1 + G Q G^T`` with
``G = M^-1 sum A_p^T P A_o`` (Schmid 90, what the pipeline reports), so each new point's changes by
``H K^-1 H^T``, ``H = G (X V)``; the dropped point's is formed whole. One factorisation of N and at most six
solves per control point (``N^-1 [E V, E G^T]``).

Applies when the cameras are held, no distortion is in play and the datum is the control
(``applicable``); otherwise whatif.rank_control's brute force serves.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..adjustment import AdjustmentOptions, AdjustmentResult
from ..geometry.collinearity import collinearity_jacobians
from ..model import CHECK, HELD, OBSERVED, TIE, Project
from .design import CONTROL_KINDS
from ..equations import weights

DEFECT_TOL = 1e-10  # K's smallest eigenvalue below this (relative to 1): the drop leaves a datum defect


def applicable(result: AdjustmentResult, options: AdjustmentOptions) -> bool:
    """Whether the update applies (module doc)."""
    layout = result.layout
    return layout.camera_width == 0 and not layout.lens_in_play(result.state) and options.datum == "control"


def ray_jacobians(plan: Project, result: AdjustmentResult):
    """Per ray at the plan: A_p (m, 2, 3) d(x, y)/d point, A_o (m, 2, 6) d(x, y)/d the photo's
    unknowns (zero where fixed), the photo's columns (m, 6) (-1: fixed) and the weights p (m, 2)."""
    ip, s, layout = plan.image_points, result.state, result.layout
    ph, pt = ip.photo_index, ip.point_index
    xyz = plan.points.xyz_approx - result.offset
    params, _ = s.camera_terms(ph)
    jac = collinearity_jacobians(s.R_ground_from_cam[ph], s.xyz0[ph], params[:, :3], xyz[pt])
    T = layout.rotation_maps(s)[ph]
    A_o = np.concatenate([jac.d_centre, jac.d_rotation @ T], axis=2)  # (m, 2, 6)
    cols = layout.photo_cols[ph]
    A_o = np.where((cols >= 0)[:, None, :], A_o, 0.0)
    return jac.d_ground, A_o, cols, weights.weight(ip.sigma_xy)


def ray_terms(plan: Project, result: AdjustmentResult):
    """Per ray: A_p^T P A_p (m, 3, 3), A_p^T P A_o (m, 3, 6) with the photo's columns (m, 6) (-1:
    fixed, zeroed)."""
    A_p, A_o, cols, p = ray_jacobians(plan, result)
    ApP = np.swapaxes(A_p, 1, 2) * p[:, None, :]  # (m, 3, 2)
    return ApP @ A_p, ApP @ A_o, cols


def rank_control_fast(plan: Project, result: AdjustmentResult, sigma_points: np.ndarray) -> list[dict]:
    """For each control point of ``plan`` (the noise-free plan of analysis.precision_only): its
    worst_sigma_P when dropped (None with a datum defect) and status, in the order of the points.
    sigma_points: the plan's point mean errors (np, 3), sigma0 = 1."""
    pts, ip = plan.points, plan.image_points
    n_pt = len(pts)
    MM_ray, U_ray, cols = ray_terms(plan, result)
    M = np.zeros((n_pt, 3, 3))
    np.add.at(M, ip.point_index, MM_ray)
    rays = np.bincount(ip.point_index, minlength=n_pt)
    ok_M = rays >= 2
    Minv = np.full((n_pt, 3, 3), np.nan)
    Minv[ok_M] = np.linalg.inv(M[ok_M])
    new = ((pts.kind == TIE) | (pts.kind == CHECK)) & np.isfinite(sigma_points).all(axis=1)
    base_trace = np.sum(sigma_points**2, axis=1)
    lu = splu(sp.csc_matrix(result.N))
    n = result.N.shape[0]
    incidence = sp.csr_matrix((np.ones(len(ip)), (ip.point_index, np.arange(len(ip)))), shape=(n_pt, len(ip)))
    order = np.argsort(ip.point_index, kind="stable")
    starts = np.searchsorted(ip.point_index[order], np.arange(n_pt + 1))
    out = []
    given_state = pts.given_state  # read off the sigmas once
    for k in np.flatnonzero(np.isin(pts.kind, list(CONTROL_KINDS.values()))):
        rows = order[starts[k]:starts[k + 1]]
        C = np.unique(cols[rows][cols[rows] >= 0])
        if len(C) == 0 or not ok_M[k]:
            out.append({"worst_sigma_P": None, "status": "not determined"})
            continue
        where = np.searchsorted(C, np.maximum(cols[rows], 0))  # (r, 6) positions in C
        U = np.zeros((3, len(C)))
        for a in range(6):  # the six photo columns of each ray (a loop of 6, not over points)
            valid = cols[rows][:, a] >= 0
            np.add.at(U.T, where[valid, a], U_ray[rows][valid][:, :, a])
        dB = -U.T @ Minv[k] @ U
        held = given_state[k] == HELD
        free = ~held
        if free.any():
            w = weights.variance_weight(np.nan_to_num(pts.sigma_given[k], nan=1.0)**2, given_state[k] == OBSERVED)
            Mf = M[k][np.ix_(free, free)] + np.diag(w[free])
            Uf = U[free]
            dB += Uf.T @ np.linalg.solve(Mf, Uf)
        lam, vec = np.linalg.eigh((dB + dB.T) / 2)
        keep = lam < -1e-12 * max(np.abs(lam).max(), 1e-300)
        V = vec[:, keep] * np.sqrt(-lam[keep])
        G = Minv[k] @ U  # (3, |C|): the dropped point's G
        rhs = np.zeros((n, V.shape[1] + 3))
        rhs[C, :V.shape[1]] = V
        rhs[C, V.shape[1]:] = G.T
        Y = lu.solve(rhs)  # N^-1 [E V, E G^T]: r + 3 solves
        XV, Z = Y[:, :V.shape[1]], Y[:, V.shape[1]:]
        K = np.eye(V.shape[1]) - V.T @ XV[C]
        kmin = np.linalg.eigvalsh(K).min() if K.size else 1.0
        if not kmin > DEFECT_TOL:
            out.append({"worst_sigma_P": None, "status": "datum defect"})
            continue
        Kinv = np.linalg.inv(K)
        # the new points: their orientation part grows by H K^-1 H^T, H = M^-1 sum U_i (X V)[cols_i]
        XVp = np.vstack([XV, np.zeros((1, XV.shape[1]))])  # row -1 reads zeros
        W = np.einsum("mia,mar->mir", U_ray, XVp[cols])  # (m, 3, r)
        S = (incidence @ W.reshape(len(ip), -1)).reshape(n_pt, 3, -1)
        H = np.einsum("nij,njr->nir", np.nan_to_num(Minv), S)
        trace = base_trace + np.einsum("nir,rs,nis->n", H, Kinv, H)
        # the dropped point, whole: M^-1 + G Q_new[C, C] G^T = M^-1 + g^T Z + (g^T X V) K^-1 (g^T X V)^T
        gXV = G @ XV[C]
        cov_k = Minv[k] + G @ Z[C] + gXV @ Kinv @ gXV.T
        values = np.append(trace[new], np.trace(cov_k))
        out.append({"worst_sigma_P": float(np.sqrt(values.max())), "status": "ok"})
    return out
