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

Compact form (``compact=True``): a condition involves at most three of its point's rays (a pair's
coplanarity two, a scale transfer three, a collinearity one), so for long tracks the k-ray
derivatives are almost all zero (a 66-ray close-range target: 129 conditions of 66 rays each, 2 %
nonzero). In the compact form ``rays`` (nc, t) names the t rays of each condition (repeated where a
condition has fewer, with zero derivatives there) and every per-ray derivative is (m, nc, t, ...)
for those rays; :func:`expanded` gives the k-ray form. The linearisation works compact and
scatters once into the whitened system's blocks (linearise.unknown_blocks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.collinearity import collinearity_jacobians


@dataclass
class Linearised:
    """Misclosures g (m, nc) and their derivatives with respect to the primitives (see module doc);
    rays: (nc, t) the rays of each condition in the compact form, None in the k-ray form."""

    g: np.ndarray
    d_plate: np.ndarray
    d_rot: np.ndarray
    d_centre: np.ndarray
    d_interior: np.ndarray
    d_control: np.ndarray
    rays: np.ndarray | None = None


def expanded(per_ray: np.ndarray, rays: np.ndarray | None, k: int) -> np.ndarray:
    """A compact derivative (m, nc, t, ...) spread over all k rays (m, nc, k, ...) (module doc);
    unchanged when rays is None (already k-ray)."""
    if rays is None:
        return per_ray
    m, nc = per_ray.shape[:2]
    out = np.zeros((m, nc, k) + per_ray.shape[3:])
    (cond, slot), (dup_cond, dup_slot) = _distinct_slots(rays)
    out[:, cond, rays[cond, slot]] = per_ray[:, cond, slot]  # one scatter of every distinct (condition, ray)
    if len(dup_cond):  # a ray repeated within a condition (zero derivatives there): added to it
        out[:, dup_cond, rays[dup_cond, dup_slot]] += per_ray[:, dup_cond, dup_slot]
    return out


def _distinct_slots(rays: np.ndarray):
    """((condition, slot) of the first occurrence of each ray in each condition's row of ``rays``
    (nc, t), (condition, slot) of the repeats): each list meets a (condition, ray) at most once."""
    repeat = np.zeros(rays.shape, dtype=bool)
    for j in range(1, rays.shape[1]):
        repeat[:, j] = (rays[:, :j] == rays[:, j: j + 1]).any(axis=1)
    return np.nonzero(~repeat), np.nonzero(repeat)


def of_rays(per_ray: np.ndarray, rays: np.ndarray | None) -> np.ndarray:
    """Per-ray quantities (m, k, ...) as the derivatives see them: (m, nc, t, ...) for the rays of
    each condition in the compact form, (m, 1, k, ...) (broadcast over the conditions) otherwise."""
    return per_ray[:, None] if rays is None else per_ray[:, rays]


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _cross(a, b):
    """np.cross of (..., 3) vectors, the same numbers in half the time (np.cross moves axes first)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


# ---------------------------------------------------------------------------------------------
# Pair geometry


def coplanarity(b, r1, r2):
    """Coplanarity of two rays with their base (Schmid 20): ``g = b . (r1 x r2)``.

    b = O2 - O1, r1, r2: (m, 3) -> g (m,), dg/db, dg/dr1, dg/dr2 (each (m, 3)).
    """
    n = _cross(r1, r2)
    g = _dot(b, n)
    return g, n, _cross(r2, b), _cross(b, r1)


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
    """g (m, nc) with derivatives d_r (m, nc, k, 3), d_O (m, nc, k, 3), d_X (m, nc, 3); in the
    compact form (module doc) d_r, d_O (m, nc, t, 3) for the rays ``rays`` (nc, t)."""

    g: np.ndarray
    d_r: np.ndarray
    d_O: np.ndarray
    d_X: np.ndarray
    rays: np.ndarray | None = None


SCALE_FORMS = ("3d", "xz")


def ray_conditions(r, xyz_centre, xyz_control, given_axes, scale_form: str = "3d",
                   star: bool = False, compact: bool = False) -> RayConditions:
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

    compact: the derivatives for the three rays of each condition (module doc), else for all k.
    """
    m, k, _ = r.shape
    if scale_form not in SCALE_FORMS:
        raise ValueError(f"unknown scale form {scale_form!r}")
    parts = []  # (g (m, n), d_r, d_O (m, n, 3, 3), d_X (m, n, 3), rays (n, 3)) of each kind of condition
    # the pair conditions, all pairs of a point at once (no loop over the rays of a long track):
    # chain (i, i + 1), i = 0..k-2, or star (0, j), j = 1..k-1
    n_pairs = k - 1
    pair = np.arange(n_pairs)
    first = np.zeros(n_pairs, dtype=int) if star else pair
    second = pair + 1
    if n_pairs > 0:
        b = xyz_centre[:, second] - xyz_centre[:, first]  # (m, k - 1, 3)
        r1, r2 = r[:, first], r[:, second]
        g, dr, dO, rays = pair_coplanarities(b, r1, r2, first, second)
        parts.append((g, dr, dO, np.zeros((m, n_pairs, 3)), rays))
    if k >= 3:
        g, dr, dO, rays = scale_transfer(b, r1, r2, k, scale_form, star)
        parts.append((g, dr, dO, np.zeros((m, k - 2, 3)), rays))
    parts += control_conditions(r, xyz_centre, xyz_control, given_axes, scale_form)
    if not parts:
        return RayConditions(np.zeros((m, 0)), np.zeros((m, 0, k, 3)), np.zeros((m, 0, k, 3)), np.zeros((m, 0, 3)))
    g, d_r, d_O, d_X, rays = (np.concatenate(column, axis=1 if i < 4 else 0) for i, column in enumerate(zip(*parts)))
    if compact:
        return RayConditions(g, d_r, d_O, d_X, rays)
    return RayConditions(g, expanded(d_r, rays, k), expanded(d_O, rays, k), d_X)


def pair_coplanarities(b, r1, r2, first, second):
    """Schmid (20) for the pairs (first[j], second[j]) of a point's rays: ``g = b . (r1 x r2)``.

    b, r1, r2: (m, p, 3) the pairs' bases O_second - O_first (m) and rays (ground frame).
    Returns g (m, p), its derivatives (m, p, 3, 3) with respect to the rays and centres
    rays (p, 3) = (first, second, second) (compact form, module doc; the third has none)."""
    g, dg_b, dg_r1, dg_r2 = coplanarity(b, r1, r2)
    zero = np.zeros_like(dg_b)
    dr = np.stack([dg_r1, dg_r2, zero], axis=2)
    dO = np.stack([-dg_b, dg_b, zero], axis=2)
    return g, dr, dO, np.stack([first, second, second], axis=1)


def scale_transfer(b, r1, r2, k: int, scale_form: str = "3d", star: bool = False):
    """Schmid's scale-transfer conditions (93) of a point's k >= 3 rays, one per consecutive triple.

    b, r1, r2: (m, k - 1, 3) the pairs of the chain (i, i + 1) or, star, of the hub (0, j). Chain:
    the scale of ray i from the pair (i - 1, i) minus its scale from the pair (i, i + 1), i = 1..k-2.
    Star: the scale of ray 0 from the pair (0, 1) minus its scale from (0, j), j = 2..k-1.
    ``scale_form`` "3d": the closest-approach scales (closest_scales, direction-free); "xz":
    Schmid's projected form (94) ``[2]_2 II_1 + [5]_1 II_2 = 0`` (projected_scales), written as the
    difference of the two scales. Returns g (m, k - 2), its derivatives (m, k - 2, 3, 3) with
    respect to the three rays and centres of each condition, and those rays (k - 2, 3) (compact
    form, module doc; the scales are dimensionless)."""
    pair_scales = closest_scales if scale_form == "3d" else projected_scales
    sc, tc, ds, dt = pair_scales(b, r1, r2)  # the scales of every pair: (m, k - 1), derivatives (m, k - 1, 3)
    q = np.arange(k - 2)
    if star:
        # scale of r_0 from the pair (0, 1) minus its scale from the pair (0, j), j = 2..k-1
        g = sc[:, :1] - sc[:, 1:]
        dr = [ds[1][:, :1] - ds[1][:, 1:], np.broadcast_to(ds[2][:, :1], ds[2][:, 1:].shape), -ds[2][:, 1:]]
        dO = [-ds[0][:, :1] + ds[0][:, 1:], np.broadcast_to(ds[0][:, :1], ds[0][:, 1:].shape), -ds[0][:, 1:]]
        rays = np.stack([np.zeros_like(q), np.ones_like(q), q + 2], axis=1)
    else:
        # scale of r_i from the pair (i-1, i) (second ray) minus its scale from (i, i+1) (first
        # ray), i = 1..k-2: pair q = i - 1 gives t, pair q + 1 gives s
        g = tc[:, :-1] - sc[:, 1:]
        dr = [dt[1][:, :-1], dt[2][:, :-1] - ds[1][:, 1:], -ds[2][:, 1:]]
        dO = [-dt[0][:, :-1], dt[0][:, :-1] + ds[0][:, 1:], -ds[0][:, 1:]]
        rays = np.stack([q, q + 1, q + 2], axis=1)
    return g, np.stack(dr, axis=2), np.stack(dO, axis=2), rays


def control_conditions(r, xyz_centre, xyz_control, given_axes, scale_form: str = "3d") -> list:
    """Schmid's conditions of a height or plan point (18, 19): the given coordinates of the first
    pair's intersection ``O_1 + s r_1`` (s its scale on the first ray: closest approach, or
    Schmid's mu' of formula 74 for the "xz" form) equal the given ones, one condition per given
    axis: Z for a height point (18), X and Y for a plan point (19). A plan point on one photo: its
    ray meets the vertical through (X, Y) (the coplanarity of the ray with that vertical). A full
    point (d = 3) or a tie point has none here.

    r, xyz_centre: (m, k, 3); xyz_control: (m, 3) (m); given_axes: three bools (X, Y, Z). Returns a
    list of (g (m, 1) m, d_r (m, 1, 3, 3), d_O (m, 1, 3, 3), d_X (m, 1, 3), rays (1, 3)), one per
    condition, in the compact form (module doc): the first two rays, or the one ray of k = 1."""
    m, k, _ = r.shape
    d = int(given_axes[0]) + int(given_axes[1]) + int(given_axes[2])
    out = []
    rays = np.array([[0, min(1, k - 1), min(1, k - 1)]])

    def new_row():
        return np.zeros((m, 3, 3)), np.zeros((m, 3, 3)), np.zeros((m, 3))

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
            out.append((xyz_meet[:, axis, None] - xyz_control[:, axis, None], dr[:, None], dO[:, None], dX[:, None],
                        rays))
    elif d == 2 and k == 1:
        # the ray and the vertical through (X, Y): coplanarity with b = (X, Y, 0) - O, r2 = e_z
        foot = np.concatenate([xyz_control[:, :2], np.zeros((m, 1))], axis=1)
        ez = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (m, 3))
        g, dg_b, dg_r1, _ = coplanarity(foot - xyz_centre[:, 0], r[:, 0], ez)
        dr, dO, dX = new_row()
        dr[:, 0] = dg_r1
        dO[:, 0] = -dg_b
        dX[:, :2] = dg_b[:, :2]
        out.append((g[:, None], dr[:, None], dO[:, None], dX[:, None], rays))
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
    camera frame. Keeps rc's form (compact or k-ray, module doc).
    """
    R = of_rays(R_ground_from_cam, rc.rays)
    Rt_g = np.matmul(rc.d_r[..., None, :], R)[..., 0, :]  # R^T dg/dr: (m, nc, k or t, 3)
    d_plate = Rt_g[..., :2]
    d_rot = _cross(of_rays(p, rc.rays), Rt_g)
    d_interior = np.stack([-Rt_g[..., 2], -Rt_g[..., 0], -Rt_g[..., 1]], -1)
    return Linearised(rc.g, d_plate, d_rot, rc.d_O, d_interior, rc.d_X, rc.rays)


# ---------------------------------------------------------------------------------------------
# Collinearity (full control)


def collinearity(xy_plate, R_ground_from_cam, xyz_centre, interior, xyz_ground, compact: bool = False) -> Linearised:
    """Collinearity of a full control point with each of its k photos (Schmid 14).

    ``g = xy_plate - (xp - c m_x/m_z, yp - c m_y/m_z)``, ``m = R^T (X - O)``, two conditions per
    photo in the order (x_1, y_1, x_2, y_2, ...). xy_plate: (m, k, 2); R_ground_from_cam:
    (m, k, 3, 3); xyz_centre, interior (c, xp, yp): (m, k, 3); xyz_ground (the control point):
    (m, 3). The projection and its derivatives are striptri.geometry.collinearity's. compact: each
    condition's derivatives for its one ray (module doc), else for all k.
    """
    n_groups, k, _ = xy_plate.shape
    jac = collinearity_jacobians(R_ground_from_cam, xyz_centre, interior, xyz_ground[:, None, :])
    g = (xy_plate - jac.xy_plate).reshape(n_groups, 2 * k)
    # condition 2j + a depends on ray j only: its row of each (m, k, 2, 3) derivative of the projection
    nc = 2 * k
    ray = np.repeat(np.arange(k), 2)

    def on_its_ray(d_projection, width=3):
        per_ray = d_projection.reshape(n_groups, nc, 1, width)
        return per_ray if compact else expanded(per_ray, ray[:, None], k)

    d_plate = on_its_ray(np.broadcast_to(np.eye(2), (n_groups, k, 2, 2)), 2)
    d_rot = on_its_ray(-jac.d_rotation)
    d_centre = on_its_ray(-jac.d_centre)
    d_interior = on_its_ray(-jac.d_interior)
    d_control = -jac.d_ground.reshape(n_groups, nc, 3)
    return Linearised(g, d_plate, d_rot, d_centre, d_interior, d_control, ray[:, None] if compact else None)
