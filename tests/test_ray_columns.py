"""Products with B grouped by ray (equations.ray_columns) against the same products with the dense B
that conditions.expanded spreads over all k rays, and the method of conditions with them against
the method with the dense products: the same adjustment and the same residual cofactors."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from striptri.equations import normal_equations as ne
from striptri.equations.block_pattern import BlockPattern
from striptri.equations import ray_columns
from striptri.equations.conditions import expanded
from striptri.equations.ray_columns import RayColumns
from striptri.selected_inverse.covariance import group_forms, ray_slots

ROOT = Path(__file__).resolve().parents[1]


def _chain_rays(k: int) -> np.ndarray:
    """The rays of a chain's conditions as conditions.ray_conditions names them: each pair as
    (first, second, second), each consecutive triple."""
    pairs = np.stack([np.arange(k - 1), np.arange(1, k), np.arange(1, k)], axis=1)
    triples = np.stack([np.arange(k - 2), np.arange(1, k - 1), np.arange(2, k)], axis=1)
    return np.concatenate([pairs, triples])


def _collinearity_rays(k: int) -> np.ndarray:
    """Two conditions on each ray, one ray each (a control point's collinearity)."""
    return np.repeat(np.arange(k), 2)[:, None]


def _star_rays(k: int) -> np.ndarray:
    """Every condition through the hub, ray 0."""
    return np.stack([np.zeros(k - 1, int), np.arange(1, k), np.arange(1, k)], axis=1)


def _dense(per_ray, rays, k):
    m, nc, _, w = per_ray.shape
    return expanded(per_ray, rays, k).reshape(m, nc, k * w)


def _symmetric(rng, m, n):
    a = rng.normal(size=(m, n, n))
    return a @ np.swapaxes(a, 1, 2) + n * np.eye(n)


@pytest.mark.parametrize("rays_of", [_chain_rays, _collinearity_rays, _star_rays])
def test_products_by_ray_equal_the_dense_products(rays_of):
    """left, transposed, times, quadratic, quadratic_blocks and summed against the products with the
    expanded B, for the rays of a chain (a ray named twice in a pair), of a control point's
    collinearity and of a star; groups() against the products of the groups' own B."""
    rng = np.random.default_rng(5)
    m, k, w = 3, 13, 11
    rays = rays_of(k)
    nc = len(rays)
    per_ray = rng.normal(size=(m, nc, rays.shape[1], w))
    B = _dense(per_ray, rays, k)
    rc = RayColumns(per_ray, rays, k)
    assert rc.n == np.bincount(np.concatenate([np.unique(r) for r in rays]), minlength=k).max()
    tol = dict(rtol=0, atol=1e-12)
    D = rng.normal(size=(m, 7, nc))
    np.testing.assert_allclose(rc.left(D).reshape(m, 7, k * w), D @ B, **tol)
    np.testing.assert_allclose(rc.left(D, 6), (D @ B).reshape(m, 7, k, w)[..., :6], **tol)
    Y = rng.normal(size=(m, nc, 5))
    np.testing.assert_allclose(rc.transposed(Y).reshape(m, k * w, 5), np.swapaxes(B, 1, 2) @ Y, **tol)
    np.testing.assert_allclose(rc.transposed(Y, 6), (np.swapaxes(B, 1, 2) @ Y).reshape(m, k, w, 5)[:, :, :6], **tol)
    Z = rng.normal(size=(m, k, 6, 4))
    B6 = B.reshape(m, nc, k, w)[..., :6].reshape(m, nc, 6 * k)
    np.testing.assert_allclose(rc.times(Z), B6 @ Z.reshape(m, 6 * k, 4), **tol)
    Q = _symmetric(rng, m, 6 * k)
    np.testing.assert_allclose(rc.quadratic(Q, 6), B6 @ Q @ np.swapaxes(B6, 1, 2), rtol=0,
                               atol=1e-12 * abs(Q).max() * k)
    S = _symmetric(rng, m, nc)
    blocks = rc.quadratic_blocks(S, 6)
    assert blocks.flags["C_CONTIGUOUS"]
    reference = (np.swapaxes(B6, 1, 2) @ S @ B6).reshape(m, k, 6, k, 6).transpose(0, 1, 3, 2, 4)
    np.testing.assert_allclose(blocks, reference, rtol=0, atol=1e-12 * abs(reference).max())
    np.testing.assert_allclose(rc.summed, B.reshape(m, nc, k, w).sum(axis=2), **tol)
    part = rc.groups(slice(1, 3))
    np.testing.assert_allclose(part.left(D[1:3]).reshape(2, 7, k * w), D[1:3] @ B[1:3], **tol)
    np.testing.assert_allclose(part.summed, rc.summed[1:3])


class _System:
    """What of_system reads of a linearise.GroupSystem."""

    def __init__(self, per_ray, rays, k):
        self.per_ray, self.rays = per_ray, rays
        self.cols = np.zeros((per_ray.shape[0], k * per_ray.shape[3]), dtype=int)


def test_the_compact_products_are_taken_for_long_chains_only():
    """of_system: chains of COMPACT_RAYS rays and more; not shorter tracks, not a star (its hub is
    in every condition), not a system without the compact form (a condition transform)."""
    rng = np.random.default_rng(1)
    k = ray_columns.COMPACT_RAYS
    for rays, long_enough in ((_chain_rays(k), True), (_chain_rays(k - 1), False), (_star_rays(k + 5), False)):
        kk = rays.max() + 1
        system = _System(rng.normal(size=(2, len(rays), 3, 8)), rays, kk)
        assert (ray_columns.of_system(system) is not None) == long_enough
    system = _System(rng.normal(size=(2, 5, 3, 8)), None, k)
    assert ray_columns.of_system(system) is None


@pytest.mark.parametrize("with_cameras", [True, False])
def test_group_products_by_ray_equal_the_dense_products(with_cameras):
    """A chunk of long one-camera tracks (cameras estimated or held): the blocks, u and the sums of
    group_products from B by ray (B^T M^-1 B) equal those of the dense whitened B~^T B~."""
    rng = np.random.default_rng(2 + with_cameras)
    m, k, n_photos, elements = 2, 14, 30, np.array([0, 1, 2, 4, 5])
    w = 6 + len(elements)
    photo = np.stack([rng.choice(n_photos, k, replace=False) for _ in range(m)])
    cam = np.zeros_like(photo)
    pat = BlockPattern(n_photos, 1, with_cameras, [(photo, cam)], elements)
    rays = _chain_rays(k)
    nc = len(rays)
    per_ray = rng.normal(size=(m, nc, 3, w))
    B = _dense(per_ray, rays, k)
    Linv = np.linalg.inv(np.linalg.cholesky(_symmetric(rng, m, nc)))
    Bw, ww, gw = Linv @ B, rng.normal(size=(m, nc)), rng.normal(size=(m, nc))
    white = ne.Whitened(Bw, ww, gw, Linv, None, RayColumns(per_ray, rays, k))
    by_ray = ne.group_products(pat, Bw, ww, gw, photo, cam, white)
    dense = ne.group_products(pat, Bw, ww, gw, photo, cam)
    for name in ("pp", "pc", "cc", "ug"):
        a, b = getattr(by_ray, name), getattr(dense, name)
        if b is None:
            assert a is None and not with_cameras
            continue
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * abs(b).max())
    np.testing.assert_array_equal(by_ray.full_cols, dense.full_cols)
    assert (by_ray.wPw, by_ray.gPg) == (dense.wPw, dense.gPg)
    scatters = pat.scatters(photo, cam, ne.sums_camera_columns(pat, cam))
    summed = ne.group_products(pat, Bw, ww, gw, photo, cam, white, scatters)
    assert summed.summed
    np.testing.assert_allclose(summed.pp, scatters[0].sums(dense.pp), rtol=0, atol=1e-11 * abs(dense.pp).max())


def test_group_forms_by_ray_equal_the_dense_forms():
    """covariance.group_forms: G Q G^T of the photo slots from G by ray equals the dense product,
    with a camera slot beside them (the cross terms stay dense)."""
    rng = np.random.default_rng(4)
    m, k, n_photos, e = 3, 15, 40, 4
    w = 6 + e
    rays = _chain_rays(k)
    nc = len(rays)
    per_ray = rng.normal(size=(m, nc, 3, w))
    G = _dense(per_ray, rays, k).reshape(m, nc, k, w)
    photo = np.stack([rng.choice(n_photos, k, replace=False) for _ in range(m)])
    photo_cols = np.arange(6 * n_photos).reshape(n_photos, 6)
    camera_cols = 6 * n_photos + np.arange(e)[None]
    n = 6 * n_photos + e
    a = rng.normal(size=(n, n))
    Qxx = a @ a.T / n + np.eye(n)

    def entries(r, c):
        return np.where((r >= 0) & (c >= 0), Qxx[r, c], 0.0)

    camera = np.zeros_like(photo)
    dense = group_forms(entries, ray_slots(G, photo, photo_cols, camera, camera_cols))
    compact = group_forms(entries, ray_slots(G, photo, photo_cols, camera, camera_cols, RayColumns(per_ray, rays, k)),
                          block_chunk=2 * (6 * k) ** 2)  # two groups per chunk: groups() of a part
    np.testing.assert_allclose(compact, dense, rtol=0, atol=1e-11 * abs(dense).max())


@pytest.fixture(scope="module")
def close_range_project(tmp_path_factory):
    sys.path.insert(0, str(ROOT / "scripts" / "bench"))
    import close_range

    from striptri.io import read_project

    net = close_range.make_close_range(20, 30, seed=5)  # 6 to 17 rays per target, c, xp, yp, k1, k2 free
    return read_project(close_range.write_close_range(tmp_path_factory.mktemp("cr") / "p", net))


def test_the_conditions_method_by_ray_equals_the_dense_products(monkeypatch, close_range_project):
    """The method of conditions on a close-range block whose long targets take the products by ray
    (COMPACT_RAYS lowered so that every group of 4 rays or more does) against the same adjustment
    with the dense products only: the same unknowns, v^T P v and residual cofactors (the gross-error
    test's), to round-off."""
    from striptri.adjustment import adjust
    from striptri.core.options import AdjustmentOptions
    from striptri.precision.residuals import residual_cofactors

    options = AdjustmentOptions(method="conditions")
    taken = []
    products = ne._blocks_by_ray
    monkeypatch.setattr(ne, "_blocks_by_ray", lambda *a: taken.append(1) or products(*a))

    def run(compact_rays):
        monkeypatch.setattr(ray_columns, "COMPACT_RAYS", compact_rays)
        result = adjust(close_range_project, options)
        assert result.converged
        return result, residual_cofactors(close_range_project, result, options)

    dense, q_dense = run(10**9)
    assert not taken
    by_ray, q_by_ray = run(4)
    assert taken
    assert by_ray.iterations == dense.iterations
    assert by_ray.vtpv == pytest.approx(dense.vtpv, rel=1e-10)
    np.testing.assert_allclose(by_ray.state.xyz0, dense.state.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(by_ray.state.interior, dense.state.interior, rtol=0, atol=1e-9)
    np.testing.assert_allclose(q_by_ray.plate, q_dense.plate, rtol=1e-9, atol=1e-12 * abs(q_dense.plate).max())
