"""The camera model: interior orientation and additional parameters per camera (docs/camera-model.md).

Ten elements per camera, in this order (CAMERA_ELEMENTS):

    c, xp, yp        principal distance and principal point (plate units)
    k1, k2, k3       radial distortion (Brown)
    p1, p2           decentering distortion (Brown)
    b1, b2           affinity (aspect) and shear (skew), in either convention

Brown's polynomial on a 2-vector ``u = (x, y)`` with ``r^2 = x^2 + y^2``::

    brown(u) = u (1 + k1 r^2 + k2 r^4 + k3 r^6) + (p1 (r^2 + 2x^2) + 2 p2 x y,
                                                   2 p1 x y + p2 (r^2 + 2y^2))

Two conventions, chosen per camera:

* ``plate`` (PLATE; DBAT, PhotoModeler, classical aerial triangulation): the *measured* plate
  coordinates are corrected. With ``xbar = (1 + b1)(x - xp)``, ``ybar = y - yp`` and
  ``(x', y') = brown(xbar, ybar)`` (k, p in plate units), the camera-frame vector of the ray is
  ``(x' + b2 y', y', -c)``. The residuals live in these refined coordinates (the correction is
  evaluated at the measured point, as DBAT does), so the weights of the measurements apply to
  the refined coordinates.
* ``image`` (IMAGE; BAL, COLMAP, OpenCV): the distortion is applied to the *projected* point in
  normalised coordinates ``n = -m_xy / m_z``: with ``(dx, dy) = brown(n)`` (k, p dimensionless),
  ``x = xp + c ((1 + b1) dx + b2 dy)``, ``y = yp + c dy``, i.e. the calibration matrix
  ``K = [[c (1 + b1), c b2, xp], [0, c, yp]]`` of computer vision (focal lengths fx = c (1 + b1),
  fy = c and skew c b2; Hartley & Zisserman 2004, section 6.1) after the distortion; the residuals
  live in the measured coordinates. b1 = b2 = 0 is the plain ``x = xp + c brown(n)``.

Both give, for every measurement, an *ideal* plate point ``xy_ideal`` whose ray is
``(xy_ideal - (xp, yp), -c)`` (the distortion-free collinearity of DESIGN section 1), which is how
the condition equations see the camera model: :func:`ideal_from_observed`. The bundle method works
the other way round, from the projected point: :func:`projection_terms`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CAMERA_ELEMENTS = ("c", "xp", "yp", "k1", "k2", "k3", "p1", "p2", "b1", "b2")
NCP = len(CAMERA_ELEMENTS)
C, XP, YP, K1, K2, K3, P1, P2, B1, B2 = range(NCP)
DISTORTION_ELEMENTS = slice(K1, NCP)
PLATE, IMAGE = 0, 1
CONVENTIONS = {"plate": PLATE, "image": IMAGE}
CONVENTION_NAMES = {v: k for k, v in CONVENTIONS.items()}
UNDISTORT_ITERATIONS = 30


def brown(u: np.ndarray, params: np.ndarray):
    """Brown's polynomial (module doc) and its derivatives.

    u: (..., 2); params: (..., NCP) (k1, k2, k3, p1, p2 used). Returns the value (..., 2), the
    derivative with respect to u (..., 2, 2) and with respect to (k1, k2, k3, p1, p2) (..., 2, 5).
    """
    x, y = u[..., 0], u[..., 1]
    k1, k2, k3, p1, p2 = (params[..., i] for i in (K1, K2, K3, P1, P2))
    r2 = x * x + y * y
    radial = r2 * (k1 + r2 * (k2 + r2 * k3))
    slope = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)  # d radial / d r2
    xy = x * y
    value = np.stack([x * (1.0 + radial) + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * xy,
                      y * (1.0 + radial) + 2.0 * p1 * xy + p2 * (r2 + 2.0 * y * y)], -1)
    off = 2.0 * xy * slope + 2.0 * p1 * y + 2.0 * p2 * x
    d_u = np.stack([np.stack([1.0 + radial + 2.0 * x * x * slope + 6.0 * p1 * x + 2.0 * p2 * y, off], -1),
                    np.stack([off, 1.0 + radial + 2.0 * y * y * slope + 2.0 * p1 * x + 6.0 * p2 * y], -1)], -2)
    r4 = r2 * r2
    d_k = np.stack([np.stack([x * r2, x * r4, x * r4 * r2, r2 + 2.0 * x * x, 2.0 * xy], -1),
                    np.stack([y * r2, y * r4, y * r4 * r2, 2.0 * xy, r2 + 2.0 * y * y], -1)], -2)
    return value, d_u, d_k


@dataclass
class IdealPoints:
    """Ideal plate points of measurements (module doc) and their derivatives.

    xy: (..., 2); d_obs: (..., 2, 2) with respect to the observation in the residual space (the
    identity for the plate convention, whose residuals are in refined coordinates);
    d_camera: (..., 2, NCP) with respect to the camera elements; converged: (...,) bool (False
    where the image convention's undistortion did not converge).
    """

    xy: np.ndarray
    d_obs: np.ndarray
    d_camera: np.ndarray
    converged: np.ndarray


def _inv2(J):
    det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
    inv = np.stack([np.stack([J[..., 1, 1], -J[..., 0, 1]], -1), np.stack([-J[..., 1, 0], J[..., 0, 0]], -1)], -2)
    return inv / det[..., None, None], det


def ideal_from_observed(xy: np.ndarray, params: np.ndarray, convention: np.ndarray,
                        xy_measured: np.ndarray | None = None) -> IdealPoints:
    """Ideal plate points of observed or adjusted plate coordinates xy (..., 2); params
    (..., NCP); convention (...,) PLATE or IMAGE, broadcast alike.

    xy_measured: the measurements when xy are adjusted observations ``l + v``. The plate
    convention evaluates its correction at the measurement and adds the residual, which lives in
    the refined coordinates: ``ideal = refine(l) + v``; the image convention undistorts ``l + v``.
    """
    xy, params = np.asarray(xy, dtype=float), np.asarray(params, dtype=float)
    shape = np.broadcast_shapes(xy.shape[:-1], params.shape[:-1], np.shape(convention))
    xy = np.broadcast_to(xy, shape + (2,))
    measured = xy if xy_measured is None else np.broadcast_to(np.asarray(xy_measured, dtype=float), shape + (2,))
    params = np.broadcast_to(params, shape + (NCP,))
    image = np.broadcast_to(np.asarray(convention) == IMAGE, shape)
    out_xy = np.empty(shape + (2,))
    d_obs = np.zeros(shape + (2, 2))
    d_cam = np.zeros(shape + (2, NCP))
    converged = np.ones(shape, dtype=bool)
    plate = ~image
    if plate.any():
        _plate_refinement(measured[plate], params[plate], out_xy, d_obs, d_cam, plate)
        if xy_measured is not None:
            out_xy[plate] += xy[plate] - measured[plate]
    if image.any():
        converged[image] = _undistort(xy[image], params[image], out_xy, d_obs, d_cam, image)
    return IdealPoints(out_xy, d_obs, d_cam, converged)


def ideal_xy(xy: np.ndarray, params: np.ndarray, convention: np.ndarray,
             xy_measured: np.ndarray | None = None) -> np.ndarray:
    """The ideal plate points alone, ``ideal_from_observed(...).xy`` (same arguments), without the
    derivatives: for the callers that only form rays (approximations, triangulation, datum points).
    Where no camera has distortion, affinity or shear (k1 ... b2 all zero, as in most aerial
    projects), the numbers ideal_from_observed gives by its arithmetic with zeros, without it
    (and without its (..., 2, NCP) derivatives: 480 MB for a 100,000-photo block's measurements).
    The image convention's undistortion that does not converge gives its last iterate, as there."""
    xy, params = np.asarray(xy, dtype=float), np.asarray(params, dtype=float)
    if np.any(params[..., DISTORTION_ELEMENTS] != 0.0):
        return ideal_from_observed(xy, params, convention, xy_measured).xy
    shape = np.broadcast_shapes(xy.shape[:-1], params.shape[:-1], np.shape(convention))
    xy = np.broadcast_to(xy, shape + (2,))
    params = np.broadcast_to(params, shape + (NCP,))
    image = np.broadcast_to(np.asarray(convention) == IMAGE, shape)
    pp, c = params[..., XP:YP + 1], params[..., C, None]
    # plate: the refinement, the identity, at the measurement plus the residual; image: xp + c n
    # with n = (x - xp) / c undistorted, itself
    if xy_measured is None:
        plate = pp + (xy - pp)
    else:
        measured = np.broadcast_to(np.asarray(xy_measured, dtype=float), shape + (2,))
        plate = pp + (measured - pp) + (xy - measured)
    return np.where(image[..., None], pp + c * ((xy - pp) / c), plate)


def _plate_refinement(xy, prm, out_xy, d_obs, d_cam, where):
    a = 1.0 + prm[:, B1]
    dx = xy[:, 0] - prm[:, XP]
    u = np.stack([a * dx, xy[:, 1] - prm[:, YP]], -1)
    val, d_u, d_k = brown(u, prm)
    b2 = prm[:, B2]
    shear = np.zeros(d_u.shape)
    shear[:, 0, 0] = shear[:, 1, 1] = 1.0
    shear[:, 0, 1] = b2
    ideal = prm[:, XP:YP + 1] + np.stack([val[:, 0] + b2 * val[:, 1], val[:, 1]], -1)
    S_du = shear @ d_u  # d (refined) / d (xbar, ybar)
    d = np.zeros((len(xy), 2, NCP))
    d[:, :, XP] = -a[:, None] * S_du[:, :, 0]
    d[:, :, YP] = -S_du[:, :, 1]
    d[:, 0, XP] += 1.0
    d[:, 1, YP] += 1.0
    d[:, :, K1:P2 + 1] = shear @ d_k
    d[:, :, B1] = dx[:, None] * S_du[:, :, 0]
    d[:, 0, B2] = val[:, 1]
    out_xy[where] = ideal
    d_obs[where] = np.eye(2)
    d_cam[where] = d


def _affine(prm: np.ndarray) -> np.ndarray:
    """The image convention's affinity and shear: A = [[1 + b1, b2], [0, 1]]. (m, NCP) -> (m, 2, 2)."""
    A = np.zeros((len(prm), 2, 2))
    A[:, 0, 0] = 1.0 + prm[:, B1]
    A[:, 0, 1] = prm[:, B2]
    A[:, 1, 1] = 1.0
    return A


def _affine_inverse(prm: np.ndarray) -> np.ndarray:
    """A^-1 = [[1/(1 + b1), -b2/(1 + b1)], [0, 1]]. (m, NCP) -> (m, 2, 2)."""
    a = 1.0 + prm[:, B1]
    Ai = np.zeros((len(prm), 2, 2))
    Ai[:, 0, 0] = 1.0 / a
    Ai[:, 0, 1] = -prm[:, B2] / a
    Ai[:, 1, 1] = 1.0
    return Ai


def _undistort(xy, prm, out_xy, d_obs, d_cam, where):
    """Image convention: the ideal point pp + c n with brown(n) = q = A^-1 (xy - pp) / c (Newton)."""
    c = prm[:, C]
    Ai = _affine_inverse(prm)
    q = np.einsum("mij,mj->mi", Ai, (xy - prm[:, XP:YP + 1]) / c[:, None])
    n = q.copy()
    tol = 1e-14 * (1.0 + np.abs(q).max(axis=-1))
    done = np.zeros(len(q), dtype=bool)
    for _ in range(UNDISTORT_ITERATIONS):
        val, d_u, _ = brown(n, prm)
        inv, _ = _inv2(d_u)
        step = np.einsum("mij,mj->mi", inv, val - q)
        n = n - step
        done = np.abs(step).max(axis=-1) <= tol
        if done.all():
            break
    val, d_u, d_k = brown(n, prm)
    inv, det = _inv2(d_u)
    ok = done & (det > 0) & np.all(np.abs(val - q) <= 1e-10 * (1.0 + np.abs(q)), axis=-1)
    d = np.zeros((len(xy), 2, NCP))
    d[:, :, C] = n - np.einsum("mij,mj->mi", inv, q)
    d[:, :, XP:YP + 1] = np.eye(2) - inv @ Ai
    d[:, :, K1:P2 + 1] = -c[:, None, None] * (inv @ d_k)
    # dq/db1 = -A^-1 (q_x, 0), dq/db2 = -A^-1 (q_y, 0); d ideal = c inv dq
    d[:, :, B1] = -c[:, None] * np.einsum("mij,mj->mi", inv, Ai[:, :, 0] * q[:, 0, None])
    d[:, :, B2] = -c[:, None] * np.einsum("mij,mj->mi", inv, Ai[:, :, 0] * q[:, 1, None])
    out_xy[where] = prm[:, XP:YP + 1] + c[:, None] * n
    d_obs[where] = inv @ Ai
    d_cam[where] = d
    return ok


def observed_from_ideal(xy_ideal: np.ndarray, params: np.ndarray, convention: np.ndarray,
                        iterations: int = 50) -> np.ndarray:
    """The measurements whose ideal plate points are xy_ideal: the inverse of
    :func:`ideal_from_observed` (for simulators and converters). Image convention: the forward
    distortion ``xp + c brown(n)``; plate convention: Newton's method on the refinement, which
    converges where the correction does not fold back. (..., 2) -> (..., 2)."""
    xy_ideal, params = np.asarray(xy_ideal, dtype=float), np.asarray(params, dtype=float)
    shape = np.broadcast_shapes(xy_ideal.shape[:-1], params.shape[:-1], np.shape(convention))
    xy_ideal = np.broadcast_to(xy_ideal, shape + (2,))
    params = np.broadcast_to(params, shape + (NCP,))
    image = np.broadcast_to(np.asarray(convention) == IMAGE, shape)
    out = np.empty(shape + (2,))
    if image.any():
        prm = params[image]
        c, pp = prm[:, C], prm[:, XP:YP + 1]
        val = brown((xy_ideal[image] - pp) / c[:, None], prm)[0]
        out[image] = pp + c[:, None] * np.einsum("mij,mj->mi", _affine(prm), val)
    plate = ~image
    if plate.any():
        prm, target = params[plate], xy_ideal[plate]
        xy = target.copy()
        for _ in range(iterations):
            ideal = ideal_from_observed(xy, prm, PLATE)
            # the refinement depends on x - xp, y - yp: d refined / d measured = I - d refined / d (xp, yp)
            J = np.eye(2) - ideal.d_camera[:, :, XP:YP + 1]
            inv, _ = _inv2(J)
            step = np.einsum("mij,mj->mi", inv, ideal.xy - target)
            xy = xy - step
            if np.abs(step).max(initial=0.0) <= 1e-15 * (1.0 + np.abs(target).max(initial=0.0)):
                break
        out[plate] = xy
    return out


@dataclass
class ProjectionTerms:
    """The bundle method's view (module doc): for each ray the observation in the residual space,
    the prediction there, and derivatives of the prediction minus the observation.

    obs, pred: (..., 2); d_ideal: (..., 2, 2) to multiply the derivatives of the ideal projection
    with respect to the point and the orientation; d_camera: (..., 2, NCP) derivative of
    ``pred - obs`` with respect to the camera elements.
    """

    obs: np.ndarray
    pred: np.ndarray
    d_ideal: np.ndarray
    d_camera: np.ndarray


def projection_terms(pred_ideal: np.ndarray, xy_obs: np.ndarray, params: np.ndarray,
                     convention: np.ndarray, xy_measured: np.ndarray | None = None) -> ProjectionTerms:
    """Residual-space terms of ideal projections pred_ideal (..., 2) (``xp - c m_x/m_z``, ...)
    and observations xy_obs (..., 2); params (..., NCP); convention (...,), broadcast alike.
    xy_measured: the measurements when xy_obs are adjusted observations (ideal_from_observed)."""
    pred_ideal, xy_obs = np.asarray(pred_ideal, dtype=float), np.asarray(xy_obs, dtype=float)
    shape = np.broadcast_shapes(pred_ideal.shape[:-1], xy_obs.shape[:-1], params.shape[:-1], np.shape(convention))
    pred_ideal = np.broadcast_to(pred_ideal, shape + (2,))
    xy_obs = np.broadcast_to(xy_obs, shape + (2,))
    params = np.broadcast_to(params, shape + (NCP,))
    image = np.broadcast_to(np.asarray(convention) == IMAGE, shape)
    c = params[..., C]
    pp = params[..., XP:YP + 1]
    n = (pred_ideal - pp) / c[..., None]
    obs = np.empty(shape + (2,))
    pred = np.empty(shape + (2,))
    d_ideal = np.zeros(shape + (2, 2))
    d_cam = np.zeros(shape + (2, NCP))
    plate = ~image
    if plate.any():
        meas = None if xy_measured is None else np.broadcast_to(xy_measured, shape + (2,))[plate]
        ideal = ideal_from_observed(xy_obs[plate], params[plate], PLATE, meas)
        obs[plate] = ideal.xy
        pred[plate] = pred_ideal[plate]
        d_ideal[plate] = np.eye(2)
        dp = -ideal.d_camera
        dp[..., :, C] += n[plate]
        dp[..., 0, XP] += 1.0
        dp[..., 1, YP] += 1.0
        d_cam[plate] = dp
    if image.any():
        prm = params[image]
        val, d_u, d_k = brown(n[image], prm)
        cc = c[image]
        A = _affine(prm)
        obs[image] = xy_obs[image]
        pred[image] = pp[image] + cc[:, None] * np.einsum("mij,mj->mi", A, val)
        d_ideal[image] = A @ d_u
        dp = np.zeros((len(prm), 2, NCP))
        dp[:, :, C] = np.einsum("mij,mj->mi", A, val)
        dp[:, 0, XP] = dp[:, 1, YP] = 1.0
        dp[:, :, K1:P2 + 1] = cc[:, None, None] * (A @ d_k)
        dp[:, 0, B1] = cc * val[:, 0]
        dp[:, 0, B2] = cc * val[:, 1]
        d_cam[image] = dp
    return ProjectionTerms(obs, pred, d_ideal, d_cam)


def has_distortion(params: np.ndarray, free: np.ndarray | None = None) -> bool:
    """True if any camera has a nonzero or estimated additional parameter (k, p, b)."""
    params = np.asarray(params)
    if np.any(params[..., DISTORTION_ELEMENTS] != 0):
        return True
    return free is not None and bool(np.any(np.asarray(free)[..., DISTORTION_ELEMENTS]))
