"""Triangulation of object points from oriented photographs (Schmid IV.B, DESIGN section 7).

* :func:`intersect_rays` - least-squares intersection of k rays (minimum sum of squared
  perpendicular distances), the start for everything else;
* :func:`schmid_pair_intersection` - Schmid's closed form for a pair (72-74), with the
  non-vanishing auxiliaries II, [2], [5] of the XZ projection;
* :func:`independent_pair_triangulation` - the independent procedure after orientation (75-80):
  one coplanarity condition adjusts the four plate coordinates, then (74) gives X, Y, Z;
* :func:`triangulate` - coordinates of every point from its rays (:class:`RayObservations`) by
  least squares on the collinearity equations, with given coordinates (:class:`GivenCoordinates`)
  held or weighted, and their precision split into an orientation part and a measurement part
  (Schmid 87-90). For an adjusted result, call ``adjusted_points.triangulate_adjusted``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import plate_vector, ray_ground
from ..geometry.collinearity import collinearity_jacobians
from ..selected_inverse.covariance import group_forms
from .conditions import coplanarity, ray_chain, RayConditions
from .normal_equations import clearly_regular
from ..model import CHECK, Project
from ..parallel import map_ordered
from ..solvers.threads import chunk_threads
from ..geometry.lens import DISTORTION_ELEMENTS, NCP, has_distortion, ideal_xy, projection_terms
from .parameters import State, UnknownLayout
from . import padding, weights
from .point_precision import orientation_part


def intersect_rays(xyz_centre: np.ndarray, r: np.ndarray, mask: np.ndarray | None = None,
                   safe: bool = False) -> np.ndarray:
    """Least-squares intersection of rays O_i + t r_i (ground frame). xyz_centre (the O_i), r:
    (m, k, 3); mask: (m, k) -> (m, 3).

    Minimises sum_i |(I - r^_i r^_i^T)(X - O_i)|^2 (r^ the unit direction). Parallel rays raise
    numpy's LinAlgError, or with ``safe`` give nan for that point (safe_solve).
    """
    rh = r / np.linalg.norm(r, axis=-1, keepdims=True)
    P = np.eye(3) - rh[..., :, None] * rh[..., None, :]
    if mask is not None:
        P = P * mask[..., None, None]
    lhs = P.sum(axis=1)
    rhs = np.einsum("mkij,mkj->mi", P, xyz_centre)
    if safe:
        return safe_solve(lhs, rhs)
    return np.linalg.solve(lhs, rhs[..., None])[..., 0]


def schmid_pair_intersection(xyz_centre1, r1, xyz_centre2, r2):
    """Intersection of a pair by Schmid (72-74). Centres O', O'' and ground rays r', r'': all
    (m, 3) -> X (m, 3), mu1, mu2 (m,).

    ``II = u'' w' - u' w''``, ``[2] = bx w'' - bz u''``, ``[5] = bz u' - bx w'``,
    ``mu' = -[2]/II``, ``mu'' = [5]/II`` (auxiliaries that do not vanish for a strip along X);
    ``X = O' + mu' r'`` and ``O'' + mu'' r''`` agree for intersecting rays; the mean is returned.
    """
    b = xyz_centre2 - xyz_centre1
    bx, bz = b[:, 0], b[:, 2]
    u1, w1, u2, w2 = r1[:, 0], r1[:, 2], r2[:, 0], r2[:, 2]
    II = u2 * w1 - u1 * w2
    a2 = bx * w2 - bz * u2
    a5 = bz * u1 - bx * w1
    mu1, mu2 = -a2 / II, a5 / II
    xyz_ground = 0.5 * ((xyz_centre1 + mu1[:, None] * r1) + (xyz_centre2 + mu2[:, None] * r2))
    return xyz_ground, mu1, mu2


@dataclass
class PairTriangulation:
    xyz: np.ndarray  # (m, 3)
    v: np.ndarray  # (m, 4) residuals of x', y', x'', y''
    vtpv: float | np.ndarray  # (m,) per point
    k: np.ndarray  # (m,) correlates
    w: np.ndarray  # (m,) absolute terms of the last linearisation
    misclosure: np.ndarray  # (m,) coplanarity of the adjusted observations (final check)


def independent_pair_triangulation(R_ground_from_cam, xyz_centre, interior, xy, sigma_xy, iterations: int = 5):
    """Schmid's independent triangulation (75-80) with the orientation held.

    Of m points, each in two photographs (the second axis): R_ground_from_cam (m, 2, 3, 3);
    xyz_centre, interior (m, 2, 3); xy, sigma_xy (m, 4) plate coordinates x', y', x'', y'' and their
    standard deviations. The single condition (20) ``{a} v + w = 0`` gives ``N = sum a^2/p`` (78),
    ``k = -w / N`` (77), ``v = a k / p`` (79) and the check ``v^T P v = -w k`` (80), iterated at
    the adjusted observations until the condition holds.
    """
    l = np.asarray(xy, dtype=float)
    q = sigma_xy**2
    lhat = l.copy()
    for _ in range(iterations):
        xy = lhat.reshape(-1, 2, 2)
        p = plate_vector(xy, interior)
        r = np.einsum("mkij,mkj->mki", R_ground_from_cam, p)
        g, dg_b, dg_r1, dg_r2 = coplanarity(xyz_centre[:, 1] - xyz_centre[:, 0], r[:, 0], r[:, 1])
        m = len(g)
        d_r = np.stack([dg_r1, dg_r2], 1)[:, None]  # (m, 1, 2, 3)
        lin = ray_chain(RayConditions(g[:, None], d_r, np.zeros_like(d_r), np.zeros((m, 1, 3))), R_ground_from_cam, p)
        a = lin.d_plate.reshape(m, 4)
        w = g + np.einsum("mi,mi->m", a, l - lhat)
        N = np.einsum("mi,mi->m", a * q, a)
        k = -w / N
        v = q * a * k[:, None]
        lhat = l + v
    xy = lhat.reshape(-1, 2, 2)
    r = ray_ground(R_ground_from_cam, xy, interior)
    g_final, *_ = coplanarity(xyz_centre[:, 1] - xyz_centre[:, 0], r[:, 0], r[:, 1])
    xyz_ground, _, _ = schmid_pair_intersection(xyz_centre[:, 0], r[:, 0], xyz_centre[:, 1], r[:, 1])
    vtpv = np.sum(v * v / q, axis=1)
    return PairTriangulation(xyz=xyz_ground, v=v, vtpv=vtpv, k=k, w=w, misclosure=g_final)


@dataclass
class Triangulated:
    """Coordinates (n_pt, 3) (nan where undetermined) and their covariance split (Schmid 90):
    cov_measurement and cov_orientation (n_pt, 3, 3), both in units of the a-priori variances.

    determined (n_pt,): the point's normal matrix is regular (coordinates and cofactors exist);
    weak (n_pt,): regular, but its rays and given coordinates determine it only in name: the
    smallest eigenvalue of its normal matrix is below WEAK_RCOND times the largest (its weakest
    direction's mean error more than 100 times its best one's: rays within about half a degree of
    one another, or a point left with the y coordinates of a strip's photos only), or its rays give
    it a mean error more than WEAK_FACTOR times the block's median (far_weaker_than_the_rest).
    :attr:`undetermined` is either (docs/decisions.md "Undetermined points")."""

    xyz: np.ndarray
    cov_measurement: np.ndarray
    cov_orientation: np.ndarray
    determined: np.ndarray
    weak: np.ndarray | None = None
    residuals: np.ndarray | None = None  # (m_ip, 2) l - f(X) of every ray at its point (``with_residuals``)

    @property
    def undetermined(self) -> np.ndarray:
        """(n_pt,) bool: not determined, or weakly determined (class doc)."""
        weak = np.zeros_like(self.determined) if self.weak is None else self.weak
        return ~self.determined | weak


def ray_terms(R_ground_from_cam, xyz_centre, params, convention, xyz_ground, xy_obs, xy_measured=None,
              with_lens: bool = True):
    """Collinearity of rays (m, k) in the residual space of the camera model (striptri.geometry.lens):
    residual ``obs - pred`` (m, k, 2) and the derivatives of the prediction with respect to the
    point, the centre, the rotation vector (m, k, 2, 3) and the camera elements (m, k, 2, NCP).

    R_ground_from_cam: (m, k, 3, 3); xyz_centre: (m, k, 3); params: (m, k, NCP); convention:
    (m, k); xyz_ground: (m, 3) one point per row; xy_obs, xy_measured: as lens.projection_terms.
    with_lens=False: no additional parameter is nonzero or estimated. The ideal projection and its
    Jacobians are striptri.geometry.collinearity's."""
    jac = collinearity_jacobians(R_ground_from_cam, xyz_centre, params[..., :3], xyz_ground[:, None, :])
    if not with_lens:
        d_camera = np.zeros(jac.d_interior.shape[:-1] + (NCP,))
        d_camera[..., :3] = jac.d_interior
        return xy_obs - jac.xy_plate, jac.d_ground, jac.d_centre, jac.d_rotation, d_camera
    t = projection_terms(jac.xy_plate, xy_obs, params, convention, xy_measured)
    return (t.obs - t.pred, t.d_ideal @ jac.d_ground, t.d_ideal @ jac.d_centre, t.d_ideal @ jac.d_rotation,
            t.d_camera)


@dataclass(frozen=True)
class RayObservations:
    """The image points whose rays are intersected, one row each (struct of arrays).

    photo_index, point_index: (m,) int. xy_plate: (m, 2) plate coordinates of the rays (of an
    adjustment: its adjusted observations); sigma_xy: (m, 2) their standard deviations (weights
    1/sigma^2). xy_measured: (m, 2) the measurements when xy_plate are adjusted observations
    (lens.ideal_from_observed), None when xy_plate are the measurements."""

    photo_index: np.ndarray
    point_index: np.ndarray
    xy_plate: np.ndarray
    sigma_xy: np.ndarray
    xy_measured: np.ndarray | None = None


@dataclass(frozen=True)
class GivenCoordinates:
    """The given coordinates of all n points (control), reduced frame like the orientation.

    xyz_ground: (n, 3), read only where ``given``; given: (n, 3) bool, which of X, Y, Z each point
    gives (model.given_axes); q_given: (n, 3) variances, > 0 a weighted observation of the
    coordinate, 0 held fixed."""

    xyz_ground: np.ndarray
    given: np.ndarray
    q_given: np.ndarray

    def __len__(self) -> int:
        return len(self.given)


def triangulate(rays: RayObservations, control: GivenCoordinates, *, state: State, layout: UnknownLayout,
                Qxx=None, iterations: int = 6, with_residuals: bool = False) -> Triangulated:
    """Least-squares coordinates of every point of ``control`` (n points) from its ``rays``, with
    given coordinates held or weighted; the orientation (``state``: R_ground_from_cam, centres and
    camera elements per photo) is held.

    Per point: unknown = the coordinates that are neither given nor weighted-fixed; observations
    = its plate coordinates (weights 1/sigma^2) and its weighted given coordinates (q_given > 0).
    Fixed given coordinates (given and q_given == 0) are held. The covariance has a measurement
    part ``(J^T P J + P_given)^-1`` and, when Qxx (N^-1 of the orientation unknowns in the columns
    of ``layout``, a dense array or a covariance.Covariance) is given, an orientation part
    ``G Qxx G^T`` with ``G = -(J^T P J + P_given)^-1 J^T P J_orient`` (Schmid 87-90), both without
    the factor sigma0^2. The orientation part is formed per batch of points with k rays by
    covariance.group_forms (Qxx read by blocks of the photo pairs that share a point, matrix
    products).

    Gauss-Newton from the rays' intersection, at most ``iterations`` steps: a batch stops when every
    step is below CONVERGED times its point's size (from adjusted observations the rays meet, and
    one step reaches the point to rounding). A point is determined when its rays and given
    coordinates are at least three observations for its unknowns and its 3x3 normal matrix is
    regular; the others are nan in ``xyz`` and False in ``determined``. ``with_residuals``: also
    each ray's residual ``obs - pred`` (m_ip, 2) at its point, in the camera model's residual space
    (nan for the rays of points not determined), as the last Gauss-Newton evaluation gives it.
    """
    n_points = len(control)
    camera_of_photo = state.camera_of_photo
    interior_photo = state.interior[camera_of_photo]  # (n_photos, NCP)
    convention_photo = state.convention[camera_of_photo]
    photo_cols, camera_cols = layout.photo_cols, np.asarray(layout.camera_cols)
    with_lens = has_distortion(interior_photo) or bool((camera_cols[..., DISTORTION_ELEMENTS] >= 0).any())
    photo_index, point_index = rays.photo_index, rays.point_index
    xyz = np.full((n_points, 3), np.nan)
    cov_m = np.zeros((n_points, 3, 3))
    cov_o = np.zeros((n_points, 3, 3))
    determined = np.zeros(n_points, dtype=bool)
    weak = np.zeros(n_points, dtype=bool)
    order = np.lexsort((photo_index, point_index))
    counts = np.bincount(point_index, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    given_mask, q_given = control.given, control.q_given
    xyz_given = np.where(given_mask, control.xyz_ground, 0.0)
    fixed = given_mask & ~(q_given > 0)
    weighted = given_mask & (q_given > 0)
    estimated = np.flatnonzero((camera_cols >= 0).any(axis=0))  # camera elements estimated anywhere
    with_orientation = Qxx is not None and n_unknowns_of(Qxx) > 0
    if with_orientation:
        forms = Qxx.group_forms if hasattr(Qxx, "group_forms") else _dense_forms(Qxx)
        rotation_maps = layout.rotation_maps(state)
    # determined when the rays and the given coordinates (held or weighted) are at least three
    enough = ((counts > 0) & (2 * counts + given_mask.sum(axis=1) >= 3)
              & ((~fixed).sum(axis=1) <= 2 * counts + weighted.sum(axis=1)))
    step = ORIENTATION_CHUNK if with_orientation else POINT_CHUNK
    # by ray count, neighbouring counts of few points joined with padded rays of weight zero
    # (equations.padding: long tracks of many lengths)
    tasks = [(k, sel_k[first: first + step]) for k, sel_k in padding.count_groups(counts, np.flatnonzero(enough))
             for first in range(0, len(sel_k), step)]

    def chunk(task):  # chunks of points (memory bounded), on the chunk threads (parallel.map_ordered)
        k, sel = task
        rows, real = padding.padded_rows(order, starts, counts, sel, k)
        ph = photo_index[rows]
        R_ground_from_cam, xyz_centre = state.R_ground_from_cam[ph], state.xyz0[ph]
        interior, conv = interior_photo[ph], convention_photo[ph]
        xy_obs = rays.xy_plate[rows]
        meas = None if rays.xy_measured is None else rays.xy_measured[rows]
        free = ~fixed[sel]  # (m, 3)
        xy_ray = ideal_xy(xy_obs, interior, conv, meas) if with_lens else xy_obs
        xyz_point = _initial_points(R_ground_from_cam, xyz_centre, interior[..., :3], xy_ray, xyz_given[sel],
                                    given_mask[sel], real)
        Pw = weights.variance_weight(q_given[sel], weighted[sel])
        wxy = weights.weight(rays.sigma_xy[rows]) * real[..., None]  # (m, k, 2); padded rays: zero
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for _ in range(iterations):
                res, dX, *_ = ray_terms(R_ground_from_cam, xyz_centre, interior, conv, xyz_point, xy_obs, meas,
                                        with_lens)
                Nx, gx = ray_normals(dX, wxy, res)
                Nx, gx = Nx + Pw[:, :, None] * np.eye(3), gx + Pw * (xyz_given[sel] - xyz_point)
                Nx, gx = _hold(Nx, gx, free)
                step = safe_solve(Nx, gx)
                xyz_point = xyz_point + step
                if _converged(step, xyz_point):
                    break
            res, dX, dO, drot, dint = ray_terms(R_ground_from_cam, xyz_centre, interior, conv, xyz_point, xy_obs,
                                                meas, with_lens)
            Nx = ray_normals(dX, wxy)[0] + Pw[:, :, None] * np.eye(3)
            weak_sel = conditioning(Nx, free) < WEAK_RCOND
            Nx, _ = _hold(Nx, np.zeros((len(sel), 3)), free)
            # a point whose rays are parallel (or numbers not finite) is not determined: left out
            Qm, ok = safe_inverse(Nx)
            ok &= np.isfinite(xyz_point).all(axis=1)
            Qm = Qm * (free[:, :, None] & free[:, None, :])
        Qo = None
        if with_orientation:
            m = len(sel)
            JX = dX.reshape(m, 2 * k, 3)
            G_rows = -Qm @ np.swapaxes(JX * wxy.reshape(m, 2 * k, 1), 1, 2)  # (m, 3, 2k): dX/d(plate)
            # rows 2j, 2j+1 of the plate coordinates depend on the unknowns of ray j only
            drot_u = drot @ rotation_maps[ph]
            J = np.concatenate([dO, drot_u, dint[..., estimated]], 3)  # (m, k, 2, 6 + e)
            # G[m, i, j] = G_rows[m, i, ray j's two rows] @ J[m, j]: one (3, 2) @ (2, 6 + e) per ray
            G = np.swapaxes(np.swapaxes(G_rows.reshape(m, 3, k, 2), 1, 2) @ J, 1, 2)  # (m, 3, k, 6 + e)
            Qo = orientation_part(G, ph, camera_of_photo[ph], photo_cols, camera_cols[:, estimated], forms)
        # the residuals of the real rays, with whether their point is determined
        found = (rows[real], res[real], ok[real.nonzero()[0]]) if with_residuals else None
        return sel, ok, xyz_point, Qm, weak_sel, Qo, found

    # the work of a point grows like k^2 with the orientation part (k x k photo pairs of Qxx), like k
    # without: sized so, the 150 long tracks of the close-range block stay in the caller's thread when
    # only intersected (0.10 s against 0.13 s on two threads), and go to the threads with the
    # orientation part (0.25 s against 0.30 s)
    size = sum(len(sel) * k * (k if with_orientation else 1) for k, sel in tasks)
    residuals = np.full((len(photo_index), 2), np.nan) if with_residuals else None
    for sel, ok, xyz_point, Qm, weak_sel, Qo, rays_res in map_ordered(chunk, tasks, chunk_threads(size)):
        if rays_res is not None:
            rows, res, of_ok = rays_res
            residuals[rows[of_ok]] = res[of_ok]
        weak[sel] = weak_sel
        xyz[sel[ok]] = xyz_point[ok]
        cov_m[sel[ok]] = Qm[ok]
        determined[sel[ok]] = True
        if Qo is not None:
            cov_o[sel[ok]] = Qo[ok]
    weak |= far_weaker_than_the_rest(cov_m, determined & (counts > 0))
    return Triangulated(xyz=xyz, cov_measurement=cov_m, cov_orientation=cov_o, determined=determined,
                        weak=weak & determined, residuals=residuals)


WEAK_FACTOR = 20.0  # a point whose rays give it a mean error this many times the block's median is weak
WEAK_MIN_POINTS = 10  # the comparison with the block needs at least this many determined points


def far_weaker_than_the_rest(cov_measurement: np.ndarray, determined: np.ndarray) -> np.ndarray:
    """(n_pt,) the determined points whose rays give them a mean error (the measurement part, largest
    direction; its eigenvalue in closed form, to 1e-8 of it at worst) more than WEAK_FACTOR times
    the median of the determined points': a point that has
    lost the coordinates that fixed it (the three x of a three-ray point rejected leave the y
    coordinates, which fix it only through small differences of the photos' attitudes) without its
    normal matrix becoming nearly singular. The measurement part alone: the block's own weakness
    (a strip bending between control) is no concern of the point's rays."""
    idx = np.flatnonzero(determined)
    out = np.zeros(len(determined), dtype=bool)
    if len(idx) < WEAK_MIN_POINTS:
        return out
    with np.errstate(all="ignore"):
        largest = symmetric_eigenvalues_3(cov_measurement[idx])[:, -1]
    median = np.median(largest)
    if not np.isfinite(median) or median <= 0:
        return out
    out[idx] = largest > WEAK_FACTOR**2 * median
    return out


POINT_CHUNK = 4096  # points triangulated at once (as AdjustmentOptions.chunk_size groups)
# ... with the orientation part, whose G Qxx G^T gathers blocks of Qxx for every point: on the
# 5,000-photo block of bench_scale the traced peak of the point precision fell from 125-156 to 64 MiB
# with 1,024 points at once instead of 4,096, for 3 % more time
ORIENTATION_CHUNK = 1024
SINGULAR_RCOND = 1e-14  # a point's 3x3 normal matrix whose eigenvalues span more than 1e14 is singular
CONVERGED = 1e-12  # the iteration of a batch of points ends when every step is below this times the point's size


def _converged(step: np.ndarray, xyz_ground: np.ndarray) -> bool:
    """True when every finite step (m, 3) is below CONVERGED times its point's largest coordinate
    (plus 1): further Gauss-Newton steps would only move the points by rounding. Points whose step
    is not finite (not determined) do not hold the batch back."""
    scale = np.max(np.abs(np.where(np.isfinite(xyz_ground), xyz_ground, 0.0)), axis=1, keepdims=True) + 1.0
    return bool(np.all((np.abs(step) <= CONVERGED * scale) | ~np.isfinite(step)))


def safe_inverse(M: np.ndarray, rcond: float = SINGULAR_RCOND) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of symmetric positive (semi)definite matrices (m, n, n) and which are regular (m,):
    a matrix with numbers that are not finite, or whose smallest eigenvalue is below ``rcond``
    times its largest, is singular; its inverse is nan. Never raises LinAlgError.

    3 x 3 matrices (a point's normal matrix) are inverted in closed form (symmetric_inverse_3),
    larger ones (a group's A Q A^T) by LAPACK once a Cholesky factorisation of the whole batch has
    shown them positive definite; an inverse is kept where it shows its matrix clearly regular:
    positive definite and ``1 / (|M|_F |M^-1|_F) > CLEARLY_REGULAR`` (normal_equations.clearly_regular),
    a lower bound of the smallest over the largest eigenvalue. Only the others (near-singular, indefinite, or not finite) go
    through LAPACK's eigenvalues first: numpy's batched eigvalsh and inv on 3 x 3 matrices took
    0.3 s of the 5,000-photo block's triangulations."""
    M = np.asarray(M, dtype=float)
    finite = np.isfinite(M).all(axis=(-2, -1))
    if M.ndim != 3 or len(M) == 0:
        return _lapack_safe_inverse(M, finite, rcond)
    n = M.shape[-1]
    safe = np.where(finite[:, None, None], M, np.eye(n))
    with np.errstate(all="ignore"):
        if n == 3:
            inv, positive = symmetric_inverse_3(safe)
        else:  # a batch that Cholesky takes whole is positive definite; else every matrix by LAPACK
            try:
                np.linalg.cholesky(safe)
            except np.linalg.LinAlgError:
                return _lapack_safe_inverse(M, finite, rcond)
            inv, positive = np.linalg.inv(safe), np.ones(len(M), dtype=bool)
        clear = finite & positive & clearly_regular(safe, inv)
    if np.all(clear):
        return inv, clear
    doubt = np.flatnonzero(~clear)
    inv_doubt, ok_doubt = _lapack_safe_inverse(safe[doubt], finite[doubt], rcond)
    inv[doubt] = inv_doubt
    clear[doubt] = ok_doubt
    return inv, clear


def _lapack_safe_inverse(M: np.ndarray, finite: np.ndarray, rcond: float):
    eye = np.broadcast_to(np.eye(M.shape[-1]), M.shape)
    safe = np.where(finite[..., None, None], M, eye)
    ev = np.linalg.eigvalsh(safe)
    ok = finite & (ev[..., 0] > rcond * np.maximum(ev[..., -1], 0.0)) & (ev[..., -1] > 0)
    inv = np.linalg.inv(np.where(ok[..., None, None], safe, eye))
    return np.where(ok[..., None, None], inv, np.nan), ok


def symmetric_inverse_3(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of symmetric 3 x 3 matrices (m, 3, 3) by their adjugates, on the Jacobi-scaled
    matrices (unit diagonal: ``M^-1 = D (D M D)^-1 D``, ``D = diag(M)^-1/2``), and whether each is
    positive definite (Sylvester: positive leading minors of the scaled matrix). A matrix that is
    not positive definite gives an inverse of no meaning (the caller tests); no warnings."""
    with np.errstate(all="ignore"):
        d = np.sqrt(np.einsum("mii->mi", M))
        S = M / (d[:, :, None] * d[:, None, :])
        a, b, c = S[:, 0, 0], S[:, 1, 1], S[:, 2, 2]
        e, f, g = S[:, 0, 1], S[:, 0, 2], S[:, 1, 2]
        A = b * c - g * g  # cofactors of the symmetric matrix
        B = f * g - e * c
        C = e * g - f * b
        det = a * A + e * B + f * C
        adj = np.stack([A, B, C, B, a * c - f * f, e * f - a * g, C, e * f - a * g, a * b - e * e], axis=1)
        inv = adj.reshape(-1, 3, 3) / det[:, None, None] / (d[:, :, None] * d[:, None, :])
        positive = (a > 0) & (a * b - e * e > 0) & (det > 0)
    return inv, positive


def symmetric_eigenvalues_3(M: np.ndarray) -> np.ndarray:
    """Eigenvalues (m, 3), ascending, of symmetric 3 x 3 matrices (m, 3, 3) in closed form (the
    trigonometric solution of the characteristic cubic, Smith 1961). Each is within about 1e-16 of
    the largest in magnitude divided by the gap between the two closest eigenvalues (relative to
    the largest): 1e-15 for distinct ones, at worst 1e-8 where two coincide (near +-1 the arc cosine
    turns rounding into its square root; tests/test_small_matrices.py). Not finite where M is not."""
    with np.errstate(all="ignore"):
        a, b, c = M[:, 0, 0], M[:, 1, 1], M[:, 2, 2]
        e, f, g = M[:, 0, 1], M[:, 0, 2], M[:, 1, 2]
        q = (a + b + c) / 3.0
        aq, bq, cq = a - q, b - q, c - q
        p = np.sqrt((aq * aq + bq * bq + cq * cq + 2.0 * (e * e + f * f + g * g)) / 6.0)
        det = aq * (bq * cq - g * g) - e * (e * cq - g * f) + f * (e * g - bq * f)
        r = np.where(p > 0, det / (2.0 * p**3), 0.0)
        phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
        largest = q + 2.0 * p * np.cos(phi)
        smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
        middle = 3.0 * q - largest - smallest
    return np.stack([smallest, middle, largest], axis=1)


def ray_normals(dX: np.ndarray, wxy: np.ndarray, res: np.ndarray | None = None):
    """The normal equations of points from their rays: ``Nx = J' W J`` (m, 3, 3) and, with the
    residuals ``res`` (m, k, 2), ``gx = J' W res`` (m, 3) (else None), for the Jacobians dX
    (m, k, 2, 3) of the plate coordinates by the point and the weights wxy (m, k, 2). As batched
    matrix products (four to five times as fast as a three-operand einsum)."""
    m = len(dX)
    J = dX.reshape(m, -1, 3)
    JtW = np.swapaxes(J * wxy.reshape(m, -1, 1), 1, 2)  # (m, 3, 2k)
    return JtW @ J, None if res is None else (JtW @ res.reshape(m, -1, 1))[..., 0]


def safe_solve(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """M^-1 b for batches (m, 3, 3), (m, 3); nan where M is singular (safe_inverse)."""
    inv, _ = safe_inverse(M)
    return np.einsum("mij,mj->mi", inv, b)


def n_unknowns_of(Qxx) -> int:
    return Qxx.shape[0] if isinstance(Qxx, np.ndarray) else Qxx.n


def _dense_forms(Qxx: np.ndarray):
    """covariance.group_forms on a dense Qxx (index -1 reads zero)."""
    Qext = np.zeros((Qxx.shape[0] + 1, Qxx.shape[0] + 1))
    Qext[:-1, :-1] = Qxx
    return lambda parts: group_forms(lambda r, c: Qext[r, c], parts)


WEAK_RCOND = 1e-4  # a point's normal matrix whose eigenvalues span more than 1e4 determines it only weakly


def conditioning(Nx: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Smallest over largest eigenvalue (m,) of the normal matrices Nx (m, 3, 3) of points over their
    free coordinates ``free`` (m, 3) (1 where none is free, 0 where not finite). Scale-free: the
    square of the ratio of the best to the weakest direction's mean error. The eigenvalues in
    closed form (symmetric_eigenvalues_3), and by LAPACK for the matrices whose ratio comes out
    below EXACT_BELOW, where their closed form's error (at worst 1e-8) could matter."""
    keep = free[:, :, None] & free[:, None, :]
    n_free = free.sum(axis=1)
    diag = np.einsum("mii->mi", Nx)
    with np.errstate(all="ignore"):
        fill = np.where(free, diag, 0.0).sum(axis=1) / np.maximum(n_free, 1)
        # a held coordinate's row becomes the mean free eigenvalue: between the free block's extremes
        M = np.where(keep, Nx, 0.0) + (~free)[:, :, None] * np.eye(3) * np.where(n_free > 0, fill, 1.0)[:, None, None]
        finite = np.isfinite(M).all(axis=(1, 2))
        M = np.where(finite[:, None, None], M, np.eye(3))
        ev = symmetric_eigenvalues_3(M)
        low = np.flatnonzero(~(ev[:, 0] > EXACT_BELOW * ev[:, -1]))
        ev[low] = np.linalg.eigvalsh(M[low])
        ratio = np.where(ev[:, -1] > 0, ev[:, 0] / np.where(ev[:, -1] > 0, ev[:, -1], 1.0), 0.0)
    return np.where(finite, ratio, 0.0)


EXACT_BELOW = 10 * WEAK_RCOND  # conditioning: ratios below this from LAPACK's eigenvalues


def _hold(Nx, gx, free):
    """Hold coordinates that are not free: their rows and columns become the identity."""
    keep = free[:, :, None] & free[:, None, :]
    Nx = np.where(keep, Nx, 0.0) + (~free)[:, :, None] * np.eye(3)
    gx = np.where(free, gx, 0.0)
    return Nx, gx


def _initial_points(R_ground_from_cam, xyz_centre, interior, xy, xyz_given, given, real=None):
    """Starting coordinates: the ray intersection (k >= 2; of the real rays (m, k) when given), or
    the ray met with the given height / the vertical through the given plan position (one ray);
    given values (held or weighted) where there are any."""
    fixed = given
    m, k, _ = xy.shape
    r = ray_ground(R_ground_from_cam, xy, interior)
    if k >= 2:
        xyz_ground = intersect_rays(xyz_centre, r, mask=real, safe=True)
    else:
        r0, O0 = r[:, 0], xyz_centre[:, 0]
        height = np.where(fixed[:, 2], xyz_given[:, 2], np.nan)
        t = np.where(np.isfinite(height), (height - O0[:, 2]) / r0[:, 2], np.nan)
        # without a given height, the point on the ray nearest the vertical through (X, Y)
        horiz = np.where(fixed[:, :2], xyz_given[:, :2], O0[:, :2])
        d2 = np.sum(r0[:, :2] ** 2, axis=1)
        t_plan = np.einsum("mi,mi->m", horiz - O0[:, :2], r0[:, :2]) / np.where(d2 > 0, d2, 1.0)
        t = np.where(np.isfinite(t), t, t_plan)
        t = np.where(t > 0, t, 1.0)
        xyz_ground = O0 + t[:, None] * r0
    return np.where(fixed, xyz_given, xyz_ground)


_STEEP = 1e-3  # a ray with a horizontal part below this (relative) is taken as vertical


def planned_points(project: Project) -> np.ndarray:
    """The planned (approximate) ground coordinates of every object point, ground metres (np, 3):
    the given coordinates (all three of a check point), else approx_points.csv, else the
    least-squares intersection of its rays through the photos' given orientations (a point on one
    photo: its ray at the given X, Y, or at the median height of the others); nan where a point is
    on no photo and given by nothing (plan.design's module doc, diagnosis)."""
    pts, ip, ph = project.points, project.image_points, project.photos
    n = len(pts)
    given = np.where(pts.given_axes | (pts.kind == CHECK)[:, None], pts.xyz_given, np.nan)
    approx = np.full((n, 3), np.nan) if pts.xyz_approx is None else np.asarray(pts.xyz_approx, dtype=float)
    origin = np.mean(ph.xyz0, axis=0) if len(ph) else np.zeros(3)
    # rays of image_points.csv through the planned orientations, relative to origin
    cam = ph.camera_index[ip.photo_index]
    params, conv = project.cameras.interior[cam], project.cameras.convention[cam]
    xy = ideal_xy(ip.xy, params, conv)
    r = ray_ground(ph.R_ground_from_cam[ip.photo_index], xy, params[:, :3])
    r = r / np.linalg.norm(r, axis=1, keepdims=True)
    o = ph.xyz0[ip.photo_index] - origin
    # least-squares intersection: sum (I - r r^T) X = sum (I - r r^T) O, per point
    P = np.eye(3) - r[:, :, None] * r[:, None, :]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    np.add.at(A, ip.point_index, P)
    np.add.at(b, ip.point_index, np.einsum("mij,mj->mi", P, o))
    rays = np.bincount(ip.point_index, minlength=n)
    multi = rays >= 2
    inter = np.full((n, 3), np.nan)
    if multi.any():
        inter[multi] = np.linalg.solve(A[multi], b[multi][..., None])[..., 0] + origin
    xyz = np.where(np.isfinite(given), given, np.where(np.isfinite(approx), approx, inter))
    single = (rays == 1) & ~np.isfinite(xyz).all(axis=1)
    if single.any():
        xyz[single] = _on_single_ray(xyz, single, ip.point_index, o + origin, r)
    return xyz


def _on_single_ray(xyz: np.ndarray, single: np.ndarray, point_index: np.ndarray, centre: np.ndarray,
                   r: np.ndarray) -> np.ndarray:
    """The points ``single`` (on one photo): the point of the ray nearest the vertical through the
    known X, Y, else the ray at the known Z or the median height of the determined points."""
    row = np.full(len(single), -1)
    row[point_index] = np.arange(len(point_index))
    rows = row[single]
    O, d, known = centre[rows], r[rows], xyz[single]
    z_known = xyz[:, 2][np.isfinite(xyz[:, 2]) & ~single]
    z_fallback = float(np.median(z_known)) if len(z_known) else 0.0
    h2 = np.sum(d[:, :2] ** 2, axis=1)
    has_xy = np.isfinite(known[:, :2]).all(axis=1) & (h2 > _STEEP**2)
    t_xy = np.einsum("mi,mi->m", np.nan_to_num(known[:, :2]) - O[:, :2], d[:, :2]) / np.where(h2 > 0, h2, 1.0)
    z = np.where(np.isfinite(known[:, 2]), known[:, 2], z_fallback)
    t_z = (z - O[:, 2]) / np.where(d[:, 2] != 0, d[:, 2], np.nan)
    t = np.where(has_xy, t_xy, t_z)
    out = O + t[:, None] * d
    return np.where(np.isfinite(known), known, out)
