"""The closed forms for a point's 3 x 3 normal matrix (equations.triangulation) against LAPACK.

safe_inverse decides regular / singular as LAPACK's eigenvalues do (smallest above SINGULAR_RCOND
times the largest) and inverts in closed form only where the closed form shows the matrix clearly
regular; every other matrix goes through LAPACK. So its decisions must equal the LAPACK route's on
every kind of matrix, and its inverses agree to rounding: on the Jacobi-scaled inverse, relative
to its largest entry, within 1e-13 for well-conditioned matrices and within (condition number) x
1e-15 otherwise, the error bound both sides share. The eigenvalues in closed form agree with
LAPACK's to about 1e-16 of the largest divided by the gap between the two closest (relative to
the largest), at worst 1e-8 where two coincide (the arc cosine of the trigonometric solution near
+-1 turns the rounding into its square root).
"""

from __future__ import annotations

import numpy as np
import pytest

from striptri.equations.normal_equations import CLEARLY_REGULAR
from striptri.equations.triangulation import (SINGULAR_RCOND, _lapack_safe_inverse, ray_normals, safe_inverse,
                                              safe_solve, symmetric_eigenvalues_3, symmetric_inverse_3)


def batch(seed, m=4000, spread=0.0):
    """Symmetric positive definite 3 x 3 matrices, their rows scaled over 10^-spread..10^spread."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(m, 3, 5)) * 10.0 ** rng.uniform(-spread, spread, (m, 3, 1))
    return A @ A.transpose(0, 2, 1)


def awkward():
    """Singular, nearly singular on both sides of SINGULAR_RCOND and of CLEARLY_REGULAR, indefinite,
    zero, not finite, and badly scaled but regular."""
    v = np.array([1.0, 2.0, 3.0])
    Q, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
    rotated = [Q @ np.diag(ev) @ Q.T for ev in ([1.0, 1.0, 1e-13], [1.0, 1.0, 1e-15], [1.0, 1.0, 1e-9],
                                                  [1.0, 1.0, 1e-7], [2.0, -1.0, 1.0])]
    return np.array([np.outer(v, v), np.diag([1.0, -1.0, 2.0]), np.zeros((3, 3)), np.full((3, 3), np.nan),
                     np.diag([1.0, 1.0, np.inf]), np.diag([1e6, 1.0, 1e-6]), np.diag([1e12, 1.0, 1.0]),
                     np.eye(3), *rotated])


def scaled_difference(a, b, M):
    d = np.sqrt(np.abs(np.einsum("mii->mi", M)))
    return np.abs((a - b) * d[:, :, None] * d[:, None, :])


@pytest.mark.parametrize("spread", [0.0, 3.0, 6.0])
def test_safe_inverse_equals_lapack(spread):
    M = np.concatenate([batch(int(spread), spread=spread), awkward()])
    finite = np.isfinite(M).all(axis=(1, 2))
    want, want_ok = _lapack_safe_inverse(M, finite, SINGULAR_RCOND)
    got, ok = safe_inverse(M)
    np.testing.assert_array_equal(ok, want_ok)
    assert np.isnan(got[~ok]).all()
    safe = np.where(finite[:, None, None], M, np.eye(3))
    cond = np.linalg.cond(safe[ok])
    err = scaled_difference(got[ok], want[ok], safe[ok]).max(axis=(1, 2))
    size = scaled_difference(want[ok], 0.0, safe[ok]).max(axis=(1, 2))
    assert np.all(err <= (1e-13 + cond * 1e-15) * size), (err / size / cond).max()


def test_awkward_matrices_decided_by_eigenvalues():
    M = awkward()
    _, ok = safe_inverse(M)
    # outer product, indefinite, zero, nan, inf: singular; ev 1e-15: singular; 1e-13, 1e-9, 1e-7: regular
    assert ok.tolist() == [False, False, False, False, False, True, True, True, True, False, True, True, False]


def test_clear_and_doubtful_paths_both_taken(monkeypatch):
    """The batch's well-conditioned matrices are inverted in closed form, the rest by LAPACK: with
    the closed form made wrong, only the matrices it keeps change."""
    import striptri.equations.triangulation as tri

    M = np.concatenate([batch(1), awkward()])
    real = tri.symmetric_inverse_3
    monkeypatch.setattr(tri, "symmetric_inverse_3", lambda S: (real(S)[0] * 2.0, real(S)[1]))
    doubled, ok = tri.safe_inverse(M)
    monkeypatch.undo()
    right, _ = tri.safe_inverse(M)
    changed = ~np.isclose(doubled, right, rtol=1e-12, equal_nan=True).all(axis=(1, 2))
    assert changed[:4000].all()  # the well-conditioned batch: closed form
    assert not changed[4000:][ok[4000:]].all()  # some of the awkward ones: LAPACK


def test_symmetric_inverse_and_definiteness():
    M = batch(2, spread=2.0)
    inv, positive = symmetric_inverse_3(M)
    assert positive.all()
    np.testing.assert_allclose(np.einsum("mij,mjk->mik", M, inv), np.broadcast_to(np.eye(3), M.shape), atol=1e-9)
    _, positive = symmetric_inverse_3(-M)
    assert not positive.any()
    assert CLEARLY_REGULAR > 1e3 * SINGULAR_RCOND  # the closed form never decides near the threshold


@pytest.mark.parametrize("spread", [0.0, 4.0])
def test_symmetric_eigenvalues_equal_lapack(spread):
    rng = np.random.default_rng(3)
    M = batch(3, spread=spread)
    M[:100] *= -1.0  # negative definite and
    M[100:200] -= 2.0 * np.einsum("mii->m", M[100:200])[:, None, None] / 3.0 * np.eye(3)  # indefinite
    v = rng.normal(size=(100, 3))
    M[200:300] = np.einsum("mi,mj->mij", v, v)  # rank one: two zero eigenvalues
    M[300] = 5.0 * np.eye(3)  # threefold
    want = np.linalg.eigvalsh(M)
    got = symmetric_eigenvalues_3(M)
    scale = np.abs(want).max(axis=1, keepdims=True)
    err = np.max(np.abs(got - want) / scale, axis=1)
    gap = (np.diff(want, axis=1) / scale).min(axis=1)  # of the two closest eigenvalues
    assert np.all(err * gap <= 1e-15 * gap + 2e-15), (err * gap).max()
    assert err.max() < 1e-7


def test_safe_solve():
    M = batch(4)
    b = np.random.default_rng(4).normal(size=(len(M), 3))
    np.testing.assert_allclose(safe_solve(M, b), np.linalg.solve(M, b[:, :, None])[:, :, 0], rtol=1e-10, atol=1e-12)


def test_conditioning_equals_lapack_ratio():
    """conditioning: the ratio of LAPACK's eigenvalues exactly where it is small (below EXACT_BELOW,
    where WEAK_RCOND decides), to 1e-8 elsewhere; held coordinates replaced as documented."""
    from striptri.equations.triangulation import EXACT_BELOW, WEAK_RCOND, conditioning

    Q, _ = np.linalg.qr(np.random.default_rng(9).normal(size=(3, 3)))
    weak = np.array([Q @ np.diag([1.0, 1.0, r]) @ Q.T for r in (0.5e-4, 0.99e-4, 1.01e-4, 5e-4, 2e-3)])
    M = np.concatenate([batch(5, m=500, spread=1.5), weak])
    free = np.ones((len(M), 3), dtype=bool)
    free[:50, 2] = False
    got = conditioning(M, free)
    fill = np.where(free, np.einsum("mii->mi", M), 0.0).sum(axis=1) / free.sum(axis=1)
    ref_M = np.where(free[:, :, None] & free[:, None, :], M, 0.0) + (~free)[:, :, None] * np.eye(3) * fill[:, None, None]
    ev = np.linalg.eigvalsh(ref_M)
    want = ev[:, 0] / ev[:, -1]
    small = want < EXACT_BELOW
    np.testing.assert_array_equal(got[small], want[small])
    np.testing.assert_allclose(got[~small], want[~small], rtol=0, atol=1e-8)
    assert (got[-5:] < WEAK_RCOND).tolist() == [True, True, False, False, False]


@pytest.mark.parametrize("n", [1, 2, 5, 9])
@pytest.mark.parametrize("with_singular", [False, True])
def test_safe_inverse_of_other_sizes_equals_lapack(n, with_singular):
    """A group's A Q A^T: the whole batch through one Cholesky test, or, with a singular or not
    finite matrix in it, every matrix through LAPACK's eigenvalues; the same decisions either way."""
    rng = np.random.default_rng(n)
    A = rng.normal(size=(300, n, n + 2)) * 10.0 ** rng.uniform(-2, 2, (300, n, 1))
    M = A @ A.transpose(0, 2, 1)
    if with_singular:
        M[5] = 0.0
        M[6, 0, 0] = np.nan
        M[7] = -M[7]
    finite = np.isfinite(M).all(axis=(1, 2))
    want, want_ok = _lapack_safe_inverse(M, finite, SINGULAR_RCOND)
    got, ok = safe_inverse(M)
    np.testing.assert_array_equal(ok, want_ok)
    assert ok.sum() == 300 - 3 * with_singular
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-10, atol=0)
    assert np.isnan(got[~ok]).all()


def test_ray_normals_equal_their_definition():
    """ray_normals: J' W J and J' W res of each point's rays, as the sums over rays and the plate's
    two axes they stand for (padded rays of weight zero add nothing)."""
    rng = np.random.default_rng(17)
    m, k = 40, 5
    dX, res = rng.normal(size=(m, k, 2, 3)), rng.normal(size=(m, k, 2))
    w = rng.uniform(0.5, 2.0, size=(m, k, 2))
    w[:, -1] = 0.0  # a padded ray
    Nx, gx = ray_normals(dX, w, res)
    for i in range(m):
        J = dX[i].reshape(2 * k, 3)
        W = np.diag(w[i].reshape(-1))
        np.testing.assert_allclose(Nx[i], J.T @ W @ J, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(gx[i], J.T @ W @ res[i].reshape(-1), rtol=1e-13, atol=1e-13)
    Nx_only, none = ray_normals(dX, w)
    assert none is None
    np.testing.assert_array_equal(Nx_only, Nx)
    np.testing.assert_allclose(ray_normals(dX[:, :-1], w[:, :-1], res[:, :-1])[0], Nx, rtol=1e-13, atol=1e-13)
