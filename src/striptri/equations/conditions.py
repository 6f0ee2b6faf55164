"""Condition equations per object point (DESIGN section 3), functional model only.

Every function here is batched over m groups of the same shape and returns the misclosures and
their analytic derivatives. Conditions know nothing of weights: ``normal_equations.whiten`` and
``conditions_method`` turn them into whitened pseudo-observations.

Two families:

* ray conditions (coplanarity, scale transfer, height and plan points) are functions of the k ground
  rays ``r`` (Schmid 11, not normalised) and projection centres ``O`` of the photos that see the
  point, plus the given control coordinates ``X``. They return derivatives with respect to r, O
  and X; :func:`ray_chain` carries them on to the plate coordinates, the rotation corrections and
  the interior orientation.
* collinearity (Schmid 14) for full control, from striptri.geometry.collinearity (the projection and its
  Jacobians, shared with the bundle and the triangulation).

The primitives, for a group of k rays and nc conditions, are returned as a :class:`Linearised`:
``d_plate (m, nc, k, 2)``, ``d_rot (m, nc, k, 3)`` (rotation vector, ``R <- R Exp(d)``),
``d_centre (m, nc, k, 3)``, ``d_interior (m, nc, k, 3)`` (c, xp, yp), ``d_control (m, nc, 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.collinearity import collinearity_jacobians


@dataclass
class Linearised:
    """Misclosures g (m, nc) and their derivatives with respect to the primitives (see module doc)."""

    g: np.ndarray
    d_plate: np.ndarray
    d_rot: np.ndarray
    d_centre: np.ndarray
    d_interior: np.ndarray
    d_control: np.ndarray


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


# ---------------------------------------------------------------------------------------------
# Pair geometry


def coplanarity(b, r1, r2):
    """Coplanarity of two rays with their base (Schmid 20): ``g = b . (r1 x r2)``.

    b = O2 - O1, r1, r2: (m, 3) -> g (m,), dg/db, dg/dr1, dg/dr2 (each (m, 3)).
    """
    n = np.cross(r1, r2)
    g = _dot(b, n)
    return g, n, np.cross(r2, b), np.cross(b, r1)


def closest_scales(b, r1, r2):
    """Scales of the closest approach of the lines O1 + s r1 and O2 + t r2 (DESIGN section 3).

    ``s = ((b x r2) . n) / (n . n)``, ``t = ((b x r1) . n) / (n . n)``, ``n = r1 x r2``, b = O2 - O1.
    Expanded with (a x b).(c x d) = (a.c)(b.d) - (a.d)(b.c) for analytic derivatives:
    ``s = [(b.r1)(r2.r2) - (b.r2)(r1.r2)] / h``, ``t = [(b.r1)(r1.r2) - (b.r2)(r1.r1)] / h``,
    ``h = (r1.r1)(r2.r2) - (r1.r2)^2``.

    Returns s, t (m,) and their derivatives ds = (ds/db, ds/dr1, ds/dr2), dt likewise, each (m, 3).
    """
    b1, b2, c12 = _dot(b, r1), _dot(b, r2), _dot(r1, r2)
    a11, a22 = _dot(r1, r1), _dot(r2, r2)
    h = a11 * a22 - c12**2
    fs = b1 * a22 - b2 * c12
    ft = b1 * c12 - b2 * a11
    s, t = fs / h, ft / h
    E = lambda a: a[..., None]  # noqa: E731  (broadcast a scalar per group over xyz)
    dh_r1 = 2 * E(a22) * r1 - 2 * E(c12) * r2
    dh_r2 = 2 * E(a11) * r2 - 2 * E(c12) * r1
    dfs_b = E(a22) * r1 - E(c12) * r2
    dfs_r1 = E(a22) * b - E(b2) * r2
    dfs_r2 = 2 * E(b1) * r2 - E(b2) * r1 - E(c12) * b
    dft_b = E(c12) * r1 - E(a11) * r2
    dft_r1 = E(b1) * r2 + E(c12) * b - 2 * E(b2) * r1
    dft_r2 = E(b1) * r1 - E(a11) * b
    ih = E(1.0 / h)
    ds = (dfs_b * ih, (dfs_r1 - E(s) * dh_r1) * ih, (dfs_r2 - E(s) * dh_r2) * ih)
    dt = (dft_b * ih, (dft_r1 - E(t) * dh_r1) * ih, (dft_r2 - E(t) * dh_r2) * ih)
    return s, t, ds, dt


def projected_scales(b, r1, r2):
    """Schmid's scales from the XZ projection of the pair (72-74, auxiliaries of 61).

    ``II = u2 w1 - u1 w2``, ``[2] = bx w2 - bz u2``, ``[5] = bz u1 - bx w1``,
    ``mu1 = -[2] / II``, ``mu2 = [5] / II``; then O1 + mu1 r1 and O2 + mu2 r2 agree in X and Z.
    Well conditioned only when the base lies roughly along X. Returns mu1, mu2 and their derivatives
    (d/db, d/dr1, d/dr2), each (m, 3), like :func:`closest_scales`.
    """
    bx, bz = b[..., 0], b[..., 2]
    u1, w1, u2, w2 = r1[..., 0], r1[..., 2], r2[..., 0], r2[..., 2]
    II = u2 * w1 - u1 * w2
    a2 = bx * w2 - bz * u2
    a5 = bz * u1 - bx * w1
    mu1, mu2 = -a2 / II, a5 / II
    z = np.zeros_like(II)

    def vec(x, zc):
        return np.stack([x, z, zc], -1)

    dII_r1, dII_r2 = vec(-w2, u2), vec(w1, -u1)
    da2_b, da2_r2 = vec(w2, -u2), vec(-bz, bx)
    da5_b, da5_r1 = vec(-w1, u1), vec(bz, -bx)
    E = lambda a: a[..., None]  # noqa: E731
    iII = E(1.0 / II)
    dmu1 = (-da2_b * iII, -E(mu1) * dII_r1 * iII, (-da2_r2 - E(mu1) * dII_r2) * iII)
    dmu2 = (da5_b * iII, (da5_r1 - E(mu2) * dII_r1) * iII, -E(mu2) * dII_r2 * iII)
    return mu1, mu2, dmu1, dmu2


# ---------------------------------------------------------------------------------------------
# Ray conditions of a point seen by k photos


@dataclass
class RayConditions:
    """g (m, nc) with derivatives d_r (m, nc, k, 3), d_O (m, nc, k, 3), d_X (m, nc, 3)."""

    g: np.ndarray
    d_r: np.ndarray
    d_O: np.ndarray
    d_X: np.ndarray


SCALE_FORMS = ("3d", "xz")


def ray_conditions(r, xyz_centre, xyz_control, given_axes, scale_form: str = "3d",
                   star: bool = False) -> RayConditions:
    """Conditions of one point seen by k >= 1 photos along its chain, with d given coordinates.

    r, xyz_centre: (m, k, 3) ground-frame rays (Schmid 11) and projection centres O in chain order;
    xyz_control: (m, 3) given coordinates X (ignored where not given); given_axes: three bools
    (X, Y, Z given). Derivatives with respect to O and X are RayConditions.d_O and d_X.
    Conditions, in this order:

    * k - 1 coplanarities of consecutive pairs (Schmid 20, :func:`pair_coplanarities`);
    * k - 2 scale transfers of consecutive triples (Schmid 93 or 94, :func:`scale_transfer`);
    * the conditions of a height or plan point (Schmid 18, 19, :func:`control_conditions`), so
      that 2k - (3 - d) conditions hold for every k.

    The count is 2k - (3 - d) whenever that is positive (DESIGN section 3).

    star: the first ray is a hub instead of the start of a path (for points whose rays cannot be
    ordered so that neighbours meet at a useful angle, groups.untangle_chains): coplanarities of
    the pairs (1, j), j = 2..k, and scale transfers "scale of r_1 from the pair (1, 2) equals its
    scale from the pair (1, j)", j = 3..k; the same number of independent conditions, so the same
    adjustment (docs/decisions.md).
    """
    m, k, _ = r.shape
    if scale_form not in SCALE_FORMS:
        raise ValueError(f"unknown scale form {scale_form!r}")
    rows_g, rows_r, rows_O, rows_X = [], [], [], []
    # the pair conditions, all pairs of a point at once (no loop over the rays of a long track):
    # chain (i, i + 1), i = 0..k-2, or star (0, j), j = 1..k-1
    n_pairs = k - 1
    pair = np.arange(n_pairs)
    first = np.zeros(n_pairs, dtype=int) if star else pair
    second = pair + 1
    if n_pairs > 0:
        b = xyz_centre[:, second] - xyz_centre[:, first]  # (m, k - 1, 3)
        r1, r2 = r[:, first], r[:, second]
        g, dr, dO = pair_coplanarities(b, r1, r2, first, second, k)
        rows_g.append(g), rows_r.append(dr), rows_O.append(dO), rows_X.append(np.zeros((m, n_pairs, 3)))
    if k >= 3:
        g, dr, dO = scale_transfer(b, r1, r2, k, scale_form, star)
        rows_g.append(g), rows_r.append(dr), rows_O.append(dO), rows_X.append(np.zeros((m, k - 2, 3)))
    for g, dr, dO, dX in control_conditions(r, xyz_centre, xyz_control, given_axes, scale_form):
        rows_g.append(g), rows_r.append(dr), rows_O.append(dO), rows_X.append(dX)
    if not rows_g:
        return RayConditions(np.zeros((m, 0)), np.zeros((m, 0, k, 3)), np.zeros((m, 0, k, 3)), np.zeros((m, 0, 3)))
    return RayConditions(
        np.concatenate(rows_g, 1), np.concatenate(rows_r, 1), np.concatenate(rows_O, 1), np.concatenate(rows_X, 1)
    )


def pair_coplanarities(b, r1, r2, first, second, k: int):
    """Schmid (20) for the pairs (first[j], second[j]) of a point's k rays: ``g = b . (r1 x r2)``.

    b, r1, r2: (m, p, 3) the pairs' bases O_second - O_first (m) and rays (ground frame).
    Returns g (m, p) and its derivatives (m, p, k, 3) with respect to each ray and each centre."""
    m, n_pairs = b.shape[:2]
    pair = np.arange(n_pairs)
    g, dg_b, dg_r1, dg_r2 = coplanarity(b, r1, r2)
    dr, dO = np.zeros((m, n_pairs, k, 3)), np.zeros((m, n_pairs, k, 3))
    dr[:, pair, first], dr[:, pair, second] = dg_r1, dg_r2
    dO[:, pair, first], dO[:, pair, second] = -dg_b, dg_b
    return g, dr, dO


def scale_transfer(b, r1, r2, k: int, scale_form: str = "3d", star: bool = False):
    """Schmid's scale-transfer conditions (93) of a point's k >= 3 rays, one per consecutive triple.

    b, r1, r2: (m, k - 1, 3) the pairs of the chain (i, i + 1) or, star, of the hub (0, j). Chain:
    the scale of ray i from the pair (i - 1, i) minus its scale from the pair (i, i + 1), i = 1..k-2.
    Star: the scale of ray 0 from the pair (0, 1) minus its scale from (0, j), j = 2..k-1.
    ``scale_form`` "3d": the closest-approach scales (closest_scales, direction-free); "xz":
    Schmid's projected form (94) ``[2]_2 II_1 + [5]_1 II_2 = 0`` (projected_scales), written as the
    difference of the two scales. Returns g (m, k - 2) and its derivatives (m, k - 2, k, 3) with
    respect to each ray and each centre (the scales are dimensionless)."""
    m = b.shape[0]
    pair_scales = closest_scales if scale_form == "3d" else projected_scales
    sc, tc, ds, dt = pair_scales(b, r1, r2)  # the scales of every pair: (m, k - 1), derivatives (m, k - 1, 3)
    q = np.arange(k - 2)
    dr, dO = np.zeros((m, k - 2, k, 3)), np.zeros((m, k - 2, k, 3))
    if star:
        # scale of r_0 from the pair (0, 1) minus its scale from the pair (0, j), j = 2..k-1
        j = q + 2
        g = sc[:, :1] - sc[:, 1:]
        dr[:, q, 0] = ds[1][:, :1] - ds[1][:, 1:]
        dr[:, q, 1] = ds[2][:, :1]
        dr[:, q, j] = -ds[2][:, 1:]
        dO[:, q, 0] = -ds[0][:, :1] + ds[0][:, 1:]
        dO[:, q, 1] = ds[0][:, :1]
        dO[:, q, j] = -ds[0][:, 1:]
    else:
        # scale of r_i from the pair (i-1, i) (second ray) minus its scale from (i, i+1) (first
        # ray), i = 1..k-2: pair q = i - 1 gives t, pair q + 1 gives s
        g = tc[:, :-1] - sc[:, 1:]
        dr[:, q, q] = dt[1][:, :-1]
        dr[:, q, q + 1] = dt[2][:, :-1] - ds[1][:, 1:]
        dr[:, q, q + 2] = -ds[2][:, 1:]
        dO[:, q, q] = -dt[0][:, :-1]
        dO[:, q, q + 1] = dt[0][:, :-1] + ds[0][:, 1:]
        dO[:, q, q + 2] = -ds[0][:, 1:]
    return g, dr, dO


def control_conditions(r, xyz_centre, xyz_control, given_axes, scale_form: str = "3d") -> list:
    """Schmid's conditions of a height or plan point (18, 19): the given coordinates of the first
    pair's intersection ``O_1 + s r_1`` (s its scale on the first ray: closest approach, or
    Schmid's mu' of formula 74 for the "xz" form) equal the given ones, one condition per given
    axis: Z for a height point (18), X and Y for a plan point (19). A plan point on one photo: its
    ray meets the vertical through (X, Y) (the coplanarity of the ray with that vertical). A full
    point (d = 3) or a tie point has none here.

    r, xyz_centre: (m, k, 3); xyz_control: (m, 3) (m); given_axes: three bools (X, Y, Z). Returns a
    list of (g (m, 1) m, d_r (m, 1, k, 3), d_O (m, 1, k, 3), d_X (m, 1, 3)), one per condition."""
    m, k, _ = r.shape
    d = int(given_axes[0]) + int(given_axes[1]) + int(given_axes[2])
    out = []

    def new_row():
        return np.zeros((m, k, 3)), np.zeros((m, k, 3)), np.zeros((m, 3))

    if d in (1, 2) and k >= 2:
        pair_scales = closest_scales if scale_form == "3d" else projected_scales
        b = xyz_centre[:, 1] - xyz_centre[:, 0]
        s, _, ds, _ = pair_scales(b, r[:, 0], r[:, 1])
        xyz_meet = xyz_centre[:, 0] + s[:, None] * r[:, 0]  # the first pair's intersection
        for axis, given in enumerate(given_axes):
            if not given:
                continue
            dr, dO, dX = new_row()
            # xyz_meet_axis = O0_axis + s r0_axis
            dr[:, 0] = r[:, 0, axis, None] * ds[1]
            dr[:, 0, axis] += s
            dr[:, 1] = r[:, 0, axis, None] * ds[2]
            dO[:, 0] = -r[:, 0, axis, None] * ds[0]
            dO[:, 0, axis] += 1.0
            dO[:, 1] = r[:, 0, axis, None] * ds[0]
            dX[:, axis] = -1.0
            out.append((xyz_meet[:, axis, None] - xyz_control[:, axis, None], dr[:, None], dO[:, None], dX[:, None]))
    elif d == 2 and k == 1:
        # the ray and the vertical through (X, Y): coplanarity with b = (X, Y, 0) - O, r2 = e_z
        foot = np.concatenate([xyz_control[:, :2], np.zeros((m, 1))], axis=1)
        ez = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (m, 3))
        g, dg_b, dg_r1, _ = coplanarity(foot - xyz_centre[:, 0], r[:, 0], ez)
        dr, dO, dX = new_row()
        dr[:, 0] = dg_r1
        dO[:, 0] = -dg_b
        dX[:, :2] = dg_b[:, :2]
        out.append((g[:, None], dr[:, None], dO[:, None], dX[:, None]))
    return out


def first_pair_intersection(r, xyz_centre) -> RayConditions:
    """The point as a ray group defines it: the closest approach on the first ray of its first pair,
    ``X = O_1 + s r_1`` (DESIGN section 3, as the height and plan point conditions use it, Schmid
    18-19), as three rows "g" = X (m, 3) with derivatives d_r, d_O (m, 3, k, 3) and d_X zero.
    r, xyz_centre: (m, k, 3), k >= 2, in chain order. Used by the distance conditions
    (striptri.equations.joint_groups)."""
    m, k, _ = r.shape
    b = xyz_centre[:, 1] - xyz_centre[:, 0]
    r0 = r[:, 0]
    s, _, ds, _ = closest_scales(b, r0, r[:, 1])
    eye = np.eye(3)
    d_r, d_O = np.zeros((m, 3, k, 3)), np.zeros((m, 3, k, 3))
    # X_axis = O0_axis + s r0_axis
    d_r[:, :, 0] = r0[:, :, None] * ds[1][:, None, :] + s[:, None, None] * eye
    d_r[:, :, 1] = r0[:, :, None] * ds[2][:, None, :]
    d_O[:, :, 0] = eye - r0[:, :, None] * ds[0][:, None, :]
    d_O[:, :, 1] = r0[:, :, None] * ds[0][:, None, :]
    return RayConditions(xyz_centre[:, 0] + s[:, None] * r0, d_r, d_O, np.zeros((m, 3, 3)))


def ray_chain(rc: RayConditions, R_ground_from_cam, p) -> Linearised:
    """Carry derivatives with respect to rays on to the primitives.

    ``r = R p`` with ``p = (x - xp, y - yp, -c)``: dr/dx = R e1, dr/dy = R e2, dr/dc = -R e3,
    dr/dxp = -R e1, dr/dyp = -R e2, and with ``R <- R Exp(d)``: dr/dd = -R [p]x, so that
    ``(dg/dr) dr/dd = p x (R^T dg/dr)``. R_ground_from_cam (R): (m, k, 3, 3), p: (m, k, 3) in the
    camera frame.
    """
    Rt_g = np.matmul(rc.d_r[..., None, :], R_ground_from_cam[:, None])[..., 0, :]  # R^T dg/dr: (m, nc, k, 3)
    d_plate = Rt_g[..., :2]
    d_rot = np.cross(p[:, None], Rt_g)
    d_interior = np.stack([-Rt_g[..., 2], -Rt_g[..., 0], -Rt_g[..., 1]], -1)
    return Linearised(rc.g, d_plate, d_rot, rc.d_O, d_interior, rc.d_X)


# ---------------------------------------------------------------------------------------------
# Collinearity (full control)


def collinearity(xy_plate, R_ground_from_cam, xyz_centre, interior, xyz_ground) -> Linearised:
    """Collinearity of a full control point with each of its k photos (Schmid 14).

    ``g = xy_plate - (xp - c m_x/m_z, yp - c m_y/m_z)``, ``m = R^T (X - O)``, two conditions per
    photo in the order (x_1, y_1, x_2, y_2, ...). xy_plate: (m, k, 2); R_ground_from_cam:
    (m, k, 3, 3); xyz_centre, interior (c, xp, yp): (m, k, 3); xyz_ground (the control point):
    (m, 3). The projection and its derivatives are striptri.geometry.collinearity's.
    """
    n_groups, k, _ = xy_plate.shape
    jac = collinearity_jacobians(R_ground_from_cam, xyz_centre, interior, xyz_ground[:, None, :])
    g = (xy_plate - jac.xy_plate).reshape(n_groups, 2 * k)
    # condition 2j + a depends on ray j only: its row of each (m, k, 2, 3) derivative of the projection
    nc = 2 * k
    row, ray = np.arange(nc), np.repeat(np.arange(k), 2)

    def on_its_ray(d_projection, width=3):
        out = np.zeros((n_groups, nc, k, width))
        out[:, row, ray] = d_projection.reshape(n_groups, nc, width)
        return out

    d_plate = on_its_ray(np.broadcast_to(np.eye(2), (n_groups, k, 2, 2)), 2)
    d_rot = on_its_ray(-jac.d_rotation)
    d_centre = on_its_ray(-jac.d_centre)
    d_interior = on_its_ray(-jac.d_interior)
    d_control = -jac.d_ground.reshape(n_groups, nc, 3)
    return Linearised(g, d_plate, d_rot, d_centre, d_interior, d_control)
