"""The convergence criterion of the simultaneous adjustments means the same at every size
(issue 12; adjustment.correction_in_sigma, has_converged, docs/decisions.md "A convergence test
that means the same at every size").

The measure ``sqrt(dx^T N dx)`` is the largest correction of any function of the unknowns in
units of that function's standard deviation. Stopping below a tolerance therefore leaves every
element within that fraction of its own (true, correlated) standard deviation of the converged
solution, on a strip of 100 photos as on one of 10,000, where the former measure
``max |dx_i| sqrt(N_ii)`` demanded corrections thousands of times below the true precision and
never converged with the defaults.
"""

import numpy as np
import pytest

from striptri import simulate as sim
from striptri.adjustment import (
    AdjustmentOptions,
    Iteration,
    adjust,
    correction_in_sigma,
    has_converged,
    largest_correction,
)
from striptri.io import read_project

from cli_support import DATA

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("convergence")


def _strip(n_photos: int, seed: int = 3):
    """A strip held by full control at its ends only (simulate's default for strips): the weakest
    and the slowest to converge, its condition number growing with the length."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=n_photos), control=sim.ControlDesign(layout="ends"))
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(seed + 1))


def test_the_measure_is_the_largest_correction_of_any_function():
    """sqrt(d' N d) = max over functions f of |f' d| / sqrt(f' N^-1 f) (Cauchy-Schwarz in the metric
    of N), reached for f = N d; every element's correction in units of its true standard deviation
    sqrt(Qxx_ii) lies below it; the former measure |d_i| sqrt(N_ii) is the same ratio with the
    standard deviation each element would have if all others were known."""
    result = adjust(read_project(DATA / "strip8"))
    N = result.N.toarray()
    Q = np.linalg.inv(N)
    rng = np.random.default_rng(7)
    for _ in range(20):
        d = Q @ rng.standard_normal(len(N))  # a correction shaped like the adjustment's (N^-1 u)
        e = correction_in_sigma(d, result.N)
        f = N @ d
        assert abs(f @ d) / np.sqrt(f @ Q @ f) == pytest.approx(e, rel=1e-9)
        for g in rng.standard_normal((50, len(N))):  # no other function changes by more
            assert abs(g @ d) / np.sqrt(g @ Q @ g) <= e * (1 + 1e-12)
        assert np.max(np.abs(d) / np.sqrt(np.diag(Q))) <= e * (1 + 1e-12)
        floor = np.zeros(len(d))
        assert largest_correction(d, np.diag(N), floor) == pytest.approx(np.max(np.abs(d) * np.sqrt(np.diag(N))))


@pytest.fixture(scope="module")
def strips():
    """For 100 and 10,000 photos: the project, the adjustment stopped at a loose tolerance, and the
    reference adjustment with the defaults."""
    out = {}
    for n in (100, 10_000):
        project = _strip(n)
        reference = adjust(project)
        loose = adjust(project, AdjustmentOptions(tolerance=LOOSE))
        out[n] = (project, loose, reference)
    return out


LOOSE = 1e-4  # above the round-off floor of both strips (4.5e-7 at 10,000 photos), so that it alone stops them


@pytest.mark.parametrize("n", [100, 10_000])
def test_the_defaults_converge_at_every_length(strips, n):
    """With the defaults (tolerance 1e-8, 30 iterations) both strips converge. (Before, the
    10,000-photo strip stalled at max |dx_i| sqrt(N_ii) = 4e-4 after 8 iterations: its round-off
    floor in the former measure, 40,000 times the tolerance.)"""
    _, _, reference = strips[n]
    assert reference.converged and reference.termination == "converged"
    assert reference.iterations <= 10
    assert reference.checks.max_condition_misclosure_sigma < 1e-6


@pytest.mark.parametrize("n", [100, 10_000])
def test_stops_at_the_same_relative_precision(strips, n):
    """Stopped at the tolerance 1e-4, every projection centre lies within 1e-4 of its standard
    deviation (sqrt(Qxx_ii), the a-priori one: sigma0 = 1) of the converged solution, at 100
    photos as at 10,000; and the correction the measure reported at the stop (or predicted for the
    next iteration) bounds that remaining error."""
    _, loose, reference = strips[n]
    assert loose.converged
    cols = reference.layout.photo_cols[:, :3]
    sigma = np.sqrt(reference.covariance.diag()[cols])
    error = np.abs(loose.state.xyz0 - reference.state.xyz0) / sigma
    assert np.max(error) < LOOSE
    # the last correction taken was still above the error left after it (the criterion is not
    # loose): the stop came at the first iteration whose measured or predicted correction was small
    h = loose.history
    assert h[-1].max_correction < LOOSE or has_converged(h, LOOSE)
    assert len(h) < 2 or h[-2].max_correction > LOOSE


def test_the_former_measure_depends_on_the_length(strips):
    """Why the former measure ``|dx_i| sqrt(N_ii)`` cannot mean the same at every size: in units of
    an element's true standard deviation it is ``|dx_i| / sqrt(Qxx_ii)`` times ``sqrt(N_ii Qxx_ii)``,
    the ratio of the true standard deviation to the one the element would have if all others were
    known, and that ratio grows with the length of a strip held at its ends (the weak bending and
    twisting of a long strip). A tolerance on it demands ever smaller corrections in true standard
    deviations as strips grow; correction_in_sigma needs no such factor."""
    factor = {}
    for n, (_, _, reference) in strips.items():
        cols = reference.layout.photo_cols[:, :3].ravel()
        ratio = np.sqrt(reference.N.diagonal()[cols] * reference.covariance.diag()[cols])
        factor[n] = float(np.median(ratio))
    assert factor[100] > 1.0
    assert factor[10_000] > 30 * factor[100]


def test_prediction_takes_the_slower_of_two_rates():
    """The next correction is predicted from the slower of the last two contraction rates: a
    quadratic drop followed by linear convergence (measured on a strip with GNSS centres and no
    control: 2.2 -> 2.8e-5 -> 1.2e-7 sd) does not stop early."""
    h = lambda *c: [Iteration(vtpv=1.0, max_correction=x, seconds=0.0) for x in c]  # noqa: E731
    assert not has_converged(h(468.0, 2.2, 2.82e-5), 1e-8)  # last rate alone would predict 4e-10
    assert has_converged(h(2.2, 2.82e-5, 1.23e-7), 1e-8)  # both rates fast: 1.23e-7 * 4.4e-3 = 5e-10
    assert not has_converged(h(1.0, 0.4, 0.1), 1e-8)
    assert has_converged(h(1.0, 0.4, 0.1), 0.2)
    # stalled at the floor: converged only below it
    assert has_converged(h(1e-3, 4.5e-7, 4.3e-7), 1e-8, floor=2e-5)
    assert not has_converged(h(1e-3, 4.5e-7, 4.3e-7), 1e-8, floor=1e-7)


def test_the_bundle_converges_on_the_long_strip_too(strips):
    """The bundle method measures the whole step (orientations and points) the same way, and
    agrees with the conditions method on the 10,000-photo strip."""
    project, _, reference = strips[10_000]
    bundle = adjust(project, AdjustmentOptions(method="bundle"))
    assert bundle.converged
    flying_height = 1500.0
    assert np.max(np.abs(bundle.state.xyz0 - reference.state.xyz0)) < 1e-6 * flying_height


@pytest.mark.parametrize("method", ["conditions", "bundle"])
@pytest.mark.parametrize("solver", ["cholmod", "cvxopt"])
def test_the_last_iterations_on_one_factor_give_the_same_adjustment(monkeypatch, solver, method):
    """Both methods solve the iterations after a correction below REUSE_FACTOR_BELOW on the factor
    they hold (chord steps; the method of conditions forms u alone, the bundle its reduced b): the
    block of 3 x 6 photos takes 5 iterations, the last two on the third's factor, and ends where
    factorising every N ends: the same iterations, the orientations to 1e-9 of their standard
    deviations' scale (metres, radians), the final checks alike, and v^T P v to 5e-12: its
    round-off, not the path's (the runs factorising every N with CHOLMOD and with cvxopt differ by
    1.7e-12, the last two iterations of one by 1.1e-12, at corrections of 1e-8 sd whose square is
    far below; the bundle's chord and factorised runs by 3e-13)."""
    from striptri.core import convergence
    from striptri.solvers import cholmod_available, cvxopt_available

    if not {"cholmod": cholmod_available, "cvxopt": cvxopt_available}[solver]():
        pytest.skip(f"{solver} is not installed")
    project = read_project(DATA / "block_3x6")
    options = AdjustmentOptions(method=method, solver=solver)
    reused = adjust(project, options)
    monkeypatch.setattr(convergence, "REUSE_FACTOR_BELOW", 0.0)
    own = adjust(project, options)
    chord = [h.solver_info.held_factor for h in reused.history]
    assert chord == [None] * 3 + [True] * 2
    assert all(h.solver_info.held_factor is None for h in own.history)
    assert reused.iterations == own.iterations
    assert reused.vtpv == pytest.approx(own.vtpv, rel=5e-12)
    np.testing.assert_allclose(reused.state.xyz0, own.state.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(reused.state.R_ground_from_cam, own.state.R_ground_from_cam, rtol=0, atol=1e-12)
    assert reused.checks.max_BTk_sigma < 1e-6 and own.checks.max_BTk_sigma < 1e-6
    assert abs(reused.checks.vtpv_reduction_relative_difference) < 1e-9


def test_the_bundles_chord_steps_start_from_normals_without_n(monkeypatch):
    """Before a chord step the bundle forms its trial's normals without the reduced N (b alone,
    bundle.adjust._next_is_chord), unless the corrections say the run converges there: the 3 x 6
    block forms two such (after the third and the fourth step; the fifth converges, its normals
    are whole for the precision) and ends at the same adjustment to the bit as with N formed in
    every trial."""
    from striptri import solvers
    from striptri.bundle import adjust as bundle, reduced

    if not solvers.cholmod_available():
        pytest.skip("cholmod is not installed")
    lean = []
    finish = reduced.ReducedNormals.finish
    monkeypatch.setattr(reduced.ReducedNormals, "finish", lambda self: lean.append(self.lean) or finish(self))
    project = read_project(DATA / "block_3x6")
    options = AdjustmentOptions(method="bundle", solver="cholmod")
    r = adjust(project, options)
    assert lean.count(True) == 2 and [h.solver_info.held_factor for h in r.history] == [None] * 3 + [True] * 2
    assert r.N is not None
    lean.clear()
    monkeypatch.setattr(bundle, "_next_is_chord", lambda *args: False)
    whole = adjust(project, options)
    assert not any(lean) and whole.iterations == r.iterations
    assert whole.vtpv == r.vtpv
    np.testing.assert_array_equal(whole.state.xyz0, r.state.xyz0)
    assert (whole.N != r.N).nnz == 0


def test_the_factor_is_kept_for_chord_steps_only_while_the_corrections_shrink_a_hundredfold():
    """keeps_factor: a chord step follows a correction below REUSE_FACTOR_BELOW sd that shrank by
    CHORD_RATE or more against the one before (or a first iteration's, or one below the round-off
    floor); not a large correction, nor one that shrank less."""
    from striptri.core import convergence
    from striptri.core.result import Iteration

    def history(*corrections):
        return [Iteration(vtpv=1.0, max_correction=c, seconds=0.0) for c in corrections]

    keeps = convergence.keeps_factor
    assert convergence.CHORD_RATE == 0.01 and convergence.REUSE_FACTOR_BELOW == 100.0
    assert keeps(history(3515.0, 14.2), 1e-9)  # 4e-3: Gauss-Newton converging fast
    assert not keeps(history(4710.0, 69.4), 1e-9)  # 1.5e-2: not yet (the film strip below)
    assert not keeps(history(1e6, 150.0), 1e-9)  # above REUSE_FACTOR_BELOW however fast
    assert keeps(history(0.05), 1e-9)  # a first iteration: no rate to judge
    assert not keeps(history(3.6e-6, 2.0e-7), 1e-9) and keeps(history(3.6e-6, 2.0e-7), 7.7e-5)  # stalled at round-off


def test_a_strongly_nonlinear_strip_takes_no_chord_step_before_gauss_newton_converges_fast(monkeypatch):
    """The scanned-film strip (self-calibrating, far approximations) by cvxopt's CHOLMOD: its second
    correction (69 sd) shrank only 68-fold, and a chord step on that factor would contract by 0.06
    then 0.7 (nine iterations with a rate limit of 0.5). The factor is kept only after Gauss-Newton's
    ten-thousand-fold step, so the run takes the five iterations of factorising every N, the last a
    chord step, and ends at the same solution."""
    from striptri.core import convergence

    project = read_project(DATA.parent / "film_strip")
    options = AdjustmentOptions(solver="cvxopt")
    chord = adjust(project, options)
    assert [h.solver_info.held_factor for h in chord.history] == [None] * 4 + [True]
    monkeypatch.setattr(convergence, "REUSE_FACTOR_BELOW", 0.0)
    own = adjust(project, options)
    assert own.iterations == chord.iterations == 5
    np.testing.assert_allclose(chord.state.xyz0, own.state.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(chord.state.R_ground_from_cam, own.state.R_ground_from_cam, rtol=0, atol=1e-12)
    monkeypatch.setattr(convergence, "REUSE_FACTOR_BELOW", 100.0)
    monkeypatch.setattr(convergence, "CHORD_RATE", 0.5)  # the first rule: chord steps from the 69 sd factor
    loose = adjust(project, options)
    assert loose.iterations > own.iterations


def test_a_chord_steps_correction_in_the_metric_of_its_n_without_n():
    """chord_correction: for a step that solved N dx = -u, sqrt(-dx^T u) is correction_in_sigma's
    sqrt(dx^T N dx) to round-off (a normal matrix of a strip with mixed units, Jacobi-badly scaled);
    for a step that did not solve it (another N), it is not."""
    import scipy.sparse as sp

    from striptri.core.convergence import chord_correction

    rng = np.random.default_rng(12)
    J = sp.random(400, 60, density=0.1, random_state=12) @ sp.diags(10.0 ** rng.uniform(-3, 3, 60))
    N = (J.T @ J + sp.identity(60) * 1e-6).tocsr()
    u = rng.normal(size=60)
    dx = -np.linalg.solve(N.toarray(), u)
    assert chord_correction(dx, u) == pytest.approx(correction_in_sigma(dx, N), rel=1e-9)
    other = -np.linalg.solve((N + sp.diags(N.diagonal())).toarray(), u)  # solved with 2 diag(N) on the diagonal
    assert abs(chord_correction(other, u) - correction_in_sigma(other, N)) > 1e-3 * correction_in_sigma(other, N)
    assert chord_correction(np.zeros(0), np.zeros(0)) == 0.0
