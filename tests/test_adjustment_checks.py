"""Schmid's checks after convergence (58, 59 and the final check), redundancy numbers, and the
agreement of the two direct solvers, on the shipped pair and strip."""

from pathlib import Path

import numpy as np
import pytest

from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io import read_project
from striptri.precision.residuals import normalised_residuals, residual_cofactors

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


@pytest.fixture(scope="module", params=["pair", "strip8"])
def adjusted(request):
    project = read_project(DATA / request.param)
    return project, adjust(project)


def test_schmid_checks_hold_after_convergence(adjusted):
    _, r = adjusted
    assert r.converged
    # final check: the adjusted observations satisfy every condition (in units of its sigma)
    assert r.checks.max_condition_misclosure_sigma < 1e-7
    # (58): B^T k = 0, the right-hand side of the normal equations vanishes at the solution
    assert r.checks.max_BTk_sigma < 1e-7
    # (59): v^T P v equals the reduced sum [LL.u] of the normal equations
    assert r.checks.vtpv_reduction_relative_difference < 1e-8


def test_vtpv_equals_the_weighted_residuals(adjusted):
    project, r = adjusted
    v = r.plate_residuals
    assert r.vtpv == pytest.approx(float(np.sum(v**2 / project.image_points.sigma_xy**2)), rel=1e-10)


def test_redundancy_numbers_add_up_to_the_redundancy(adjusted):
    project, r = adjusted
    cof = residual_cofactors(project, r)
    numbers = cof.redundancy_numbers(project, r)
    total = sum(float(np.sum(x)) for x in numbers.values())
    assert total == pytest.approx(r.redundancy, rel=1e-9)
    assert np.all(numbers["plate"] > -1e-12) and np.all(numbers["plate"] < 1 + 1e-12)


def test_normalised_residuals_and_redundancy_numbers_rebuild_vtpv(adjusted):
    """sum r_i w_i^2 = sum (qvv_i/q_i) v_i^2/qvv_i = v^T P v: the cofactors Qvv (from N^-1) and the
    residuals (from the iterations) are computed independently, so this ties them together."""
    project, r = adjusted
    cof = residual_cofactors(project, r)
    w = normalised_residuals(r.plate_residuals, cof.plate)
    rn = cof.redundancy_numbers(project, r)["plate"]
    ok = np.isfinite(w)
    assert float(np.sum(rn[ok] * w[ok] ** 2)) == pytest.approx(r.vtpv, rel=1e-8)


def test_dense_and_sparse_solvers_agree(adjusted):
    project, r = adjusted
    s = adjust(project, AdjustmentOptions(solver="sparse"))
    np.testing.assert_allclose(s.state.xyz0, r.state.xyz0, atol=1e-9 * 1500)
    np.testing.assert_allclose(s.state.R_ground_from_cam, r.state.R_ground_from_cam, atol=1e-11)
    assert s.vtpv == pytest.approx(r.vtpv, rel=1e-9)


def test_xz_scale_form_equals_3d_on_a_strip_along_x():
    project = read_project(DATA / "strip8")
    a = adjust(project)
    b = adjust(project, AdjustmentOptions.of(scale_form="xz"))
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, atol=1e-9 * 1500)
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-9)


@pytest.mark.parametrize("method", ["conditions", "bundle"])
@pytest.mark.parametrize("name", ["cholmod", "cvxopt"])
def test_final_checks_solve_with_the_converged_iterations_factor(monkeypatch, name, method):
    """The final checks of a converged adjustment solve with the factor the solver holds (its last
    factorisation: the iterations after a small correction are chord steps on the one before them,
    conditions_method.adjust._iteration, bundle.adjust._step): one factorisation per iteration
    that was not a chord step and none more, and (59) holds as tightly as with N factorised again
    at the solution. An adjustment stopped at its iteration limit factorises N at the solution for
    the next correction."""
    from striptri import solvers

    solver_class = solvers.selection._SOLVER_CLASSES[name]
    try:
        solver_class(solvers.SolverOptions(name), solvers.Structure(0))
    except solvers.SolverUnavailable:
        pytest.skip(f"{name} is not installed")
    calls = []
    original = solver_class.solve
    monkeypatch.setattr(solver_class, "solve", lambda self, N, b: calls.append(1) or original(self, N, b))
    project = read_project(DATA / "strip8")
    r = adjust(project, AdjustmentOptions(method=method, solver=name))
    factorised = [h for h in r.history if h.solver_info.held_factor is None]
    assert r.converged and len(calls) == len(factorised) < len(r.history)
    assert r.checks.vtpv_reduction_relative_difference < 1e-8 and r.checks.max_BTk_sigma < 1e-7
    calls.clear()
    stopped = adjust(project, AdjustmentOptions(method=method, solver=name, max_iterations=2, keep_unconverged=True))
    assert not stopped.converged and len(calls) == 3
    assert "correction" in stopped.termination_message
