"""The reduced normal matrix S^T N_full S gathered from the block numbers (BlockPattern.reduced_matrix)
against the sparse products it replaces."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from striptri.equations.block_pattern import BlockPattern, ReducedPattern
from striptri.equations.normal_equations import TRIANGULAR_BLOCK, lower_inverse


def _pattern(rng, n_photos=9, n_cameras=2, with_cameras=True, elements=(0, 1, 2, 5)):
    chunks = []
    for k in (2, 3, 4):
        photo = np.stack([rng.choice(n_photos, k, replace=False) for _ in range(5)])
        chunks.append((photo, rng.integers(0, n_cameras, photo.shape)))
    return BlockPattern(n_photos, n_cameras, with_cameras, chunks, np.array(elements))


def _selection(rng, n_full, tie, fixed=0.2):
    """0/1 S: about the fraction ``fixed`` of the elements fixed, the others numbered; with ``tie``
    some pairs of elements share one unknown."""
    col = np.full(n_full, -1)
    free = np.flatnonzero(rng.random(n_full) >= fixed)
    col[free] = np.arange(len(free))
    if tie:
        twins = rng.choice(free, size=(6, 2), replace=False)
        col[twins[:, 1]] = col[twins[:, 0]]
        used, col[col >= 0] = np.unique(col[col >= 0], return_inverse=True)
    rows = np.flatnonzero(col >= 0)
    n = col.max() + 1
    return sp.csr_matrix((np.ones(len(rows)), (rows, col[rows])), shape=(n_full, n))


@pytest.mark.parametrize("with_cameras", [True, False])
def test_block_pattern_holds_every_pair_of_a_group_and_the_diagonal(with_cameras):
    """BlockPattern's pp, pc, cc (from sparse incidence products) are the sorted unique keys
    a n + b of every photo-photo, photo-camera and camera-camera pair within a group, plus every
    photo's and camera's diagonal block: the definition, ray pair by ray pair. Groups of one
    camera and of two, photos seen by no group, and a chunk of one-ray groups."""
    rng = np.random.default_rng(11)
    n_photos, n_cameras = 12, 3  # photo 11 and camera 2 in no group
    chunks = []
    for k in (1, 2, 3, 5):
        photo = np.stack([rng.choice(n_photos - 1, k, replace=False) for _ in range(7)])
        cam = rng.integers(0, n_cameras - 1, photo.shape) if k != 3 else np.zeros_like(photo)
        chunks.append((photo, cam))
    pat = BlockPattern(n_photos, n_cameras, with_cameras, chunks)

    def keys(a, b, nb):
        return {int(x) * nb + int(y) for ra, rb in zip(a, b) for x in ra for y in rb}

    pp = set().union(*(keys(ph, ph, n_photos) for ph, _ in chunks)) | {i * (n_photos + 1) for i in range(n_photos)}
    assert pat.pp.dtype == np.int64 and pat.pp.tolist() == sorted(pp)
    if with_cameras:
        pc = set().union(*(keys(ph, c, n_cameras) for ph, c in chunks))
        cc = set().union(*(keys(c, c, n_cameras) for _, c in chunks)) | {i * (n_cameras + 1) for i in range(n_cameras)}
        assert pat.pc.tolist() == sorted(pc) and pat.cc.tolist() == sorted(cc)
        assert len(pat.pc) < n_photos * n_cameras  # camera 2 is in no group
    else:
        assert len(pat.pc) == len(pat.cc) == 0
    empty = BlockPattern(4, 2, True, [])
    assert empty.pp.tolist() == [0, 5, 10, 15] and empty.pc.tolist() == [] and empty.cc.tolist() == [0, 3]


@pytest.mark.parametrize("fixed", [0.2, 0.0])
@pytest.mark.parametrize("with_cameras", [True, False])
@pytest.mark.parametrize("tie", [False, True])
def test_reduced_matrix_equals_the_product_of_the_selection(with_cameras, tie, fixed):
    """S^T N_full S from the block numbers (ReducedPattern): the product's numbers and its CSR
    structure, with fixed elements (block numbers that land nowhere) or none, with tied elements
    (summed entries) or none, with the cameras' blocks or without."""
    rng = np.random.default_rng(3 + 2 * tie + with_cameras)
    pat = _pattern(rng, with_cameras=with_cameras)
    S = _selection(rng, pat.n_full, tie, fixed)
    assert (S.getnnz(axis=1) == 0).any() == (fixed > 0)
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


@pytest.mark.parametrize("fixed", [0.0, 0.2, 0.6, 1.0])
def test_photo_blocks_are_placed_as_the_sort_places_them(fixed):
    """ReducedPattern.of_photo_blocks (a pattern of photo blocks whose kept elements S numbers in
    order, without ties): the same order, indices and indptr, of the same types, as the sort of
    every entry; None where S ties elements or numbers them out of order, and BlockPattern then
    sorts."""
    for seed in range(6):
        rng = np.random.default_rng(40 + seed)
        pat = _pattern(rng, with_cameras=False)
        S = _selection(rng, pat.n_full, False, fixed)
        fast = ReducedPattern.of_photo_blocks(pat.pp, pat.n_photos, S)
        slow = ReducedPattern(pat._full_indices(), S)
        for name in ("order", "indices", "indptr"):
            assert np.array_equal(getattr(fast, name), getattr(slow, name)), name
            assert getattr(fast, name).dtype == getattr(slow, name).dtype, name
        assert fast.starts is None and slow.starts is None and fast.shape == slow.shape
    if fixed == 1.0:  # nothing to estimate: an empty N
        assert fast.shape == (0, 0) and len(fast.order) == 0
        return
    tied = _selection(rng, pat.n_full, True, fixed)
    assert ReducedPattern.of_photo_blocks(pat.pp, pat.n_photos, tied) is None
    reversed_order = sp.csr_matrix(S.toarray()[:, ::-1])  # the same elements kept, numbered backwards
    assert ReducedPattern.of_photo_blocks(pat.pp, pat.n_photos, reversed_order) is None
    assert pat.reduction(reversed_order).starts is None  # sorted instead
    expected = (reversed_order.T @ pat.matrix(np.ones((len(pat.pp), 6, 6)), None, None) @ reversed_order).tocsr()
    expected.sort_indices()
    got = pat.reduced_matrix(reversed_order, np.ones((len(pat.pp), 6, 6)), None, None)
    assert np.array_equal(got.indptr, expected.indptr) and np.array_equal(got.indices, expected.indices)


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
    from striptri.equations import normal_equations as ne

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


def _two_cameras(path):
    """The project at path with every other photo taken by a second camera (a copy of the first)."""
    import csv

    def second_camera(rows):
        return [r if i % 2 else [r[0], "CAM2"] + r[2:] for i, r in enumerate(rows)]

    for name, rows_of in (("cameras.csv", lambda rows: rows + [["CAM2"] + rows[-1][1:]]),
                          ("photos.csv", second_camera)):
        with open(path / name, newline="") as f:
            header, *rows = list(csv.reader(f))
        with open(path / name, "w", newline="") as f:
            csv.writer(f).writerows([header] + rows_of(rows))
    return path


def _bundle_normals(monkeypatch, project, path, damping=0.0, chunk_size=5):
    """The bundle's reduced normals at the approximations (points triangulated) by one path of
    bundle.reduced: "general" (k (6 + w) columns per point, ray pair by ray pair), "one_camera"
    (camera columns summed over the rays of a point, where all are of one camera) or "dense"
    (bundle.dense); returns the normals, whether they were summed dense and, per chunk, whether it
    summed its camera columns."""
    from striptri.bundle import dense, reduced
    from striptri.bundle.adjust import _Problem
    from striptri.bundle.points import initial_points
    from striptri.core.options import AdjustmentOptions

    camera_sum_rays, dense_work_ratio = {"general": (10**9, 0), "one_camera": (2, 0), "dense": (10**9, 10**9)}[path]
    monkeypatch.setattr(reduced, "CAMERA_SUM_RAYS", camera_sum_rays)
    monkeypatch.setattr(dense, "DENSE_WORK_RATIO", dense_work_ratio)
    options = AdjustmentOptions(method="bundle", chunk_size=chunk_size)
    problem = _Problem(project, options)  # the scatters and the dense sum follow the thresholds
    xyz = initial_points(problem.batches, problem.initial_state, problem.obs, problem.unknowns, chunk_size,
                         None if project.points.xyz_approx is None else project.points.xyz_approx - problem.offset)
    cam = problem.initial_state.camera_of_photo
    chunks = list(problem.chunks(problem.initial_state, xyz))
    summed = [reduced.sums_camera_columns(problem.pattern, cam[c.batch.photo_index]) for c in chunks]
    padded = any(getattr(c.batch, "real", None) is not None for c in chunks)  # bundle.padding
    assert padded == (problem.dense and len(problem.linearised) < len(problem.batches))
    normals = problem.assemble(problem.initial_state, xyz, damping)
    normals.padded = padded
    return normals, problem.dense, summed


def _assert_same_normals(fast, general):
    scale = abs(general.N).max()
    np.testing.assert_allclose(fast.N.toarray(), general.N.toarray(), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(fast.b, general.b, rtol=0, atol=1e-12 * abs(general.b).max())
    np.testing.assert_allclose(fast.d, general.d, rtol=1e-12)
    assert fast.ee == pytest.approx(general.ee, rel=1e-12)
    assert fast.reduced == pytest.approx(general.reduced, rel=1e-12)


@pytest.mark.parametrize("damping", [0.0, 1e-3])
@pytest.mark.parametrize("path", ["one_camera", "dense", "dense_two_cameras"])
def test_bundle_reductions_equal_the_general_reduction(monkeypatch, tmp_path, damping, path):
    """The bundle's faster reductions on a close-range project (long tracks, self-calibration) give
    the reduced camera system N_rcs, b_rcs, e^T e, sum b_p^T N_pp^-1 b_p and the LM diagonal of the
    general reduction over k (6 + w) columns per point, to round-off: points whose rays all see one
    camera summing their camera columns before the reduction
    (bundle.reduced.reduce_points_one_camera), and all points summed dense (bundle.dense), with one
    camera or two cameras among the rays of a point."""
    import sys
    from pathlib import Path

    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    net = close_range.make_close_range(24, 40, seed=3)  # 7 to 20 rays per target, c, xp, yp, k1, k2 free
    written = close_range.write_close_range(tmp_path / "p", net)
    project = read_project(_two_cameras(written) if path == "dense_two_cameras" else written)
    assert len(project.cameras.ids) == (2 if path == "dense_two_cameras" else 1)
    general, general_dense, general_summed = _bundle_normals(monkeypatch, project, "general", damping)
    assert general.pattern.with_cameras and len(general.pattern.cc) > 0  # the cameras are estimated
    assert not general_dense and not any(general_summed)
    fast, is_dense, summed = _bundle_normals(monkeypatch, project, path.removesuffix("_two_cameras"), damping)
    assert is_dense if path.startswith("dense") else (not is_dense and all(summed))
    assert fast.padded == is_dense  # dense: the tracks of 7 to 20 rays joined with padded rays (bundle.padding)
    _assert_same_normals(fast, general)


@pytest.mark.parametrize("path", ["general", "one_camera"])
def test_bundle_lean_normals_have_the_full_normals_b(monkeypatch, tmp_path, path):
    """The bundle's normals for a chord step (_Problem.assemble(lean=True): no N) have the right-hand
    side b_rcs, the LM diagonal, e^T e and sum b_p^T N_pp^-1 b_p of the full normals, to round-off
    (to the bit on the general path, whose formula they share), on the close-range project with
    self-calibration; the dense Schur always forms N."""
    import sys
    from pathlib import Path

    from striptri.bundle import dense, reduced
    from striptri.bundle.adjust import _Problem
    from striptri.bundle.points import initial_points
    from striptri.core.options import AdjustmentOptions
    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    project = read_project(close_range.write_close_range(tmp_path / "p", close_range.make_close_range(24, 40, seed=3)))
    monkeypatch.setattr(reduced, "CAMERA_SUM_RAYS", 10**9 if path == "general" else 2)
    monkeypatch.setattr(dense, "DENSE_WORK_RATIO", 0)
    problem = _Problem(project, AdjustmentOptions(method="bundle", chunk_size=5))
    assert not problem.dense and problem.pattern.with_cameras
    xyz = initial_points(problem.batches, problem.initial_state, problem.obs, problem.unknowns, 5,
                         None if project.points.xyz_approx is None else project.points.xyz_approx - problem.offset)
    full = problem.assemble(problem.initial_state, xyz)
    lean = problem.assemble(problem.initial_state, xyz, lean=True)
    assert lean.lean and lean.N is None and full.N is not None and len(lean.kept) == len(full.kept)
    if path == "general":
        assert np.array_equal(lean.b, full.b) and np.array_equal(lean.d, full.d)
    np.testing.assert_allclose(lean.b, full.b, rtol=0, atol=1e-12 * abs(full.b).max())
    np.testing.assert_allclose(lean.d, full.d, rtol=1e-12)
    assert lean.ee == full.ee and lean.reduced == pytest.approx(full.reduced, rel=1e-12)
    monkeypatch.setattr(dense, "DENSE_WORK_RATIO", 10**9)
    summed_dense = _Problem(project, AdjustmentOptions(method="bundle", chunk_size=5))
    assert summed_dense.dense and summed_dense.assemble(summed_dense.initial_state, xyz, lean=True).N is not None


@pytest.mark.parametrize("damping", [0.0, 1e-3])
def test_bundle_dense_padded_equals_dense_unpadded(monkeypatch, tmp_path, damping):
    """The dense sum with small batches of neighbouring ray counts joined and padded with rays of
    weight zero (bundle.padding) equals the dense sum batch by batch, to round-off."""
    import sys
    from pathlib import Path

    from striptri.equations import padding  # the rule of joining
    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    project = read_project(close_range.write_close_range(tmp_path / "p", close_range.make_close_range(24, 40, seed=3)))
    padded, is_dense, _ = _bundle_normals(monkeypatch, project, "dense", damping, chunk_size=4096)
    assert is_dense and padded.padded
    monkeypatch.setattr(padding, "SMALL_BATCH", 1)  # no batch joined
    plain, is_dense, _ = _bundle_normals(monkeypatch, project, "dense", damping, chunk_size=4096)
    assert is_dense and not plain.padded
    _assert_same_normals(padded, plain)


def test_dense_scatters_worked_out_once_equal_those_of_each_chunk(tmp_path):
    """The dense sum with each chunk's places in G_Y, G_N and N_full worked out once per adjustment
    (bundle.dense.DenseScatter, the problem's scatters) is the dense sum that works them out chunk
    by chunk: the same numbers in the same order, so exactly equal; a scatter whose first column
    is not the next free one (a chunk added out of order) is not used."""
    import sys
    from pathlib import Path

    from striptri.bundle.adjust import _Problem
    from striptri.bundle.dense import DenseSchur, DenseScatter
    from striptri.bundle.points import initial_points
    from striptri.core.options import AdjustmentOptions
    from striptri.io import read_project
    from striptri.equations.block_pattern import ray_columns

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    project = read_project(close_range.write_close_range(tmp_path / "p", close_range.make_close_range(24, 40, seed=3)))
    problem = _Problem(project, AdjustmentOptions(method="bundle", chunk_size=7))
    assert problem.dense and all(isinstance(sc, DenseScatter) for sc in problem.scatters)
    state = problem.initial_state
    xyz = initial_points(problem.batches, state, problem.obs, problem.unknowns, 7, None)
    chunks = list(problem.chunks(state, xyz))
    assert len(chunks) == len(problem.scatters) > 2
    once, each = (DenseSchur(problem.pattern.n_full, problem.n_points) for _ in range(2))
    for chunk, scatter in zip(chunks, problem.scatters):
        full_cols = ray_columns(problem.pattern, chunk.batch.photo_index, state.camera_of_photo[chunk.batch.photo_index])
        np.testing.assert_array_equal(scatter.full_cols, full_cols)
        r1 = once.add(chunk.Jc, chunk.Jp, chunk.N_pp, chunk.b_p, scatter.full_cols, scatter)
        r2 = each.add(chunk.Jc, chunk.Jp, chunk.N_pp, chunk.b_p, full_cols)
        assert r1 == r2
    for a, b in zip(once.finish(), each.finish()):
        np.testing.assert_array_equal(a, b)
    # out of order: the second chunk's scatter offered first is not used (its columns would be wrong)
    second = chunks[1]
    wrong, right = (DenseSchur(problem.pattern.n_full, problem.n_points) for _ in range(2))
    wrong.add(second.Jc, second.Jp, second.N_pp, second.b_p, problem.scatters[1].full_cols, problem.scatters[1])
    right.add(second.Jc, second.Jp, second.N_pp, second.b_p, problem.scatters[1].full_cols)
    np.testing.assert_array_equal(wrong.G_Y, right.G_Y)


@pytest.mark.parametrize("name", ["pair, weighted control", "strip, single-photo weighted control",
                                  "strip, plan points, check points", "strip, IMU, held angle, bases, interior",
                                  "pair, one-photo points of every kind", "block_3x6"])
@pytest.mark.parametrize("path", ["one_camera", "dense"])
def test_bundle_reductions_on_the_bundle_cases(monkeypatch, name, path):
    """The same on the bundle's test projects (test_bundle.CASES): weighted and held control,
    one-photo points, plan points, observed elements and interior orientation (camera columns in N
    where the cameras are estimated)."""
    from test_bundle import CASES

    project = CASES[name]()
    general, _, _ = _bundle_normals(monkeypatch, project, "general")
    fast, is_dense, _ = _bundle_normals(monkeypatch, project, path)
    assert is_dense == (path == "dense")
    _assert_same_normals(fast, general)


@pytest.mark.parametrize("case", ["block_3x6", "close range, one camera", "close range, general"])
def test_bundle_normals_formed_in_the_chunk_threads_equal_those_of_one_thread(monkeypatch, tmp_path, case):
    """Each chunk's share of the bundle's reduced camera system is formed in its chunk thread
    (ReducedNormals.products) and added up by the caller in the chunks' order: N, b, the LM
    diagonal, e^T e, the reduced sum and the kept chunks are those of one thread to the bit, for the
    full and the lean normals, with the cameras held (block_3x6) and estimated (close range, its
    points summed by camera or ray pair by ray pair)."""
    import sys
    from pathlib import Path

    from striptri import parallel
    from striptri.bundle import adjust as bundle_adjust
    from striptri.bundle import dense, reduced
    from striptri.bundle.points import initial_points
    from striptri.core.options import AdjustmentOptions
    from striptri.io import read_project
    from striptri.solvers import threads

    if case == "block_3x6":
        from test_bundle import CASES

        project = CASES[case]()
    else:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
        import close_range

        project = read_project(close_range.write_close_range(tmp_path / "p", close_range.make_close_range(24, 40, seed=3)))
        monkeypatch.setattr(reduced, "CAMERA_SUM_RAYS", 2 if case.endswith("one camera") else 10**9)
    monkeypatch.setattr(dense, "DENSE_WORK_RATIO", 0)  # the block pattern, whose chunks the threads reduce
    monkeypatch.setattr(threads, "PARALLEL_MIN_RAY_PAIRS", 0)
    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    used = []
    map_ordered = parallel.map_ordered
    monkeypatch.setattr(bundle_adjust, "map_ordered",
                        lambda fn, items, n: (used.append(n), map_ordered(fn, items, n))[1])
    problem = bundle_adjust._Problem(project, AdjustmentOptions(method="bundle", chunk_size=3))
    assert not problem.dense and len(problem.scatters) > 4
    state = problem.initial_state
    xyz = initial_points(problem.batches, state, problem.obs, problem.unknowns, 3,
                         None if project.points.xyz_approx is None else project.points.xyz_approx - problem.offset)
    for lean in (False, True):
        formed = {}
        for n in (1, 2):
            used.clear()
            with threads.use_threads(n):
                formed[n] = problem.assemble(state, xyz, lean=lean)
            assert used == [n]
        one, two = formed[1], formed[2]
        assert (one.N is None) == (two.N is None) == lean
        if not lean:
            assert np.array_equal(one.N.toarray(), two.N.toarray())
        assert np.array_equal(one.b, two.b) and np.array_equal(one.d, two.d)
        assert one.ee == two.ee and one.reduced == two.reduced
        assert [c.batch.point_index.tolist() for c in one.kept] == [c.batch.point_index.tolist() for c in two.kept]


def _conditions_normals(monkeypatch, project, full_product_rays, chunk_size=5, compact_rays=10**9):
    """The method of conditions' N, u, wPw, ug, gPg at the approximations, with groups of
    full_product_rays rays or more taking the whole products (normal_equations.add_groups) and
    groups of compact_rays rays or more their products ray by ray (ray_columns; by default none);
    returns the accumulator and, per chunk, whether it summed its camera columns (and so has
    camera-summed scatters: one photo-camera block per ray)."""
    from striptri.equations import normal_equations as ne
    from striptri.equations import ray_columns
    from striptri.conditions_method.adjust import _Problem
    from striptri.core.options import AdjustmentOptions

    monkeypatch.setattr(ne, "FULL_PRODUCT_RAYS", full_product_rays)
    monkeypatch.setattr(ray_columns, "COMPACT_RAYS", compact_rays)
    problem = _Problem(project, AdjustmentOptions(method="conditions", chunk_size=chunk_size))
    cam = problem.initial_state.camera_of_photo
    chunks = [c.photo_index for b in problem.batches for c in b.chunks(chunk_size)]
    summed = [ne.sums_camera_columns(problem.assembly.pattern, cam[photo]) for photo in chunks]
    per_ray = [scatter_pc.P.shape[1] == photo.size for photo, (_, scatter_pc, _) in zip(chunks, problem.assembly.scatters)]
    assert summed == per_ray  # the scatters made once per adjustment follow the branch add_groups takes
    sweep = problem.sweep(problem.initial_state, problem.obs.plate, problem.obs.control)
    return problem.assemble(sweep, 1), summed


@pytest.mark.parametrize("by_ray", [False, True])
@pytest.mark.parametrize("cameras", ["one", "two"])
def test_conditions_long_one_camera_tracks_equal_the_ray_pair_products(monkeypatch, tmp_path, cameras, by_ray):
    """The method of conditions on a close-range project (long tracks, self-calibration): groups
    whose rays all see one camera, their camera columns summed and scattered once per ray and once
    per group (BlockPattern.scatters with camera_summed), and groups of two cameras (the whole
    product, ray-pair scatters), give N, u, wPw, ug and gPg of the ray-pair products to round-off.
    by_ray: the whitening and the one-camera products formed ray by ray from the compact B
    (ray_columns, as ``B^T M^-1 B``), against the dense ``B~^T B~`` of the reference."""
    import sys
    from pathlib import Path

    from striptri.io import read_project

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
    import close_range

    net = close_range.make_close_range(24, 40, seed=3)  # 7 to 20 rays per target, c, xp, yp, k1, k2 free
    written = close_range.write_close_range(tmp_path / "p", net)
    project = read_project(_two_cameras(written) if cameras == "two" else written)
    general, general_summed = _conditions_normals(monkeypatch, project, 10**9)
    assert general.pattern.with_cameras and len(general.pattern.cc) > 0  # the cameras are estimated
    assert not any(general_summed)
    from striptri.equations import normal_equations as ne

    taken = []  # the chunks whose products were formed ray by ray
    by_ray_products = ne._blocks_by_ray
    monkeypatch.setattr(ne, "_blocks_by_ray", lambda *a: taken.append(1) or by_ray_products(*a))
    # every group takes the whole product (and, by_ray, its products ray by ray)
    long, summed = _conditions_normals(monkeypatch, project, 2, compact_rays=2 if by_ray else 10**9)
    assert bool(taken) == (by_ray and cameras == "one")  # two cameras per track: the dense products
    assert all(summed) if cameras == "one" else not any(summed)
    scale = abs(general.N).max()
    np.testing.assert_allclose(long.N.toarray(), general.N.toarray(), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(long.u, general.u, rtol=0, atol=1e-12 * abs(general.u).max())
    np.testing.assert_allclose(long.ug, general.ug, rtol=0, atol=1e-12 * abs(general.ug).max())
    assert long.wPw == pytest.approx(general.wPw, rel=1e-12)
    assert long.gPg == pytest.approx(general.gPg, rel=1e-12)


@pytest.mark.parametrize("n", [1, 3, TRIANGULAR_BLOCK, TRIANGULAR_BLOCK + 1, 60, 129])
def test_lower_inverse_equals_the_general_inverse(n):
    """The triangular inverse by halves (the whitening's L^-1) against numpy's general inverse, for
    sizes at, below and above the split, batched over groups: equal to round-off (the Cholesky
    factors of well-conditioned M, as the scaled conditions give), lower triangular exactly."""
    rng = np.random.default_rng(n)
    A = rng.normal(size=(5, n, n))
    L = np.linalg.cholesky(A @ np.swapaxes(A, 1, 2) + n * np.eye(n))
    got = lower_inverse(L)
    want = np.linalg.inv(L)
    assert np.abs(got - want).max() <= 1e-13 * np.abs(want).max()
    assert np.all(np.triu(got, 1) == 0.0)
    assert lower_inverse(L[:0]).shape == (0, n, n)


def test_a_chunk_scatter_adds_its_blocks_where_they_belong(monkeypatch):
    """ChunkScatter sums a chunk's ray-pair blocks by position and adds them at their positions, or
    over the stretch of positions they span (SPAN_FILL): both equal np.add.at of every block, and
    the two layouts give the same numbers to the last bit."""
    from striptri.equations import block_pattern

    rng = np.random.default_rng(5)
    pos = rng.choice(np.arange(40, 90), size=(7, 3, 3))  # 7 groups of 3 rays: pairs onto 50 of 200 positions
    blocks = rng.normal(size=(7, 3, 3, 2, 2))
    reference = np.zeros((200, 4))
    np.add.at(reference, pos.ravel(), blocks.reshape(-1, 4))
    out = {}
    for f in (0.0, np.inf):
        monkeypatch.setattr(block_pattern, "SPAN_FILL", f)
        scatter = block_pattern.ChunkScatter(pos)
        assert (scatter.span is not None) == (f == 0.0)
        target = np.zeros(200 * 4)
        scatter.add(target, blocks)
        out[f] = target
    np.testing.assert_allclose(out[0.0].reshape(200, 4), reference, rtol=1e-14, atol=1e-14)
    np.testing.assert_array_equal(out[0.0], out[np.inf])


def test_a_chunk_scatters_summation_matrix_is_the_one_a_coo_conversion_makes(monkeypatch):
    """ChunkScatter builds its summation matrix P from one stable sort of the pairs by position: the
    same distinct positions as np.unique and, row for row, the same columns in the same order as
    the CSR matrix scipy makes of the pairs' (row, pair) coordinates, in both layouts; so its sums
    are the same numbers to the last bit."""
    import scipy.sparse as sp

    from striptri.equations import block_pattern

    rng = np.random.default_rng(8)
    pos = rng.choice(np.arange(30, 1000), size=(9, 4, 4))
    for f in (0.0, np.inf):
        monkeypatch.setattr(block_pattern, "SPAN_FILL", f)
        scatter = block_pattern.ChunkScatter(pos)
        positions, inverse = np.unique(pos, return_inverse=True)
        np.testing.assert_array_equal(scatter.positions, positions)
        row = inverse.ravel() if scatter.span is None else positions[inverse.ravel()] - positions[0]
        rows = len(positions) if scatter.span is None else positions[-1] - positions[0] + 1
        want = sp.csr_matrix((np.ones(pos.size), (row, np.arange(pos.size))), shape=(rows, pos.size))
        assert scatter.P.shape == want.shape and scatter.P.indices.dtype == want.indices.dtype
        np.testing.assert_array_equal(scatter.P.indptr, want.indptr)
        np.testing.assert_array_equal(scatter.P.indices, want.indices)
        np.testing.assert_array_equal(scatter.P.data, want.data)
    empty = block_pattern.ChunkScatter(np.zeros((0, 3, 3), dtype=np.int64))
    assert len(empty.positions) == 0 and empty.P.shape == (0, 0)


@pytest.mark.parametrize("case", ["block_3x6", "close_range_one_camera", "close_range_two_cameras"])
def test_an_assembly_without_normals_forms_the_same_u(tmp_path, case):
    """A chord step's assembly (assemble_normals with normals False: group_misclosures, no ray-pair
    products) forms u, ug, w^T P w, g^T P g, the largest misclosure and the kept whitened chunks of
    the full assembly to the last bit, and no N; on a block with the cameras held and on close
    range (long tracks of one camera, summed camera columns, and of two cameras)."""
    import sys
    from pathlib import Path

    from striptri.conditions_method.adjust import _Problem
    from striptri.core.options import AdjustmentOptions
    from striptri.io import read_project

    from cli_support import DATA

    if case == "block_3x6":
        project = read_project(DATA / "block_3x6")
    else:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
        import close_range

        written = close_range.write_close_range(tmp_path / "p", close_range.make_close_range(24, 40, seed=3))
        project = read_project(_two_cameras(written) if case.endswith("two_cameras") else written)
    problem = _Problem(project, AdjustmentOptions(method="conditions", chunk_size=16))
    sweep = problem.sweep(problem.initial_state, problem.obs.plate, problem.obs.control)
    full = problem.assemble(sweep, 1, keep=True)
    alone = problem.assemble(sweep, 1, keep=True, normals=False)
    assert alone.N is None and full.N.nnz > 0
    assert problem.assembly.pattern.with_cameras == (case != "block_3x6")
    for name in ("u", "ug"):
        assert np.array_equal(getattr(alone, name), getattr(full, name))
    assert (alone.wPw, alone.gPg, alone.max_misclosure) == (full.wPw, full.gPg, full.max_misclosure)
    assert len(alone.kept) == len(full.kept) > 1
    for a, b in zip(alone.kept, full.kept):
        assert np.array_equal(a.Bw, b.Bw) and np.array_equal(a.ww, b.ww) and np.array_equal(a.Gt, b.Gt)
