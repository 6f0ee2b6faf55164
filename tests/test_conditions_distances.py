"""Observed distances in the method of conditions and in precision and reliability (issue 17;
striptri.equations.joint_groups): the distance condition on the groups' intersections, the joint groups,
their agreement with the bundle, the redundancy numbers and w-tests of the distances."""

from dataclasses import replace

import numpy as np
import pytest

from striptri.precision import export as ce
from striptri import model
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.bundle import solve_bundle
from striptri.model import Distances
from striptri.geometry.collinearity import collinearity_jacobians
from striptri.conditions_method import adjust_conditions
from striptri.conditions_method.adjust import _Problem
from striptri.equations.linearise import At
from striptri.core.options import AdjustmentOptions, ConditionsOptions
from striptri.errors import InputError
from striptri.equations.joint_groups import joint_point_precision
from striptri.precision.residuals import joint_point_covariance, residual_cofactors
from striptri.adjustment import adjust
from striptri.reliability import ALPHA0, blunder_options, critical_value, detect_blunders
from striptri.reliability.distances import distance_table
from striptri.reliability.outcome import subset
from striptri.reliability.snooping import STOPPED_DISTANCE

from distance_support import strip_with_truth

OPTIONS = AdjustmentOptions(tolerance=1e-10, max_iterations=30)


_strip = strip_with_truth


def _with(project, true_xyz, held: dict, pairs, sigma, offsets=None, held_angles=True):
    """Every point a tie point but those in held (index -> (kind, sigma or nan)), given at their true
    coordinates; photo 0's angles held; the distances between pairs at their true length plus offsets."""
    n = len(project.points)
    kind = np.full(n, model.TIE)
    xyz_given = np.full((n, 3), np.nan)
    sigma_given = np.full((n, 3), np.nan)
    for p, (k, s) in held.items():
        kind[p], xyz_given[p], sigma_given[p] = k, true_xyz[p], s
    points = replace(project.points, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given)
    photos = project.photos
    if held_angles:
        sa = photos.sigma_angles.copy()
        sa[0] = 0.0
        photos = replace(photos, sigma_angles=sa)
    a, b = np.array([p for p, _ in pairs]), np.array([q for _, q in pairs])
    d = np.linalg.norm(true_xyz[a] - true_xyz[b], axis=1) + (0.0 if offsets is None else np.asarray(offsets))
    return replace(project, points=points, photos=photos,
                   distances=Distances(a, b, d, np.broadcast_to(np.asarray(sigma, float), d.shape).copy(),
                                       np.arange(len(d)) + 2))


# ------------------------------------------------------------------ the Jacobian of the distance condition


def _joint_system(project, state, plate_hat, control_hat, d_hat):
    prob = _Problem(project, OPTIONS)
    T = prob.layout.rotation_maps(state)
    return prob, prob.joint.systems(At(state, prob.layout, T, prob.obs, plate_hat, control_hat), d_hat)


def test_distance_condition_jacobian_matches_central_differences():
    project, usable, true_xyz = _strip(sigma_image=0.005)
    P, Q, R = usable[0], usable[-1], usable[3]
    # a tie-tie distance and a distance to a weighted full control point
    project = _with(project, true_xyz, {P: (model.FULL, 0.02), usable[1]: (model.FULL, np.nan)}, [(Q, R), (P, R)],
                    [0.01, 0.02], [0.03, -0.02])
    prob = _Problem(project, OPTIONS)
    obs, state = prob.obs, prob.initial_state
    plate, control = obs.plate.copy(), obs.control.copy()
    d_hat = project.distances.distance.copy()
    (js,) = prob.joint.systems(At.of(state, prob.layout, obs, plate, control), d_hat)
    rows = js.n_conditions - len(project.distances) + np.arange(len(project.distances))
    # the scaled distance rows: g = s (|X_a - X_b| - d^), s the scale linearise-style (a constant here)
    scale = js.g[rows] / (np.linalg.norm(js.xyz[js.component.ends[:, 0]] - js.xyz[js.component.ends[:, 1]], axis=1)
                          - d_hat[js.component.distances])

    def g_at(plate_, control_, d_, state_):
        (j,) = prob.joint.systems(At.of(state_, prob.layout, obs, plate_, control_), d_)
        ends = j.component.ends
        return (np.linalg.norm(j.xyz[ends[:, 0]] - j.xyz[ends[:, 1]], axis=1) - d_[j.component.distances]) * scale

    h_plate, h_ground = 1e-5, 1e-4
    # plate coordinates, control coordinates and the distances (positions in the joint observation vector)
    numeric = np.zeros((len(rows), len(js.Q)))
    for c, (o, t) in enumerate(zip(js.plate_pos, js.plate_target)):
        up, dn = plate.copy(), plate.copy()
        up.reshape(-1)[t] += h_plate
        dn.reshape(-1)[t] -= h_plate
        numeric[:, o] = (g_at(up, control, d_hat, state) - g_at(dn, control, d_hat, state)) / (2 * h_plate)
    for o, t in zip(js.control_pos, js.control_target):
        up, dn = control.copy(), control.copy()
        up.reshape(-1)[t] += h_ground
        dn.reshape(-1)[t] -= h_ground
        numeric[:, o] = (g_at(plate, up, d_hat, state) - g_at(plate, dn, d_hat, state)) / (2 * h_ground)
    for o, e in zip(js.distance_pos, js.component.distances):
        up, dn = d_hat.copy(), d_hat.copy()
        up[e] += h_ground
        dn[e] -= h_ground
        numeric[:, o] = (g_at(plate, control, up, state) - g_at(plate, control, dn, state)) / (2 * h_ground)
    A = js.A[rows]
    assert np.abs(numeric[:, js.plate_pos]).max() > 1e-3  # the rays do enter
    assert np.allclose(A, numeric, rtol=1e-6, atol=1e-6 * np.abs(A).max())
    # photo elements: each unknown column, in the parametrisation the solver updates
    n = prob.layout.n_unknowns
    numeric_B = np.zeros((len(rows), n))
    for col in range(n):
        dx = np.zeros(n)
        h = 1e-5  # metres for the centres, radians for the rotation unknowns
        dx[col] = h
        up, dn = state.updated(prob.layout, dx), state.updated(prob.layout, -dx)
        numeric_B[:, col] = (g_at(plate, control, d_hat, up) - g_at(plate, control, d_hat, dn)) / (2 * h)
    B = np.zeros((len(rows), n + 1))
    np.add.at(B, (slice(None), np.where(js.cols >= 0, js.cols, n)), js.B[rows])
    assert np.abs(B[:, :n]).max() > 1e-3
    assert np.allclose(B[:, :n], numeric_B, rtol=1e-5, atol=1e-6 * np.abs(B).max())


# ------------------------------------------------------------------ conditions = bundle


def _add_distances(project, true_xyz, pairs, sigma, offsets):
    a, b = np.array([p for p, _ in pairs]), np.array([q for _, q in pairs])
    d = np.linalg.norm(true_xyz[a] - true_xyz[b], axis=1) + np.asarray(offsets, float)
    return replace(project, distances=Distances(a, b, d, np.full(len(d), float(sigma)), np.arange(len(d)) + 2))


def _strip_case(name):
    project, usable, true_xyz = _strip(sigma_image=0.005)
    ties = usable[project.points.kind[usable] == model.TIE]
    P, Q, R, S = usable[0], usable[-1], ties[1], ties[len(ties) // 2]
    if name == "scale bar":  # between two tie points
        return _add_distances(project, true_xyz, [(R, S)], 0.01, [0.03])
    if name == "chain":  # two distances sharing the point S, one of them to a held control point
        control = int(np.flatnonzero(project.points.kind == model.FULL)[0])
        return _add_distances(project, true_xyz, [(R, S), (S, control)], 0.01, [0.03, -0.02])
    # a distance to a weighted full control point, the scale from the distances alone
    return _with(project, true_xyz, {P: (model.FULL, 0.05), Q: (model.HEIGHT, 0.05), usable[1]: (model.HEIGHT, np.nan)},
                 [(P, S), (S, Q)], 0.02, [0.02, -0.03])


def _close_range(tmp_path, n_photos=14, n_targets=24):
    import sys
    from pathlib import Path

    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    net = close_range.make_close_range(n_photos, n_targets, n_control=3, seed=5)
    project = read_project(close_range.write_close_range(tmp_path / "p", net))
    true_xyz = np.array([net.xyz_ground[close_range.target_ids(n_targets).index(pid)] for pid in project.points.ids])
    return project, true_xyz


def _assert_same(project, tol=1e-7):
    b = solve_bundle(project, OPTIONS)
    c = adjust_conditions(project, OPTIONS)
    assert b.result.termination == c.termination == "converged"
    assert c.redundancy == b.result.redundancy
    assert c.n_conditions == b.result.n_conditions and c.n_observations == b.result.n_observations
    assert c.vtpv == pytest.approx(b.result.vtpv, rel=tol)
    assert np.abs(c.state.xyz0 - b.result.state.xyz0).max() < tol
    assert np.abs(c.state.R_ground_from_cam - b.result.state.R_ground_from_cam).max() < tol
    xyz_c = triangulate_adjusted(project, c).xyz
    ok = np.isfinite(b.xyz_points).all(axis=1)
    assert np.abs(xyz_c[ok] - b.xyz_points[ok]).max() < tol
    dist = project.distances
    adjusted_c = np.linalg.norm(xyz_c[dist.point_from] - xyz_c[dist.point_to], axis=1)
    assert np.abs(adjusted_c - dist.distance - b.distance_residuals).max() < tol
    # Schmid's final checks: every condition satisfied, B^T k = 0, (59)
    assert c.checks.max_condition_misclosure_sigma < 1e-6
    assert c.checks.max_BTk_sigma < 1e-6
    assert abs(c.checks.vtpv_reduction_relative_difference) < 1e-6
    return b, c


@pytest.mark.parametrize("name", ["scale bar", "chain", "weighted control"])
def test_conditions_equal_the_bundle_with_distances_on_a_strip(name):
    project = _strip_case(name)
    b, c = _assert_same(project)
    plain = adjust_conditions(replace(project, distances=None), OPTIONS)
    r = len(project.distances)
    assert c.redundancy == plain.redundancy + r and c.n_conditions == plain.n_conditions + r
    assert c.n_observations == plain.n_observations + r
    assert np.abs(b.distance_residuals).max() > 1e-4  # the distances are not satisfied trivially


def test_conditions_equal_the_bundle_with_a_scale_bar_close_range(tmp_path):
    project, true_xyz = _close_range(tmp_path)
    ties = np.flatnonzero(project.points.kind == model.TIE)
    far = ties[np.argmax(np.linalg.norm(true_xyz[ties] - true_xyz[ties[0]], axis=1))]
    project = _add_distances(project, true_xyz, [(ties[0], far)], 1e-4, [2e-4])
    _assert_same(project)


def test_noise_free_strip_scaled_by_a_scale_bar_is_recovered():
    project, usable, true_xyz = _strip(sigma_image=0.0)
    P, Q = usable[0], usable[-1]
    # P held, photo 0's angles held, the scale from the distance P-Q alone (a minimal datum)
    project = _with(project, true_xyz, {P: (model.FULL, np.nan)}, [(P, Q)], 0.001)
    c = adjust_conditions(project, OPTIONS)
    assert c.termination == "converged" and c.vtpv < 1e-12
    xyz = triangulate_adjusted(project, c).xyz + c.offset
    i, j = np.triu_indices(len(usable), 1)
    got = np.linalg.norm(xyz[usable[i]] - xyz[usable[j]], axis=1)
    want = np.linalg.norm(true_xyz[usable[i]] - true_xyz[usable[j]], axis=1)
    assert np.abs(got - want).max() < 1e-7


# ------------------------------------------------------------------ precision and reliability


def _dense_bundle_cofactors(project, result, xyz):
    """An independent reference: the bundle's Gauss-Markov model with the points as unknowns, its
    whole Jacobian J (plate rows, weighted control rows, distance rows) formed densely at the
    solution (orientation result.state, points xyz (n_pt, 3) reduced frame) and inverted densely.
    Returns (Qx over [orientation unknowns, free point coordinates], J, sigmas of the rows, the
    row slices (plate, control, distances), the column of each point coordinate (n_pt, 3), -1)."""
    lay, state, ip = result.layout, result.state, project.image_points
    assert lay.camera_width == 0 and not (project.photos.sigma_xyz0 > 0).any()
    n = lay.n_unknowns
    q_control = (project.points.sigma_given ** 2)
    given = project.points.given_axes
    in_bundle = np.isfinite(xyz).all(axis=1)
    free = in_bundle[:, None] & ~(given & ~(q_control > 0))
    col = np.full((len(xyz), 3), -1)
    col[free] = n + np.arange(int(free.sum()))
    width = n + int(free.sum())
    rows_used = np.flatnonzero(in_bundle[ip.point_index])
    ph, pt = ip.photo_index[rows_used], ip.point_index[rows_used]
    interior = project.cameras.interior[project.photos.camera_index[ph], :3]
    jac = collinearity_jacobians(state.R_ground_from_cam[ph], state.xyz0[ph], interior, xyz[pt])
    T = lay.rotation_maps(state)[ph]
    d_rot = np.einsum("mai,mij->maj", jac.d_rotation, T)
    J_plate = np.zeros((len(rows_used), 2, width + 1))
    pc = np.where(lay.photo_cols[ph] >= 0, lay.photo_cols[ph], width)
    for a in range(2):
        np.add.at(J_plate[:, a], (np.arange(len(ph))[:, None], pc), np.concatenate([jac.d_centre[:, a], d_rot[:, a]], 1))
        np.add.at(J_plate[:, a], (np.arange(len(ph))[:, None], np.where(col[pt] >= 0, col[pt], width)), jac.d_ground[:, a])
    J_plate = J_plate.reshape(-1, width + 1)[:, :width]
    s_plate = ip.sigma_xy[rows_used].ravel()
    wc = np.argwhere(free & given & (q_control > 0))
    J_ctrl = np.zeros((len(wc), width))
    J_ctrl[np.arange(len(wc)), col[wc[:, 0], wc[:, 1]]] = 1.0
    s_ctrl = np.sqrt(q_control[wc[:, 0], wc[:, 1]])
    dist = project.distances
    u = xyz[dist.point_from] - xyz[dist.point_to]
    u /= np.linalg.norm(u, axis=1)[:, None]
    J_d = np.zeros((len(dist), width + 1))
    for sign, ends in ((1.0, dist.point_from), (-1.0, dist.point_to)):
        c = np.where(col[ends] >= 0, col[ends], width)
        np.add.at(J_d, (np.arange(len(dist))[:, None], c), sign * u)
    J = np.vstack([J_plate, J_ctrl, J_d[:, :width]])
    sig = np.concatenate([s_plate, s_ctrl, dist.sigma])
    Jw = J / sig[:, None]
    Qx = np.linalg.inv(Jw.T @ Jw)
    parts = (slice(0, len(s_plate)), slice(len(s_plate), len(s_plate) + len(s_ctrl)),
             slice(len(s_plate) + len(s_ctrl), len(sig)))
    return Qx, J, sig, parts, col, rows_used


@pytest.mark.parametrize("name", ["scale bar", "chain", "weighted control"])
def test_redundancy_numbers_and_sigmas_equal_the_dense_bundle(name):
    project = _strip_case(name)
    b = solve_bundle(project, OPTIONS)
    result = b.result
    cof = residual_cofactors(project, result, OPTIONS)
    rn = cof.redundancy_numbers(project, result)
    total = sum(float(np.sum(v)) for v in rn.values())
    assert total == pytest.approx(result.redundancy, abs=1e-9 * result.redundancy)
    Qx, J, sig, parts, col, rows_used = _dense_bundle_cofactors(project, result, b.xyz_points)
    qvv_dense = sig**2 - np.einsum("ri,ij,rj->r", J, Qx, J)
    # the reference's own redundancy (observations - unknowns) is the adjustment's
    assert float(np.sum(qvv_dense / sig**2)) == pytest.approx(result.redundancy, rel=1e-9)
    d = project.distances
    assert np.allclose(cof.distances, qvv_dense[parts[2]], rtol=1e-9, atol=0)
    sigma_adjusted_dense = np.sqrt(np.einsum("ri,ij,rj->r", J[parts[2]], Qx, J[parts[2]]))
    assert np.allclose(np.sqrt(d.sigma**2 - cof.distances), sigma_adjusted_dense, rtol=1e-9)
    # the plate coordinates of the joined points (their w-tests see the coupling) and all others
    assert np.allclose(cof.plate[rows_used].ravel(), qvv_dense[parts[0]], rtol=1e-7, atol=1e-12 * sig[0] ** 2)
    # the points' (90) precision: the joint intersection equals the bundle's point covariance
    # and the rigorous joint form (92) likewise
    tri = joint_point_precision(project, result, triangulate_adjusted(project, result, orientation_part=True))
    q92 = joint_point_covariance(project, result, tri, OPTIONS)
    ends = np.unique(np.concatenate([d.point_from, d.point_to]))
    for p in ends:
        c = col[p]
        ref = np.zeros((3, 3))
        f = c >= 0
        ref[np.ix_(f, f)] = Qx[np.ix_(c[f], c[f])]
        for got in (tri.cov_measurement[p] + tri.cov_orientation[p], q92[p]):
            assert np.allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    assert any((col[q] >= 0).all() for q in ends)  # a point with its coordinates free is compared
    # the exported covariance of all points (covariance_export), cross-covariances included
    e = ce.joint_covariance(project, result, triangulate_adjusted(project, result, orientation_part=False),
                            ("points",))
    free = [q for q in range(len(project.points)) if (col[q] >= 0).all()
            and f"points/{project.points.ids[q]}/X" in e.labels]
    assert set(ends) & set(free)
    rows = np.concatenate([e.point_rows(project.points.ids[q]) for q in free])
    ref = Qx[np.ix_(col[free].ravel(), col[free].ravel())]
    got = e.cov[np.ix_(rows, rows)] / e.sigma0**2
    assert np.abs(got - ref).max() < 1e-9 * np.abs(ref).max()


# ------------------------------------------------------------------ bad input


def test_a_distance_to_a_single_ray_point_is_an_input_error_for_both_methods():
    project, usable, true_xyz = _strip(sigma_image=0.005)
    ties = usable[project.points.kind[usable] == model.TIE]
    single = int(ties[-1])
    rows = np.flatnonzero(project.image_points.point_index == single)
    keep = np.ones(len(project.image_points), dtype=bool)
    keep[rows[1:]] = False  # the tie point keeps one ray
    project = subset(project, keep)
    bad = _add_distances(project, true_xyz, [(ties[1], ties[2]), (ties[3], single)], 0.01, [0.0, 0.0])
    for method in ("conditions", "bundle"):
        with pytest.raises(InputError) as info:
            adjust(bad, AdjustmentOptions(method=method))
        assert info.value.path == "distances.csv" and info.value.line == 3
        assert f"point {project.points.ids[single]} is measured on 1 photo" in info.value.reason


def test_a_distance_to_an_unmeasured_control_point_is_an_input_error():
    project, usable, true_xyz = _strip(sigma_image=0.005)
    full = int(np.flatnonzero(project.points.kind == model.FULL)[0])
    project = subset(project, project.image_points.point_index != full)
    bad = _add_distances(project, true_xyz, [(full, usable[2])], 0.01, [0.0])
    with pytest.raises(InputError, match="measured on no photo"):
        adjust(bad, AdjustmentOptions(method="conditions"))


# ------------------------------------------------------------------ w-tests of the distances


def _checked_bar(seed, gross=0.0):
    """A strip with its control and a scale bar between two tie points whose sigma is of the order
    of the points' precision (so the bar is checked: redundancy number well above 0)."""
    project, usable, true_xyz = _strip(sigma_image=0.005, seed=seed)
    ties = usable[project.points.kind[usable] == model.TIE]
    sigma = 0.05
    rng = np.random.default_rng(seed + 100)
    return _add_distances(project, true_xyz, [(ties[0], ties[-1])], sigma, [rng.normal(0, sigma) + gross * sigma])


@pytest.mark.parametrize("procedure", ["snoop", "snoop-classic"])
@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_a_gross_distance_is_flagged_and_no_plate_row_is_rejected_for_it(method, procedure):
    project = _checked_bar(seed=11, gross=20.0)
    options = replace(OPTIONS, method=method)
    det = detect_blunders(project, options, blunder_options(procedure))
    assert det.stopped == STOPPED_DISTANCE and not det.rejected
    xyz = triangulate_adjusted(det.project, det.result).xyz
    cols = distance_table(det.project, det.result, xyz, options, det.critical)
    r, w = cols["redundancy"][0], cols["w"][0]
    assert r > 0.2  # checked: a 20-sigma error shows as w = 20 sqrt(r) on average, +- 1 (N(0, 1))
    assert cols["flag"] == ["suspect"] and abs(abs(w) - 20 * np.sqrt(r)) < 4.0
    # the plate rows of the bar's points see the error too, less clearly than the bar itself
    assert np.nanmax(np.abs(det.w)) < abs(w)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_clean_distances_pass_the_w_test(seed):
    project = _checked_bar(seed)
    options = replace(OPTIONS, method="conditions")
    det = detect_blunders(project, options, blunder_options("snoop"))
    xyz = triangulate_adjusted(det.project, det.result).xyz
    cols = distance_table(det.project, det.result, xyz, options, det.critical)
    assert det.stopped != STOPPED_DISTANCE
    assert cols["flag"] == [""] and abs(cols["w"][0]) < critical_value(ALPHA0)  # alpha0 = 0.001 per test


def test_snooping_that_would_leave_a_distance_point_with_one_ray_takes_the_row_back():
    project, usable, true_xyz = _strip(sigma_image=0.005)
    rays = np.bincount(project.image_points.point_index, minlength=len(project.points))
    two = usable[(project.points.kind[usable] == model.TIE) & (rays[usable] == 2)]
    ties = usable[project.points.kind[usable] == model.TIE]
    p, q = int(two[0]), int(next(t for t in ties if t != two[0]))
    row = int(np.flatnonzero(project.image_points.point_index == p)[0])
    xy = project.image_points.xy.copy()
    xy[row, 0] += 50 * project.image_points.sigma_xy[row, 0]
    project = replace(project, image_points=replace(project.image_points, xy=xy))
    project = _add_distances(project, true_xyz, [(p, q)], 0.05, [0.0])
    det = detect_blunders(project, replace(OPTIONS, method="conditions"), blunder_options("snoop-classic"))
    assert det.stopped.startswith("failure: distances.csv") and "measured on 1 photo" in det.stopped
    assert not det.rejected and len(det.result.plate_residuals) == len(project.image_points)


@pytest.mark.parametrize("solver", ["sparse", "banded", "cholmod", "gauss-seidel", "pcg", "strip-pcg"])
def test_every_solver_agrees_with_dense_on_joint_groups(solver):
    """The joint groups add blocks between photos that share no point (the distance's two ends):
    every solver takes them (tolerances: the iterative solvers' convergence test, 1e-8 sigma)."""
    if solver == "cholmod":
        pytest.importorskip("sksparse")
    project = _strip_case("chain")
    ref = adjust_conditions(project, replace(OPTIONS, solver="dense"))
    got = adjust_conditions(project, replace(OPTIONS, solver=solver))
    assert got.termination == "converged"
    assert got.vtpv == pytest.approx(ref.vtpv, rel=1e-9)
    assert np.abs(got.state.xyz0 - ref.state.xyz0).max() < 1e-7


def test_free_network_with_one_scale_bar():
    """Without control, inner constraints (datum "inner") and one scale bar: the bar fixes the scale
    (6 datum directions left instead of 7) and, having no redundancy, is met exactly; v^T P v and
    the redundancy are those of the free network without it."""
    project, usable, true_xyz = _strip(sigma_image=0.005)
    n = len(project.points)
    project = replace(project, points=replace(project.points, kind=np.full(n, model.TIE),
                                              xyz_given=np.full((n, 3), np.nan), sigma_given=np.full((n, 3), np.nan)))
    bar = _add_distances(project, true_xyz, [(usable[1], usable[-2])], 0.01, [0.05])
    options = replace(OPTIONS, datum="inner")
    with_bar, without = adjust_conditions(bar, options), adjust_conditions(project, options)
    assert len(with_bar.free_network) == 6 and len(without.free_network) == 7
    assert with_bar.redundancy == without.redundancy
    assert with_bar.vtpv == pytest.approx(without.vtpv, rel=1e-9)
    xyz = triangulate_adjusted(bar, with_bar).xyz
    d = bar.distances
    assert abs(np.linalg.norm(xyz[d.point_from[0]] - xyz[d.point_to[0]]) - d.distance[0]) < 1e-8


def test_schmids_projected_scale_form_gives_the_same_adjustment_with_distances():
    """The members' own conditions in Schmid's XZ form (94): the distance conditions still use the
    closest approach of the first pair; at convergence the adjustment is the same."""
    project = _strip_case("chain")
    a = adjust_conditions(project, OPTIONS)
    b = adjust_conditions(project, replace(OPTIONS, conditions=ConditionsOptions(scale_form="xz")))
    assert b.termination == "converged" and b.vtpv == pytest.approx(a.vtpv, rel=1e-9)
    assert np.abs(a.state.xyz0 - b.state.xyz0).max() < 1e-7
