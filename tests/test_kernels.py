"""solvers.kernels (scipy's BLAS and LAPACK through ctypes, on C-ordered arrays) against numpy.

Each kernel's result in C-order terms against the dense numpy expression, to rounding (the
matrices are well conditioned: 1e-12 relative), on shapes that are not square, so that a swapped
dimension or leading dimension shows. That they release the GIL is a matter of speed, measured in
docs/decisions.md, not tested here.
"""

from __future__ import annotations

import numpy as np
import pytest

from striptri.solvers import kernels


@pytest.fixture(autouse=True, params=["ctypes", "f2py"])
def route(request, monkeypatch):
    """Every test through both routes: ctypes (the GIL released) and scipy's f2py wrappers (what
    the kernels fall back to where the routines are not exported)."""
    if request.param == "f2py":
        monkeypatch.setattr(kernels, "_routine", lambda module, name: None)
        assert not kernels.releases_gil()
    else:
        assert kernels.releases_gil()
    return request.param


def spd(n, rng):
    A = rng.normal(size=(n, n + 3))
    return A @ A.T + n * np.eye(n)


def close(a, b):
    return np.max(np.abs(a - b)) <= 1e-12 * max(np.max(np.abs(b)), 1.0)


@pytest.mark.parametrize("n", [1, 7, 40])
def test_cholesky_and_inverse(n):
    rng = np.random.default_rng(n)
    A = spd(n, rng)
    F = A.copy()
    F[np.triu_indices(n, 1)] = 7.0  # only the lower triangle is read, the upper is left alone
    assert kernels.cholesky_lower(F) == 0
    L = np.tril(F)
    assert close(L @ L.T, A)
    assert np.all(F[np.triu_indices(n, 1)] == 7.0)
    assert close(L, np.linalg.cholesky(A))
    assert kernels.inverse_from_cholesky(F) == 0
    inv = np.tril(F) + np.tril(F, -1).T
    assert close(inv, np.linalg.inv(A))


def test_cholesky_reports_the_failing_column():
    rng = np.random.default_rng(3)
    A = spd(6, rng)
    A[4, 4] = -1.0
    assert kernels.cholesky_lower(A) == 5  # LAPACK's 1-based column


@pytest.mark.parametrize("right", [True, False])
@pytest.mark.parametrize("transposed", [True, False])
def test_triangular_solves(right, transposed):
    rng = np.random.default_rng(5)
    L = np.linalg.cholesky(spd(9, rng))
    Lfull = L.copy()
    L[np.triu_indices(9, 1)] = np.nan  # never read
    B = rng.normal(size=(13, 9) if right else (9, 13))
    X = B.copy()
    kernels.solve_lower(L, X, right=right, transposed=transposed, alpha=-2.0)
    T = Lfull.T if transposed else Lfull
    want = -2.0 * (B @ np.linalg.inv(T) if right else np.linalg.inv(T) @ B)
    assert close(X, want)


def test_lower_product_and_symmetric_times():
    rng = np.random.default_rng(8)
    A = rng.normal(size=(11, 4))
    out = np.full((11, 11), 5.0)
    kernels.lower_product(A, out)
    low = np.tril_indices(11)
    assert close(out[low], (A @ A.T)[low])
    assert np.all(out[np.triu_indices(11, 1)] == 5.0)
    S = spd(11, rng)
    Slow = np.tril(S) + np.triu(np.full((11, 11), np.nan), 1)  # the upper triangle is never read
    B = rng.normal(size=(11, 3))
    assert close(kernels.symmetric_times(Slow, B), S @ B)


def test_rejects_fortran_order_and_other_types():
    with pytest.raises(ValueError, match="C-contiguous float64"):
        kernels.cholesky_lower(np.asfortranarray(np.eye(3))[:, ::-1])
    with pytest.raises(ValueError, match="C-contiguous float64"):
        kernels.symmetric_times(np.eye(3, dtype=np.float32), np.ones((3, 2)))



def test_views_at_an_offset_and_read_only_inputs():
    """A kernel reads and writes where the array's view starts (a block of rows of a larger array,
    as the supernodes' views of the flat factor are), and takes read-only inputs (their pointer
    comes through numpy, not a ctypes double laid over the buffer)."""
    rng = np.random.default_rng(9)
    flat = rng.normal(size=60)
    outside = np.concatenate([flat[:12], flat[42:]])
    B = flat[12:42].reshape(6, 5)  # C-contiguous, 12 values into the buffer
    before = B.copy()
    L = np.tril(spd(5, rng))
    kernels.solve_lower(L, B, right=True, transposed=False)
    assert close(B, before @ np.linalg.inv(L))
    assert np.array_equal(np.concatenate([flat[:12], flat[42:]]), outside)  # nothing else written
    S = spd(6, rng)
    S.setflags(write=False)
    X = rng.normal(size=(6, 2))
    X.setflags(write=False)
    assert close(kernels.symmetric_times(S, X), S @ X)
    out = np.zeros((6, 6))
    kernels.lower_product(X, out)
    assert close(out[np.tril_indices(6)], (X @ X.T)[np.tril_indices(6)])
