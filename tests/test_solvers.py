"""One suite every solver of the normal equations must pass (DESIGN section 5; scipy ``_lsq``
mixin style): each concrete solver is a subclass of :class:`SolverSuite` that names it.

Agreement with the dense reference is measured on the Jacobi-scaled unknowns ``y = dx sqrt(N_ii)``
(metres, radians and millimetres alike): ``|y - y_ref| / |y_ref|``. Direct solvers: 1e-10.
Iterative solvers stop at the relative residual ``tol`` of the scaled system, which bounds the
relative error by ``cond(N~) tol`` (``|e|/|y| <= cond |r|/|b|``); they must meet twice that bound.
"""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from dataclasses import replace

from striptri import simulate as sim
from striptri import solvers
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io import read_project
from striptri.solvers import (
    SOLVERS,
    SingularNormalMatrix,
    SlowConvergenceWarning,
    SolverOptions,
    SolverUnavailable,
    Structure,
    make_solver,
)
from striptri.equations.parameters import build_layout
from striptri.solvers import memory, selection, strips
from striptri.solvers.synthetic import block_normal_matrix, strip_normal_matrix

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
FLYING_HEIGHT = 1500.0  # m, data/synthetic_strips/README.md
DIRECT_RTOL = 1e-10
HOLDS_FACTOR = ("cholmod", "cvxopt")  # the solvers whose factor serves solve_again


def scaled_error(N, dx, ref) -> float:
    s = np.sqrt(N.diagonal())
    return float(np.linalg.norm((dx - ref) * s) / np.linalg.norm(ref * s))


def scaled_condition(N) -> float:
    s = 1.0 / np.sqrt(N.diagonal())
    return float(np.linalg.cond(N.toarray() * s[:, None] * s[None, :]))


def dense_reference(N, b):
    return make_solver(SolverOptions("dense"), Structure(N.shape[0])).solve(N, b).dx


def strip_case(n_photos, n_cameras, seed):
    return strip_normal_matrix(n_photos, np.random.default_rng(seed), n_cameras=n_cameras)


def block_case(n_strips, photos, n_cameras, seed):
    return block_normal_matrix(n_strips, photos, np.random.default_rng(seed), n_cameras=n_cameras)


def indefinite_case():
    """12 x 12, both 6x6 diagonal blocks the identity (positive definite), N itself indefinite
    (eigenvalues -1 and 3): [[I, 2I], [2I, I]]."""
    eye = np.eye(6)
    return sp.csr_matrix(np.block([[eye, 2 * eye], [2 * eye, eye]])), Structure(12, np.array([0, 6]))


def datum_defect_case(seed=3):
    """A strip with tie conditions only: every 6x6 block regular, N singular (6 free directions)."""
    return strip_normal_matrix(6, np.random.default_rng(seed), control=False)


class SolverSuite:
    """The tests every solver passes; a subclass sets ``name`` (and ``iterative``)."""

    name = "dense"
    iterative = False
    defaults: dict = {}  # options of this suite's solver unless a test says otherwise

    def make(self, structure, **options):
        return make_solver(SolverOptions(self.name, **{**self.defaults, **options}), structure)

    def assert_agrees(self, N, structure, b=None, seed=0, solver=None, **options):
        rng = np.random.default_rng(seed)
        b = rng.normal(size=N.shape[0]) if b is None else b
        solver = solver or self.make(structure, **options)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SlowConvergenceWarning)  # slow is fine here, wrong is not
            result = solver.solve(N, b)
        ref = dense_reference(N, b)
        err = scaled_error(N, result.dx, ref)
        if self.iterative:
            tol = options.get("inner_tolerance", SolverOptions().inner_tolerance)
            bound = 2 * scaled_condition(N) * tol
            assert result.info.converged and result.info.relative_residual < tol
            assert err < bound, (err, bound)
        else:
            assert err < DIRECT_RTOL, err
        assert result.solver == solver.name
        return result

    # -- structures of strips and blocks -------------------------------------------------------

    @pytest.mark.parametrize("n_photos", [2, 3, 8, 25])
    @pytest.mark.parametrize("n_cameras", [0, 1, 2])
    def test_strip_block_banded(self, n_photos, n_cameras):
        """6x6 blocks within two photos of the diagonal, camera columns last coupling everything."""
        N, st = strip_case(n_photos, n_cameras, seed=n_photos + 10 * n_cameras)
        self.assert_agrees(N, st)

    @pytest.mark.parametrize("shape", [(3, 6, 0), (4, 10, 1), (2, 25, 3)])
    def test_multi_strip_block(self, shape):
        """Block-sparse, not banded: strips side by side, numbered strip after strip."""
        N, st = block_case(*shape, seed=sum(shape))
        self.assert_agrees(N, st)

    def test_without_block_starts(self):
        """Structure without blocks: consecutive blocks of 6 columns are taken."""
        N, _ = strip_case(10, 1, seed=5)
        self.assert_agrees(N, Structure(N.shape[0]))

    @pytest.mark.parametrize("n", [1, 2, 6, 7])
    def test_tiny_systems(self, n):
        rng = np.random.default_rng(n)
        G = rng.normal(size=(n + 3, n))
        N = sp.csr_matrix(G.T @ G)
        self.assert_agrees(N, Structure(n, np.arange(0, n, 6)))

    def test_zero_size(self):
        result = self.make(Structure(0)).solve(sp.csr_matrix((0, 0)), np.zeros(0))
        assert result.dx.shape == (0,)

    def test_one_solver_object_over_several_iterations(self):
        """Made once, called per outer iteration: new numbers (same pattern), new right-hand sides,
        then a pattern that has lost some entries and one that has more."""
        solver = None
        for k in range(3):
            N, st = strip_case(12, 1, seed=21 + k)  # same pattern, other numbers
            solver = solver or self.make(st)
            self.assert_agrees(N, st, seed=k, solver=solver)
        rng = np.random.default_rng(4)
        # fewer entries: a coupling block between photos 0 and 2 set to exact zero and dropped
        Nz = N.tolil()
        Nz[0:6, 12:18] = 0.0
        Nz[12:18, 0:6] = 0.0
        Nz = Nz.tocsr()
        Nz.eliminate_zeros()
        if np.all(np.linalg.eigvalsh(Nz.toarray()) > 0):
            self.assert_agrees(Nz, st, seed=7, solver=solver)
        # more entries: a tie between photos 0 and 5 (outside the band)
        extra = sp.lil_matrix(N.shape)
        v = rng.normal(size=(1, 12))
        cols = np.r_[0:6, 30:36]
        extra[np.ix_(cols, cols)] = v.T @ v
        self.assert_agrees(sp.csr_matrix(N + extra), st, seed=8, solver=solver)

    def test_solve_again_with_the_held_factor(self):
        """A solver told to hold its factor (the adjustment's final checks) solves another right-hand
        side for the N of its last solve; the CHOLMOD solvers hold one, the others say None. Not
        held unless told, and not after release or a failed solve."""
        N, st = strip_case(12, 1, seed=31)
        rng = np.random.default_rng(31)
        b, b2 = rng.normal(size=N.shape[0]), rng.normal(size=N.shape[0])
        solver = self.make(st)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SlowConvergenceWarning)
            solver.solve(N, b)
            assert solver.solve_again(b2) is None  # dropped after the solve unless held
            solver.holds_factor = True
            N2, _ = strip_case(12, 1, seed=32)  # same pattern, other numbers: the last solve's N counts
            solver.solve(N, b)
            solver.solve(N2, b)
        again = solver.solve_again(b2)
        assert solver.holding() == (again is not None)
        if self.name not in HOLDS_FACTOR:
            assert again is None
            return
        assert scaled_error(N2, again, dense_reference(N2, b2)) < DIRECT_RTOL
        solver.release()
        assert solver.solve_again(b2) is None and not solver.holding()
        solver.solve(N2, b)
        assert solver.holding()
        bad, _ = indefinite_case()
        with pytest.raises(SingularNormalMatrix):
            solver.solve(bad, np.ones(12))
        assert solver.solve_again(b2) is None and not solver.holding()

    # -- singular and indefinite N ---------------------------------------------------------------

    def test_zero_column_is_singular_at_that_column(self):
        N, st = strip_case(5, 0, seed=2)
        N = N.tolil()
        N[14, :] = 0.0
        N[:, 14] = 0.0
        with pytest.raises(SingularNormalMatrix) as exc:
            self.make(st).solve(N.tocsr(), np.ones(N.shape[0]))
        assert exc.value.column == 14

    def test_dependent_columns_within_a_block(self):
        """Two equal columns of one photo: its diagonal block (and N) is singular."""
        rng = np.random.default_rng(9)
        N, st = strip_case(5, 1, seed=9)
        G = rng.normal(size=(40, N.shape[0]))
        G[:, 9] = G[:, 8]
        A = G.T @ G
        A[:, 9], A[9, :] = A[:, 8], A[8, :]  # exactly equal columns
        with pytest.raises(SingularNormalMatrix) as exc:
            self.make(st).solve(sp.csr_matrix(A), rng.normal(size=N.shape[0]))
        assert exc.value.column in (8, 9)

    def test_indefinite_matrix_with_regular_blocks(self):
        N, st = indefinite_case()
        with pytest.raises(SingularNormalMatrix):
            self.make(st, max_inner_iterations=5000).solve(N, np.arange(1.0, 13.0))

    def test_datum_defect(self):
        """Every block regular, N of rank n - 6. Direct solvers raise; an iterative one either
        raises or reports that it did not converge (never a silent, converged answer)."""
        N, st = datum_defect_case()
        b = np.random.default_rng(1).normal(size=N.shape[0])
        if not self.iterative:
            with pytest.raises(SingularNormalMatrix) as exc:
                self.make(st).solve(N, b)
            assert exc.value.column is not None
            return
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = self.make(st).solve(N, b)
            except SingularNormalMatrix:
                return
        assert not result.info.converged
        assert any(issubclass(w.category, SlowConvergenceWarning) for w in caught)

    # -- real normal matrices ------------------------------------------------------------------

    def test_real_normal_matrix_of_strip8(self, strip8_dense):
        _, result = strip8_dense
        st = Structure(result.n_unknowns, result.layout.block_starts())
        self.assert_agrees(result.N, st)

    def test_adjust_strip8_gives_the_dense_orientations(self, strip8_dense):
        project, ref = strip8_dense
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SlowConvergenceWarning)
            r = adjust(project, AdjustmentOptions(solver=self.name))
        assert r.converged and r.solver == self.name
        assert np.abs(r.state.xyz0 - ref.state.xyz0).max() < 1e-9 * FLYING_HEIGHT
        assert np.abs(r.state.R_ground_from_cam - ref.state.R_ground_from_cam).max() < 1e-9
        assert r.vtpv == pytest.approx(ref.vtpv, rel=1e-9)
        if self.iterative:
            assert all(h.solver_info.converged and h.solver_info.inner_iterations > 0 for h in r.history)


class IterativeSuite(SolverSuite):
    """What only the iterative solvers report: inner iterations, residual, convergence, slowness."""

    iterative = True
    # the synthetic strips converge slowly for Gauss-Seidel (thousands of sweeps): correctness is
    # tested here, speed in scripts/bench/bench_solvers.py
    defaults = {"max_inner_iterations": 50000}
    slow_limit = solvers.SLOW_SWEEPS

    def test_reports_inner_iterations(self):
        N, st = strip_case(8, 1, seed=3)
        result = self.assert_agrees(N, st)
        info = result.info
        assert info.inner_iterations >= 1
        assert info.slow is (info.inner_iterations > self.slow_limit)
        assert 0 < info.relative_residual < SolverOptions().inner_tolerance

    def test_a_looser_tolerance_needs_fewer_iterations(self):
        N, st = strip_case(8, 1, seed=3)
        tight = self.assert_agrees(N, st, inner_tolerance=1e-12)
        loose = self.assert_agrees(N, st, inner_tolerance=1e-6)
        assert loose.info.inner_iterations < tight.info.inner_iterations

    def test_warns_when_it_converges_slowly(self):
        N, st = strip_case(30, 1, seed=6)
        with pytest.warns(SlowConvergenceWarning, match="did not reach"):
            result = self.make(st, max_inner_iterations=3).solve(N, np.ones(N.shape[0]))
        assert result.info.slow is True and result.info.converged is False
        assert result.info.inner_iterations == 3

    @pytest.mark.parametrize("warm_start", ["zero", "previous", "projected"])
    def test_warm_starts_give_the_same_solution(self, warm_start):
        N, st = strip_case(10, 1, seed=12)
        solver = self.make(st, warm_start=warm_start)
        for seed in range(3):
            result = self.assert_agrees(N, st, seed=seed, solver=solver, warm_start=warm_start)
            assert result.info.warm_start == warm_start

    def test_zero_right_hand_side(self):
        N, st = strip_case(4, 0, seed=1)
        result = self.make(st).solve(N, np.zeros(N.shape[0]))
        assert np.all(result.dx == 0) and result.info.converged


class TestDense(SolverSuite):
    name = "dense"


class TestSparse(SolverSuite):
    name = "sparse"


class TestBanded(SolverSuite):
    name = "banded"

    @pytest.mark.parametrize("n_cameras", [0, 1, 3])
    def test_bandwidth_of_a_strip_and_its_camera_border(self, n_cameras):
        """Schmid Fig. 10: blocks within two photos of the diagonal, band 17; cameras a border."""
        N, st = strip_case(20, n_cameras, seed=4)
        result = self.assert_agrees(N, st)
        assert result.info.as_dict() == {"bandwidth": 17, "border": 3 * n_cameras}

    def test_bandwidth_of_the_real_strip8(self, strip8_dense):
        project, _ = strip8_dense
        r = adjust(project, AdjustmentOptions(solver="banded"))
        assert all(h.solver_info.as_dict() == {"bandwidth": 17, "border": 0} for h in r.history)


class TestCholmod(SolverSuite):
    name = "cholmod"

    @pytest.fixture(autouse=True)
    def _needs_scikit_sparse(self):
        pytest.importorskip("sksparse.cholmod")

    def test_analyses_once_per_adjustment(self):
        N, st = block_case(3, 8, 1, seed=2)
        solver = self.make(st)
        for seed in range(3):
            result = self.assert_agrees(N * (1.0 + seed), st, seed=seed, solver=solver)
        assert result.info.analyses == 1

    def test_an_adjustment_analyses_once(self, strip8_dense):
        """One symbolic analysis for every factorisation of an adjustment (the iterations that solve
        on a held factor, chord steps, report that instead)."""
        project, _ = strip8_dense
        r = adjust(project, AdjustmentOptions(solver="cholmod"))
        factorised = [h.solver_info.analyses for h in r.history if h.solver_info.held_factor is None]
        assert r.iterations > 1 and factorised == [1] * len(factorised) and len(factorised) >= 2

    def test_a_held_factor_is_refactorised_in_its_own_memory(self, tmp_path):
        """While the solver holds its factor (an adjustment's whole run), a new N is
        factorised into the memory of the last factor (Factor.cholesky_inplace), released or not:
        the same numbers to the last bit as a new factor, without taking the factor's pages from
        the system again. Five refactorisations of a 4,803-unknown block: about 16,000 page faults
        with a new factor each time, under a quarter of that in place. Not held, the factor is
        dropped after each solve, as before."""
        import subprocess

        N, st = block_case(4, 6, 1, seed=12)
        b = np.random.default_rng(12).normal(size=N.shape[0])
        held, fresh = self.make(st), self.make(st)
        held.holds_factor = True
        held.solve(N, b)
        for k in range(1, 4):
            Nk = N * (1.0 + k) + sp.diags(N.diagonal() * 0.01 * k)
            held.release()
            x = held.solve(Nk, b).dx
            assert np.array_equal(x, fresh.solve(Nk, b).dx)
        held.holds_factor = False
        held.release()
        assert held.solve_again(b) is None
        script = tmp_path / "refactorise.py"
        script.write_text(REFACTORISE_SCRIPT)

        def faults(mode: str) -> int:
            proc = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, timeout=120)
            assert proc.returncode == 0, proc.stderr
            return int(proc.stdout)

        assert 4 * faults("held") < faults("dropped")

    @pytest.mark.parametrize("method", ["conditions", "bundle"])
    def test_an_adjustment_refactorises_in_place(self, strip8_dense, method, monkeypatch):
        """Both methods hold their solver's factor for the whole run: every factorisation after the
        first writes into the last one's memory, and the memory is let go when the run ends (also
        the bundle method's, which never asks for solve_again). The result is the dense solver's."""
        from striptri.solvers.sparse_cholesky import CholmodSolver

        project, dense = strip8_dense
        reused, made = [], []
        solve = CholmodSolver.solve

        def spying(solver, N, b):
            made.append(solver)
            reused.append(solver._numeric is not None)
            return solve(solver, N, b)

        monkeypatch.setattr(CholmodSolver, "solve", spying)
        r = adjust(project, AdjustmentOptions(method=method, solver="cholmod"))
        reference = dense if method == "conditions" else adjust(project, AdjustmentOptions(method=method, solver="dense"))
        assert len(reused) >= 2 and reused == [False] + [True] * (len(reused) - 1)
        assert len(set(map(id, made))) == 1
        assert made[0]._numeric is None and made[0].solve_again(np.ones(3)) is None
        np.testing.assert_allclose(r.vtpv, reference.vtpv, rtol=1e-9)


REFACTORISE_SCRIPT = """
import resource, sys
import numpy as np
from striptri.solvers import SolverOptions, make_solver
from striptri.solvers.synthetic import block_normal_matrix
N, st = block_normal_matrix(20, 40, np.random.default_rng(5), n_cameras=1)
b = np.ones(N.shape[0])
solver = make_solver(SolverOptions("cholmod"), st)
solver.holds_factor = sys.argv[1] == "held"
solver.solve(N, b)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for k in range(5):
    solver.release()
    solver.solve(N * (1.0 + k), b)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


class TestCvxopt(SolverSuite):
    name = "cvxopt"

    @pytest.fixture(autouse=True)
    def _needs_cvxopt(self):
        pytest.importorskip("cvxopt.cholmod")

    def test_analyses_once_per_adjustment(self):
        N, st = block_case(3, 8, 1, seed=2)
        solver = self.make(st)
        for seed in range(3):
            result = self.assert_agrees(N * (1.0 + seed), st, seed=seed, solver=solver)
        assert result.info.analyses == 1

    def test_an_adjustment_analyses_once(self, strip8_dense):
        """One symbolic analysis for every factorisation of an adjustment (the iterations that solve
        on a held factor, chord steps, report that instead)."""
        project, _ = strip8_dense
        r = adjust(project, AdjustmentOptions(solver="cvxopt"))
        factorised = [h.solver_info.analyses for h in r.history if h.solver_info.held_factor is None]
        assert r.iterations > 1 and factorised == [1] * len(factorised) and len(factorised) >= 2


class TestGaussSeidel(IterativeSuite):
    name = "gauss-seidel"

    def test_over_relaxation(self):
        N, st = strip_case(8, 1, seed=3)
        plain = self.assert_agrees(N, st)
        sor = self.assert_agrees(N, st, relaxation=1.3)
        assert sor.info.relaxation == 1.3
        assert sor.info.inner_iterations != plain.info.inner_iterations


class TestPcg(IterativeSuite):
    name = "pcg"
    slow_limit = solvers.SLOW_PCG


class TestStripPcg(IterativeSuite):
    """A strip is one block of its preconditioner, so a single strip converges within a few
    iterations (the camera columns): the tests of speed use a block of strips instead."""

    name = "strip-pcg"
    slow_limit = solvers.SLOW_STRIP_PCG

    def test_a_looser_tolerance_needs_fewer_iterations(self):
        N, st = block_case(4, 10, 1, seed=3)
        tight = self.assert_agrees(N, st, inner_tolerance=1e-12)
        loose = self.assert_agrees(N, st, inner_tolerance=1e-6)
        assert loose.info.inner_iterations < tight.info.inner_iterations

    def test_warns_when_it_converges_slowly(self):
        N, st = block_case(4, 10, 1, seed=6)
        with pytest.warns(SlowConvergenceWarning, match="did not reach"):
            result = self.make(st, max_inner_iterations=3).solve(N, np.ones(N.shape[0]))
        assert result.info.slow is True and result.info.converged is False
        assert result.info.inner_iterations == 3

    @pytest.mark.parametrize("preconditioner", strips.PRECONDITIONERS)
    def test_block_of_strips_with_cameras(self, preconditioner):
        """Five strips of 12 photos and two cameras: five banded blocks of bandwidth 17 (Schmid
        Fig. 10), the 6 camera columns one dense block; both preconditioners reach the reference."""
        N, st = block_case(5, 12, 2, seed=4)
        solver = strips.StripPcgSolver(SolverOptions("strip-pcg"), st, preconditioner)
        result = self.assert_agrees(N, st, solver=solver)
        assert {k: getattr(result.info, k) for k in ("strips", "bandwidth", "dense_block", "preconditioner")} == {
            "strips": 5, "bandwidth": 17, "dense_block": 6, "preconditioner": preconditioner}
        assert result.info.inner_iterations > 1  # the couplings between strips are iterated

    def test_one_strip_is_solved_by_its_banded_factor(self):
        N, st = strip_case(200, 0, seed=2)
        result = self.assert_agrees(N, st)
        assert result.info.inner_iterations == 1 and result.info.strips == 1

    def test_groups_without_structure(self):
        """No groups: columns of group -1 are one dense block up to DENSE_REST columns, runs of
        RUN_BLOCKS blocks beyond; any partition gives the reference solution."""
        N, st = strip_case(250, 1, seed=7)
        bare = Structure(st.n_unknowns, st.block_starts)
        part = strips.strip_partition(bare, N.shape[0])
        assert part.n_groups == 3 and part.k == N.shape[0]  # 251 blocks: runs of 100, 100, 51
        self.assert_agrees(N, bare)
        small, sst = strip_case(20, 1, seed=7)
        assert strips.strip_partition(Structure(sst.n_unknowns, sst.block_starts), small.shape[0]).k == 0

    def test_strips_in_their_own_column_order(self):
        """Photos of two strips interleaved in the column order: each strip gathers its columns."""
        N, st = block_case(2, 15, 0, seed=5)
        new = np.arange(30)
        old_photo = new // 2 + 15 * (new % 2)  # new photos 0, 2, 4, ... are strip 0's, 1, 3, ... strip 1's
        perm = (6 * np.repeat(old_photo, 6) + np.tile(np.arange(6), 30))  # old column of each new column
        Np = sp.csr_matrix(N[perm][:, perm])
        Np.sort_indices()
        groups = np.tile([0, 1], 15)
        stp = Structure(st.n_unknowns, st.block_starts, groups)
        result = self.assert_agrees(Np, stp)
        assert result.info.strips == 2 and result.info.bandwidth == 17


def _simulated(n_photos, n_strips, layout, every_k=4, seed=5):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=n_photos, n_strips=n_strips),
        points=sim.PointDesign(extra_ties_per_model=2),
        control=sim.ControlDesign(layout=layout, every_k=every_k, every_k_kind="XYZ"),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(seed + 1))


@pytest.mark.parametrize("n_photos, n_strips, layout", [(1000, 1, "every-k"), (60, 6, "perimeter")])
def test_strip_pcg_adjusts_like_the_direct_solver(n_photos, n_strips, layout):
    """A 1,000-photo strip (full control every 20 models) and a 360-photo block of 6 strips:
    strip-pcg's adjustment gives the direct solver's projection centres (within 1e-6 of the
    flying height) and converges in every outer iteration."""
    project = _simulated(n_photos, n_strips, layout, every_k=20 if n_strips == 1 else 4)
    ref = adjust(project, AdjustmentOptions(solver="cholmod" if solvers.cholmod_available() else "sparse"))
    r = adjust(project, AdjustmentOptions(solver="strip-pcg"))
    assert r.converged and r.solver == "strip-pcg" and r.iterations == ref.iterations
    assert np.abs(r.state.xyz0 - ref.state.xyz0).max() < 1e-6 * FLYING_HEIGHT
    assert r.vtpv == pytest.approx(ref.vtpv, rel=1e-8)
    infos = [h.solver_info for h in r.history]
    assert all(i.converged and i.strips == n_strips and i.bandwidth == 17 for i in infos)
    if n_strips == 1:
        assert all(i.inner_iterations == 1 for i in infos)


def test_block_groups_of_a_layout():
    """Structure.groups from the photos' strips: one group per strip in order of appearance,
    cameras -1; a photo held fixed has no block (and so no group)."""
    project = _simulated(5, 3, "perimeter")
    layout = build_layout(project)
    groups = layout.block_groups(project.photos.strip_ids)
    assert len(groups) == len(layout.block_starts())
    np.testing.assert_array_equal(groups, np.repeat([0, 1, 2], 5))
    held = replace(project.photos, sigma_xyz0=project.photos.sigma_xyz0.copy(),
                   sigma_angles=project.photos.sigma_angles.copy())
    held.sigma_xyz0[6], held.sigma_angles[6] = 0.0, 0.0
    layout = build_layout(replace(project, photos=held))
    np.testing.assert_array_equal(layout.block_groups(project.photos.strip_ids), np.r_[[0] * 5, [1] * 4, [2] * 5])


def test_warm_starts_in_an_adjustment(monkeypatch):
    """Warm starts of strip-pcg in an adjustment of a block (docs/solvers.md has the measurement):
    the same result; 'projected' never needs more inner iterations than 'zero' (it starts from the
    multiple of the last correction that is closest in the energy norm, never worse than zero),
    'previous' needs more in the later outer iterations (the corrections shrink)."""
    project = _simulated(30, 5, "perimeter")
    counts = {}
    for start in ("zero", "previous", "projected"):
        monkeypatch.setitem(selection._SOLVER_CLASSES, "strip-pcg",
                            lambda o, s, start=start: strips.StripPcgSolver(replace(o, warm_start=start), s))
        r = adjust(project, AdjustmentOptions(solver="strip-pcg"))
        assert r.converged and all(h.solver_info.warm_start == start for h in r.history)
        counts[start] = np.array([h.solver_info.inner_iterations for h in r.history])
    assert counts["zero"].shape == counts["projected"].shape == counts["previous"].shape
    assert np.all(counts["projected"] <= counts["zero"] + 1)
    assert counts["previous"][1:].sum() > counts["zero"][1:].sum()


def test_auto_takes_strip_pcg_when_a_direct_factor_would_not_fit(monkeypatch):
    """The factor's memory is estimated from N's pattern before factorising (solvers.memory) and
    compared with the budget (STRIPTRI_MEMORY_BUDGET, else memory.MEMORY_BUDGET, else MemAvailable)."""
    monkeypatch.delenv(memory.ENVIRONMENT, raising=False)
    wide, wst = block_case(3, 100, 1, seed=1)
    strip, sst = strip_case(100, 1, seed=1)
    choice = solvers.sparse_choice()
    estimate = memory.factor_bytes(wide, solvers.bandwidth(wide), choice)
    monkeypatch.setattr(memory, "MEMORY_BUDGET", int(4 * estimate))
    assert solvers.resolve_solver("auto", wide.shape[0], wide, wst) == choice
    assert solvers.resolve_solver("auto", strip.shape[0], strip, sst) == "banded"
    monkeypatch.setattr(memory, "MEMORY_BUDGET", int(estimate))  # the factor may take half of it
    assert solvers.resolve_solver("auto", wide.shape[0], wide, wst) == "strip-pcg"
    monkeypatch.setenv(memory.ENVIRONMENT, "1K")  # the environment variable wins
    monkeypatch.setattr(memory, "MEMORY_BUDGET", 10**15)
    assert solvers.resolve_solver("auto", strip.shape[0], strip, sst) == "strip-pcg"
    auto = make_solver(SolverOptions("auto"), wst)
    b = np.random.default_rng(3).normal(size=wide.shape[0])
    result = auto.solve(wide, b)
    assert auto.name == result.solver == "strip-pcg" and auto.iterative
    assert scaled_error(wide, result.dx, dense_reference(wide, b)) < 1e-6


def test_auto_adjustment_within_a_small_memory_budget(monkeypatch):
    """With a budget too small for any factor the whole adjustment, final checks included, runs on
    strip-pcg and gives the direct result."""
    project = _simulated(30, 4, "perimeter")
    ref = adjust(project, AdjustmentOptions(solver="dense"))
    monkeypatch.setenv(memory.ENVIRONMENT, "1K")
    made = []
    original = selection._SOLVER_CLASSES["dense"]
    monkeypatch.setitem(selection._SOLVER_CLASSES, "dense", lambda o, s: made.append(1) or original(o, s))
    r = adjust(project)
    assert r.solver == "strip-pcg" and r.converged and not made
    assert np.abs(r.state.xyz0 - ref.state.xyz0).max() < 1e-6 * FLYING_HEIGHT
    assert r.checks.vtpv_reduction_relative_difference < 1e-6


@pytest.mark.parametrize("text, value", [("2G", 2 * 2**30), ("500M", 500 * 2**20), ("123456", 123456),
                                         ("1.5k", 1536), ("2GiB", 2 * 2**30)])
def test_memory_budget_from_the_environment(monkeypatch, text, value):
    monkeypatch.setenv(memory.ENVIRONMENT, text)
    assert memory.memory_budget() == value


@pytest.mark.parametrize("text", ["lots", "-1G", "0"])
def test_a_bad_memory_budget_is_refused(monkeypatch, text):
    monkeypatch.setenv(memory.ENVIRONMENT, text)
    with pytest.raises(ValueError, match=memory.ENVIRONMENT):
        memory.memory_budget()


def test_factor_estimate_against_cholmod():
    """The estimate of nnz(L) is within a factor 2 of CHOLMOD's (nested dissection) on a synthetic
    block and a strip (the fit itself: the benchmark blocks, docs/solvers.md)."""
    cholmod = pytest.importorskip("sksparse.cholmod")
    for N, _ in (block_case(20, 40, 0, seed=1), strip_case(800, 0, seed=1)):
        A = sp.csc_matrix(N)
        f = cholmod.analyze(A, mode="supernodal", ordering_method="nesdis")
        f.cholesky_inplace(A)
        actual = f.L().nnz
        estimate = memory.factor_entries(N, solvers.bandwidth(N))
        assert actual / 2 < estimate < 2 * actual, (estimate, actual)


@pytest.fixture(scope="module")
def strip8_dense():
    project = read_project(DATA / "strip8")
    return project, adjust(project, AdjustmentOptions(solver="dense"))


# -- choosing a solver ---------------------------------------------------------------------------


def test_every_solver_has_a_suite():
    suites = {cls.name for cls in (TestDense, TestSparse, TestBanded, TestCholmod, TestCvxopt, TestGaussSeidel,
                                    TestPcg, TestStripPcg)}
    assert suites == set(SOLVERS) - {"auto"}


def test_auto_picks_from_the_pattern():
    tiny = sp.csr_matrix(np.eye(solvers.DENSE_LIMIT))
    assert solvers.resolve_solver("auto", tiny.shape[0], tiny) == "dense"
    N, st = strip_case(100, 1, seed=1)
    assert solvers.resolve_solver("auto", N.shape[0], N, st) == "banded"
    wide, wst = block_case(3, 100, 1, seed=1)  # strips of 100 photos side by side: bandwidth ~ 6 x 100
    assert solvers.resolve_solver("auto", wide.shape[0], wide, wst) == solvers.sparse_choice()
    auto = make_solver(SolverOptions("auto"), st)
    result = auto.solve(N, np.ones(N.shape[0]))
    assert auto.name == result.solver == "banded"


def test_auto_solves_a_nearly_full_matrix_dense():
    """Beyond DENSE_LIMIT unknowns, a matrix with at least DENSE_FILL of its entries nonzero (a close
    range's) up to DENSE_FULL_LIMIT unknowns is solved dense; sparser, or larger, it is not."""
    from striptri.solvers.selection import DENSE_FILL, DENSE_FULL_LIMIT, nearly_full

    rng = np.random.default_rng(5)
    n = 2 * solvers.DENSE_LIMIT
    A = rng.standard_normal((2 * n, n))
    full = sp.csr_matrix(A.T @ A)
    assert solvers.resolve_solver("auto", n, full) == "dense"
    banded = sp.csr_matrix(full.toarray() * (np.abs(np.subtract.outer(np.arange(n), np.arange(n))) < 0.2 * n))
    assert banded.nnz < DENSE_FILL * n * n and solvers.resolve_solver("auto", n, banded) == "banded"
    assert not nearly_full(sp.identity(DENSE_FULL_LIMIT + 1, format="csr") + sp.csr_matrix(
        np.ones((DENSE_FULL_LIMIT + 1, DENSE_FULL_LIMIT + 1))))
    result = make_solver(SolverOptions("auto"), Structure(n)).solve(full, np.ones(n))
    assert result.solver == "dense"
    np.testing.assert_allclose(full @ result.dx, np.ones(n), rtol=0, atol=1e-9)


def test_auto_in_an_adjustment_reports_the_concrete_solver(strip8_dense):
    project, ref = strip8_dense
    r = adjust(project)
    assert r.solver in set(SOLVERS) - {"auto"}
    assert np.abs(r.state.xyz0 - ref.state.xyz0).max() < 1e-9 * FLYING_HEIGHT


def _without(monkeypatch, *modules):
    for m in modules:
        monkeypatch.setitem(sys.modules, m, None)


def test_without_scikit_sparse(monkeypatch):
    """make_solver('cholmod') names the install command; auto never picks cholmod."""
    _without(monkeypatch, "sksparse", "sksparse.cholmod", "cvxopt", "cvxopt.cholmod")
    assert not solvers.cholmod_available() and not solvers.cvxopt_available()
    with pytest.raises(SolverUnavailable, match=r"libsuitesparse-dev.*pip install 'striptri\[cholmod\]'"):
        make_solver(SolverOptions("cholmod"), Structure(10))
    wide, wst = block_case(3, 100, 1, seed=1)
    assert solvers.resolve_solver("auto", wide.shape[0], wide, wst) == "sparse"
    assert solvers.resolve_solver("auto", 10**6) == "sparse"


def test_without_cvxopt(monkeypatch):
    """make_solver('cvxopt') names the pip extra."""
    _without(monkeypatch, "cvxopt", "cvxopt.cholmod")
    assert not solvers.cvxopt_available()
    with pytest.raises(SolverUnavailable, match=r"pip install 'striptri\[fast\]'"):
        make_solver(SolverOptions("cvxopt"), Structure(10))


def test_auto_takes_cvxopt_after_a_plain_pip_install(monkeypatch):
    """Without scikit-sparse, auto's sparse factorisation is cvxopt's CHOLMOD when installed."""
    pytest.importorskip("cvxopt.cholmod")
    _without(monkeypatch, "sksparse", "sksparse.cholmod")
    wide, wst = block_case(3, 100, 1, seed=1)
    assert solvers.sparse_choice() == "cvxopt"
    assert solvers.resolve_solver("auto", wide.shape[0], wide, wst) == "cvxopt"
    auto = make_solver(SolverOptions("auto"), wst)
    b = np.random.default_rng(2).normal(size=wide.shape[0])
    result = auto.solve(wide, b)
    assert auto.name == result.solver == "cvxopt"
    assert scaled_error(wide, result.dx, dense_reference(wide, b)) < DIRECT_RTOL


@pytest.mark.parametrize("reference", [True, False])
def test_auto_prefers_cvxopt_to_cholmod_on_the_reference_blas(monkeypatch, reference):
    """Both installed: cholmod, unless its CHOLMOD calls the reference BLAS (docs/solvers.md)."""
    pytest.importorskip("cvxopt.cholmod")
    pytest.importorskip("sksparse.cholmod")
    from striptri.solvers import selection

    monkeypatch.setattr(selection, "on_reference_blas", lambda solver: reference)
    assert solvers.sparse_choice() == ("cvxopt" if reference else "cholmod")


def test_auto_does_not_import_cvxopt_when_cholmod_is_taken():
    """cvxopt is imported only where auto may take it: CHOLMOD on an optimised BLAS takes the
    blocks, and the run then neither imports cvxopt nor loads its OpenBLAS (a fresh interpreter,
    whose modules are its own)."""
    pytest.importorskip("cvxopt.cholmod")
    pytest.importorskip("sksparse.cholmod")
    from striptri.solvers.describe import on_reference_blas

    if on_reference_blas("cholmod"):
        pytest.skip("CHOLMOD runs on the reference BLAS here: auto takes cvxopt")
    code = ("import sys; from striptri import solvers; print(solvers.sparse_choice(), "
            "'cvxopt' in sys.modules, 'cvxopt.cholmod' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["cholmod", "False", "False"]


@pytest.mark.parametrize("bad", [dict(name="lu"), dict(relaxation=2.0), dict(relaxation=0.0),
                                 dict(inner_tolerance=0.0), dict(max_inner_iterations=0),
                                 dict(warm_start="last")])
def test_options_are_validated(bad):
    with pytest.raises(ValueError):
        SolverOptions(**bad)


def test_one_off_solve_and_inverse_agree_with_the_reference():
    N, st = strip_case(6, 1, seed=8)
    b = np.random.default_rng(0).normal(size=N.shape[0])
    for name in ("dense", "sparse", "banded", "pcg"):
        assert scaled_error(N, solvers.solve(N, b, name, st).dx, dense_reference(N, b)) < 1e-9
    Q = solvers.inverse(N)
    np.testing.assert_allclose(Q @ N.toarray(), np.eye(N.shape[0]), atol=1e-8)


def _block_starts_by_loop(layout):
    """The definition of block_starts, set by set: a set's new columns are those beyond every
    column of the sets before it."""
    starts, photo_of_block, seen = [], [], -1
    for i, cols in enumerate(layout._column_sets()):
        new = cols[cols > seen]
        if len(new):
            starts.append(int(new.min()))
            photo_of_block.append(i)
            seen = int(new.max())
    return np.array(starts, dtype=int), np.array(photo_of_block, dtype=int)


@pytest.mark.parametrize("seed", range(4))
def test_block_starts_of_layouts_with_held_and_shared_columns(seed):
    """block_starts and block_groups (vectorised) against the set-by-set definition, on layouts
    with held photos, held angles, centre components shared along an enforced base (a column
    repeated in the next photo) and cameras with some elements free."""
    from striptri.equations.parameters import UnknownLayout

    rng = np.random.default_rng(seed)
    n, n_cam, col, rows = 40, 3, 0, []
    for i in range(n):
        row = -np.ones(6, dtype=int)
        if rng.random() < 0.15:  # held photo
            rows.append(row)
            continue
        for k in range(6):
            if k < 3 and rows and rows[-1][k] >= 0 and rng.random() < 0.2:  # a base component enforced
                row[k] = rows[-1][k]
            elif rng.random() < 0.85:
                row[k], col = col, col + 1
        rows.append(row)
    cameras = -np.ones((n_cam, 10), dtype=int)
    for j in range(n_cam):
        for e in np.flatnonzero(rng.random(10) < 0.4):
            cameras[j, e], col = col, col + 1
    layout = UnknownLayout(np.array(rows), cameras, col, "omega-phi-kappa", np.zeros((n, 3), bool), np.zeros((n, 3)))
    starts, photo_of_block = _block_starts_by_loop(layout)
    np.testing.assert_array_equal(layout.block_starts(), starts)
    strips = [f"s{i // 10}" if i % 7 else "" for i in range(n)]
    groups = layout.block_groups(strips)
    assert len(groups) == len(starts)
    is_photo = photo_of_block < n
    assert np.all(groups[~is_photo] == -1)
    names = np.array(strips)[photo_of_block[is_photo]]
    assert np.all((groups[is_photo] == -1) == (names == ""))
    for a in np.unique(names[names != ""]):  # one group per strip, numbered in order of first appearance
        assert len(set(groups[is_photo][names == a])) == 1


class TestCholmodScikitSparse(TestCholmod):
    """The same suite on scikit-sparse's calls of CHOLMOD, the route where CHOLMOD's own cannot be
    made (another CHOLMOD than 3, 64-bit indices; striptri.solvers.cholmod_direct)."""

    @pytest.fixture(autouse=True)
    def _scikit_route(self, monkeypatch):
        from striptri.solvers import sparse_cholesky

        monkeypatch.setattr(sparse_cholesky, "DIRECT", False)
