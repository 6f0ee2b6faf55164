"""Interior orientation from fiducial marks: the fit per photo and image points to the plate.

The fit (:func:`fit_fiducials`) is a Gauss-Markov adjustment per photo, all photos at once:
observations the measured fiducials ``q_scan`` (px, weights 1 / sigma_px^2), unknowns the
transformation's parameters (:mod:`striptri.film.transform`), the calibrated fiducial coordinates
exact. Linear for the similarity and the affine transformation (one step); the projective one starts
from the affine fit and iterates Gauss-Newton.

Test of a fiducial (Baarda's w-test on each coordinate, a priori sigma): ``w = v / sqrt(qvv)``,
``qvv = sigma^2 - a N^-1 a^T``; a fiducial is flagged when the larger |w| of its two coordinates
exceeds W_LIMIT = 3.29 (two-sided alpha = 0.001, the limit of residuals.csv); data snooping leaves
the worst one out and fits again (:func:`fit_fiducials`), so one bad mark is not smeared over the
others. With no redundancy (e.g. 4 fiducials and a projective transformation) w and sigma0 are nan
and nothing is flagged.

Image points (:func:`plate_points`): ``xy = F^-1(q; p)`` with the covariance
``C_xy = Jq C_q Jq^T + Jp C_p Jp^T``, ``C_p = N^-1`` (the a priori cofactors of the fit, sigma0 = 1:
the fit's sigma0 from a handful of fiducials is too uncertain to scale by). The adjustment's model
carries sigma_x, sigma_y per measurement only: the x-y correlation of a point and the correlation
between the points of one photo (they share the transformation's errors) are dropped
(docs/decisions.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri.film import transform
from ..equations import weights

W_LIMIT = 3.29
MAX_ITERATIONS = 20
STEP_TOLERANCE = 1e-12  # relative size of a projective Gauss-Newton step that ends the iteration


@dataclass(frozen=True)
class FiducialFit:
    """The fit of every photo.

    kind: transformation; params (P, n); cov_params (P, n, n) (px^2 units of the parameters,
    a priori); v: residuals (P, F, 2) px in q_scan = (col, -row) (fitted - measured; nan where a
    fiducial is not measured); w (P, F, 2) normalised residuals; flagged (P, F) bool; sigma0 (P,)
    (nan without redundancy); redundancy (P,) int; measured (P, F) bool.
    """

    kind: str
    params: np.ndarray
    cov_params: np.ndarray
    v: np.ndarray
    w: np.ndarray
    flagged: np.ndarray
    sigma0: np.ndarray
    redundancy: np.ndarray
    measured: np.ndarray


def _normal_solve(A, l, weight):
    """Batched weighted least squares: A (P, k, n), l (P, k), weight (P, k) -> x (P, n), N^-1."""
    N = np.einsum("pki,pk,pkj->pij", A, weight, A)
    Ninv = np.linalg.inv(N)
    return np.einsum("pij,pj->pi", Ninv, np.einsum("pki,pk,pk->pi", A, weight, l)), Ninv


def fit_fiducials(kind: str, xy_plate: np.ndarray, q_scan: np.ndarray, sigma_px: np.ndarray,
                  measured: np.ndarray) -> FiducialFit:
    """Fit the transformation of every photo to its measured fiducials, with data snooping.

    xy_plate: (P, F, 2) calibrated fiducial coordinates (mm) of each photo's camera; q_scan: (P, F, 2)
    measured (col, -row) px (anything where not measured); sigma_px: (P, F) > 0; measured: (P, F) bool,
    at least MIN_FIDUCIALS[kind] per photo (the caller checks).

    Data snooping (Baarda): while a photo's largest |w| exceeds W_LIMIT and leaving that fiducial
    out keeps a redundancy >= 1, it is flagged and left out of the photo's fit, one at a time. A
    flagged fiducial's w is then its residual against the final fit over the standard deviation of
    that prediction error, ``sqrt(sigma^2 + a N^-1 a^T)``.
    """
    xy_plate = np.asarray(xy_plate, dtype=float)
    measured = np.asarray(measured, dtype=bool)
    sigma_px = np.asarray(sigma_px, dtype=float)
    q = np.where(measured[..., None], q_scan, 0.0)
    n = transform.N_PARAMS[kind]
    used = measured.copy()
    P = len(measured)
    while True:
        p, Ninv, v, w, redundancy = _fit(kind, xy_plate, q, sigma_px, measured, used)
        score = np.nan_to_num(np.abs(w), nan=0.0).max(-1) * used  # (P, F)
        worst = score.argmax(1)
        rows = np.arange(P)
        reject = (score[rows, worst] > W_LIMIT) & (2 * (used.sum(1) - 1) - n >= 1)
        if not reject.any():
            break
        used[rows[reject], worst[reject]] = False
    weight = np.where(used, weights.weight(sigma_px), 0.0)
    vtpv = np.nansum(v * v * weight[..., None], (1, 2))
    with np.errstate(invalid="ignore"):
        sigma0 = np.where(redundancy > 0, np.sqrt(vtpv / np.maximum(redundancy, 1)), np.nan)
    flagged = measured & (~used | (np.nan_to_num(np.abs(w), nan=0.0).max(-1) > W_LIMIT))
    return FiducialFit(kind, p, Ninv, v, w, flagged, sigma0, redundancy, measured)


def _fit(kind, xy_plate, q, sigma_px, measured, used):
    """One fit with the fiducials ``used``: params, N^-1, v and w of every measured fiducial, redundancy."""
    P, F = measured.shape
    weight = np.repeat(np.where(used, weights.weight(sigma_px), 0.0), 2, axis=1)
    lin = "affine" if kind == "projective" else kind
    n0 = transform.N_PARAMS[lin]
    _, _, A = transform.scan_from_plate(lin, np.zeros((P, n0)), xy_plate)
    p, Ninv = _normal_solve(A.reshape(P, 2 * F, n0), q.reshape(P, 2 * F), weight)
    if kind == "projective":
        p = np.concatenate([p, np.zeros((P, 2))], 1)
        for _ in range(MAX_ITERATIONS):
            q_fit, _, A = transform.scan_from_plate(kind, p, xy_plate)
            dp, Ninv = _normal_solve(A.reshape(P, 2 * F, 8), (q - q_fit).reshape(P, 2 * F), weight)
            p = p + dp
            if np.all(np.abs(dp) <= STEP_TOLERANCE * (1.0 + np.abs(p))):
                break
    n = transform.N_PARAMS[kind]
    q_fit, _, A = transform.scan_from_plate(kind, p, xy_plate)
    A = A.reshape(P, 2 * F, n)
    _, Ninv = _normal_solve(A, np.zeros((P, 2 * F)), weight)
    redundancy = 2 * used.sum(1) - n
    var = np.repeat(sigma_px ** 2, 2, axis=1)
    a_q_a = np.einsum("pki,pij,pkj->pk", A, Ninv, A)
    in_fit = weight > 0
    # used: qvv = sigma^2 - a N^-1 a^T; left out: the prediction error's sigma^2 + a N^-1 a^T
    qvv = np.where(in_fit, var - a_q_a, var + a_q_a)
    testable = (redundancy[:, None] > 0) & (qvv > 1e-10 * var) & np.repeat(measured, 2, axis=1)
    v = np.where(np.repeat(measured, 2, axis=1), (q_fit.reshape(P, 2 * F) - q.reshape(P, 2 * F)), np.nan)
    w = np.where(testable, v / np.sqrt(np.where(testable, qvv, 1.0)), np.nan)
    return p, Ninv, v.reshape(P, F, 2), w.reshape(P, F, 2), redundancy


def undetermined(kind: str, xy_plate: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(P,) True where a photo's measured fiducials cannot determine the transformation (collinear or
    coincident marks): the design matrix at the identity, its rows scaled by the fiducials' spread,
    has a singular value below 1e-9 of its largest. xy_plate (P, F, 2) mm; measured (P, F) bool."""
    xy_plate = np.asarray(xy_plate, dtype=float)
    P = len(xy_plate)
    scale = np.maximum(np.abs(np.where(measured[..., None], xy_plate, 0.0)).max((1, 2)), 1e-300)
    xy = xy_plate / scale[:, None, None]
    identity = {"similarity": [1.0, 0.0, 0.0, 0.0], "affine": [0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                "projective": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]}[kind]
    _, _, A = transform.scan_from_plate(kind, np.tile(identity, (P, 1)), xy)
    A = np.where(measured[..., None, None], A, 0.0).reshape(P, -1, transform.N_PARAMS[kind])
    sv = np.linalg.svd(A, compute_uv=False)
    return sv[:, -1] < 1e-9 * sv[:, 0]


def plate_points(fit: FiducialFit, photo_index: np.ndarray, q_scan: np.ndarray, sigma_q: np.ndarray):
    """Image points of scans to the plate, with their propagated sigmas.

    photo_index: (m,) into the fit's photos; q_scan: (m, 2) px (col, -row); sigma_q: (m, 2) px.
    Returns xy_plate (m, 2) mm, cov_xy (m, 2, 2) mm^2, sigma_xy (m, 2) mm (its diagonal's roots).
    """
    p = fit.params[photo_index]
    xy, J_q, J_p = transform.plate_from_scan(fit.kind, p, q_scan)
    cov = (np.einsum("mij,mj,mkj->mik", J_q, np.asarray(sigma_q, dtype=float) ** 2, J_q)
           + np.einsum("mij,mjl,mkl->mik", J_p, fit.cov_params[photo_index], J_p))
    return xy, cov, np.sqrt(np.einsum("mii->mi", cov))
