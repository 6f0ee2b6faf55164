"""Observations of the unknowns themselves: GNSS centres, IMU angles, camera constants and
statoscope base components (Schmid 17, 24). Each is a group with A = I (DESIGN section 4):
``g = l - f(x)``, ``B = -df/dx``, ``M = sigma^2``.

Every observation depends on at most three columns; they are stored as rows of fixed width 3.
With the GNSS model in play (striptri.model (GnssModel)) the rows are 9 wide: an antenna position
depends on its centre element, the photo's 3 rotation unknowns, the camera's 3 lever-arm
components, the strip's shift and drift component; IMU angles on the 3 rotation unknowns and the 3
boresight unknowns; the observed GNSS elements (GNSS_ELEMENT) on their own column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import OBSERVED, Project
from .parameters import State, UnknownLayout, uses_gnss
from ..geometry.rotations import angles_from_R, angles_jacobian, log_so3, skew, wrap_angle

CENTRE, ANGLE, INTERIOR, BASE, GNSS_ELEMENT = 0, 1, 2, 3, 4
# ``other`` of a GNSS_ELEMENT row: which group (gnss_unknowns.GROUPS); ``index`` the camera (lever,
# boresight) or strip (shift, drift)
LEVER, BORESIGHT, SHIFT, DRIFT = 0, 1, 2, 3
GNSS_WIDTH = 9


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
        """f(x^) (p,), gradient rows (p, w) and their columns (p, w) (-1 = none); w = 3, or
        GNSS_WIDTH with the GNSS model (module doc)."""
        p = len(self)
        gnss = state.gnss is not None
        width = GNSS_WIDTH if gnss else 3
        f = np.zeros(p)
        grad = np.zeros((p, width))
        cols = -np.ones((p, width), dtype=int)
        s = self.what == CENTRE
        f[s] = state.xyz0[self.index[s], self.element[s]]
        grad[s, 0] = 1.0
        cols[s, 0] = layout.photo_cols[self.index[s], self.element[s]]
        if gnss:
            _antenna_terms(np.flatnonzero(s), self, state, layout, rotation_maps, f, grad, cols)
            _gnss_element_terms(np.flatnonzero(self.what == GNSS_ELEMENT), self, state, layout, f, grad, cols)
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
        if len(s) and gnss:
            _imu_terms(s, self, state, layout, rotation_maps, f, grad, cols)
        elif len(s):
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
    for (i, a) in zip(*np.nonzero(ph.centre_state == OBSERVED)):
        rows.append((CENTRE, i, a, -1, ph.xyz0[i, a] - offset[a], ph.sigma_xyz0[i, a]))
    for (i, a) in zip(*np.nonzero(ph.angle_state == OBSERVED)):
        rows.append((ANGLE, i, a, -1, ph.angles[i, a], ph.sigma_angles[i, a]))
    cams = project.cameras
    for (j, e) in zip(*np.nonzero(cams.interior_state == OBSERVED)):
        rows.append((INTERIOR, j, e, -1, cams.interior[j, e], cams.sigma_interior[j, e]))
    b = project.bases
    for f, t, ax, val, sig in zip(b.photo_from, b.photo_to, b.axis, b.value, b.sigma):
        if sig > 0:
            rows.append((BASE, t, ax, f, val, sig))
    if uses_gnss(project):
        rows += _gnss_element_rows(project)
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


def _antenna_terms(s, rows: "ParameterObservations", state: State, layout: UnknownLayout, T, f, grad, cols) -> None:
    """The antenna position rows s of ``rows`` (model.GnssModel): ``A = O + R e + shift + drift
    dt``, component ``element``; adds to f and fills the gradient columns 1-8 (rotation 3, lever arm
    3, shift, drift). d(R Exp(d) e)/dd = -R [e]x."""
    index, element = rows.index, rows.element
    if not len(s):
        return
    g, gc = state.gnss, layout.gnss_cols
    photos, a = index[s], element[s]
    m = np.arange(len(s))
    R = state.R_ground_from_cam[photos]
    cam = state.camera_of_photo[photos]
    e = g.lever[cam]
    f[s] += np.einsum("mj,mj->m", R[m, a], e)
    grad[s, 1:4] = np.einsum("mj,mjk->mk", -(R @ skew(e))[m, a], T[photos])
    cols[s, 1:4] = layout.photo_cols[photos][:, 3:]
    grad[s, 4:7] = R[m, a]
    cols[s, 4:7] = gc.lever[cam]
    strip = g.strip[photos]
    has = strip >= 0
    st, ah, sh = strip[has], a[has], s[has]
    dt = g.dt[photos][has]
    f[sh] += g.shift[st, ah] + g.drift[st, ah] * dt
    grad[sh, 7] = 1.0
    cols[sh, 7] = gc.shift[st, ah]
    grad[sh, 8] = dt
    cols[sh, 8] = gc.drift[st, ah]


def _imu_terms(s, rows: "ParameterObservations", state: State, layout: UnknownLayout, T, f, grad, cols) -> None:
    """The IMU angle rows s of ``rows``: ``angles(R Exp(b))`` (model.GnssModel), R <- R Exp(d)
    and Exp(b) <- Exp(b) Exp(db): d/dd = J(R Exp(b)) Exp(b)^T T, d/ddb = J(R Exp(b))."""
    index, element = rows.index, rows.element
    photos = index[s]
    m = np.arange(len(s))
    cam = state.camera_of_photo[photos]
    Rb = state.gnss.R_cam_from_imu[cam]
    R_imu = state.R_ground_from_cam[photos] @ Rb
    f[s] = angles_from_R(R_imu, layout.convention)[m, element[s]]
    J = angles_jacobian(R_imu, layout.convention)[m, element[s]]  # (m, 3)
    grad[s, :3] = np.einsum("mj,mkj,mkl->ml", J, Rb, T[photos])
    cols[s, :3] = layout.photo_cols[photos][:, 3:]
    grad[s, 3:6] = J
    cols[s, 3:6] = layout.gnss_cols.boresight[cam]


def right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """d log(Exp(phi) Exp(d)) / dd at d = 0: (..., 3) -> (..., 3, 3),
    ``I + [phi]x / 2 + (1/theta^2 - (1 + cos theta) / (2 theta sin theta)) [phi]x^2``
    (Barfoot, State Estimation for Robotics, 2017, eq. 7.77 with the sign of the right Jacobian)."""
    phi = np.asarray(phi, dtype=float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = th < 1e-6
    ts = np.where(small, 1.0, th)
    coef = np.where(small, 1.0 / 12.0, 1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    K = skew(phi)
    return np.eye(3) + 0.5 * K + coef * (K @ K)


def _gnss_element_terms(s, pobs: "ParameterObservations", state: State, layout: UnknownLayout, f, grad, cols) -> None:
    """Observed lever arms, boresights (as rotation vectors), shifts and drifts."""
    if not len(s):
        return
    g, gc = state.gnss, layout.gnss_cols
    k, a, group = pobs.index[s], pobs.element[s], pobs.other[s]
    grad[s, 0] = 1.0
    for code, values, columns in ((LEVER, g.lever, gc.lever), (SHIFT, g.shift, gc.shift), (DRIFT, g.drift, gc.drift)):
        t = group == code
        f[s[t]] = values[k[t], a[t]]
        cols[s[t], 0] = columns[k[t], a[t]]
    t = np.flatnonzero(group == BORESIGHT)
    if len(t):
        R = g.R_cam_from_imu[k[t]]
        f[s[t]] = log_so3(R)[np.arange(len(t)), a[t]]
        grad[s[t], :3] = right_jacobian_inverse(log_so3(R))[np.arange(len(t)), a[t]]
        cols[s[t], :3] = gc.boresight[k[t]]


def _gnss_element_rows(project: Project) -> list:
    """Rows (what, index, element, other, value, sigma) of the observed GNSS elements."""
    g = project.gnss
    rows = []
    for code, values, sigma, state in ((LEVER, g.lever, g.sigma_lever, g.lever_state),
                                       (BORESIGHT, g.boresight, g.sigma_boresight, g.boresight_state)):
        for (j, a) in zip(*np.nonzero(state == OBSERVED)):
            rows.append((GNSS_ELEMENT, j, a, code, values[j, a], sigma[j, a]))
    for code, mode, sigma in ((SHIFT, g.shift, g.sigma_shift), (DRIFT, g.drift, g.sigma_drift)):
        if mode == "observed":
            for j in range(g.n_strips):
                for a in range(3):
                    rows.append((GNSS_ELEMENT, j, a, code, 0.0, sigma))
    return rows
