"""CHOLMOD called directly (striptri.solvers.cholmod_direct) against scikit-sparse's calls of the same
library, the work beside its factorisations (striptri.solvers.beside), and the selected inversion's
symbolic analysis made there (selected_inverse.symbolic.symbolic_ahead)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from striptri import selected_inverse
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.io import read_project
from striptri.selected_inverse import symbolic
from striptri.solvers import SingularNormalMatrix, SolverOptions, beside, jacobi_scaled, make_solver
from striptri.solvers import sparse_cholesky
from striptri.solvers.synthetic import block_normal_matrix

cholmod = pytest.importorskip("sksparse.cholmod")
from striptri.solvers.cholmod_direct import DirectFactor, direct_library  # noqa: E402

LIB = direct_library(cholmod.__file__)
DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
needs_direct = pytest.mark.skipif(LIB is None, reason="the CHOLMOD under scikit-sparse is not CHOLMOD 3")


def scaled_block(n_strips=6, per_strip=12, seed=4):
    N, st = block_normal_matrix(n_strips, per_strip, np.random.default_rng(seed), n_cameras=1)
    Ns, _ = jacobi_scaled(N)
    return Ns, st


@needs_direct
@pytest.mark.parametrize("mode", ["supernodal", "simplicial"])
@pytest.mark.parametrize("ordering", ["nesdis", "amd", "natural"])
def test_the_same_factor_as_scikit_sparse(mode, ordering):
    """The same analysis (permutation), solutions and pivots to the last bit, factorised twice in
    the same memory and again after its values were given back."""
    Ns, _ = scaled_block()
    A = Ns.T
    mine = DirectFactor(LIB, A, mode, ordering)
    theirs = cholmod.analyze(A, mode=mode, ordering_method=ordering).cholesky(A)
    assert np.array_equal(mine.perm, theirs.P())
    b = np.random.default_rng(1).normal(size=A.shape[0])
    for _ in range(2):
        assert mine.factorize(A) is None
        assert np.array_equal(mine.solve(b), theirs.solve_A(b))
        assert np.array_equal(mine.pivots(), np.sqrt(np.maximum(theirs.D(), 0.0)))
    mine.drop_values()
    assert mine.factorize(A * 2.0) is None
    theirs.cholesky_inplace(A * 2.0)
    assert np.array_equal(mine.solve(b), theirs.solve_A(b))
    mine.close()
    mine.close()  # twice is nothing


@needs_direct
def test_not_positive_definite_names_the_column_scikit_sparse_names():
    Ns, _ = scaled_block()
    bad = Ns.tolil()
    bad[40, 40] = -1.0
    A = sp.csc_matrix(bad.T)
    A.sort_indices()
    mine = DirectFactor(LIB, A, "supernodal", "nesdis")
    failed = mine.factorize(A)
    theirs = cholmod.analyze(A, mode="supernodal", ordering_method="nesdis")
    with pytest.raises(cholmod.CholmodNotPositiveDefiniteError) as exc:
        theirs.cholesky(A)
    assert failed == exc.value.column and mine.perm[failed] == 40
    good = Ns.T  # the same pattern, positive definite: factorised again after the failure
    b = np.ones(A.shape[0])
    assert mine.factorize(good) is None
    assert np.array_equal(mine.solve(b), theirs.cholesky(good).solve_A(b))


@needs_direct
def test_the_solver_names_the_column_either_route_names(monkeypatch):
    """An indefinite N (a 2 x 2 minor of columns 12 and 13 with a negative determinant): both
    routes stop at the same column, one of the two."""
    N, st = block_normal_matrix(4, 8, np.random.default_rng(2), n_cameras=1)
    N = N.tolil()
    N[12, 13] = N[13, 12] = 2.0 * np.sqrt(N[12, 12] * N[13, 13])
    N = sp.csr_matrix(N)
    named = []
    for direct in (True, False):
        monkeypatch.setattr(sparse_cholesky, "DIRECT", direct)
        solver = make_solver(SolverOptions("cholmod"), st)
        with pytest.raises(SingularNormalMatrix) as exc:
            solver.solve(N, np.ones(N.shape[0]))
        assert isinstance(solver._factor, DirectFactor) == direct
        named.append(exc.value.column)
    assert named[0] == named[1] and named[0] in (12, 13)


def test_only_32_bit_sorted_indices_are_read_directly():
    A = sp.csc_matrix(sp.identity(4))
    assert DirectFactor.usable(A)
    wide = A.copy()
    wide.indices, wide.indptr = A.indices.astype(np.int64), A.indptr.astype(np.int64)  # scipy would narrow them
    assert not DirectFactor.usable(wide)


@needs_direct
def test_the_factorisation_lets_the_interpreter_go():
    """A Python thread counts while the main thread factorises by CHOLMOD's own call: it counts at
    least a third as fast as while the main thread sleeps (a call holding the GIL, as
    scikit-sparse's does, leaves it a few per cent: its Python before the call)."""
    N, _ = block_normal_matrix(40, 60, np.random.default_rng(7), n_cameras=1)  # factorised in 0.05-0.1 s
    A = jacobi_scaled(N)[0].T
    mine = DirectFactor(LIB, A, "supernodal", "nesdis")
    mine.factorize(A)  # the factor's memory taken once

    def rate(wait) -> float:
        count, stop = [0], threading.Event()

        def spin():
            while not stop.is_set():
                count[0] += 1

        thread = threading.Thread(target=spin)
        thread.start()
        time.sleep(0.01)
        before, t0 = count[0], time.perf_counter()
        wait()
        during, took = count[0] - before, time.perf_counter() - t0
        stop.set()
        thread.join()
        return during / took

    free = np.median([rate(lambda: time.sleep(0.05)) for _ in range(3)])
    factorising = np.median([rate(lambda: mine.factorize(A)) for _ in range(3)])
    assert factorising > free / 3, (factorising, free)


# ------------------------------------------------------------------------------------ beside


def test_a_task_goes_on_only_in_windows():
    """Outside a factorisation the task waits at its pauses; inside one it goes on; its result,
    once wanted, comes without windows."""
    steps, reached = [], threading.Event()

    def work(n, pause):
        for k in range(n):
            pause()
            steps.append(k)
            if k == 1:
                reached.set()
        return sum(steps)

    task = beside.BesideTask(work, 5)
    time.sleep(0.05)
    assert steps == [] and not task.done
    with beside.factorising():
        assert reached.wait(5.0)
    assert task.result() == 10 and steps == list(range(5))


def test_a_task_that_fails_or_is_cancelled_answers_none():
    def fails(pause):
        pause()
        raise ValueError("no")

    task = beside.BesideTask(fails)
    assert task.result() is None
    cancelled = beside.BesideTask(lambda pause: pause() or 1)
    cancelled.cancel()
    assert cancelled.result() is None


# ------------------------------------------------------------------------- symbolic ahead


def same_supernodes(a, b) -> bool:
    return (np.array_equal(a.order, b.order) and np.array_equal(a.start, b.start)
            and np.array_equal(a.offset, b.offset) and len(a.rows) == len(b.rows)
            and all(np.array_equal(x, y) for x, y in zip(a.rows, b.rows))
            and all(len(x) == len(y) and all(p[:3] == q[:3] and np.array_equal(p[3], q[3]) and p[4] == q[4]
                                             for p, q in zip(x, y)) for x, y in zip(a.targets, b.targets)))


PARAMS = ("nesdis", 48, 0.5)


def test_the_analysis_made_ahead_is_the_analysis(monkeypatch):
    """Made ahead with pauses (in a window) and taken for a matrix that reads the same pattern
    arrays: the same supernodes as made directly, and not made a second time."""
    N, st = block_normal_matrix(8, 15, np.random.default_rng(3), n_cameras=1)
    direct = symbolic._symbolic(jacobi_scaled(N)[0], st, *PARAMS)
    pauses = []
    paced = symbolic._symbolic(N, st, *PARAMS, pause=lambda: pauses.append(1))
    assert same_supernodes(paced, direct) and len(pauses) >= 5
    symbolic.symbolic_ahead(N, st, *PARAMS)
    copy = sp.csr_matrix((N.data, N.indices.copy(), N.indptr.copy()), shape=N.shape)
    assert symbolic.analysed_ahead(jacobi_scaled(N)[0]) and not symbolic.analysed_ahead(copy)
    with beside.factorising():
        task = symbolic._ahead.task
        assert task.result() is not None
    made = []
    monkeypatch.setattr(symbolic, "_symbolic", lambda *a, **k: made.append(1))
    taken = symbolic.symbolic(jacobi_scaled(N)[0], st, *PARAMS)  # the scaled N shares N's index arrays
    assert same_supernodes(taken, direct) and made == [] and symbolic._ahead is None


def test_another_pattern_is_analysed_here(monkeypatch):
    N, st = block_normal_matrix(6, 10, np.random.default_rng(3), n_cameras=1)
    symbolic.symbolic_ahead(N, st, *PARAMS)
    task = symbolic._ahead.task
    copy = sp.csr_matrix((N.data, N.indices.copy(), N.indptr.copy()), shape=N.shape)  # the same numbers elsewhere
    direct = symbolic._symbolic(N, st, *PARAMS)
    assert same_supernodes(symbolic.symbolic(copy, st, *PARAMS), direct)
    assert symbolic._ahead is None and task.result() is None  # cancelled
    symbolic.symbolic_ahead(N, st, *PARAMS)
    assert same_supernodes(symbolic.symbolic(N, st, "mmd", 48, 0.5), symbolic._symbolic(N, st, "mmd", 48, 0.5))
    assert symbolic._ahead is None


def test_an_analysis_waiting_for_its_windows_holds_no_numbers():
    """A task that never runs (a strip's solver opens no windows, its precision takes the banded
    route) keeps N's pattern arrays, not N: its numbers go with the iteration."""
    import gc
    import weakref

    N, st = block_normal_matrix(6, 10, np.random.default_rng(3), n_cameras=1)
    numbers = weakref.ref(N.data)
    symbolic.symbolic_ahead(N, st, *PARAMS)
    task = symbolic._ahead.task
    del N
    gc.collect()
    assert numbers() is None and not task.done
    symbolic._drop_ahead()
    assert task.result() is None


def test_memory_given_back_is_not_the_pattern():
    """The pattern's owner gone, an array at the same address is not taken for it."""
    N, _ = block_normal_matrix(3, 5, np.random.default_rng(1))
    indices = N.indices.copy()
    held = symbolic._Held.of(indices)
    assert held.same(indices) and held.same(indices[:])
    del indices
    assert not held.same(N.indices)


@needs_direct
@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_an_adjustment_analyses_for_the_precision_beside_its_factorisations(monkeypatch, method):
    """The adjustment's first solve starts the symbolic analysis of the selected inversion; it runs
    beside CHOLMOD's factorisations, and the precision takes it: the same mean errors as without
    (more blocks than AHEAD_MAX_BLOCKS: analysed where it is used)."""
    from striptri import simulate as sim

    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=10, n_strips=4, overlap=2 / 3, sidelap=0.6),
                                 control=sim.ControlDesign(layout="perimeter", every_k=2))
    project, _ = sim.simulate_project("block", sim.SimulateOptions(design=design), seed=5)
    monkeypatch.setattr(selected_inverse, "BANDED_MAX_BANDWIDTH", 6)  # this small block on the sparse route
    where = []
    original = symbolic._symbolic

    def spy(*args, pause=symbolic._no_pause, **kw):
        where.append(threading.current_thread().name)
        return original(*args, pause=pause, **kw)

    monkeypatch.setattr(symbolic, "_symbolic", spy)
    options = AdjustmentOptions(method=method, solver="cholmod")
    r = adjust(project, options)
    sigma = r.covariance.photo_blocks()
    assert where == ["striptri-beside"]
    where.clear()
    monkeypatch.setattr(selected_inverse, "AHEAD_MAX_BLOCKS", len(r.layout.photo_cols) - 1)  # too many blocks
    again = adjust(project, options)
    assert np.array_equal(again.covariance.photo_blocks(), sigma) and where == ["MainThread"]


# ------------------------------------------------------------------------------------ prepare


@needs_direct
def test_the_first_solve_takes_the_analysis_prepared_from_the_pattern(monkeypatch):
    """prepare (the adjustments call it with N's pattern before its numbers) analyses on a thread
    and takes the factor's memory; the first solve uses it: the same solution to the last bit, one
    analysis, none made at the solve."""
    from striptri.solvers.base import pattern_matrix
    from striptri.solvers.sparse_cholesky import CholmodSolver

    N, st = block_normal_matrix(3, 90, np.random.default_rng(8), n_cameras=1)  # wide enough for auto's cholmod
    b = np.random.default_rng(9).normal(size=N.shape[0])
    expected = make_solver(SolverOptions("cholmod"), st).solve(N, b).dx
    for name in ("cholmod", "auto"):
        solver = make_solver(SolverOptions(name), st)
        solver.prepare(pattern_matrix(N.indptr, N.indices, N.shape))
        concrete = solver if name == "cholmod" else solver._chosen
        assert isinstance(concrete, CholmodSolver) and concrete._prepared is not None
        with monkeypatch.context() as m:
            m.setattr(CholmodSolver, "_analyse", lambda self, A: pytest.fail("analysed at the solve"))
            result = solver.solve(N, b)
        assert np.array_equal(result.dx, expected) and result.info.analyses == 1


@needs_direct
def test_a_prepared_analysis_of_another_pattern_is_not_taken():
    from striptri.solvers.base import pattern_matrix

    N, st = block_normal_matrix(5, 12, np.random.default_rng(8), n_cameras=1)
    b = np.ones(N.shape[0])
    other = N.tolil()
    other[0, N.shape[0] - 1] = other[N.shape[0] - 1, 0] = 1e-3 * N[0, 0]  # one entry more
    other = sp.csr_matrix(other)
    solver = make_solver(SolverOptions("cholmod"), st)
    solver.prepare(pattern_matrix(other.indptr, other.indices, other.shape))
    result = solver.solve(N, b)
    assert np.array_equal(result.dx, make_solver(SolverOptions("cholmod"), st).solve(N, b).dx)
    assert result.info.analyses == 1 and solver._prepared is None


@needs_direct
@pytest.mark.parametrize("method", ["bundle", "conditions"])
def test_the_bundle_method_tells_its_solver_the_pattern_ahead(monkeypatch, method):
    """The bundle method prepares its solver with the reduced pattern (the first solve then finds
    the analysis made); the method of conditions does not (its peak of memory: decisions.md)."""
    from striptri.solvers.sparse_cholesky import CholmodSolver

    project = read_project(DATA / "strip8")
    told, analysed = [], []
    prepare, analyse = CholmodSolver.prepare, CholmodSolver._analyse
    monkeypatch.setattr(CholmodSolver, "prepare", lambda self, P: told.append(P.shape) or prepare(self, P))
    monkeypatch.setattr(CholmodSolver, "_analyse", lambda self, A: analysed.append(A.shape) or analyse(self, A))
    r = adjust(project, AdjustmentOptions(method=method, solver="cholmod"))
    assert r.converged
    n = r.layout.n_unknowns
    assert told == ([(n, n)] if method == "bundle" else [])
    assert analysed == ([] if method == "bundle" else [(n, n)])
