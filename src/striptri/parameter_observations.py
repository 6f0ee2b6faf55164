"""Observations of the unknowns themselves: GNSS centres, IMU angles, camera constants and
statoscope base components (Schmid 17, 24). Each is a group with A = I (DESIGN section 4):
``g = l - f(x)``, ``B = -df/dx``, ``M = sigma^2``.

Every observation depends on at most three columns; they are stored as rows of fixed width 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import Project
from .parameters import State, UnknownLayout
from .rotations import angles_from_R, angles_jacobian, wrap_angle

CENTRE, ANGLE, INTERIOR, BASE = 0, 1, 2, 3


@dataclass(frozen=True)
class ParameterObservations:
    """p observations: what (CENTRE/ANGLE/INTERIOR/BASE), index (photo or camera), element (axis or
    angle or c/xp/yp), other (photo_from of a base, else -1), value l (reduced frame for centres),
    sigma."""

    what: np.ndarray
    index: np.ndarray
    element: np.ndarray
    other: np.ndarray
    value: np.ndarray
    sigma: np.ndarray

    def __len__(self) -> int:
        return len(self.value)

    def evaluate(self, state: State, layout: UnknownLayout, rotation_maps: np.ndarray):
        """f(x^) (p,), gradient rows (p, 3) and their columns (p, 3) (-1 = none)."""
        p = len(self)
        f = np.zeros(p)
        grad = np.zeros((p, 3))
        cols = -np.ones((p, 3), dtype=int)
        s = self.what == CENTRE
        f[s] = state.xyz0[self.index[s], self.element[s]]
        grad[s, 0] = 1.0
        cols[s, 0] = layout.photo_cols[self.index[s], self.element[s]]
        s = self.what == INTERIOR
        f[s] = state.interior[self.index[s], self.element[s]]
        grad[s, 0] = 1.0
        cols[s, 0] = layout.camera_cols[self.index[s], self.element[s]]
        s = self.what == BASE
        f[s] = state.xyz0[self.index[s], self.element[s]] - state.xyz0[self.other[s], self.element[s]]
        grad[s, 0], grad[s, 1] = 1.0, -1.0
        cols[s, 0] = layout.photo_cols[self.index[s], self.element[s]]
        cols[s, 1] = layout.photo_cols[self.other[s], self.element[s]]
        s = np.flatnonzero(self.what == ANGLE)
        if len(s):
            photos = self.index[s]
            R_ground_from_cam = state.R_ground_from_cam[photos]
            angles = angles_from_R(R_ground_from_cam, layout.convention)
            f[s] = angles[np.arange(len(s)), self.element[s]]
            J = angles_jacobian(R_ground_from_cam, layout.convention) @ rotation_maps[photos]
            grad[s] = J[np.arange(len(s)), self.element[s]]
            cols[s] = layout.photo_cols[photos][:, 3:]
        return f, grad, cols

    def misclosure(self, f: np.ndarray) -> np.ndarray:
        """l - f(x), angle differences wrapped into (-pi, pi]."""
        d = self.value - f
        a = self.what == ANGLE
        d[a] = wrap_angle(d[a])
        return d


def build_parameter_observations(project: Project, offset: np.ndarray) -> ParameterObservations:
    rows = []  # (what, index, element, other, value, sigma)
    ph = project.photos
    for (i, a) in zip(*np.nonzero(ph.sigma_xyz0 > 0)):
        rows.append((CENTRE, i, a, -1, ph.xyz0[i, a] - offset[a], ph.sigma_xyz0[i, a]))
    for (i, a) in zip(*np.nonzero(ph.sigma_angles > 0)):
        rows.append((ANGLE, i, a, -1, ph.angles[i, a], ph.sigma_angles[i, a]))
    cams = project.cameras
    observed = np.isfinite(cams.sigma_interior) & (cams.sigma_interior > 0)
    for (j, e) in zip(*np.nonzero(observed)):
        rows.append((INTERIOR, j, e, -1, cams.interior[j, e], cams.sigma_interior[j, e]))
    b = project.bases
    for f, t, ax, val, sig in zip(b.photo_from, b.photo_to, b.axis, b.value, b.sigma):
        if sig > 0:
            rows.append((BASE, t, ax, f, val, sig))
    if not rows:
        e = np.zeros(0)
        return ParameterObservations(e.astype(int), e.astype(int), e.astype(int), e.astype(int), e, e)
    cols = list(zip(*rows))
    return ParameterObservations(
        what=np.array(cols[0], dtype=int),
        index=np.array(cols[1], dtype=int),
        element=np.array(cols[2], dtype=int),
        other=np.array(cols[3], dtype=int),
        value=np.array(cols[4], dtype=float),
        sigma=np.array(cols[5], dtype=float),
    )
