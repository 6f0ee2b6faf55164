"""Absolute orientation of a strip model: a 3D similarity fitted to the control, then optionally a
polynomial strip correction of the classical kind (DESIGN section 8).

Frames: ``xyz_model`` in the strip's model frame (the first photograph's frame, arbitrary scale),
``xyz_ground`` in the (reduced) ground frame; ``xyz_ground = t + s R_ground_from_model xyz_model``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import NumericalFailure
from ..geometry.rotations import exp_so3, skew


@dataclass(frozen=True)
class Similarity:
    """xyz_ground = t + scale * R_ground_from_model @ xyz_model."""

    t: np.ndarray
    scale: float
    R_ground_from_model: np.ndarray

    def apply(self, xyz_model: np.ndarray) -> np.ndarray:
        """(..., 3) model -> ground."""
        return self.t + self.scale * np.einsum("ij,...j->...i", self.R_ground_from_model, xyz_model)


def umeyama(xyz_model: np.ndarray, xyz_ground: np.ndarray) -> Similarity:
    """Closed-form least-squares similarity (Umeyama 1991) between (n, 3) point sets, n >= 3."""
    mu_m, mu_g = xyz_model.mean(0), xyz_ground.mean(0)
    a, b = xyz_model - mu_m, xyz_ground - mu_g
    U, S, Vt = np.linalg.svd(b.T @ a / len(a))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    scale = float(np.trace(np.diag(S) @ D) / np.mean(np.sum(a * a, 1)))
    return Similarity(mu_g - scale * R @ mu_m, scale, R)


# The similarity's Jacobian is rank-deficient (control on a line, or no height) when its smallest
# singular value is below this fraction of the largest: far above round-off (1e-16 relative), far
# below the ratio of a layout that fixes the similarity.
RANK_TOLERANCE = 1e-10


@dataclass(frozen=True)
class SimilarityFit:
    similarity: Similarity
    residuals: np.ndarray  # (n_pt, 3) given - fitted, nan where not given
    redundancy: int
    iterations: int
    converged: bool


def fit_similarity(xyz_model: np.ndarray, xyz_given: np.ndarray, given: np.ndarray, start: Similarity,
                   tolerance: float = 1e-12, max_iterations: int = 30) -> SimilarityFit:
    """The 7 parameters by least squares on every given coordinate (full, plan and height control),
    all weighted alike (metres). xyz_model, xyz_given: (n, 3); given: (n, 3) bool.

    Unknowns t (3), a rotation vector on the left (``R <- Exp(d) R``) and the log of the scale;
    Gauss-Newton from ``start`` until every correction is below ``tolerance`` (relative).
    """
    n_eq = int(given.sum())
    if n_eq < 7:
        raise NumericalFailure(f"the control gives {n_eq} coordinates for the 7 elements of the strip's absolute "
                               "orientation; at least two full points and one height point are needed.", reason="datum_defect")
    t, s, R = start.t.copy(), start.scale, start.R_ground_from_model.copy()
    rows = np.flatnonzero(given.any(1))
    Xm, Xg, gv = xyz_model[rows], xyz_given[rows], given[rows]
    converged, it = False, 0
    for it in range(1, max_iterations + 1):
        sRX = s * Xm @ R.T
        pred = t + sRX
        J = np.concatenate([np.broadcast_to(np.eye(3), (len(rows), 3, 3)), -skew(sRX), sRX[:, :, None]], 2)
        J, e = J[gv], (Xg - pred)[gv]
        sv = np.linalg.svd(J, compute_uv=False)
        if sv[-1] < RANK_TOLERANCE * sv[0]:
            raise NumericalFailure("the control does not fix the strip's absolute orientation (e.g. all on one "
                                   "line, or no height); add control away from the strip axis.", reason="datum_defect")
        dx = np.linalg.lstsq(J, e, rcond=None)[0]
        t, R, s = t + dx[:3], exp_so3(dx[3:6]) @ R, s * np.exp(dx[6])
        if np.max(np.abs(dx[:3])) < tolerance * max(1.0, s * np.abs(Xm).max()) and np.max(np.abs(dx[3:])) < tolerance:
            converged = True
            break
    sim = Similarity(t, float(s), R)
    res = np.full(xyz_model.shape, np.nan)
    res[rows] = np.where(gv, Xg - sim.apply(Xm), np.nan)
    return SimilarityFit(sim, res, n_eq - 7, it, converged)


@dataclass(frozen=True)
class StripPolynomial:
    """Corrections dX, dY, dZ as polynomials in the along-strip coordinate
    ``u = (xyz - origin) . axis / half_length`` (about -1 .. 1 over the strip):
    ``d_a(u) = sum_k coefficients[a][k] u^k``; an axis without enough control has no terms."""

    origin: np.ndarray
    axis: np.ndarray
    half_length: float
    coefficients: tuple

    def u(self, xyz: np.ndarray) -> np.ndarray:
        return (xyz - self.origin) @ self.axis / self.half_length

    def correction(self, xyz: np.ndarray) -> np.ndarray:
        u = self.u(xyz)
        return np.stack([np.polynomial.polynomial.polyval(u, c) if len(c) else np.zeros_like(u)
                         for c in self.coefficients], -1)


def fit_strip_polynomial(residuals: np.ndarray, xyz_ground: np.ndarray, centres_ground: np.ndarray,
                         degree: int) -> StripPolynomial:
    """Fit the classical strip correction to the control residuals after the similarity.

    residuals: (n, 3) given - similarity (nan where not given); xyz_ground: (n, 3) the points after
    the similarity; centres_ground: (n_photos, 3) in strip order, which defines the strip axis (first
    to last centre, horizontal). Each axis gets its own least-squares polynomial of ``degree``, lowered
    to (number of distinct positions along the strip - 1) where the control has fewer; positions less
    than half a base apart count as one, so that control in pairs across the strip does not raise it.
    """
    axis = centres_ground[-1] - centres_ground[0]
    axis[2] = 0.0
    half = float(np.linalg.norm(axis)) / 2
    axis = axis / (2 * half)
    origin = centres_ground.mean(0)
    poly = StripPolynomial(origin, axis, half, ((), (), ()))
    # positions along the strip closer than half a base count as one (control in pairs across the strip)
    tol = 0.5 * float(np.median(np.linalg.norm(np.diff(centres_ground, axis=0), axis=1))) / half
    coefs = []
    for a in range(3):
        sel = np.isfinite(residuals[:, a])
        u = np.sort(poly.u(xyz_ground[sel]))
        distinct = int(len(u) > 0) + int(np.sum(np.diff(u) > tol))
        deg = min(degree, distinct - 1)
        if deg < 0:
            coefs.append(())
            continue
        u = poly.u(xyz_ground[sel])
        V = np.polynomial.polynomial.polyvander(u, deg)
        coefs.append(tuple(np.linalg.lstsq(V, residuals[sel, a], rcond=None)[0]))
    return StripPolynomial(origin, axis, half, tuple(coefs))
