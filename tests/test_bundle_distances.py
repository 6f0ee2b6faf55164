"""Distance observations between object points in the bundle method (striptri.bundle.distances)."""

from dataclasses import replace

import numpy as np
import pytest

from striptri import model
from striptri.bundle import solve_bundle
from striptri.bundle.adjust import _Problem
from striptri.bundle.distances import Distances, linearise_distances
from striptri.core.options import AdjustmentOptions

from distance_support import strip_with_truth


def test_distance_jacobian_matches_central_differences():
    rng = np.random.default_rng(5)
    xyz = rng.normal(size=(4, 3)) * 100
    free = np.ones((4, 3), dtype=bool)
    free[3, 2] = False
    dist = Distances(np.array([0, 2, 1]), np.array([1, 3, 2]), np.array([50.0, 80.0, 120.0]), np.array([0.01, 0.02, 0.5]))
    e, Ja, Jb = linearise_distances(dist, xyz, free)
    h = 1e-4
    for r in range(len(dist)):
        for end, J in ((dist.point_from[r], Ja), (dist.point_to[r], Jb)):
            for i in range(3):
                up, down = xyz.copy(), xyz.copy()
                up[end, i] += h
                down[end, i] -= h
                # J dX = e + v: the row is d|X_a - X_b|/dX / sigma, and e falls as the length grows
                numeric = -(linearise_distances(dist, up, free)[0][r] - linearise_distances(dist, down, free)[0][r]) / (2 * h)
                expected = numeric if free[end, i] else 0.0
                assert J[r, i] == pytest.approx(expected, rel=1e-7, abs=1e-9)


_strip = strip_with_truth


def _datum(project, true_xyz, held: dict[int, int]):
    """Every point a tie point but those in held (index -> kind), given at their true coordinates."""
    n = len(project.points)
    kind = np.full(n, model.TIE)
    xyz_given = np.full((n, 3), np.nan)
    for p, k in held.items():
        kind[p] = k
        xyz_given[p] = true_xyz[p]
    points = replace(project.points, kind=kind, xyz_given=xyz_given, sigma_given=np.full((n, 3), np.nan))
    return replace(project, points=points)


def _scaled_by_distance(project, true_xyz, P, Q, sigma):
    """P held, photo 0's angles held, the scale from the distance P-Q (a minimal datum)."""
    project = _datum(project, true_xyz, {P: model.FULL})
    sigma_angles = project.photos.sigma_angles.copy()
    sigma_angles[0] = 0.0
    d = np.linalg.norm(true_xyz[P] - true_xyz[Q])
    return replace(project, photos=replace(project.photos, sigma_angles=sigma_angles),
                   distances=Distances(np.array([P]), np.array([Q]), np.array([d]), np.array([sigma])))


def _pair_distances(xyz, pts):
    i, j = np.triu_indices(len(pts), 1)
    return np.linalg.norm(xyz[pts[i]] - xyz[pts[j]], axis=1)


def test_noise_free_block_scaled_by_a_distance_is_recovered():
    project, usable, true_xyz = _strip(sigma_image=0.0)
    P, Q = usable[0], usable[-1]
    sol = solve_bundle(_scaled_by_distance(project, true_xyz, P, Q, sigma=0.001))
    assert sol.result.termination == "converged"
    xyz = sol.xyz_points + sol.result.offset
    np.testing.assert_allclose(_pair_distances(xyz, usable), _pair_distances(true_xyz, usable), rtol=1e-8)
    np.testing.assert_allclose(xyz[P], true_xyz[P], atol=1e-9)
    assert np.abs(sol.distance_residuals).max() < 1e-7


def test_scale_bar_equals_two_held_points_up_to_a_similarity():
    project, usable, true_xyz = _strip(sigma_image=0.005)
    P, Q, R = usable[0], usable[-1], usable[len(usable) // 2]
    bar = solve_bundle(_scaled_by_distance(project, true_xyz, P, Q, sigma=1e-6))
    held = solve_bundle(_datum(project, true_xyz, {P: model.FULL, Q: model.FULL, R: model.HEIGHT}))
    others = np.setdiff1d(usable, [P, Q])
    a = _pair_distances(bar.xyz_points, others)
    b = _pair_distances(held.xyz_points, others)
    np.testing.assert_allclose(a, b, rtol=1e-6)
    # the shape with noise differs from the truth far more than the two agree
    assert np.max(np.abs(a / _pair_distances(true_xyz, others) - 1)) > 1e-5
    assert bar.result.vtpv == pytest.approx(held.result.vtpv, rel=1e-6)
    assert bar.result.redundancy == held.result.redundancy


def test_converged_solution_is_stationary_in_the_distance_points():
    """The cost with a weak distance (sigma comparable to the points' precision) has zero gradient
    in the distance points' coordinates and the orientation unknowns: the coupled elimination
    solves the coupled problem."""
    project, usable, true_xyz = _strip(sigma_image=0.005)
    P, Q = usable[1], usable[-2]
    project = _datum(project, true_xyz, {usable[0]: model.FULL, usable[-1]: model.FULL, usable[2]: model.FULL})
    d = np.linalg.norm(true_xyz[P] - true_xyz[Q]) + 0.05  # a distance off by 5 sigma
    project = replace(project, distances=Distances(np.array([P]), np.array([Q]), np.array([d]), np.array([0.01])))
    sol = solve_bundle(project, AdjustmentOptions(tolerance=1e-6))
    problem = _Problem(project, AdjustmentOptions())
    state = sol.result.state
    xyz = sol.xyz_points
    h = 1e-5
    for p in (P, Q):
        for i in range(3):
            up, down = xyz.copy(), xyz.copy()
            up[p, i] += h
            down[p, i] -= h
            g = (problem.cost(state, up) - problem.cost(state, down)) / (2 * h)
            curvature = (problem.cost(state, up) - 2 * problem.cost(state, xyz) + problem.cost(state, down)) / h**2
            assert abs(g) / np.sqrt(curvature) < 1e-3
    for j in range(problem.layout.n_unknowns):  # the orientation unknowns
        step = np.zeros(problem.layout.n_unknowns)
        step[j] = 1e-6
        up, down = state.updated(problem.layout, step), state.updated(problem.layout, -step)
        c_up, c_0, c_down = problem.cost(up, xyz), problem.cost(state, xyz), problem.cost(down, xyz)
        g = (c_up - c_down) / 2e-6
        assert abs(g) / np.sqrt(max(c_up - 2 * c_0 + c_down, 1e-300) / 1e-12) < 1e-3
    free = solve_bundle(replace(project, distances=None))
    length = lambda s: np.linalg.norm(s.xyz_points[P] - s.xyz_points[Q])  # noqa: E731
    assert length(sol) - length(free) > 0.01  # the distance pulls the two points apart
    assert abs(sol.distance_residuals[0]) < abs(length(free) - d) / 10
    assert sol.distance_residuals[0] == pytest.approx(length(sol) - d, abs=1e-12)
    assert sol.result.checks.vtpv_reduction_relative_difference < 1e-6
    assert sol.result.checks.max_point_gradient_sigma < 1e-6  # (58) for the points, the distance's share included
