"""Every analytic Jacobian against central differences, in the parametrisation the solver updates.

Central differences with step h have truncation error O(h^2 f''') and round-off O(eps f / h);
with h = 1e-5 of each variable's scale both are below 1e-9 of the derivative here, so a relative
agreement of 1e-6 (per condition, relative to the largest derivative of that condition in the
same array) leaves a wide margin yet catches any wrong term. Rotations are perturbed as the
solver does, ``R <- R Exp(d)`` (DESIGN section 1), with scipy's exponential map, not striptri's.
Orientations are random, including steep ones (any attitude, cameras looking sideways or up).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from synthetic_pairs import NoiseOptions, PairOptions, make_pair, strip_points

from striptri.geometry import collinearity
from striptri.equations import conditions
from striptri import model
from striptri.adjustment import observations_of
from striptri.equations.groups import build_batches
from striptri.equations.linearise import At, evaluate, linearise, unknown_blocks
from striptri.equations.parameter_observations import build_parameter_observations
from striptri.equations.parameters import build_layout, initial_state, reduction_offset
from striptri.geometry.rotations import angles_from_R, angles_jacobian

RTOL = 1e-6


def exp_map(d):
    d = np.asarray(d, dtype=float)
    return Rotation.from_rotvec(d.reshape(-1, 3)).as_matrix().reshape(d.shape[:-1] + (3, 3))


def numeric_jacobian(fun, x, h):
    """Central differences of a batched function. x: (m, *shape); fun(x) -> (m, *out).
    h: step (scalar or broadcastable to shape). Returns (m, *out, *shape)."""
    x = np.asarray(x, dtype=float)
    shape = x.shape[1:]
    h = np.broadcast_to(np.asarray(h, dtype=float), shape)
    cols = []
    for idx in np.ndindex(*shape):
        e = np.zeros_like(x)
        e[(slice(None),) + idx] = h[idx]
        cols.append((fun(x + e) - fun(x - e)) / (2 * h[idx]))
    J = np.stack(cols, -1)
    return J.reshape(J.shape[:-1] + shape)


def assert_jacobian(analytic, numeric, n_out_axes, rtol=RTOL):
    """Compare per output (the first 1 + n_out_axes axes), relative to the largest analytic
    derivative of that output in this array (entries exactly zero on both sides pass)."""
    analytic, numeric = np.broadcast_arrays(analytic, numeric)
    assert analytic.shape == numeric.shape
    lead = analytic.shape[: 1 + n_out_axes]
    a = analytic.reshape(lead + (-1,))
    n = numeric.reshape(lead + (-1,))
    scale = np.maximum(np.abs(a).max(-1, keepdims=True), np.abs(n).max(-1, keepdims=True))
    err = np.abs(a - n)
    worst = float(np.max(err / np.where(scale > 0, scale, 1.0)))
    assert worst < rtol, f"largest relative difference {worst:.3g}"
    return worst


def random_rotations(rng, m, steep=True):
    """Uniform random attitudes (steep: anything) or near-vertical ones (within 5 deg)."""
    if steep:
        return Rotation.random(m, random_state=rng.integers(2**31)).as_matrix()
    return Rotation.from_rotvec(rng.normal(0, np.radians(3), size=(m, 3))).as_matrix()


def strip_geometry(rng, m, k, rotate_scene=True):
    """m groups of k photos along a strip at 1500 m (base ~900 m) looking at a common ground
    point, rays of plate length (~150 mm) slightly off the point (non-intersecting), given
    coordinates near it; optionally the whole scene rigidly rotated (steep orientations).
    Returns r, O: (m, k, 3); X: (m, 3)."""
    O = np.zeros((m, k, 3))
    O[..., 0] = 900.0 * np.arange(k) - 900.0 * (k - 1) / 2 + rng.normal(0, 20, (m, k))
    O[..., 1] = rng.normal(0, 20, (m, k))
    O[..., 2] = 1500.0 + rng.normal(0, 20, (m, k))
    P = np.stack([rng.uniform(-300, 300, m), rng.uniform(-900, 900, m), rng.uniform(-80, 80, m)], -1)
    target = P[:, None, :] + rng.normal(0, 3.0, (m, k, 3))
    r = target - O
    r *= 150.0 / np.linalg.norm(r, axis=-1, keepdims=True)
    X = P + rng.normal(0, 2.0, (m, 3))
    if rotate_scene:
        Q = random_rotations(rng, m)
        r = np.einsum("mij,mkj->mki", Q, r)
        O = np.einsum("mij,mkj->mki", Q, O)
        X = np.einsum("mij,mj->mi", Q, X)
    return r, O, X


# ---------------------------------------------------------------------------------------------
# pair geometry


@pytest.mark.parametrize("rotate", [False, True], ids=["near-vertical", "steep"])
def test_coplanarity(rotate):
    rng = np.random.default_rng(1)
    r, O, _ = strip_geometry(rng, 8, 2, rotate)
    b, r1, r2 = O[:, 1] - O[:, 0], r[:, 0], r[:, 1]
    g, d_b, d_r1, d_r2 = conditions.coplanarity(b, r1, r2)
    assert np.allclose(g, np.einsum("mi,mi->m", b, np.cross(r1, r2)))
    f = lambda bb, a1, a2: conditions.coplanarity(bb, a1, a2)[0]  # noqa: E731
    assert_jacobian(d_b, numeric_jacobian(lambda x: f(x, r1, r2), b, 1e-3), 0)
    assert_jacobian(d_r1, numeric_jacobian(lambda x: f(b, x, r2), r1, 1e-3), 0)
    assert_jacobian(d_r2, numeric_jacobian(lambda x: f(b, r1, x), r2, 1e-3), 0)


@pytest.mark.parametrize(
    "fun, rotate",
    [(conditions.closest_scales, False), (conditions.closest_scales, True), (conditions.projected_scales, False)],
    ids=["closest, near-vertical", "closest, steep", "projected xz"],
)
def test_pair_scales(fun, rotate):
    rng = np.random.default_rng(2)
    r, O, _ = strip_geometry(rng, 8, 2, rotate)
    b, r1, r2 = O[:, 1] - O[:, 0], r[:, 0], r[:, 1]
    s, t, ds, dt = fun(b, r1, r2)
    args = [b, r1, r2]
    for which, (value, deriv) in enumerate([(s, ds), (t, dt)]):
        for a in range(3):
            def f(x, a=a):
                xs = list(args)
                xs[a] = x
                return fun(*xs)[which]
            assert_jacobian(deriv[a], numeric_jacobian(f, args[a], 1e-5 * np.abs(args[a]).max()), 0)


def test_closest_scales_are_the_closest_points():
    """The defining property (DESIGN section 3): O1 + s r1 - (O2 + t r2) is normal to both rays."""
    rng = np.random.default_rng(3)
    r, O, _ = strip_geometry(rng, 8, 2, True)
    s, t, _, _ = conditions.closest_scales(O[:, 1] - O[:, 0], r[:, 0], r[:, 1])
    gap = O[:, 0] + s[:, None] * r[:, 0] - O[:, 1] - t[:, None] * r[:, 1]
    for j in range(2):
        cos = np.einsum("mi,mi->m", gap, r[:, j]) / (np.linalg.norm(gap, axis=1) * np.linalg.norm(r[:, j], axis=1))
        assert np.abs(cos).max() < 1e-9


# ---------------------------------------------------------------------------------------------
# ray conditions of a point in k photos

KINDS = {"tie": model.TIE, "height": model.HEIGHT, "plan": model.PLAN}


def _ray_cases():
    for kind in KINDS:
        for k in (1, 2, 3, 4):
            for form, rotate in (("3d", False), ("3d", True), ("xz", False)):
                yield kind, k, form, rotate, False
        for k in (3, 4, 5):  # the hub layout of chains that no order saves (groups.untangle_chains)
            yield kind, k, "3d", True, True


@pytest.mark.parametrize("kind, k, form, rotate, star", list(_ray_cases()))
def test_ray_conditions(kind, k, form, rotate, star):
    rng = np.random.default_rng([4, k, model.GIVEN_AXES[KINDS[kind]].count(True), rotate])
    r, O, X = strip_geometry(rng, 6, k, rotate)
    axes = model.GIVEN_AXES[KINDS[kind]]
    rc = conditions.ray_conditions(r, O, X, axes, form, star)
    nc = max(0, 2 * k - (3 - sum(axes)))
    assert rc.g.shape == (6, nc)
    assert rc.d_r.shape == (6, nc, k, 3) and rc.d_O.shape == (6, nc, k, 3) and rc.d_X.shape == (6, nc, 3)
    if nc == 0:
        return
    g = lambda rr, OO, XX: conditions.ray_conditions(rr, OO, XX, axes, form, star).g  # noqa: E731
    assert_jacobian(rc.d_r, numeric_jacobian(lambda x: g(x, O, X), r, 1e-3), 1)
    assert_jacobian(rc.d_O, numeric_jacobian(lambda x: g(r, x, X), O, 1e-2), 1)
    assert_jacobian(rc.d_X, numeric_jacobian(lambda x: g(r, O, x), X, 1e-2), 1)


def test_ray_conditions_vanish_for_consistent_rays():
    """Exact rays through a point with the given coordinates: every condition is zero (both
    scale forms), and a perturbed plate makes them non-zero (the test can fail)."""
    rng = np.random.default_rng(5)
    m, k = 5, 4
    O = np.zeros((m, k, 3))
    O[..., 0] = 900.0 * np.arange(k)
    O[..., 1] = rng.normal(0, 20, (m, k))
    O[..., 2] = 1500 + rng.normal(0, 20, (m, k))
    X = np.stack([rng.uniform(500, 800, m), rng.uniform(-500, 500, m), rng.uniform(-50, 50, m)], -1)
    r = (X[:, None, :] - O) * 0.1
    for kind in KINDS.values():
        for form, star in (("3d", False), ("xz", False), ("3d", True)):
            g = conditions.ray_conditions(r, O, X, model.GIVEN_AXES[kind], form, star).g
            # round-off of b . (r1 x r2) with |b| |r|^2 ~ 1e8: far below 1e-6
            assert np.abs(g).max() < 1e-6
            r_bad = r.copy()
            r_bad[:, 1, 1] += 0.01  # the second ray misses the point
            g_bad = conditions.ray_conditions(r_bad, O, X + 1.0, model.GIVEN_AXES[kind], form, star).g
            assert np.abs(g_bad).max() > 1e-3


# ---------------------------------------------------------------------------------------------
# chain rule to the primitives; collinearity


def _primitives(rng, m, k, rotate):
    """Plate coordinates, attitudes, centres, interior (per ray), control for m groups of k rays:
    the aerial geometry of strip_geometry seen by near-vertical cameras of any heading (the point
    inside the format), then, for steep cases, the whole scene rigidly rotated at random."""
    r, O, X = strip_geometry(rng, m, k, rotate_scene=False)
    interior = np.broadcast_to([152.0, 0.01, -0.02], (m, k, 3)).copy()
    interior[..., 0] += rng.normal(0, 0.5, (m, k))
    heading = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi, (m * k, 1))).as_matrix()
    R = (random_rotations(rng, m * k, steep=False) @ heading).reshape(m, k, 3, 3)
    p_cam = np.einsum("mkji,mkj->mki", R, r)  # the plate point whose ray R p is parallel to r
    assert np.all(p_cam[..., 2] < 0)
    p_cam *= (interior[..., 0] / -p_cam[..., 2])[..., None]
    xy = p_cam[..., :2] + interior[..., 1:]
    if rotate:
        Q = random_rotations(rng, m)
        R = np.einsum("mij,mkjl->mkil", Q, R)
        O = np.einsum("mij,mkj->mki", Q, O)
        X = np.einsum("mij,mj->mi", Q, X)
    return xy, R, O, interior, X


def _ray_chain_g(xy, d, O, interior, X, R, axes, form):
    p = np.stack([xy[..., 0] - interior[..., 1], xy[..., 1] - interior[..., 2], -interior[..., 0]], -1)
    r = np.einsum("mkij,mkj->mki", R @ exp_map(d), p)
    return conditions.ray_conditions(r, O, X, axes, form).g


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("k", [1, 2, 3, 4])
@pytest.mark.parametrize("rotate", [False, True], ids=["near-vertical", "steep"])
def test_ray_chain(kind, k, rotate):
    axes = model.GIVEN_AXES[KINDS[kind]]
    rng = np.random.default_rng([6, k, sum(axes), rotate])
    m = 5
    xy, R, O, interior, X = _primitives(rng, m, k, rotate)
    p = np.stack([xy[..., 0] - interior[..., 1], xy[..., 1] - interior[..., 2], -interior[..., 0]], -1)
    r = np.einsum("mkij,mkj->mki", R, p)
    lin = conditions.ray_chain(conditions.ray_conditions(r, O, X, axes, "3d"), R, p)
    nc = max(0, 2 * k - (3 - sum(axes)))
    assert lin.g.shape == (m, nc) and lin.d_plate.shape == (m, nc, k, 2) and lin.d_rot.shape == (m, nc, k, 3)
    assert lin.d_interior.shape == (m, nc, k, 3) and lin.d_centre.shape == (m, nc, k, 3)
    if nc == 0:
        return
    d0 = np.zeros((m, k, 3))
    g = lambda xy_=xy, d_=d0, O_=O, i_=interior, X_=X: _ray_chain_g(xy_, d_, O_, i_, X_, R, axes, "3d")  # noqa: E731
    assert np.allclose(lin.g, g())
    assert_jacobian(lin.d_plate, numeric_jacobian(lambda x: g(xy_=x), xy, 1e-3), 1)
    assert_jacobian(lin.d_rot, numeric_jacobian(lambda x: g(d_=x), d0, 1e-6), 1)
    assert_jacobian(lin.d_centre, numeric_jacobian(lambda x: g(O_=x), O, 1e-2), 1)
    assert_jacobian(lin.d_interior, numeric_jacobian(lambda x: g(i_=x), interior, 1e-3), 1)
    assert_jacobian(lin.d_control, numeric_jacobian(lambda x: g(X_=x), X, 1e-2), 1)


@pytest.mark.parametrize("k", [1, 2, 3])
@pytest.mark.parametrize("rotate", [False, True], ids=["near-vertical", "steep"])
def test_collinearity(k, rotate):
    rng = np.random.default_rng([7, k, rotate])
    m = 5
    xy, R, O, interior, X = _primitives(rng, m, k, rotate)
    xy = xy + rng.normal(0, 0.01, xy.shape)  # not exactly on the ray: g != 0
    lin = conditions.collinearity(xy, R, O, interior, X)
    assert lin.g.shape == (m, 2 * k)
    d0 = np.zeros((m, k, 3))

    def g(xy_=xy, d_=d0, O_=O, i_=interior, X_=X):
        Rd = R @ exp_map(d_)
        mvec = np.einsum("mkji,mkj->mki", Rd, X_[:, None, :] - O_)
        proj = i_[..., 1:] - i_[..., :1] * mvec[..., :2] / mvec[..., 2:]
        return (xy_ - proj).reshape(len(xy_), -1)

    assert np.allclose(lin.g, g())
    assert_jacobian(lin.d_plate, numeric_jacobian(lambda x: g(xy_=x), xy, 1e-3), 1)
    assert_jacobian(lin.d_rot, numeric_jacobian(lambda x: g(d_=x), d0, 1e-6), 1)
    assert_jacobian(lin.d_centre, numeric_jacobian(lambda x: g(O_=x), O, 1e-2), 1)
    assert_jacobian(lin.d_interior, numeric_jacobian(lambda x: g(i_=x), interior, 1e-3), 1)
    assert_jacobian(lin.d_control, numeric_jacobian(lambda x: g(X_=x), X, 1e-2), 1)


@pytest.mark.parametrize("k", [1, 3])
@pytest.mark.parametrize("rotate", [False, True], ids=["near-vertical", "steep"])
def test_collinearity_jacobians(k, rotate):
    """striptri.geometry.collinearity, the one collinearity (Schmid 14) of the conditions, the bundle, the
    triangulation and the resection: its plate coordinates against the formula written out here,
    its derivatives with respect to the point, the centre, the rotation vector of R <- R Exp(d) and
    (c, xp, yp) against central differences. Called batched over (m, k) rays with each point
    broadcast over its k rays, as the callers do."""
    rng = np.random.default_rng([9, k, rotate])
    m = 5
    _, R, O, interior, X = _primitives(rng, m, k, rotate)
    jac = collinearity.collinearity_jacobians(R, O, interior, X[:, None, :])
    assert jac.xy_plate.shape == (m, k, 2)
    derivatives = (jac.d_ground, jac.d_centre, jac.d_rotation, jac.d_interior)
    assert all(d.shape == (m, k, 2, 3) for d in derivatives)

    # one ray per row for the differences: (m k, ...)
    n = m * k
    R1, O1, i1 = R.reshape(n, 3, 3), O.reshape(n, 3), interior.reshape(n, 3)
    X1 = np.repeat(X, k, axis=0)
    d0 = np.zeros((n, 3))

    def xy(d_=d0, O_=O1, i_=i1, X_=X1):
        mvec = np.einsum("nji,nj->ni", R1 @ exp_map(d_), X_ - O_)
        return i_[:, 1:] - i_[:, :1] * mvec[:, :2] / mvec[:, 2:]

    np.testing.assert_allclose(jac.xy_plate.reshape(n, 2), xy(), rtol=0, atol=1e-9)  # mm
    np.testing.assert_array_equal(collinearity.plate_from_ground(R, O, interior, X[:, None, :]), jac.xy_plate)
    d_ground, d_centre, d_rotation, d_interior = (d.reshape(n, 2, 3) for d in derivatives)
    assert_jacobian(d_ground, numeric_jacobian(lambda x: xy(X_=x), X1, 1e-2), 1)
    assert_jacobian(d_centre, numeric_jacobian(lambda x: xy(O_=x), O1, 1e-2), 1)
    assert_jacobian(d_rotation, numeric_jacobian(lambda x: xy(d_=x), d0, 1e-6), 1)
    assert_jacobian(d_interior, numeric_jacobian(lambda x: xy(i_=x), i1, 1e-3), 1)


# ---------------------------------------------------------------------------------------------
# reported angles as functions of R


def _angle_test_rotations(rng, convention, n=40):
    """Random attitudes, steep ones included, away from the convention's gimbal lock (the middle
    angle within 85 deg of level) where the angles are differentiable."""
    R = Rotation.random(4 * n, random_state=rng.integers(2**31)).as_matrix()
    middle = angles_from_R(R, convention)[:, 1]
    return R[np.abs(middle) < np.radians(85.0)][:n]


@pytest.mark.parametrize("convention", model.ROTATION_CONVENTIONS)
def test_angles_jacobian(convention):
    rng = np.random.default_rng(8)
    R = _angle_test_rotations(rng, convention)
    J = angles_jacobian(R, convention)
    a0 = angles_from_R(R, convention)

    def angles(d):
        da = angles_from_R(R @ exp_map(d), convention) - a0
        return np.angle(np.exp(1j * da))  # differences, wrapped (alpha, kappa near +-pi)

    num = numeric_jacobian(angles, np.zeros((len(R), 3)), 1e-6)
    assert_jacobian(J, num, 1)


# ---------------------------------------------------------------------------------------------
# the Gauss-Helmert blocks: B against finite differences under State.updated, A in l^


def _layout_project(convention):
    """A strip of three with every kind of unknown: a free camera (c, xp, yp), a fixed Z0, a
    photo with one angle held fixed (partial rotation), IMU-observed angles, GNSS centres, an
    enforced base component (two photos share a column) and an observed one."""
    truth, project = make_pair(PairOptions(n_photos=3, points=strip_points()), NoiseOptions(), seed=21)
    R = project.photos.R_ground_from_cam
    photos = replace(
        project.photos,
        angles=angles_from_R(R, convention),
        sigma_xyz0=np.array([[np.nan, np.nan, 0.0], [0.05, 0.05, 0.1], [np.nan] * 3]),
        sigma_angles=np.array([[np.nan] * 3, [0.0, np.nan, np.nan], [1e-3, 1e-3, np.nan]]),
    )
    bases = model.BaseComponents(
        photo_from=np.array([0, 1]), photo_to=np.array([2, 2]), axis=np.array([1, 2]),
        value=np.array([truth.xyz0[2, 1] - truth.xyz0[0, 1], truth.xyz0[2, 2] - truth.xyz0[1, 2]]),
        sigma=np.array([np.nan, 0.1]),
    )
    cameras = replace(project.cameras, sigma_interior=np.full((1, 3), np.inf))
    settings = replace(project.settings, rotation=convention)
    return replace(project, photos=photos, bases=bases, cameras=cameras, settings=settings)


def _steps(layout, n_unknowns):
    """FD step per column: 1e-2 m for centres, 1e-6 rad for rotations, 1e-4 mm for the camera."""
    h = np.full(n_unknowns, np.nan)
    for e in range(6):
        cols = layout.photo_cols[:, e]
        h[cols[cols >= 0]] = 1e-2 if e < 3 else 1e-6
    cam = layout.camera_cols[layout.camera_cols >= 0]
    h[cam] = 1e-4
    assert np.all(np.isfinite(h))
    return h


@pytest.mark.parametrize("convention", model.ROTATION_CONVENTIONS)
def test_linearise_B_and_A(convention):
    project = _layout_project(convention)
    offset = reduction_offset(project)
    state = initial_state(project, offset)
    layout = build_layout(project)
    # the layout really has what the test is about
    assert layout.partial_rotation.any() and np.any(layout.camera_cols >= 0) and np.any(layout.photo_cols < 0)
    shared = layout.photo_cols[:, :3][layout.photo_cols[:, :3] >= 0]
    assert len(np.unique(shared)) < len(shared)
    T = layout.rotation_maps(state)
    obs = observations_of(project, offset)
    rng = np.random.default_rng(9)
    plate_hat = obs.plate + rng.normal(0, 1e-4, obs.plate.shape)  # l^ != l, as after an iteration
    control_hat = obs.control + np.where(obs.q_control > 0, rng.normal(0, 1e-3, obs.control.shape), 0.0)
    h = _steps(layout, layout.n_unknowns)
    batches = build_batches(project)
    families = set()
    for batch in batches:
        families.add((batch.family, batch.k, batch.given_axes))
        system = linearise(batch, At(state, layout, T, obs, plate_hat, control_hat))
        m, nc = system.g.shape
        lin0 = evaluate(batch, state, plate_hat, control_hat)
        # the conditions are scaled per row (linearise docstring); recover the scale from A
        A0 = np.concatenate(
            [conditions.expanded(lin0.d_plate, lin0.rays, batch.k).reshape(m, nc, -1)]
            + ([lin0.d_control] if batch.has_control else []), 2
        )
        pick = np.argmax(np.abs(A0), axis=2)
        at_pick = lambda a: np.take_along_axis(a, pick[..., None], 2)[..., 0]  # noqa: E731
        scale = at_pick(system.A) / at_pick(A0)
        assert np.allclose(system.A, scale[..., None] * A0, rtol=1e-12, atol=0)
        assert np.allclose(system.g, scale * lin0.g, rtol=1e-12, atol=1e-300)

        # B: scatter into global columns (tied elements add up), against differences under updated()
        B_glob = np.zeros((m, nc, layout.n_unknowns))
        for u in range(system.B.shape[2]):
            valid = system.cols[:, u] >= 0
            B_glob[valid, :, system.cols[valid, u]] += system.B[valid, :, u]
        B_num = np.zeros_like(B_glob)
        for j in range(layout.n_unknowns):
            e = np.zeros(layout.n_unknowns)
            e[j] = h[j]
            gp = evaluate(batch, state.updated(layout, e), plate_hat, control_hat).g
            gm = evaluate(batch, state.updated(layout, -e), plate_hat, control_hat).g
            B_num[:, :, j] = scale * (gp - gm) / (2 * h[j])
        assert_jacobian(B_glob, B_num, 1)

        # A: derivatives in the current observations l^ (plate rows of the group, then control)
        k = batch.k

        def g_of_l(lvec):
            ph, ch = plate_hat.copy(), control_hat.copy()
            ph[batch.image_rows] = lvec[:, : 2 * k].reshape(m, k, 2)
            if batch.has_control:
                ch[batch.point_index] = lvec[:, 2 * k :]
            return scale * evaluate(batch, state, ph, ch).g

        l_hat = system.l_hat
        step = np.where(np.arange(l_hat.shape[1]) < 2 * k, 1e-4, 1e-3)
        A_num = numeric_jacobian(g_of_l, l_hat, step)
        assert_jacobian(system.A, A_num, 1)
    # every shape of group was exercised: collinearity and ray groups of 1, 2 and 3 rays
    assert {f[0] for f in families} == {"collinearity", "rays"}
    assert {f[1] for f in families} >= {1, 2, 3}


@pytest.mark.parametrize("convention", model.ROTATION_CONVENTIONS)
def test_parameter_observation_gradients(convention):
    """Observed centres, angles (in the file convention) and base components: gradients in the
    unknowns against finite differences under State.updated."""
    project = _layout_project(convention)
    offset = reduction_offset(project)
    state = initial_state(project, offset)
    layout = build_layout(project)
    pobs = build_parameter_observations(project, offset)
    assert len(pobs) >= 3 + 2 + 1
    f0, grad, cols = pobs.evaluate(state, layout, layout.rotation_maps(state))
    G = np.zeros((len(pobs), layout.n_unknowns))
    for a in range(3):
        valid = cols[:, a] >= 0
        np.add.at(G, (np.flatnonzero(valid), cols[valid, a]), grad[valid, a])
    h = _steps(layout, layout.n_unknowns)
    G_num = np.zeros_like(G)
    for j in range(layout.n_unknowns):
        e = np.zeros(layout.n_unknowns)
        e[j] = h[j]
        fp = pobs.evaluate(state.updated(layout, e), layout, layout.rotation_maps(state))[0]
        fm = pobs.evaluate(state.updated(layout, -e), layout, layout.rotation_maps(state))[0]
        # differences wrapped into (-pi, pi] (angles near +-pi); the others are far below pi
        G_num[:, j] = np.angle(np.exp(1j * (fp - fm))) / (2 * h[j])
    assert_jacobian(G, G_num, 0)


# ---------------------------------------------------------------------------------------------
# the compact form of the conditions (each condition's own rays) against the k-ray form


@pytest.mark.parametrize("convention", ["image", "plate"])
def test_compact_derivatives_equal_the_k_ray_form(tmp_path, convention):
    """Long close-range tracks (7 to 20 rays) through a distorting lens, as chains and as stars, as
    tie, height and plan points: the compact derivatives (conditions module doc) that evaluate
    gives for a group's own conditions, spread over the k rays, equal those of the same conditions
    given to evaluate in the k-ray form (as a ray_function) to the last bit, and so do the blocks
    of the unknowns. The k-ray form broadcasts each ray's rotation, plate vector and lens
    derivatives over the conditions; the compact form gathers them by each condition's rays. The
    ray indices themselves are checked against central differences by test_ray_conditions (the
    k-ray form is the compact one spread), and the whole linearisation, full control included, by
    test_linearise_B_and_A."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    from striptri.geometry import lens
    from striptri.io import read_project

    net = close_range.make_close_range(24, 40, seed=5)
    project = read_project(close_range.write_close_range(tmp_path / "p", net))
    interior = project.cameras.interior.copy()
    interior[:, [lens.K1, lens.K2, lens.P1, lens.B1]] = (2e-4, -3e-7, 1e-5, 1e-4) if convention == "plate" else (
        -0.05, 0.02, 1e-4, 1e-3)
    cameras = replace(project.cameras, interior=interior, convention=np.full(1, lens.CONVENTIONS[convention]))
    project = replace(project, cameras=cameras)
    offset = reduction_offset(project)
    state, layout, obs = initial_state(project, offset), build_layout(project), observations_of(project, offset)
    assert layout.lens_in_play(state)
    rng = np.random.default_rng(4)
    plate_hat = obs.plate + rng.normal(0, 1e-4, obs.plate.shape)
    control_hat = rng.normal(0, 10.0, (len(project.points), 3))
    T = layout.rotation_maps(state)
    shapes = set()
    for batch in build_batches(project):
        if batch.family != "rays":
            continue
        for b in (batch, replace(batch, star=True), replace(batch, given_axes=(False, False, True)),
                  replace(batch, given_axes=(True, True, False), star=True)):
            shapes.add((b.star, b.given_axes))
            k_ray_conditions = lambda r, O, b=b: conditions.ray_conditions(  # noqa: E731
                r, O, control_hat[b.point_index], b.given_axes, "3d", b.star)
            compact = evaluate(b, state, plate_hat, control_hat, plate_measured=obs.plate)
            k_ray = evaluate(b, state, plate_hat, control_hat, plate_measured=obs.plate, ray_function=k_ray_conditions)
            assert compact.rays is not None and compact.rays.shape[1] == 3 and k_ray.rays is None
            for name in ("d_plate", "d_rot", "d_centre", "d_interior"):
                got = conditions.expanded(getattr(compact, name), compact.rays, b.k)
                assert np.array_equal(got, getattr(k_ray, name)), (name, b.k, b.star, b.given_axes)
            assert np.array_equal(compact.g, k_ray.g) and np.array_equal(compact.d_control, k_ray.d_control)
            B_compact, cols = unknown_blocks(compact, b, state, layout, T)
            B_k_ray, cols_k = unknown_blocks(k_ray, b, state, layout, T)
            assert np.array_equal(B_compact, B_k_ray) and np.array_equal(cols, cols_k)
    assert {(False, (False, False, False)), (True, (False, False, False)), (False, (False, False, True)),
            (True, (True, True, False))} <= shapes


def test_cross_product_equals_numpy():
    """conditions._cross: np.cross's numbers, with broadcasting over leading axes."""
    from striptri.equations.conditions import _cross

    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(7, 1, 4, 3)), rng.normal(size=(7, 5, 4, 3))
    np.testing.assert_array_equal(_cross(a, b), np.cross(a, b))
    np.testing.assert_array_equal(_cross(b[0, 0], a[0, 0]), np.cross(b[0, 0], a[0, 0]))
