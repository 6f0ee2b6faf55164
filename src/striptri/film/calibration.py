"""A camera calibration report turned into the camera model (issue 16; docs/decisions.md "Scanned film", docs/file-formats.md).

USGS-style reports print the calibrated principal distance, the principal point of
autocollimation (PPA) and the calibrated principal point, or point of best symmetry (PBS), both in
the fiducial system, and the radial distortion ``dr`` (micrometres, positive outward) at radial
distances r = 10, 20, ... mm, along each of the four semi-diagonals and averaged.

The camera model (:mod:`striptri.geometry.lens`, plate convention) corrects a measured point at radius r
from the principal point to ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)``: the distortion it represents is
``dr(r) = -(k1 r^3 + k2 r^5 + k3 r^7)`` (plate units), with r the radius of the measured point, as
the table's radial distances are. :func:`fit_radial_distortion` fits k1, k2 (and k3) to the table
by linear least squares and gives the residuals of the fit in micrometres. The principal point of
the model is the PBS, the centre of the radial distortion (docs/decisions.md); the PPA is reported
beside it.

USGS reports (SMAC) also print K0, a term linear in r: their printed distortion is
``dr = -(K0 r + K1 r^3 + K2 r^5)`` (checked against reports OSL/2985, OSL/3030 and OSL/3221 in
tests/test_film_calibration.py). The camera model has no linear term, but none is needed: a
correction ``x (1 + K0 + K1 r^2 + ...)`` with principal distance c gives the same ray as
``x (1 + k1 r^2 + ...)`` with ``c / (1 + K0)`` and ``k_i = K_i / (1 + K0)`` (decentring terms
likewise divided). :func:`camera_elements` does that fold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri.geometry.lens import C, K1, K2, K3, NCP, P1, P2, XP, YP

UM_PER_MM = 1000.0


@dataclass(frozen=True)
class RadialFit:
    """The radial distortion table fitted to the camera model.

    radius_mm: (m,) table radii; dr_um: (m,) the table's distortion (averaged over the diagonals
    when the report gives several); k: (3,) k1, k2, k3 (plate units: mm^-2, mm^-4, mm^-6; k3 = 0
    when two terms are fitted); model_um: (m,) the model's distortion at the radii; residual_um:
    (m,) model - table; rms_um: root mean square of the residuals (over the m - terms redundancy
    when positive, else 0); n_terms: 2 or 3.
    """

    radius_mm: np.ndarray
    dr_um: np.ndarray
    k: np.ndarray
    model_um: np.ndarray
    residual_um: np.ndarray
    rms_um: float
    n_terms: int
    k0: float = 0.0


def model_distortion_mm(radius_mm: np.ndarray, k: np.ndarray, k0: float = 0.0) -> np.ndarray:
    """dr = -(k0 r + k1 r^3 + k2 r^5 + k3 r^7) (mm) at radius_mm (m,), k (3,)."""
    r = np.asarray(radius_mm, dtype=float)
    return -(k0 * r + k[0] * r ** 3 + k[1] * r ** 5 + k[2] * r ** 7)


def fit_radial_distortion(radius_mm: np.ndarray, dr_um: np.ndarray, n_terms: int = 2,
                          linear_term: bool = False) -> RadialFit:
    """Least-squares k1..k_{n_terms} (and k0 when linear_term) to a table dr_um (m,) or (d, m) (one
    row per diagonal, averaged; nan entries skipped) at radius_mm (m,). The columns are scaled to
    unit norm before the solve (r^7 at 150 mm is 1.7e15). The rms is over the redundancy."""
    radius_mm = np.asarray(radius_mm, dtype=float)
    dr = np.asarray(dr_um, dtype=float)
    dr = np.nanmean(dr, axis=0) if dr.ndim == 2 else dr
    keep = np.isfinite(dr)
    r = radius_mm[keep]
    powers = ([1] if linear_term else []) + [2 * j + 3 for j in range(n_terms)]
    A = -np.column_stack([r ** e for e in powers])
    scale = np.linalg.norm(A, axis=0)
    sol, *_ = np.linalg.lstsq(A / scale, dr[keep] / UM_PER_MM, rcond=None)
    sol = sol / scale
    k0 = float(sol[0]) if linear_term else 0.0
    k = np.zeros(3)
    k[:n_terms] = sol[int(linear_term):]
    model_um = model_distortion_mm(radius_mm, k, k0) * UM_PER_MM
    residual = model_um - dr
    redundancy = int(keep.sum()) - len(powers)
    rms = float(np.sqrt(np.nansum(residual ** 2) / redundancy)) if redundancy > 0 else 0.0
    return RadialFit(radius_mm, dr, k, model_um, residual, rms, n_terms, k0)


def camera_elements(c: float, pbs: tuple[float, float], fit: RadialFit, p1: float = 0.0, p2: float = 0.0) -> np.ndarray:
    """The camera model's elements (lens.CAMERA_ELEMENTS order, plate convention) of a calibration:
    c and k0 folded (module doc), principal point = PBS, b1 = b2 = 0. -> (NCP,)"""
    scale = 1.0 + fit.k0
    out = np.zeros(NCP)
    out[C], out[XP], out[YP] = c / scale, pbs[0], pbs[1]
    out[K1], out[K2], out[K3] = fit.k / scale
    out[P1], out[P2] = p1 / scale, p2 / scale
    return out
