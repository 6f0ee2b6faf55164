"""Pre-analysis of a plan: the precision and reliability of its adjustment, from the design alone.

The precision of a least-squares adjustment depends on the design (geometry, weights, datum), not
on the measurements. ``analyse(project, options)`` adjusts the plan's noise-free measurements
(design.noise_free_project) from the plan's own values: the adjustment ends at the plan (every
correction zero to rounding) and its normal matrix is the design's normal matrix at the plan. Its
result is taken with sigma0 = 1 (the a-priori sigmas are the precision of the measurements), so
that every mean error it reports is the a-priori one ``sqrt(Qxx_ii)``:

* photos' and points' mean errors as ``striptri adjust`` computes them (Schmid 81-90), with the
  same code (pipeline.photo_table, point_table);
* internal reliability: redundancy numbers r_i and minimal detectable biases MDB_i of every plate
  coordinate (reliability.measures.plate_reliability, Baarda's alpha0 = 0.001, beta0 = 0.80);
* external reliability: Baarda's bias-to-noise ratio ``bnr_i = delta0 sqrt((1 - r_i) / r_i)`` and,
  per ground point, the largest shift of each coordinate that an undetected blunder of MDB_i size in
  one of the point's own measurements causes: exactly (plan.external) where the cameras are held and
  no distortion is in play, otherwise the bound ``|dX| <= bnr_i sigma_X`` (Cauchy-Schwarz in the
  metric of Qxx: every function f of the unknowns moves by at most bnr_i sqrt(f^T Qxx f)).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.adjusted_points import triangulate_adjusted
from ..adjustment import AdjustmentOptions, AdjustmentResult, adjust
from ..model import CHECK, TIE, Project
from ..reliability import PlateReliability, plate_reliability
from ..equations.triangulation import Triangulated
from .design import noise_free_project, planned_points
from .external import external_exact, photos_bound
from .ranking import applicable


@dataclass
class PlanAnalysis:
    """What the design gives. project: the noise-free plan; result: its adjustment with sigma0 = 1;
    points: the ground points with their cofactors (Schmid 90); sigma_points (np, 3) their a-priori
    mean errors (m, nan where undetermined); reliability: per plate coordinate (m, 2);
    external (np, 3): the largest shift of a point by an undetected MDB-sized blunder in one of its
    own measurements (m; inf where one of them is not checked at all), exact (external.external_exact)
    or, where that does not apply, the bound (external_bound): external_method "exact" or "bound";
    external_photos (np, 3): the bound on its shift by such a blunder in any measurement of the
    photos that see it (external.photos_bound, m)."""

    project: Project
    result: AdjustmentResult
    points: Triangulated
    sigma_points: np.ndarray
    reliability: PlateReliability
    external: np.ndarray
    external_method: str = "bound"
    external_photos: np.ndarray | None = None

    def precision_figures(self) -> dict:
        """Worst and RMS a-priori mean errors of the new points (tie and check points: those the
        adjustment determines), planimetric sigma_XY = sqrt(sigma_X^2 + sigma_Y^2) and sigma_Z (m)."""
        return precision_figures(self.project, self.sigma_points)


def precision_figures(project: Project, sigma_points: np.ndarray) -> dict:
    """See PlanAnalysis.precision_figures; None where there is no new point."""
    kind = project.points.kind
    sel = ((kind == TIE) | (kind == CHECK)) & np.isfinite(sigma_points).all(axis=1)
    if not sel.any():
        return {"n_points": 0, "worst_sigma_XY": None, "rms_sigma_XY": None, "worst_sigma_Z": None, "rms_sigma_Z": None}
    s = sigma_points[sel]
    sxy = np.hypot(s[:, 0], s[:, 1])
    return {"n_points": int(sel.sum()),
            "worst_sigma_XY": float(sxy.max()), "rms_sigma_XY": float(np.sqrt(np.mean(sxy**2))),
            "worst_sigma_Z": float(s[:, 2].max()), "rms_sigma_Z": float(np.sqrt(np.mean(s[:, 2] ** 2)))}


def point_sigmas(result: AdjustmentResult, points: Triangulated) -> np.ndarray:
    """A-priori mean errors of the points (np, 3), as pipeline.point_table computes them."""
    cov = (points.cov_measurement + points.cov_orientation) * result.sigma0_for_precision**2
    sig = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
    return np.where(points.determined[:, None], sig, np.nan)


def precision_only(project: Project, options: AdjustmentOptions, xyz_ground: np.ndarray | None = None
                   ) -> tuple[Project, AdjustmentResult, Triangulated, np.ndarray]:
    """The noise-free plan, its adjustment with sigma0 = 1, the points and their mean errors.
    xyz_ground: the planned points (design.planned_points of ``project`` by default). Raises
    NumericalFailure for a design with a datum defect (naming it) or a singular normal matrix."""
    plan = noise_free_project(project, planned_points(project) if xyz_ground is None else xyz_ground)
    result = replace(adjust(plan, options), sigma0=1.0)
    points = triangulate_adjusted(plan, result, orientation_part=True)
    return plan, result, points, point_sigmas(result, points)


def analyse(project: Project, options: AdjustmentOptions = AdjustmentOptions(),
            xyz_ground: np.ndarray | None = None) -> PlanAnalysis:
    """Precision and reliability of the plan ``project`` (module doc)."""
    plan, result, points, sigma = precision_only(project, options, xyz_ground)
    rel = plate_reliability(plan, result, options)
    around = photos_bound(plan, rel, sigma)
    if applicable(result, options):
        return PlanAnalysis(plan, result, points, sigma, rel, external_exact(plan, result, rel), "exact", around)
    return PlanAnalysis(plan, result, points, sigma, rel, external_bound(plan, rel, sigma), "bound", around)


def external_bound(project: Project, rel: PlateReliability, sigma_points: np.ndarray) -> np.ndarray:
    """Per point, the largest bias-to-noise ratio of its own plate coordinates times its mean
    errors (module doc): (np, 3) m; inf where one of its coordinates is not checked."""
    ip = project.image_points
    worst = np.zeros(len(project.points))
    np.maximum.at(worst, ip.point_index, np.max(rel.bnr, axis=1))
    return worst[:, None] * sigma_points
