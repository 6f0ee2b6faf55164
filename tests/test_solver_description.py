"""solvers.describe: which factorisation and which BLAS solved the normal equations (summary.json)."""

from __future__ import annotations

import ctypes
import json
import os
import sys
import threading

import numpy as np
import pytest
import scipy.sparse as sp

from striptri.core.runs import RunOptions
from striptri import solvers
from striptri.solvers import SOLVERS, SolverInfo, SolverOptions, describe, make_solver
from striptri.solvers.cvxopt_cholesky import lower_triangle
from striptri.solvers.describe import blas_path, on_reference_blas
from striptri.solvers.synthetic import block_normal_matrix

CONCRETE = [s for s in SOLVERS if s != "auto"]


def _mapped_files() -> set[str]:
    with open("/proc/self/maps") as f:
        return {os.path.realpath(line.split()[-1]) for line in f if "/" in line}


@pytest.mark.parametrize("name", CONCRETE)
def test_every_solver_is_described_in_json(name):
    d = describe(name)
    assert set(d) == {"factorisation", "blas"}
    assert all(isinstance(v, str) and v for v in d.values())
    json.dumps(d)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/maps")
@pytest.mark.parametrize("name", ["dense", "banded", "sparse", "cholmod", "cvxopt"])
def test_the_blas_found_is_a_library_loaded_in_this_process(name):
    if name == "cholmod":
        pytest.importorskip("sksparse.cholmod")
    if name == "cvxopt":
        pytest.importorskip("cvxopt.cholmod")
    path = blas_path(name)
    assert path is not None and os.path.realpath(path) in _mapped_files()
    assert os.path.realpath(path) in describe(name)["blas"]


def test_the_description_follows_the_solver_info():
    assert describe("banded", SolverInfo(bandwidth=17, border=3))["factorisation"] == (
        "LAPACK banded Cholesky (pbtrf), bandwidth 17, dense border of 3 camera columns")
    assert describe("banded", SolverInfo(bandwidth=17, border=0))["factorisation"] == (
        "LAPACK banded Cholesky (pbtrf), bandwidth 17")


# what describe() (and summary.json's history, for the iterative ones) reads of each solver's report
_REPORTED = {
    "banded": {"bandwidth", "border"},
    "cholmod": {"analyses", "mode", "ordering"},
    "pcg": {"inner_iterations", "relative_residual", "converged", "slow", "tolerance", "warm_start", "restarts"},
    "strip-pcg": {"inner_iterations", "relative_residual", "converged", "slow", "preconditioner", "strips",
                  "bandwidth", "dense_block"},
}


@pytest.mark.parametrize("name", sorted(_REPORTED))
def test_a_solve_reports_a_solver_info_with_what_describe_reads(name):
    """SolveResult.info is a SolverInfo (not a dict) holding the fields describe() words: a
    solver that stopped reporting one would describe itself without it."""
    if name == "cholmod":
        pytest.importorskip("sksparse.cholmod")
    # two strips (one strip for banded: a second would join the border) and two cameras (6 columns)
    N, st = block_normal_matrix(1 if name == "banded" else 2, 8, np.random.default_rng(3), n_cameras=2)
    result = make_solver(SolverOptions(name), st).solve(N, np.ones(N.shape[0]))
    info = result.info
    assert isinstance(info, SolverInfo)
    assert _REPORTED[name] <= set(info.as_dict())
    assert all(v is not None for v in info.as_dict().values())
    text = describe(name, info)["factorisation"]
    if name == "banded":
        assert info.border == 6 and text.endswith(f"bandwidth {info.bandwidth}, dense border of 6 camera columns")
    if name == "strip-pcg":
        assert info.strips == 2 and text.endswith(f"2 strips of bandwidth {info.bandwidth}, a dense block of 6 camera "
                                                  "columns")


def test_solver_info_is_a_frozen_record_of_the_reported_fields():
    info = SolverInfo(bandwidth=17, border=0)
    assert info.as_dict() == {"bandwidth": 17, "border": 0}  # 0 is reported, None is not
    assert SolverInfo().as_dict() == {}
    damped = info.merged(damping=1e-3)
    assert damped.as_dict() == {"bandwidth": 17, "border": 0, "damping": 1e-3} and info.damping is None
    with pytest.raises(AttributeError):
        info.bandwidth = 3


def test_cholmod_names_its_version_mode_and_ordering():
    pytest.importorskip("sksparse.cholmod")
    N, st = block_normal_matrix(4, 10, np.random.default_rng(1), n_cameras=1)
    solver = make_solver(SolverOptions("cholmod"), st)
    result = solver.solve(N, np.ones(N.shape[0]))
    text = describe(solver, result.info)["factorisation"]
    assert text.startswith("CHOLMOD ") and "SuiteSparse" in text
    assert result.info.mode in text and "ordering" in text
    assert describe("cholmod", SolverInfo(mode="simplicial", ordering="amd"))["factorisation"].count("simplicial") == 1


def test_an_auto_solver_is_described_by_its_choice():
    N, st = block_normal_matrix(3, 100, np.random.default_rng(1), n_cameras=1)
    auto = make_solver(SolverOptions("auto"), st)
    with pytest.raises(ValueError, match="concrete"):
        describe(auto)
    result = auto.solve(N, np.ones(N.shape[0]))
    assert describe(auto, result.info) == describe(result.solver, result.info)


def test_unknown_solver_is_refused():
    with pytest.raises(ValueError, match="unknown solver"):
        describe("lu")


def test_cholmod_runs_its_openmp_regions_with_dynamic_threads():
    """Debian's CHOLMOD asks OpenMP for 4 threads per supernode whatever OMP_NUM_THREADS says;
    the solver switches libgomp's dynamic adjustment on in the thread that factorises."""
    cholmod = pytest.importorskip("sksparse.cholmod")
    lib = ctypes.CDLL(cholmod.__file__)
    try:
        get_dynamic = lib.omp_get_dynamic
    except AttributeError:
        pytest.skip("CHOLMOD built without OpenMP")
    N, st = block_normal_matrix(3, 8, np.random.default_rng(1))
    seen = {}

    def run():
        make_solver(SolverOptions("cholmod"), st).solve(N, np.ones(N.shape[0]))
        seen["dynamic"] = get_dynamic()

    t = threading.Thread(target=run)  # a fresh thread: OpenMP's settings are per thread
    t.start()
    t.join()
    assert seen["dynamic"] == 1


def test_reference_blas_is_recognised():
    """on_reference_blas agrees with the words of the description."""
    for name in ("dense", "cholmod", "cvxopt"):
        if name == "cholmod" and not solvers.cholmod_available():
            continue
        if name == "cvxopt" and not solvers.cvxopt_available():
            continue
        assert on_reference_blas(name) == describe(name)["blas"].startswith("reference BLAS")
    assert not on_reference_blas("dense")  # scipy's wheels bring OpenBLAS


def test_lower_triangle_of_cvxopt_matches_scipy():
    N, _ = block_normal_matrix(3, 8, np.random.default_rng(4), n_cameras=2)
    A = sp.csr_matrix(N)
    A.sort_indices()
    indptr, rows, values = lower_triangle(A)
    ref = sp.tril(A, format="csc")
    ref.sort_indices()
    assert np.array_equal(indptr, ref.indptr) and np.array_equal(rows, ref.indices)
    assert np.array_equal(values, ref.data)


@pytest.mark.parametrize("solver", ["dense", "cholmod"])
def test_summary_json_names_the_factorisation_and_blas_that_ran(tmp_path, solver):
    """summary.json's "factorisation" and "blas" are describe() of the solver that solved the last
    iteration, and report.html shows them."""
    from pathlib import Path

    from striptri.pipeline import run_adjust

    if solver == "cholmod" and not solvers.cholmod_available():
        pytest.skip("scikit-sparse not installed")
    project = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "block_3x6"
    out = tmp_path / "out"
    run_adjust(project, out, RunOptions(solver=solver))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == solver
    expected = describe(solver, SolverInfo(mode="supernodal") if solver == "cholmod" else None)
    assert summary["blas"] == expected["blas"]
    assert summary["factorisation"].split(",")[0] == expected["factorisation"].split(",")[0]
    assert ("supernodal" in summary["factorisation"]) == (solver == "cholmod")
    html = (out / "report.html").read_text()
    assert "BLAS it ran on" in html and summary["blas"].split(" (")[0] in html


def test_sequential_method_says_it_factorises_no_normal_matrix_of_the_strip():
    from types import SimpleNamespace

    from striptri.pipeline import SEQUENTIAL_FACTORISATION, solver_description

    d = solver_description(SimpleNamespace(solver="sequential", history=[]))
    assert d["factorisation"] == SEQUENTIAL_FACTORISATION and d["blas"] == describe("dense")["blas"]
