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


@pytest.mark.parametrize("damping", [0.0, 1e-3])
def test_bundle_one_camera_reduction_equals_the_general_reduction(monkeypatch, tmp_path, damping):
    """Points whose rays all see one camera (close range, self-calibration) sum their camera
    columns before the reduction (bundle.reduced.reduce_points_one_camera): the same reduced
    camera system N_rcs, b_rcs, e^T e, sum b_p^T N_pp^-1 b_p and LM diagonal as the general
    reduction over k (6 + w) columns per point, to round-off."""
    import sys
    from pathlib import Path

    from striptri.bundle import reduced
    from striptri.bundle.adjust import _Problem
    from striptri.bundle.points import initial_points
    from striptri.core.options import AdjustmentOptions
    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    net = close_range.make_close_range(24, 40, seed=3)  # 7 to 20 rays per target, c, xp, yp, k1, k2 free
    project = read_project(close_range.write_close_range(tmp_path / "p", net))
    options = AdjustmentOptions(method="bundle", chunk_size=5)

    def normals(camera_sum_rays):
        monkeypatch.setattr(reduced, "CAMERA_SUM_RAYS", camera_sum_rays)
        problem = _Problem(project, options)  # the scatters follow the threshold
        xyz = initial_points(problem.batches, problem.initial_state, problem.obs, problem.unknowns,
                             options.chunk_size, None)
        cam = problem.initial_state.camera_of_photo
        summed = [reduced.sums_camera_columns(problem.pattern, cam[c.batch.photo_index])
                  for c in problem.chunks(problem.initial_state, xyz)]
        return problem.assemble(problem.initial_state, xyz, damping), summed

    one_camera, summed = normals(reduced.CAMERA_SUM_RAYS)
    general, summed_general = normals(10**9)
    assert general.pattern.with_cameras and len(general.pattern.cc) > 0  # the camera is estimated
    assert any(summed) and not all(summed) and not any(summed_general)  # both paths in play
    scale = abs(general.N).max()
    np.testing.assert_allclose(one_camera.N.toarray(), general.N.toarray(), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(one_camera.b, general.b, rtol=0, atol=1e-12 * abs(general.b).max())
    np.testing.assert_allclose(one_camera.d, general.d, rtol=1e-12)
    assert one_camera.ee == pytest.approx(general.ee, rel=1e-12)
    assert one_camera.reduced == pytest.approx(general.reduced, rel=1e-12)

