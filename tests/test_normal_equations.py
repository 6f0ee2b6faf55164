"""The reduced normal matrix S^T N_full S gathered from the block numbers (BlockPattern.reduced_matrix)
against the sparse products it replaces."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from striptri.normal_equations import BlockPattern, ReducedPattern


def _pattern(rng, n_photos=9, n_cameras=2, with_cameras=True, elements=(0, 1, 2, 5)):
    chunks = []
    for k in (2, 3, 4):
        photo = np.stack([rng.choice(n_photos, k, replace=False) for _ in range(5)])
        chunks.append((photo, rng.integers(0, n_cameras, photo.shape)))
    return BlockPattern(n_photos, n_cameras, with_cameras, chunks, np.array(elements))


def _selection(rng, n_full, tie):
    """0/1 S: about a fifth of the elements fixed, the others numbered; with ``tie`` some pairs of
    elements share one unknown."""
    col = np.full(n_full, -1)
    free = np.flatnonzero(rng.random(n_full) > 0.2)
    col[free] = np.arange(len(free))
    if tie:
        twins = rng.choice(free, size=(6, 2), replace=False)
        col[twins[:, 1]] = col[twins[:, 0]]
        used, col[col >= 0] = np.unique(col[col >= 0], return_inverse=True)
    rows = np.flatnonzero(col >= 0)
    n = col.max() + 1
    return sp.csr_matrix((np.ones(len(rows)), (rows, col[rows])), shape=(n_full, n))


@pytest.mark.parametrize("with_cameras", [True, False])
@pytest.mark.parametrize("tie", [False, True])
def test_reduced_matrix_equals_the_product_of_the_selection(with_cameras, tie):
    rng = np.random.default_rng(3 + 2 * tie + with_cameras)
    pat = _pattern(rng, with_cameras=with_cameras)
    S = _selection(rng, pat.n_full, tie)
    w = pat.camera_width
    for _ in range(2):  # the second call reuses the structure worked out by the first
        pp = rng.normal(size=(len(pat.pp), 6, 6))
        pc = rng.normal(size=(len(pat.pc), 6, w))
        cc = rng.normal(size=(len(pat.cc), w, w))
        expected = (S.T @ pat.matrix(pp, pc, cc) @ S).toarray()
        got = pat.reduced_matrix(S, pp, pc, cc)
        assert got.has_canonical_format
        np.testing.assert_allclose(got.toarray(), expected, rtol=1e-14, atol=1e-13)
        ref = sp.csr_matrix(S.T @ pat.matrix(pp, pc, cc) @ S)
        ref.sum_duplicates()
        ref.sort_indices()  # the same structure as the product's: no entry more, none less
        assert np.array_equal(got.indptr, ref.indptr) and np.array_equal(got.indices, ref.indices)
    assert (pat._reduction[1].starts is not None) == tie


def test_a_selection_with_weights_other_than_one_is_refused():
    rng = np.random.default_rng(1)
    pat = _pattern(rng)
    S = _selection(rng, pat.n_full, False) * 2.0
    with pytest.raises(ValueError, match="at most one unknown"):
        ReducedPattern(pat._full_indices(), S)


@pytest.mark.parametrize("one_camera", [True, False])
def test_long_track_products_equal_the_ray_pair_products(monkeypatch, one_camera):
    """Groups of FULL_PRODUCT_RAYS or more rays take the whole product Bw^T Bw (with the camera
    columns summed first when all rays of each group have one camera): the same N and u as the
    ray-pair products of short tracks."""
    from striptri import normal_equations as ne

    rng = np.random.default_rng(8 + one_camera)
    m, k, n_photos, n_cameras, elements = 3, 14, 20, 3, np.array([0, 1, 2, 4])
    photo = np.stack([rng.choice(n_photos, k, replace=False) for _ in range(m)])
    cam = np.repeat(rng.integers(0, n_cameras, (m, 1)), k, 1) if one_camera else rng.integers(0, n_cameras, (m, k))
    pat = BlockPattern(n_photos, n_cameras, True, [(photo, cam)], elements)
    S = _selection(rng, pat.n_full, False)
    width = 6 + len(elements)
    nc = 2 * k - 3
    Bw, ww, gw = rng.normal(size=(m, nc, k * width)), rng.normal(size=(m, nc)), rng.normal(size=(m, nc))

    def assembled(threshold):
        monkeypatch.setattr(ne, "FULL_PRODUCT_RAYS", threshold)
        acc = ne.PatternAccumulator(pat, S)
        acc.add_groups(Bw, ww, gw, photo, cam)
        return acc.finish()

    long, short = assembled(ne.FULL_PRODUCT_RAYS), assembled(k + 1)
    scale = abs(short.N).max()
    np.testing.assert_allclose(long.N.toarray(), short.N.toarray(), rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(long.u, short.u, rtol=1e-13)
