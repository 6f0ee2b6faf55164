"""An independent collinearity bundle adjustment, the reference for the method of conditions.

Written from scratch for the tests: it does not use striptri's conditions, linearise, parameters,
groups or adjustment modules, only the data model, ``camera.project`` (collinearity, Schmid 14)
and ``rotations.R_from_opk``. DESIGN section 4: at convergence the conditions method must equal
this adjustment with the object points as unknowns.

Unknowns (as corrections to start values, in a frame reduced by a round offset):

* per photo X0, Y0, Z0 (unless held fixed, sigma 0) and three small omega-phi-kappa angles
  ``a`` of a local rotation, ``R = R_start Rx Ry Rz(a)`` (a local chart at the start attitude,
  so no camera orientation is excluded; a new chart after every iteration);
* per object point its coordinates that are not held fixed: all three for a tie point, X and Y
  for a fixed height point, Z for a fixed plan point, none for a fixed full point; a weighted
  control coordinate is an unknown with the extra observation ``(given - X) / sigma``.

Observations, whitened by their standard deviations: plate coordinates ``(xy - project(...)) /
sigma``, weighted control coordinates, observed projection centres (GNSS). Solved by
Gauss-Newton with a central-difference Jacobian, so that no derivative is shared with the code
under test. Camera interior orientation is held fixed (only that case is supported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri import model
from striptri.geometry.camera import project
from striptri.geometry.rotations import R_from_opk


@dataclass(frozen=True)
class BundleResult:
    """Ground frame (offset added back). xyz0 (n, 3); R_ground_from_cam (n, 3, 3); points (np, 3)
    (given values for fixed coordinates; nan for points measured on no plate); plate_residuals
    (m, 2) v = adjusted - measured; vtpv, redundancy (observations - unknowns), sigma0.
    Q_photo (n, 6, 6): the photo blocks of (J^T J)^-1 (a-priori sigma0 = 1), in the order X0, Y0,
    Z0 and the local angles, which to first order are the rotation vector d of R <- R Exp(d)
    (Rx Ry Rz(a) = I + [a]x + O(a^2)); rows and columns of elements held fixed are 0."""

    xyz0: np.ndarray
    R_ground_from_cam: np.ndarray
    points: np.ndarray
    plate_residuals: np.ndarray
    vtpv: float
    redundancy: int
    sigma0: float
    n_observations: int
    n_unknowns: int
    iterations: int
    converged: bool
    Q_photo: np.ndarray
    Q_points: np.ndarray | None = None  # (np, 3, 3) point blocks of (J^T J)^-1 (fixed coordinates 0)


class _Problem:
    """Bookkeeping of the unknowns and the whitened residual function."""

    def __init__(self, project: model.Project):
        cams, photos, ip, pts = project.cameras, project.photos, project.image_points, project.points
        if np.isfinite(cams.sigma_interior).any():
            raise NotImplementedError("the reference bundle holds the interior orientation fixed")
        if np.isfinite(photos.sigma_angles).any():
            raise NotImplementedError("the reference bundle takes attitudes as free")
        if len(project.bases):
            raise NotImplementedError("the reference bundle has no base components")
        self.project = project
        self.offset = np.round(photos.xyz0.mean(axis=0))
        self.interior = cams.interior[photos.camera_index]  # (n, 3)
        n = len(photos)

        kind = np.where(pts.kind == model.CHECK, model.TIE, pts.kind)
        given = np.array([model.GIVEN_AXES[int(k)] for k in kind], dtype=bool).reshape(-1, 3)
        weighted = given & np.isfinite(pts.sigma_given) & (pts.sigma_given > 0)
        measured = np.bincount(ip.point_index, minlength=len(pts)) > 0
        self.point_fixed = given & ~weighted
        self.point_unknown = ~self.point_fixed & measured[:, None]
        self.weighted = weighted & measured[:, None]
        self.given = np.where(given, pts.xyz_given - self.offset, np.nan)

        self.centre_fixed = photos.sigma_xyz0 == 0
        self.centre_observed = photos.sigma_xyz0 > 0  # nan compares False
        # unknown vector: [photo centres (free ones), photo local angles (3 n), point coordinates]
        self.n_centre = int((~self.centre_fixed).sum())
        self.n_photo = self.n_centre + 3 * n
        self.n_point = int(self.point_unknown.sum())
        self.n_unknowns = self.n_photo + self.n_point

        self.sigma_xy = ip.sigma_xy
        self.n_observations = (
            2 * len(ip) + int(self.weighted.sum()) + int(self.centre_observed.sum())
        )

    # ------------------------------------------------------------------------------------
    def unpack(self, x, centres, R, points):
        """Centres, rotations and points at the correction vector x (start values given)."""
        n = len(centres)
        centres = centres.copy()
        centres[~self.centre_fixed] += x[: self.n_centre]
        a = x[self.n_centre : self.n_photo].reshape(n, 3)
        R = R @ R_from_opk(a)
        points = points.copy()
        points[self.point_unknown] += x[self.n_photo :]
        return centres, R, points

    def residuals(self, x, centres0, R0, points0):
        """Whitened residuals (observed - computed) / sigma, all observations."""
        ip, photos = self.project.image_points, self.project.photos
        centres, R, points = self.unpack(x, centres0, R0, points0)
        i, j = ip.photo_index, ip.point_index
        xy = project(R[i], centres[i], self.interior[i], points[j])
        parts = [((ip.xy - xy) / self.sigma_xy).ravel()]
        pts = self.project.points
        parts.append((self.given - points)[self.weighted] / pts.sigma_given[self.weighted])
        observed = photos.xyz0 - self.offset
        parts.append((observed - centres)[self.centre_observed] / photos.sigma_xyz0[self.centre_observed])
        return np.concatenate(parts)

    def point_columns(self) -> np.ndarray:
        """(np, 3) column of each point coordinate in the unknown vector, -1 where not unknown."""
        cols = -np.ones(self.point_unknown.shape, dtype=int)
        cols[self.point_unknown] = self.n_photo + np.arange(self.n_point)
        return cols

    def photo_columns(self) -> np.ndarray:
        """(n, 6) column of each photo element in the unknown vector, -1 where held fixed."""
        n = len(self.project.photos)
        cols = -np.ones((n, 6), dtype=int)
        cols[:, :3][~self.centre_fixed] = np.arange(self.n_centre)
        cols[:, 3:] = self.n_centre + np.arange(3 * n).reshape(n, 3)
        return cols

    def steps(self, flying_height: float):
        """Central-difference steps: 1e-5 of the flying height for lengths, 1e-5 rad for angles."""
        h = np.full(self.n_unknowns, 1e-5 * flying_height)
        h[self.n_centre : self.n_photo] = 1e-5
        return h


def _initial_points(problem: _Problem, centres, R):
    """Start values of the points: least-squares intersection of the rays of the approximate
    orientations; given coordinates where given; a single ray cut by its given Z, or brought
    nearest to the vertical through its given X, Y."""
    ip = problem.project.image_points
    n_pt = len(problem.project.points)
    p = np.stack([ip.xy[:, 0] - problem.interior[ip.photo_index, 1], ip.xy[:, 1] - problem.interior[ip.photo_index, 2],
                  -problem.interior[ip.photo_index, 0]], -1)
    rays = np.einsum("mij,mj->mi", R[ip.photo_index], p)
    u = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    points = np.where(np.isfinite(problem.given), problem.given, 0.0)
    for j in range(n_pt):
        rows = np.flatnonzero(ip.point_index == j)
        if len(rows) == 0:
            points[j] = np.nan
            continue
        have = np.isfinite(problem.given[j])
        O = centres[ip.photo_index[rows]]
        if len(rows) >= 2:
            P = np.eye(3)[None] - u[rows, :, None] * u[rows, None, :]
            X = np.linalg.solve(P.sum(0), np.einsum("kij,kj->i", P, O))
        elif have[2]:
            t = (problem.given[j, 2] - O[0, 2]) / u[rows[0], 2]
            X = O[0] + t * u[rows[0]]
        elif have[0] and have[1]:
            d = u[rows[0], :2]
            t = (problem.given[j, :2] - O[0, :2]) @ d / (d @ d)
            X = O[0] + t * u[rows[0]]
        else:
            raise ValueError(f"point {j}: one ray and no given height or plan position")
        points[j] = np.where(have, problem.given[j], X)
    return points


def bundle_adjust(project: model.Project, max_iterations: int = 60, tolerance: float = 1e-10) -> BundleResult:
    """Adjust the project as a collinearity bundle (module doc).

    Gauss-Newton on the whitened residuals with a central-difference Jacobian and step halving
    (against divergence from poor start values);
    converged when every correction is below ``tolerance`` times the standard deviation the
    unknown would have if all others were known (1 / column norm of the whitened Jacobian), or
    when the corrections, already below 1e-7 of it, stop shrinking (the round-off floor).
    """
    problem = _Problem(project)
    photos = project.photos
    centres = photos.xyz0 - problem.offset
    R = photos.R_ground_from_cam.copy()
    points = _initial_points(problem, centres, R)
    flying_height = float(np.median(np.abs(centres[:, 2] - np.nanmedian(points[:, 2]))))
    h = problem.steps(flying_height)
    x0 = np.zeros(problem.n_unknowns)

    def cost(x):
        r = problem.residuals(x, centres, R, points)
        return r, float(r @ r)

    def jacobian(r):
        J = np.empty((len(r), problem.n_unknowns))
        for k in range(problem.n_unknowns):
            e = np.zeros(problem.n_unknowns)
            e[k] = h[k]
            J[:, k] = (cost(e)[0] - cost(-e)[0]) / (2 * h[k])
        return J

    converged = False
    previous = np.inf
    r, f = cost(x0)
    for iterations in range(1, max_iterations + 1):
        J = jacobian(r)
        norms = np.linalg.norm(J, axis=0)
        dx = np.linalg.lstsq(J / norms, -r, rcond=None)[0] / norms  # column-equilibrated
        # step halving against divergence far from the solution only: near it, changes of the
        # cost at the level of round-off must not stop the full Gauss-Newton step
        step = 1.0
        while True:
            r_new, f_new = cost(step * dx)
            if f_new <= f * (1 + 1e-9) or step < 1e-6:
                break
            step /= 2
        # move the start values to the new estimate (new local rotation chart)
        centres, R, points = problem.unpack(step * dx, centres, R, points)
        r, f = r_new, f_new
        criterion = float(np.max(np.abs(dx) * norms)) if len(dx) else 0.0  # the full correction
        # converged: below tolerance, or at the round-off floor (tiny and no longer shrinking)
        if criterion < tolerance or (criterion < 1e-7 and criterion > 0.25 * previous):
            converged = True
            break
        previous = criterion

    # precision at the solution: (J^T J)^-1 (column-equilibrated inverse)
    J = jacobian(r) if problem.n_unknowns else np.zeros((len(r), 0))
    norms = np.linalg.norm(J, axis=0)
    Jn = J / norms
    Qxx = np.linalg.inv(Jn.T @ Jn) / np.outer(norms, norms)
    cols = problem.photo_columns()
    Qp = np.pad(Qxx, ((0, 1), (0, 1)))  # column -1 reads zeros
    Q_photo = Qp[cols[:, :, None], cols[:, None, :]]
    pcols = problem.point_columns()
    Q_points = Qp[pcols[:, :, None], pcols[:, None, :]]

    m = len(project.image_points)
    v = -(r[: 2 * m].reshape(m, 2) * problem.sigma_xy)  # adjusted - measured
    redundancy = problem.n_observations - problem.n_unknowns
    return BundleResult(
        xyz0=centres + problem.offset,
        R_ground_from_cam=R,
        points=points + problem.offset,
        plate_residuals=v,
        vtpv=f,
        redundancy=int(redundancy),
        sigma0=float(np.sqrt(f / redundancy)) if redundancy > 0 else float("nan"),
        n_observations=problem.n_observations,
        n_unknowns=problem.n_unknowns,
        iterations=iterations,
        converged=converged,
        Q_photo=Q_photo,
        Q_points=Q_points,
    )
