"""Inactive image points (issue 17): image_points.csv rows with ``active = 0``.

How users keep rejected measurements: the reader puts such rows into
``Project.inactive_image_points`` instead of ``Project.image_points``, so no adjustment, plan or
study ever sees them. After the adjustment each gets the residual it would have,
``v = f(x^) - l``: its point (the adjusted point, triangulated from the adjusted plate coordinates
of the active rows with the adjusted orientation held, which at convergence is the bundle method's
point unknown and the intersection the method of conditions implies) projected into its photo with
the adjusted orientation and camera (distortion included). nan where its point is not determined
by the active rows. The plate corrections of ``[corrections]`` are applied to these rows as to the
active ones. residuals.csv lists them after the active rows with the flag ``inactive``; the report
has a section on them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.result import AdjustmentResult
from ..model import ImagePoints, Project
from ..equations.plate_corrections import correct_project
from ..reliability.outcome import predicted_residuals

FLAG_INACTIVE = "inactive"


@dataclass(frozen=True)
class InactiveResiduals:
    """rows: the inactive ImagePoints (as read, before plate corrections); v: (m, 2) residuals
    ``f(x^) - l`` in plate units (of the corrected coordinates when [corrections] applies); nan
    where the point is not determined."""

    rows: ImagePoints
    v: np.ndarray

    def __len__(self) -> int:
        return len(self.rows)


def none(project: Project) -> bool:
    """Whether the project has no inactive rows."""
    return project.inactive_image_points is None or len(project.inactive_image_points) == 0


def inactive_residuals(project: Project, adjusted: Project, result: AdjustmentResult) -> InactiveResiduals:
    """Residuals of ``project.inactive_image_points`` against ``result``, the adjustment of
    ``adjusted`` (the project's active rows, or those blunder detection kept). ``project``: as
    read (its plate coordinates before [corrections])."""
    rows = project.inactive_image_points
    if rows is None or len(rows) == 0:
        rows = ImagePoints(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)))
        return InactiveResiduals(rows, np.zeros((0, 2)))
    own, _ = correct_project(replace(project, image_points=rows, inactive_image_points=None))
    v = predicted_residuals(own, adjusted, result, np.arange(len(rows)))
    return InactiveResiduals(rows, v)


def residual_columns(project: Project, inactive: InactiveResiduals) -> dict:
    """residuals.csv's columns (pipeline.residual_table) for the inactive rows: v, flag
    ``inactive``, w and the MDBs empty (they took no part in the adjustment)."""
    m = len(inactive)
    nan = np.full(m, np.nan)
    return {
        "photo_id": [project.photos.ids[i] for i in inactive.rows.photo_index],
        "point_id": [project.points.ids[i] for i in inactive.rows.point_index],
        "vx": inactive.v[:, 0], "vy": inactive.v[:, 1], "w": nan, "flag": [FLAG_INACTIVE] * m,
        "mdb_x": nan, "mdb_y": nan,
    }


def summary_entry(project: Project, inactive: InactiveResiduals, listed: int = 20) -> dict:
    """summary.json's ``inactive``: the count, how many have a residual (point determined), the RMS
    of vx and vy over those (plate units, None without any) and the ``listed`` largest by |v|
    (photo_id, point_id, vx, vy)."""
    v = inactive.v
    ok = np.isfinite(v).all(axis=1)
    rms = np.sqrt(np.mean(v[ok] ** 2, axis=0)) if ok.any() else [None, None]
    size = np.where(ok, np.hypot(v[:, 0], v[:, 1]), -1.0)
    order = np.argsort(-size, kind="stable")[:listed]
    return {
        "n": len(inactive), "n_determined": int(ok.sum()),
        "rms_vx": None if rms[0] is None else float(rms[0]), "rms_vy": None if rms[1] is None else float(rms[1]),
        "largest": [{"photo_id": project.photos.ids[inactive.rows.photo_index[i]],
                     "point_id": project.points.ids[inactive.rows.point_index[i]],
                     "vx": float(v[i, 0]) if ok[i] else None, "vy": float(v[i, 1]) if ok[i] else None}
                    for i in order],
    }
