"""External reliability, exactly: the shift of each point by an MDB-sized blunder in one of its own
plate coordinates (where plan.ranking.applicable; analysis.external_bound otherwise).

With the points eliminated (plan.ranking), a blunder g in plate coordinate a of ray i of point j
(weight p_a) moves the orientation unknowns by ``do = Q (s - U_j^T t)``, ``s = A_o,i[a]^T p_a g``
on ray i's photo columns, ``t = M_j^-1 A_p,i[a]^T p_a g`` (M_j over the point's free axes plus the
weights of its weighted control; zero on held axes), ``U_j = sum A_p^T P A_o`` over the point's
rays and Q = N^-1; and the point by ``dX = t - M_j^-1 U_j do`` (the least-squares solution is
linear in the observations; Schmid's points are the bundle's). ``U_j Q U_j^T`` and ``U_j Q s``
involve only the blocks of Q between the photos that see the point, which the selected inverse
holds: one ``G Q G^T`` per point (covariance.group_forms, batched by ray count) with G's rows
U_j and the 2k vectors s of its plate coordinates.
"""

from __future__ import annotations

import numpy as np

from ..adjustment import AdjustmentResult
from ..selected_inverse.covariance import Slots
from ..model import HELD, OBSERVED, Project
from ..reliability import PlateReliability
from .ranking import ray_jacobians
from ..equations import weights


def own_point_shifts(plan: Project, result: AdjustmentResult, rel: PlateReliability) -> np.ndarray:
    """dX (m, 2, 3), ground m: the shift of the point of every plate coordinate (rows of
    image_points, x and y) by a blunder of its MDB; nan where the MDB is not finite."""
    ip, pts = plan.image_points, plan.points
    m, n_pt = len(ip), len(pts)
    A_p, A_o, cols, p = ray_jacobians(plan, result)
    pt = ip.point_index
    sigma = pts.sigma_given
    weighted = pts.given_state == OBSERVED
    held = pts.given_state == HELD
    ApP = np.swapaxes(A_p, 1, 2) * p[:, None, :]  # (m, 3, 2)
    M = np.zeros((n_pt, 3, 3))
    np.add.at(M, pt, ApP @ A_p)
    M += np.einsum("ni,ij->nij", weights.variance_weight(sigma**2, weighted), np.eye(3))
    free = (~held).astype(float)
    Mf = M * free[:, :, None] * free[:, None, :] + np.einsum("ni,ij->nij", 1.0 - free, np.eye(3))
    Minv = np.zeros((n_pt, 3, 3))
    ok = np.abs(np.linalg.det(Mf)) > 0
    Minv[ok] = np.linalg.inv(Mf[ok]) * (free[ok, :, None] * free[ok, None, :])
    g = np.where(np.isfinite(rel.mdb), rel.mdb, 0.0)  # (m, 2)
    t = np.einsum("mij,mja->mai", Minv[pt], ApP * g[:, None, :])  # (m, 2, 3)
    s = A_o * (p * g)[:, :, None]  # (m, 2, 6)
    U = ApP @ A_o  # (m, 3, 6)
    out = np.full((m, 2, 3), np.nan)
    rays = np.bincount(pt, minlength=n_pt)
    order = np.argsort(pt, kind="stable")  # rows grouped by point
    for k in np.unique(rays[rays > 0]):  # batches by ray count (a few shapes), not points
        members = np.flatnonzero(rays == k)
        rows = order[np.isin(pt[order], members)].reshape(len(members), k)  # (mk, k) rows of each point
        mk = len(members)
        G = np.zeros((mk, 3 + 2 * k, k, 6))
        G[:, :3] = np.swapaxes(U[rows], 1, 2)  # (mk, 3, k, 6)
        for i in range(k):  # the k rays of the batch's shape
            G[:, 3 + 2 * i:5 + 2 * i, i] = s[rows[:, i]]
        F = result.covariance.group_forms([Slots(G, ip.photo_index[rows], result.layout.photo_cols)])
        UQU, UQs = F[:, :3, :3], F[:, :3, 3:]  # (mk, 3, 3), (mk, 3, 2k)
        tk = t[rows].reshape(mk, 2 * k, 3)
        Udo = UQs - UQU @ np.swapaxes(tk, 1, 2)  # (mk, 3, 2k): U_j do of each coordinate
        dX = tk - np.swapaxes(Minv[members] @ Udo, 1, 2)  # (mk, 2k, 3)
        out[rows.ravel()] = dX.reshape(mk * k, 2, 3)
    return np.where(np.isfinite(rel.mdb)[:, :, None], out, np.nan)


def external_exact(plan: Project, result: AdjustmentResult, rel: PlateReliability) -> np.ndarray:
    """Per point (np, 3) the largest |shift| of each coordinate by an MDB-sized blunder in one of its
    own plate coordinates; inf where one of them is not checked (MDB inf)."""
    ip = plan.image_points
    shifts = np.abs(own_point_shifts(plan, result, rel))  # (m, 2, 3)
    worst = np.zeros((len(plan.points), 3))
    np.maximum.at(worst, ip.point_index, np.nan_to_num(np.max(shifts, axis=1), nan=0.0))
    unchecked = np.zeros(len(plan.points), dtype=bool)
    np.logical_or.at(unchecked, ip.point_index, ~np.isfinite(rel.mdb).all(axis=1))
    return np.where(unchecked[:, None], np.inf, worst)


def photos_bound(plan: Project, rel: PlateReliability, sigma_points: np.ndarray) -> np.ndarray:
    """Per point k (np, 3), m: the bound on the shift of each coordinate of k by an undetected
    MDB-sized blunder in any plate coordinate of the photos that see k (the measurements of the other
    points of those photos included): ``max_a bnr_a * sigma_Xk`` over those coordinates a (Baarda's
    bound |df| <= bnr_a sigma_f holds for every function f of the unknowns, Cauchy-Schwarz in the
    metric of Qxx). inf where one of them is not checked; 0 on a held axis; nan where k is not
    determined.
    The exact shift of the other points is not computed: it needs the blocks of Q = N^-1 between
    photos that share no point, which the selected inverse does not hold (docs/plan.md)."""
    ip = plan.image_points
    n_photos = len(plan.photos)
    worst_photo = np.zeros(n_photos)
    np.maximum.at(worst_photo, ip.photo_index, np.max(rel.bnr, axis=1))  # bnr inf where r = 0
    worst = np.zeros(len(plan.points))
    np.maximum.at(worst, ip.point_index, worst_photo[ip.photo_index])
    held = sigma_points == 0  # a held axis does not move (0, not inf x 0)
    return np.where(held, 0.0, worst[:, None] * np.where(held, 1.0, sigma_points))
