"""A free network whose inner constraints act on object points (issue 17, striptri.equations.point_datum), in
both methods, against the photo datum after an S-transformation (covariance_export.s_transform)."""

import io
import json
import shutil
import sys
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from striptri import model
from striptri import simulate as sim
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.bundle import solve_bundle
from striptri.model import Distances
from striptri.precision.export import CovarianceRequest, covariance_file, joint_covariance, s_transform
from striptri.errors import NumericalFailure
from striptri.io import read_project, write_project
from striptri.pipeline import triangulate_result
from striptri.equations.point_datum import JointBlock, export_correction, points_correction
from striptri.geometry.rotations import R_from_angles, angles_jacobian

from cli_support import assert_clean_failure, run

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import close_range  # noqa: E402
import scale_cases  # noqa: E402

TOL = 1e-12  # convergence tolerance of the comparisons: both methods converged far below the 1e-7 m asked


def _block(sigma_image=0.005, seed=11):
    """A two-strip block without any control (every point a tie point), with approximate
    coordinates of every point (approx_points.csv) 1 m off the truth. Returns the project and the
    true coordinates of its points and projection centres."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4, n_strips=2),
                                 control=sim.ControlDesign(layout="ends"), points=sim.PointDesign(extra_ties_per_model=4))
    truth = sim.make_truth(design, np.random.default_rng(seed))
    p = sim.perturb(truth, sim.NoiseOptions(sigma_image=sigma_image, stated_sigma_image=0.005),
                    np.random.default_rng(seed + 1))
    n = len(p.points)
    true_xyz = np.array([truth.xyz_ground[truth.point_ids.index(pid)] for pid in p.points.ids])
    approx = true_xyz + np.random.default_rng(seed + 2).normal(scale=1.0, size=(n, 3))
    points = replace(p.points, kind=np.full(n, model.TIE), xyz_given=np.full((n, 3), np.nan),
                     sigma_given=np.full((n, 3), np.nan), xyz_approx=approx)
    true_centres = np.array([truth.xyz0[truth.photo_ids.index(pid)] for pid in p.photos.ids])
    return replace(p, points=points), true_xyz, true_centres


def _used(project):
    """The points of the adjustment: those with two or more rays."""
    return np.flatnonzero(np.bincount(project.image_points.point_index, minlength=len(project.points)) >= 2)


def _run(project, method, datum, datum_points=()):
    """The result and the adjusted points of the adjustment (ground frame, _used's order): the
    bundle's unknowns, the conditions method's intersection of the adjusted rays."""
    options = AdjustmentOptions(method=method, datum=datum, tolerance=TOL, datum_points=datum_points)
    if method == "bundle":
        sol = solve_bundle(project, options)
        r, xyz = sol.result, sol.xyz_points
    else:
        r = adjust(project, options)
        xyz = triangulate_adjusted(project, r).xyz
    return r, xyz[_used(project)] + r.offset


def _helmert(a, b):
    """The similarity b ~ s R a + t (least squares, Umeyama): (s, R, t) and the largest residual."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, S, Vt = np.linalg.svd((b - cb).T @ (a - ca))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / np.sum((a - ca) ** 2)
    t = cb - s * R @ ca
    return s, R, t, float(np.abs(a @ R.T * s + t - b).max())


@pytest.fixture(scope="module")
def noisy():
    project, _, _ = _block()
    runs = {(m, d): _run(project, m, d) for m in ("conditions", "bundle") for d in ("inner", "inner-points")}
    return project, runs


# ---------------------------------------------------------------- noise-free recovery, both methods


@pytest.mark.parametrize("method", ["conditions", "bundle"])
@pytest.mark.parametrize("datum", ["inner", "inner-points"])
def test_noise_free_block_without_control_is_recovered_up_to_a_similarity(method, datum):
    project, true_xyz, true_centres = _block(sigma_image=0.0)
    r, xyz = _run(project, method, datum)
    assert r.converged and len(r.free_network) == 7 and r.free_network.mode == datum
    used = _used(project)
    *_, resid = _helmert(np.vstack([xyz, r.state.xyz0 + r.offset]), np.vstack([true_xyz[used], true_centres]))
    assert resid < 1e-7


def _close_range(tmp_path, monkeypatch, noise_free: bool):
    """The small close-range case of the benchmark (scripts/bench/close_range.py: a dome of targets,
    rings of convergent photos, the camera self-calibrated with k1, k2) without its control."""
    case = scale_cases.CASES["close-small"]
    if noise_free:  # the generator's noise; project.toml keeps the stated sigma
        with monkeypatch.context() as m:
            m.setattr(close_range, "SIGMA_IMAGE", 0.0)
            net = close_range.make_close_range(case.photos, case.strips_or_targets, seed=scale_cases.CLOSE_SEED)
    else:
        net = close_range.make_close_range(case.photos, case.strips_or_targets, seed=scale_cases.CLOSE_SEED)
    folder = close_range.write_close_range(tmp_path / "close", net)
    (folder / "control.csv").unlink()
    project = read_project(folder)
    true_xyz = net.xyz_ground[[int(i[1:]) - 1 for i in project.points.ids]]
    return project, net, true_xyz


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_noise_free_close_range_with_self_calibration_is_recovered(tmp_path, monkeypatch, method):
    project, net, true_xyz = _close_range(tmp_path, monkeypatch, noise_free=True)
    r, xyz = _run(project, method, "inner-points")
    assert r.converged and len(r.free_network) == 7
    *_, resid = _helmert(np.vstack([xyz, r.state.xyz0 + r.offset]), np.vstack([true_xyz[_used(project)], net.xyz0]))
    assert resid < 1e-7
    free = r.layout.camera_cols[0] >= 0
    np.testing.assert_allclose(r.state.interior[0][free], net.interior[free], rtol=1e-9, atol=1e-12)


def test_close_range_conditions_equal_bundle_in_the_point_datum(tmp_path, monkeypatch):
    project, _, _ = _close_range(tmp_path, monkeypatch, noise_free=False)
    (a, xa), (b, xb) = (_run(project, m, "inner-points") for m in ("conditions", "bundle"))
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-7)
    np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-7)
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, rtol=0, atol=1e-7)
    np.testing.assert_allclose(b.state.interior, a.state.interior, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------- conditions = bundle in each datum


@pytest.mark.parametrize("datum", ["inner", "inner-points"])
def test_conditions_equal_bundle_in_the_free_network(noisy, datum):
    project, runs = noisy
    (a, xa), (b, xb) = runs[("conditions", datum)], runs[("bundle", datum)]
    assert a.converged and b.converged and a.redundancy == b.redundancy
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-7)
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, rtol=0, atol=1e-7)
    # orientations: the rotations, as the ground displacement over 1 km
    np.testing.assert_allclose(b.state.R_ground_from_cam, a.state.R_ground_from_cam, rtol=0, atol=1e-10)
    np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-7)
    # and their precision
    np.testing.assert_allclose(b.photo_mean_errors("omega-phi-kappa")[0], a.photo_mean_errors("omega-phi-kappa")[0],
                               rtol=1e-6)


@pytest.mark.parametrize("seed, datum", [(20, "inner-points"), (22, "inner")])
def test_damped_bundle_reaches_the_datum_of_the_conditions_method(seed, datum):
    """Approximations 100 m and 6 deg off: the bundle's Gauss-Newton steps fail and it takes a dozen
    Levenberg-Marquardt steps (damped reduced system, minimum constraints, S-transformation), yet
    it ends in the same datum as the method of conditions, whose iteration takes another path."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4, n_strips=2),
                                 control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=4))
    truth = sim.make_truth(design, np.random.default_rng(11))
    p = sim.perturb(truth, sim.NoiseOptions(approx_position_error=100, approx_angle_error=6),
                    np.random.default_rng(seed))
    n = len(p.points)
    p = replace(p, points=replace(p.points, kind=np.full(n, model.TIE), xyz_given=np.full((n, 3), np.nan),
                                  sigma_given=np.full((n, 3), np.nan)))
    (b, xb), (c, xc) = (_run(p, m, datum) for m in ("bundle", "conditions"))
    assert sum(1 for h in b.history if h.solver_info.damping) >= 5
    assert b.vtpv == pytest.approx(c.vtpv, rel=1e-9)
    np.testing.assert_allclose(b.state.xyz0, c.state.xyz0, rtol=0, atol=1e-7)
    np.testing.assert_allclose(xb, xc, rtol=0, atol=1e-7)


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_with_plan_control_only_the_height_is_fixed_by_the_datum_points(method):
    """Plan control (X, Y held) leaves only the translation in Z free: the point datum fixes that one
    direction, sum (Z - Z0) = 0 over the datum points, and keeps the plan control exactly."""
    project, true_xyz, _ = _block()
    used = _used(project)
    plan = used[[0, 7, 15, 30]]
    kind, given = project.points.kind.copy(), project.points.xyz_given.copy()
    kind[plan] = model.PLAN
    given[plan, :2] = true_xyz[plan, :2]
    project = replace(project, points=replace(project.points, kind=kind, xyz_given=given))
    r, xyz = _run(project, method, "inner-points")
    assert r.converged and len(r.free_network) == 1
    assert r.free_network.summary(r.state, r.offset)["free_directions"] == ["translation in Z"]
    np.testing.assert_allclose(xyz[[0, 7, 15, 30], :2], true_xyz[plan, :2], rtol=0, atol=1e-9)
    dz = xyz[:, 2] - project.points.xyz_approx[used, 2]
    assert abs(dz.sum()) < 1e-9 * len(used) and np.abs(dz).max() > 0.1
    other = "bundle" if method == "conditions" else "conditions"
    np.testing.assert_allclose(_run(project, other, "inner-points")[1], xyz, rtol=0, atol=1e-7)


def test_the_two_datums_differ(noisy):
    """The datums are not the same one (else the comparisons below prove nothing): the photo and
    the point datum place the block differently."""
    _, runs = noisy
    d = np.abs(runs[("bundle", "inner")][0].state.xyz0 - runs[("bundle", "inner-points")][0].state.xyz0).max()
    assert d > 0.1


# ---------------------------------------------------------------- the constraint


def _similarity_of(xyz, xyz0, scale=True):
    """The linearised similarity between points xyz and their approximations xyz0 (n, 3): the
    least-squares fit of ``xyz - xyz0`` by ``t + w x (X0 - c) + m (X0 - c)`` (a rigid motion without
    ``scale``), as the largest motion it gives any of the points (m). Zero when the Helmert fit of
    xyz onto xyz0, linearised at xyz0, is the identity."""
    c = xyz0 - xyz0.mean(axis=0)
    n = len(xyz)
    A = np.zeros((n, 3, 7))
    A[:, :, :3] = np.eye(3)
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        A[:, :, 3 + a] = np.cross(e, c)
    A[:, :, 6] = c
    A = A if scale else A[:, :, :6]
    k = np.linalg.lstsq(A.reshape(3 * n, -1), (xyz - xyz0).ravel(), rcond=None)[0]
    return float(np.abs(A @ k).max())


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_datum_points_have_no_similarity_to_their_approximations(noisy, method):
    project, runs = noisy
    _, xyz = runs[(method, "inner-points")]
    used = _used(project)
    extent = np.ptp(xyz, axis=0).max()
    x0 = project.points.xyz_approx[used]
    assert _similarity_of(xyz, x0) < 1e-9 * extent
    # the photo datum does not do that
    _, xyz_photo = runs[(method, "inner")]
    assert _similarity_of(xyz_photo, x0) > 1e-3 * extent


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_a_subset_of_datum_points_carries_the_constraint_alone(noisy, method):
    project, runs = noisy
    used = _used(project)
    subset = used[::3]
    ids = tuple(str(project.points.ids[i]) for i in subset)
    r, xyz = _run(project, method, "inner-points", ids)
    assert r.converged and r.free_network.points is not None and len(r.free_network.points.index) == len(ids)
    assert r.vtpv == pytest.approx(runs[(method, "inner-points")][0].vtpv, rel=1e-9)  # the datum changes nothing else
    where = {p: k for k, p in enumerate(used)}
    sel = [where[p] for p in subset]
    extent = np.ptp(xyz, axis=0).max()
    assert _similarity_of(xyz[sel], project.points.xyz_approx[subset]) < 1e-9 * extent
    # the others are free: over all points the similarity is not zero
    assert _similarity_of(xyz, project.points.xyz_approx[used]) > 1e-4 * extent


# ---------------------------------------------------------------- the check: S-transformation


def _point_block(export, ids):
    rows = [k for p in ids for k in export.point_rows(p)]
    return rows, export.cov[np.ix_(rows, rows)]


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_point_datum_equals_the_photo_datum_s_transformed(noisy, method):
    """Inner constraints on the points against inner constraints on the photos S-transformed to the
    same datum points (W = I): the points' covariance equal to 1e-9 relative once the two frames
    (which differ by a finite similarity) are brought together; mean errors of ratios of distances and
    of angles, invariant under a similarity, equal to 1e-9 relative without any transformation."""
    project, runs = noisy
    rph, rpt = runs[(method, "inner")][0], runs[(method, "inner-points")][0]
    eph = joint_covariance(project, rph, triangulate_adjusted(project, rph), ("photos", "points"))
    ept = joint_covariance(project, rpt, triangulate_adjusted(project, rpt), ("photos", "points"))
    ids = [str(project.points.ids[i]) for i in rpt.free_network.points.index]
    assert len(ids) == len({lab.split("/")[1] for lab in ept.labels if lab.startswith("points/")})  # all points
    st = s_transform(eph, ids)
    rows, q_st = _point_block(st, ids)
    _, q_pt = _point_block(ept, ids)
    xa, xb = st.values[rows].reshape(-1, 3), ept.values[rows].reshape(-1, 3)
    s, R, _, resid = _helmert(xa, xb)
    assert resid < 1e-7  # coordinates equal after the similarity
    assert abs(s - 1.0) > 1e-4  # a real change of frame
    B = np.kron(np.eye(len(ids)), s * R)
    np.testing.assert_allclose(B @ q_st @ B.T, q_pt, rtol=0, atol=1e-9 * np.abs(q_pt).max())
    # the datum points' precision is minimal in trace in their own datum: below the photo datum's and
    # below that of the datum of a subset of them (the frames' scale brought together)
    _, q_ph = _point_block(eph, ids)
    _, q_sub = _point_block(s_transform(eph, ids[::3]), ids)
    assert np.trace(q_pt) < s * s * min(np.trace(q_ph), np.trace(q_sub))
    # invariant quantities: a ratio of two distances, an angle at a point, in each datum's own covariance
    for export_a, export_b in ((eph, ept), (st, ept)):
        for f in (_ratio, _angle):
            ma, mb = (np.sqrt(g @ e.cov @ g) for e, g in ((e, f(e, ids)) for e in (export_a, export_b)))
            assert mb == pytest.approx(ma, rel=1e-9)


def _ratio(export, ids):
    """Gradient of |P0 P5| / |P2 P9| over the export's labels."""
    d1, f1 = export.distance(ids[0], ids[5])
    d2, f2 = export.distance(ids[2], ids[9])
    return f1 / d2 - f2 * d1 / d2**2


def _angle(export, ids):
    """Gradient of the angle at ids[1] between the directions to ids[4] and ids[7]."""
    a, b, c = (np.array(export.point_rows(p)) for p in (ids[1], ids[4], ids[7]))
    u, w = export.values[b] - export.values[a], export.values[c] - export.values[a]
    nu, nw = np.linalg.norm(u), np.linalg.norm(w)
    cos = u @ w / (nu * nw)
    du = (w / (nu * nw) - cos * u / nu**2) * (-1.0 / np.sqrt(1 - cos**2))
    dw = (u / (nu * nw) - cos * w / nw**2) * (-1.0 / np.sqrt(1 - cos**2))
    g = np.zeros(len(export.labels))
    g[b], g[c], g[a] = du, dw, -(du + dw)
    return g


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_point_datum_cofactors_are_a_generalised_inverse(noisy, method):
    """Qxx of the point datum: a generalised inverse of N (N Q N = N), whose part besides the datum
    points' own term H K V K^T H^T is orthogonal to the point datum's constraints C."""
    _, runs = noisy
    r = runs[(method, "inner-points")][0]
    N, Q, fn = r.N.toarray(), r.Qxx, r.free_network
    assert np.abs(N @ Q @ N - N).max() < 1e-9 * np.abs(N).max()
    HK = fn.H @ fn.points.K
    own = HK @ fn.extra @ HK.T
    assert np.abs(own).max() > 1e-3 * np.abs(Q).max()  # not negligible
    assert np.abs(fn.C.T @ (Q - own)).max() < 1e-9 * np.abs(fn.C).max() * np.abs(Q).max()
    np.testing.assert_allclose(Q, Q.T, rtol=0, atol=1e-12 * np.abs(Q).max())


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_points_csv_precision_is_the_exported_covariance(noisy, method):
    """points.csv's mean errors (triangulate_adjusted, Schmid 90 with the point datum's cross term)
    are the diagonal of the exported covariance."""
    project, runs = noisy
    r = runs[(method, "inner-points")][0]
    tri = triangulate_adjusted(project, r, orientation_part=True)
    e = joint_covariance(project, r, tri, ("points",))
    idx = r.free_network.points.index
    got = np.einsum("pii->pi", tri.cov_measurement[idx] + tri.cov_orientation[idx]) * r.sigma0_for_precision**2
    want = np.array([np.diag(e.cov[np.ix_(e.point_rows(str(project.points.ids[p])),
                                          e.point_rows(str(project.points.ids[p])))]) for p in idx])
    np.testing.assert_allclose(got, want, rtol=1e-9)


# ---------------------------------------------------------------- distances: scale not free


def test_bundle_point_datum_with_a_scale_bar():
    """With a distance the scale is not free: six directions, the constraint holds, the bar is kept."""
    project, true_xyz, _ = _block(sigma_image=0.0)
    used = _used(project)
    P, Q = int(used[0]), int(used[-1])
    d = float(np.linalg.norm(true_xyz[P] - true_xyz[Q]))
    project = replace(project, distances=Distances(np.array([P]), np.array([Q]), np.array([d]), np.array([0.001])))
    for datum in ("inner", "inner-points"):
        sol = solve_bundle(project, AdjustmentOptions(method="bundle", datum=datum, tolerance=TOL))
        r = sol.result
        assert r.converged and len(r.free_network) == 6
        assert "scale" not in " ".join(r.free_network.summary(r.state, r.offset)["free_directions"])
        xyz = sol.xyz_points[used] + r.offset
        assert abs(np.linalg.norm(sol.xyz_points[P] - sol.xyz_points[Q]) - d) < 1e-7
        *_, resid = _helmert(xyz, true_xyz[used])
        assert resid < 1e-6
    x0 = project.points.xyz_approx[used]
    # the rigid part only: the scale came from the bar
    assert _similarity_of(xyz, x0, scale=False) < 1e-9 * np.ptp(xyz, axis=0).max()


def test_with_a_scale_bar_distances_keep_their_mean_errors_between_the_datums():
    """The issue's check with the scale from a distance (bundle): six free directions, so distances
    between points are invariant; their mean errors are equal to 1e-9 relative in the photo and the
    point datum, and the photo datum's covariance S-transformed by a rigid motion (6 parameters) to
    the datum points is the point datum's."""
    project, true_xyz, _ = _block()
    used = _used(project)
    P, Q = int(used[0]), int(used[-1])
    d = float(np.linalg.norm(true_xyz[P] - true_xyz[Q]))
    project = replace(project, distances=Distances(np.array([P]), np.array([Q]), np.array([d]), np.array([0.001])))
    (rph, _), (rpt, _) = (_run(project, "bundle", datum) for datum in ("inner", "inner-points"))
    eph = joint_covariance(project, rph, triangulate_adjusted(project, rph), ("points",))
    ept = joint_covariance(project, rpt, triangulate_adjusted(project, rpt), ("points",))
    ids = [str(project.points.ids[i]) for i in rpt.free_network.points.index]
    for a, b in ((0, 5), (2, 9), (3, 30), (1, len(ids) - 2)):
        ma, mb = (np.sqrt(f @ e.cov @ f) for e, f in ((e, e.distance(ids[a], ids[b])[1]) for e in (eph, ept)))
        assert mb == pytest.approx(ma, rel=1e-9)
    st = s_transform(eph, ids, scale=False)
    rows, q_st = _point_block(st, ids)
    _, q_pt = _point_block(ept, ids)
    s, R, _, resid = _helmert(st.values[rows].reshape(-1, 3), ept.values[rows].reshape(-1, 3))
    assert resid < 1e-7 and abs(s - 1.0) < 1e-9
    B = np.kron(np.eye(len(ids)), R)
    np.testing.assert_allclose(B @ q_st @ B.T, q_pt, rtol=0, atol=1e-9 * np.abs(q_pt).max())


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_without_distances_the_per_point_form_is_kept(noisy, method):
    """Without distances points.csv's cross term is the per-point form, bit for bit (the path the
    joint groups leave alone), and the general form (own_blocks, each point a group of one) agrees."""
    project, runs = noisy
    r = runs[(method, "inner-points")][0]
    terms = r.free_network.points
    tri = triangulate_adjusted(project, r, orientation_part=True)
    Qm, Hp, K = tri.cov_measurement, terms.H, terms.K
    A = Hp @ K @ np.swapaxes(Hp, 1, 2) @ Qm[terms.index]
    want = np.zeros_like(Qm)
    want[terms.index] = -(A + np.swapaxes(A, 1, 2))
    assert np.array_equal(points_correction(terms, Qm), want)
    ones = [JointBlock(np.array([p]), Qm[p], Hp[k]) for k, p in enumerate(terms.index)]
    np.testing.assert_allclose(points_correction(terms, Qm, ones), want, rtol=0, atol=1e-13 * np.abs(want).max())
    rows = 3 * np.arange(len(terms.index))
    FH = np.random.default_rng(1).normal(size=(3 * len(rows), Hp.shape[2]))
    plain = export_correction(terms, FH, rows, Qm, terms.index)
    np.testing.assert_allclose(export_correction(terms, FH, rows, Qm, terms.index, ones), plain, rtol=0,
                               atol=1e-13 * np.abs(plain).max())


# ---------------------------------------------------------------- scale bars between datum points


def _with_bars(project, true_xyz):
    """The block with three scale bars that over-determine the scale (observed 2e-4, -1e-4, 1e-4
    relative off the truth, sigma 2 mm: they pull the points, 0.1 to 0.4 m): a chain P-Q-R (one joint
    group of three points) and S-T (one of two)."""
    used = _used(project)
    ends = np.array([[used[0], used[-1]], [used[-1], used[20]], [used[5], used[30]]])
    d = np.linalg.norm(true_xyz[ends[:, 0]] - true_xyz[ends[:, 1]], axis=1) * np.array([1.0002, 0.9999, 1.0001])
    return replace(project, distances=Distances(ends[:, 0], ends[:, 1], d, np.full(3, 0.002)))


@pytest.fixture(scope="module")
def bars():
    """The block with scale bars, adjusted by both methods in the photo and the point datum (every
    point, and every second point: the datum then holds some members of the joint groups only)."""
    project, true_xyz, _ = _block()
    project = _with_bars(project, true_xyz)
    subset = tuple(str(project.points.ids[i]) for i in _used(project)[::2])
    runs = {(m, d, k): _run(project, m, d, pts) for m in ("conditions", "bundle")
            for d, k, pts in (("inner", "all", ()), ("inner-points", "all", ()), ("inner-points", "subset", subset))}
    return project, runs


def _datum_ids(project, r):
    return [str(project.points.ids[i]) for i in r.free_network.points.index]


@pytest.mark.parametrize("which", ["all", "subset"])
def test_conditions_equal_bundle_in_the_point_datum_with_scale_bars(bars, which):
    """The point datum with distances between datum points: the iteration's constraint intersects
    the joint groups together (the bars pull the points, so the points' own rays alone do not give
    the datum: without the coupling the conditions method does not converge to the bundle's)."""
    project, runs = bars
    (a, xa), (b, xb) = runs[("conditions", "inner-points", which)], runs[("bundle", "inner-points", which)]
    assert a.converged and b.converged and a.redundancy == b.redundancy
    ids = _datum_ids(project, a)
    assert ids == _datum_ids(project, b) and len(ids) == len(_used(project)[:: 1 if which == "all" else 2])
    dist = project.distances
    where = {p: k for k, p in enumerate(_used(project))}
    lengths = np.linalg.norm(xb[[where[p] for p in dist.point_from]] - xb[[where[p] for p in dist.point_to]], axis=1)
    # the bars have residuals (a lone bar would only give the scale and fit exactly): they pull their
    # points away from their own rays' intersection
    assert np.abs(lengths - dist.distance).min() > 1e-5
    joined = {str(project.points.ids[p]) for p in np.concatenate([dist.point_from, dist.point_to])}
    assert (joined <= set(ids)) == (which == "all")  # the subset leaves members of the groups out
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-7)
    np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-7)
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, rtol=0, atol=1e-7)
    extent = np.ptp(xb, axis=0).max()
    sel = [where[int(i)] for i in b.free_network.points.index]
    assert _similarity_of(xb[sel], project.points.xyz_approx[b.free_network.points.index], scale=False) < 1e-9 * extent


@pytest.mark.parametrize("method", ["conditions", "bundle"])
@pytest.mark.parametrize("which", ["all", "subset"])
def test_points_csv_sigmas_are_covariance_npz_with_scale_bars(bars, method, which):
    """points.csv's mean errors (pipeline.triangulate_result: the joint groups intersected together,
    the point datum's cross terms with their cross blocks) equal the diagonal of covariance.npz, for
    every point, in the point datum with scale bars."""
    project, runs = bars
    r = runs[(method, "inner-points", which)][0]
    tri = triangulate_result(project, r)
    used = _used(project)
    got = np.einsum("pii->pi", tri.cov_measurement[used] + tri.cov_orientation[used]) * r.sigma0_for_precision**2
    npz = np.load(io.BytesIO(covariance_file(project, r, CovarianceRequest(("points",)))))
    labels = list(npz["labels"])
    rows = [[labels.index(f"points/{project.points.ids[p]}/{a}") for a in "XYZ"] for p in used]
    want = np.array([npz["covariance"][i, i] for i in rows])
    np.testing.assert_allclose(got, want, rtol=1e-9)


def _frame_change(src, dst):
    """The block-diagonal map B of an export ``src`` (ground frame 1) into ``dst``'s frame, the two
    solutions differing by a finite rigid motion R (fitted on the points): R on the points and the
    projection centres, ``J(R R_k) J(R_k)^-1`` on the angles of photo k (angles_jacobian: a
    perturbation of R_k, on the right, is the same rotation vector in both frames). Returns B and
    the largest residual of the fit."""
    pts = [i for i, lab in enumerate(src.labels) if lab.startswith("points/")]
    s, R, _, resid = _helmert(src.values[pts].reshape(-1, 3), dst.values[pts].reshape(-1, 3))
    B = np.zeros((len(src.labels), len(src.labels)))
    k = 0
    while k < len(src.labels):
        if src.labels[k].startswith("photos/"):
            ang = src.values[k + 3:k + 6]
            Rk = R_from_angles(ang, src.convention)
            J = angles_jacobian(np.stack([Rk, R @ Rk]), src.convention)
            B[k:k + 3, k:k + 3] = R
            B[k + 3:k + 6, k + 3:k + 6] = J[1] @ np.linalg.inv(J[0])
            k += 6
        else:
            B[k:k + 3, k:k + 3] = R
            k += 3
    return B, resid, s


@pytest.mark.parametrize("method", ["conditions", "bundle"])
@pytest.mark.parametrize("which", ["all", "subset"])
def test_full_covariance_of_the_point_datum_is_the_photo_datum_s_transformed_with_scale_bars(bars, method, which):
    """The issue's check with scale bars for the whole exported covariance (photos and points): the
    photo datum's S-transformed by a rigid motion (the bars give the scale) to the datum points is
    the point datum's, 1e-9 of its largest entry, once the finite rigid motion between the two
    solutions is brought in."""
    project, runs = bars
    rph, rpt = runs[(method, "inner", "all")][0], runs[(method, "inner-points", which)][0]
    eph = joint_covariance(project, rph, triangulate_adjusted(project, rph), ("photos", "points"))
    ept = joint_covariance(project, rpt, triangulate_adjusted(project, rpt), ("photos", "points"))
    st = s_transform(eph, _datum_ids(project, rpt), scale=False)
    B, resid, s = _frame_change(st, ept)
    assert resid < 1e-7 and abs(s - 1.0) < 1e-9
    assert np.abs(B - np.eye(len(B))).max() > 1e-6  # a real change of frame
    np.testing.assert_allclose(B @ st.cov @ B.T, ept.cov, rtol=0, atol=1e-9 * np.abs(ept.cov).max())


# ---------------------------------------------------------------- bad input


def _keep_rows(project, keep):
    """The project with only the image points ``keep`` (bool per row)."""
    ip = project.image_points
    arrays = {f.name: getattr(ip, f.name)[keep] for f in fields(ip)
              if isinstance(getattr(ip, f.name), np.ndarray) and len(getattr(ip, f.name)) == len(keep)}
    return replace(project, image_points=replace(ip, **arrays))


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_points_with_one_ray_are_no_datum_points(noisy, method):
    """A tie point left with one ray takes no part; a plan point with one ray takes part (its height
    from the ray) but is no datum point by default; named as one it is refused, explained."""
    project, _ = noisy
    used = _used(project)
    lonely, plan = used[3], used[8]
    ip = project.image_points
    keep = np.ones(len(ip.point_index), dtype=bool)
    for p in (lonely, plan):
        keep[np.flatnonzero(ip.point_index == p)[1:]] = False
    kind, given = project.points.kind.copy(), project.points.xyz_given.copy()
    kind[plan] = model.PLAN
    given[plan, :2] = project.points.xyz_approx[plan, :2]
    q = replace(_keep_rows(project, keep), points=replace(project.points, kind=kind, xyz_given=given))
    r, _ = _run(q, method, "inner-points")
    assert r.converged and len(r.free_network.points.index) == len(used) - 2
    assert lonely not in r.free_network.points.index and plan not in r.free_network.points.index
    for p in (lonely, plan):
        ids = (str(q.points.ids[p]),) + tuple(str(q.points.ids[i]) for i in used[10:12])
        with pytest.raises(NumericalFailure, match="take no part in the adjustment with two or more rays"):
            adjust(q, AdjustmentOptions(method=method, datum="inner-points", datum_points=ids))


def test_datum_points_on_a_line_are_explained(noisy):
    project, _ = noisy
    used = _used(project)
    # three points on a line cannot fix the rotation about it: moved onto one by their approximations
    three = used[:3]
    approx = project.points.xyz_approx.copy()
    approx[three[2]] = 2 * approx[three[1]] - approx[three[0]]
    on_line = replace(project, points=replace(project.points, xyz_approx=approx))
    with pytest.raises(NumericalFailure, match="cannot fix"):
        adjust(on_line, AdjustmentOptions(datum="inner-points",
                                          datum_points=tuple(str(project.points.ids[i]) for i in three)))


@pytest.fixture(scope="module")
def folder(tmp_path_factory, noisy):
    project, _ = noisy
    out = tmp_path_factory.mktemp("pd") / "block"
    write_project(out, project)
    return out


def _toml(folder, text):
    (folder / "project.toml").write_text((folder / "project.toml").read_text() + text)


def test_command_line_point_datum_and_its_summary(folder, tmp_path):
    proc = run("adjust", folder, "--out", tmp_path / "o", "--method", "bundle", "--datum", "inner-points", "--quiet")
    assert proc.returncode == 0, proc.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    rays = {}
    for line in (folder / "image_points.csv").read_text().splitlines()[1:]:
        if line and not line.startswith("#"):
            rays[line.split(",")[1]] = rays.get(line.split(",")[1], 0) + 1
    assert s["datum"]["mode"] == "inner-points"
    assert s["datum"]["n_datum_points"] == sum(1 for k in rays.values() if k >= 2)
    assert len(s["datum"]["free_directions"]) == 7 and "scale" in s["datum"]["free_directions"]
    assert "inner constraints on" in (tmp_path / "o" / "report.html").read_text()
    ids = sorted(p for p, k in rays.items() if k >= 2)[:4]
    proc = run("adjust", folder, "--out", tmp_path / "o2", "--datum", "inner-points", "--datum-points", ",".join(ids),
               "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "o2" / "summary.json").read_text())["datum"]["n_datum_points"] == 4


@pytest.mark.parametrize("given, words", [(["NOPE", 0, 1], "NOPE"), ([0, 1], "at least three")])
def test_command_line_bad_datum_points(noisy, folder, tmp_path, given, words):
    ids = [p if isinstance(p, str) else str(noisy[0].points.ids[p]) for p in given]
    proc = run("adjust", folder, "--out", tmp_path / "o", "--datum", "inner-points", "--datum-points", ",".join(ids))
    message = assert_clean_failure(proc, 2)
    assert words in message and "command line" in message
    assert "('" not in message  # the ids as given, not a Python tuple
    assert not (tmp_path / "o").exists()


def test_sequential_with_a_free_network_names_the_datum(folder, tmp_path):
    """The project asks for the point datum, the command line for the sequential method: the message
    names the datum the project gave (not a --datum the user did not type)."""
    copy = tmp_path / "p"
    shutil.copytree(folder, copy)
    _toml(copy, '\n[datum]\nmode = "inner-points"\n')
    message = assert_clean_failure(run("adjust", copy, "--out", tmp_path / "o", "--method", "sequential"), 2)
    assert "datum 'inner-points'" in message and "--method sequential" in message
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("text, words", [
    ('\n[datum]\nmode = "inner-points"\npoints = ["NOPE", "X1", "X2"]\n', "NOPE, X1, X2 not among the object points"),
    ('\n[datum]\nmode = "inner-points"\npoints = ["X1", "X2"]\n', "at least three"),
    ('\n[datum]\nmode = "inner"\npoints = ["X1", "X2", "X3"]\n', "inner-points"),
])
def test_project_toml_bad_datum_points(folder, tmp_path, text, words):
    copy = tmp_path / "p"
    shutil.copytree(folder, copy)
    _toml(copy, text)
    message = assert_clean_failure(run("adjust", copy, "--out", tmp_path / "o"), 2)
    lines = (copy / "project.toml").read_text().splitlines()
    line = next(k for k, t in enumerate(lines, start=1) if t.startswith("points"))
    assert words in message and f"project.toml, line {line}" in message
    assert not (tmp_path / "o").exists()
