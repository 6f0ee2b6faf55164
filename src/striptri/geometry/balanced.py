"""Balanced radial distortion: a reparametrisation of the camera on input and output (issue 17).

Many calibration programs print the radial distortion *balanced* about a zero-crossing radius r0,

    dr = k1' r (r^2 - r0^2) + k2' r (r^4 - r0^4) + k3' r (r^6 - r0^6),

i.e. Brown's radial polynomial with the linear term ``-a0 r``, ``a0 = k1' r0^2 + k2' r0^4 +
k3' r0^6``, chosen so that dr(r0) = 0, together with a principal distance c' that absorbs the mean
scale (the "calibrated focal length"; Fraser 1997, ISPRS J. Photogramm. 52: 149-159; the PhotoModeler
help page "Radial lens distortion" gives the same conversion, there with A0 = -a0). striptri adjusts the
*Gaussian* (unbalanced) form of docs/camera-model.md; the balanced values are converted on input
(cameras.csv column ``r0``) and back on output. With ``s = 1 - a0`` the two forms give identical rays:

* plate convention (the measured coordinates are corrected, r of the measured point in plate units,
  r0 in plate units): ``brown'(u) = s brown(u)`` with ``k = k'/s``, ``p = p'/s``, so the ray
  ``(x' + b2 y', y', -c')`` is parallel to the Gaussian one with ``c = c'/s``;
* image convention (the projection is distorted, r the normalised radius of the ideal point, r0
  normalised too, r0 = radius / c): ``x - xp = c' brown'(n) = c' s brown(n)``, so ``c = c' s``.

Back, with the Gaussian k: ``S = k1 r0^2 + k2 r0^4 + k3 r0^6``, ``s = 1/(1 + S)``, ``k' = s k``,
``p' = s p`` and ``c' = s c`` (plate) or ``c' = c/s`` (image). Decentering (p1, p2) is scaled with the
radial terms because only then are the rays identical; programs that leave p unscaled differ by the
factor s (1 - 1e-4 for usual lenses). xp, yp, b1, b2 are unchanged. Elements in this module are
the lens.CAMERA_ELEMENTS columns (c, k1, k2, k3, p1, p2 change).
"""

from __future__ import annotations

import numpy as np

from .lens import C, IMAGE, K1, K2, K3, NCP, P1, P2

CHANGED = (C, K1, K2, K3, P1, P2)  # the elements the reparametrisation changes, in this order
BALANCED_NAMES = ("c_balanced", "k1_balanced", "k2_balanced", "k3_balanced", "p1_balanced", "p2_balanced")


def _powers(r0: np.ndarray) -> np.ndarray:
    """(n,) -> (n, 3): r0^2, r0^4, r0^6."""
    r2 = np.asarray(r0, dtype=float) ** 2
    return np.stack([r2, r2 * r2, r2 * r2 * r2], -1)


def gaussian_from_balanced(interior: np.ndarray, r0: np.ndarray, convention: np.ndarray) -> np.ndarray:
    """Gaussian camera elements from balanced ones. interior: (n, NCP) with c', k', p' at their
    columns; r0: (n,) (nan = not balanced: the row is returned unchanged); convention: (n,)
    lens.PLATE or IMAGE. -> (n, NCP)."""
    out = np.array(interior, dtype=float, copy=True).reshape(-1, NCP)
    r0 = np.asarray(r0, dtype=float).reshape(-1)
    on = np.isfinite(r0)
    if not on.any():
        return out
    x = out[on]
    s = 1.0 - np.einsum("ni,ni->n", x[:, K1:K3 + 1], _powers(r0[on]))
    image = np.asarray(convention).reshape(-1)[on] == IMAGE
    x[:, C] = np.where(image, x[:, C] * s, x[:, C] / s)
    for e in (K1, K2, K3, P1, P2):
        x[:, e] = x[:, e] / s
    out[on] = x
    return out


def balanced_from_gaussian(interior: np.ndarray, r0: np.ndarray, convention: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Balanced camera elements from Gaussian ones (the inverse of gaussian_from_balanced) and the
    Jacobian of the changed elements (CHANGED) with respect to the Gaussian ones (CHANGED).
    -> (n, NCP), (n, 6, 6); rows with r0 nan: unchanged, Jacobian the identity."""
    out = np.array(interior, dtype=float, copy=True).reshape(-1, NCP)
    n = len(out)
    r0 = np.asarray(r0, dtype=float).reshape(-1)
    J = np.broadcast_to(np.eye(6), (n, 6, 6)).copy()
    on = np.isfinite(r0)
    if not on.any():
        return out, J
    x = out[on]
    pw = _powers(r0[on])  # dS/dk
    S = np.einsum("ni,ni->n", x[:, K1:K3 + 1], pw)
    s = 1.0 / (1.0 + S)
    ds = -(s * s)[:, None] * pw  # ds/dk, (m, 3)
    image = np.asarray(convention).reshape(-1)[on] == IMAGE
    g = x[:, list(CHANGED)]  # c, k1, k2, k3, p1, p2 (Gaussian)
    Jm = np.zeros((len(x), 6, 6))
    # k' = s k, p' = s p: d/d(own) = s, d/dk_j = (k or p) ds/dk_j
    for row in range(1, 6):
        Jm[:, row, row] = s
        Jm[:, row, 1:4] += g[:, row, None] * ds
    # c' = s c (plate) or c (1 + S) = c / s (image)
    Jm[:, 0, 0] = np.where(image, 1.0 / s, s)
    Jm[:, 0, 1:4] = np.where(image[:, None], g[:, 0, None] * pw, g[:, 0, None] * ds)
    x[:, C] = np.where(image, g[:, 0] / s, g[:, 0] * s)
    for e in (K1, K2, K3, P1, P2):
        x[:, e] = x[:, e] * s
    out[on] = x
    J[on] = Jm
    return out, J


def output_columns(cameras_r0: np.ndarray | None, interior: np.ndarray, convention: np.ndarray,
                   Q_changed: np.ndarray, sigma0: float) -> dict:
    """cameras.csv's balanced columns for cameras given with r0 (docs/file-formats.md): ``r0``,
    BALANCED_NAMES and their sigmas, propagated from the cofactors ``Q_changed`` (n, 6, 6) of the
    Gaussian elements CHANGED (zero where held) as ``sigma0 sqrt(diag(J Q J^T))``; empty for
    cameras without r0. {} when no camera has one."""
    if cameras_r0 is None or not np.isfinite(cameras_r0).any():
        return {}
    values, J = balanced_from_gaussian(interior, cameras_r0, convention)
    Q = J @ Q_changed @ np.swapaxes(J, 1, 2)
    sig = sigma0 * np.sqrt(np.maximum(np.einsum("nii->ni", Q), 0.0))
    on = np.isfinite(cameras_r0)
    cols: dict = {"r0": cameras_r0}
    for name, e in zip(BALANCED_NAMES, CHANGED):
        cols[name] = np.where(on, values[:, e], np.nan)
    estimated = np.einsum("nii->ni", Q_changed) > 0
    for k, name in enumerate(BALANCED_NAMES):
        # a balanced element is determined when any Gaussian element it depends on is estimated
        depends = (np.abs(J[:, k, :]) > 0) & estimated
        cols[f"sigma_{name}"] = np.where(on & depends.any(axis=1), sig[:, k], np.nan)
    return cols
