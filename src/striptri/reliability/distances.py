"""The output table of distances.csv's rows with their tests (issue 17): the adjusted distance, its
residual, mean error, redundancy number, w-test and MDB (bundle.distances.distance_columns), from
the joint groups of the points the distances join (joint_groups, precision.distance_cofactors).

A distance is tested like a plate measurement (w = v / sqrt(qvv), a-priori sigma0 = 1) and flagged
"suspect" above the critical value, but never rejected by data snooping: the scale of a close-range
network often rests on one scale bar, whose rejection would leave the datum short; snooping stops
instead when a distance has the largest |w| (reliability.snooping), so that the plate rows its gross
error spoils are not rejected for it (docs/decisions.md).
"""

from __future__ import annotations

import math

import numpy as np

from ..bundle.distances import distance_columns
from ..core.options import AdjustmentOptions
from ..core.result import SUCCESSFUL_TERMINATIONS, AdjustmentResult
from ..model import Project
from ..precision.residuals import distance_cofactors
from .measures import ALPHA0, critical_value, distance_tests


def distance_table(project: Project, result: AdjustmentResult, xyz: np.ndarray,
                   options: AdjustmentOptions = AdjustmentOptions(), critical: float | None = None) -> dict:
    """distances.csv's columns (docs/file-formats.md) for the adjusted points xyz (n_pt, 3, reduced
    frame); the tests only for a simultaneous adjustment that ended with a result (else empty).
    critical: the w-test's critical value (default that of ALPHA0)."""
    dist = project.distances
    critical = critical_value(ALPHA0) if critical is None or not math.isfinite(critical) else critical
    tests = None
    if result.method in ("conditions", "bundle") and result.termination in SUCCESSFUL_TERMINATIONS:
        qvv, _ = distance_cofactors(project, result, options)
        adjusted = np.linalg.norm(xyz[dist.point_from] - xyz[dist.point_to], axis=1)
        tests = distance_tests(project, qvv, adjusted)
    return distance_columns(project.points.ids, dist, xyz, tests, result.sigma0_for_precision, critical)
