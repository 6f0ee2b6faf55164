"""The observations of a project as the adjustments use them: original values and cofactors, in
the reduced frame (parameters.reduction_offset)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import OBSERVED, Project


@dataclass(frozen=True)
class Observations:
    """All observations of the point groups (original values l and cofactors).

    plate: (m_ip, 2) measured plate coordinates; q_plate: (m_ip, 2) their variances.
    control: (n_pt, 3) given coordinates (0 where not given); q_control: (n_pt, 3) variances,
    0 = held fixed or not given.
    """

    plate: np.ndarray
    q_plate: np.ndarray
    control: np.ndarray
    q_control: np.ndarray


def observations_of(project: Project, offset: np.ndarray) -> Observations:
    """The project's plate measurements and given control coordinates (minus ``offset``, the
    reduced frame) with their variances; a control coordinate counts only on the axes its kind
    gives (model.given_axes)."""
    pts = project.points
    given = np.isfinite(pts.xyz_given) & pts.given_axes
    control = np.where(given, pts.xyz_given - offset, 0.0)
    q_control = np.where(pts.given_state == OBSERVED, np.nan_to_num(pts.sigma_given) ** 2, 0.0)  # held: 0
    ip = project.image_points
    return Observations(plate=ip.xy.copy(), q_plate=ip.sigma_xy**2, control=control, q_control=q_control)
