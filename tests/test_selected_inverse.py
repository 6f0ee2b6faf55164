"""Selected inversion (striptri.selected_inverse) against the dense inverse, every route.

Agreement is measured on the Jacobi-scaled inverse ``D N^-1 D`` (``D = diag(N)^1/2``, so that
metres, radians and millimetres count alike): the largest difference of a requested entry from
``np.linalg.inv`` relative to the largest requested entry, at most 1e-10 (the test matrices have
scaled condition numbers below about 1e6, so both sides carry errors of about 1e-10 at most).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from striptri.adjustment import adjust
from striptri.io import read_project
from striptri.equations.parameters import UnknownLayout
from striptri.selected_inverse import METHODS, for_layout, photo_blocks, selected_inverse
from striptri.solvers import SingularNormalMatrix, cholmod_available

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
RTOL = 1e-10
ROUTES = [m for m in METHODS if m != "auto" and (m != "cholmod" or cholmod_available())]


# ------------------------------------------------------------------------------ test matrices


def normal_matrix(photo_groups, n_photos: int, n_cameras: int, rng, control_every: int = 3, control=True):
    """``G' G`` (sparse) for condition rows on groups of photos (coefficients summing to zero over a
    group: a datum defect, as coplanarity has), 6 control rows on every ``control_every``-th photo,
    each photo's camera (photo mod n_cameras) in its rows; columns in random units 1e-2..1e2.
    Returns N and the block starts (photos of 6, then cameras of 3)."""
    n = 6 * n_photos + 3 * n_cameras
    entries = []  # (row, columns, values) of the rows of G

    def add(columns, values):
        entries.append((np.full(len(columns), len(entries)), columns, values))

    for group in photo_groups:
        for _ in range(4 * len(group)):
            a = rng.normal(size=(len(group), 6))
            a -= a.mean(axis=0)
            columns = (6 * np.array(group)[:, None] + np.arange(6)).ravel()
            values = a.ravel()
            if n_cameras:
                cam = group[0] % n_cameras
                columns = np.concatenate([columns, 6 * n_photos + 3 * cam + np.arange(3)])
                values = np.concatenate([values, 0.3 * rng.normal(size=3)])
            add(columns, values)
    if control:
        for photo in range(0, n_photos, control_every):
            for coef in rng.normal(size=(6, 6)):
                add(6 * photo + np.arange(6), coef)
    for j in range(3 * n_cameras):  # a weak observation of each camera constant
        add(np.array([6 * n_photos + j]), np.array([0.1]))
    r, c, v = (np.concatenate(x) for x in zip(*entries))
    G = sp.csr_matrix((v, (r, c)), shape=(len(entries), n)) @ sp.diags(10.0 ** rng.uniform(-2, 2, n))
    starts = np.concatenate([np.arange(0, 6 * n_photos, 6), 6 * n_photos + np.arange(0, 3 * n_cameras, 3)])
    return sp.csr_matrix(G.T @ G), starts


def strip(n_photos, n_cameras=0, seed=0, control=True):
    """A strip: 6x6 blocks within two photos of the diagonal (pairs and triples of photos)."""
    groups = [(i, i + 1) for i in range(n_photos - 1)] + [(i, i + 1, i + 2) for i in range(n_photos - 2)]
    return normal_matrix(groups, n_photos, n_cameras, np.random.default_rng(seed), control=control)


def block(n_strips, per_strip, n_cameras=0, seed=0):
    """Parallel strips numbered strip by strip, with sidelap groups of four photos."""
    idx = np.arange(n_strips * per_strip).reshape(n_strips, per_strip)
    groups = [tuple(idx[s, p: p + 2]) for s in range(n_strips) for p in range(per_strip - 1)]
    groups += [tuple(idx[s, p: p + 3]) for s in range(n_strips) for p in range(per_strip - 2)]
    groups += [(idx[s, p], idx[s, p + 1], idx[s + 1, p], idx[s + 1, p + 1])
               for s in range(n_strips - 1) for p in range(per_strip - 1)]
    return normal_matrix(groups, n_strips * per_strip, n_cameras, np.random.default_rng(seed))


@functools.lru_cache(maxsize=None)
def real_normal_matrix(name: str, free_camera: bool = False):
    project = read_project(DATA / name)
    if free_camera:
        cams = dataclasses.replace(project.cameras, sigma_interior=np.full_like(project.cameras.sigma_interior, np.inf))
        project = dataclasses.replace(project, cameras=cams)
    result = adjust(project)
    return result.N, result.layout


def dense_inverse(N):
    """np.linalg.inv of the Jacobi-scaled N, unscaled (the scaling only changes the units of the
    unknowns; without it LU works on entries 1e8 apart and is itself the less accurate side)."""
    s = 1.0 / np.sqrt(N.diagonal())
    return np.linalg.inv(N.toarray() * s[:, None] * s[None, :]) * s[:, None] * s[None, :]


def check_blocks(N, inv, pairs=()):
    """Every diagonal block, the named pairs and the diagonal against np.linalg.inv (scaled)."""
    ref = dense_inverse(N)
    d = np.sqrt(N.diagonal())
    scaled_ref = ref * d[:, None] * d[None, :]
    dp = np.append(d, 0.0)
    refp = np.pad(ref, ((0, 1), (0, 1)))  # index -1 reads zeros
    worst, largest = 0.0, 0.0
    keys = [(i, i) for i in range(len(inv.blocks))] + list(pairs)
    for i, j in keys:
        I, J = inv.blocks[i], inv.blocks[j]
        got = inv.pair(i, j) if i != j else inv.block(i)
        want = refp[np.ix_(I, J)]
        scale = dp[I][:, None] * dp[J][None, :]
        worst = max(worst, float(np.max(np.abs((got - want) * scale), initial=0.0)))
        largest = max(largest, float(np.max(np.abs(want * scale), initial=0.0)))
    diag_err = np.max(np.abs(inv.diag() * d * d - np.diag(scaled_ref)))
    largest = max(largest, float(np.max(np.diag(scaled_ref))))
    print(f"{inv.method}: {worst / largest:.1e}")
    assert worst <= RTOL * largest, (worst, largest)
    assert diag_err <= RTOL * largest, (diag_err, largest)
    return ref


# ------------------------------------------------------------------------------------ routes


@pytest.mark.parametrize("method", ROUTES)
@pytest.mark.parametrize("n_cameras", [0, 1, 2])
def test_strip_equals_dense_inverse(method, n_cameras):
    N, starts = strip(40, n_cameras, seed=n_cameras)
    pairs = [(0, 1), (5, 7), (0, 39), (12, 30)]  # neighbours, two apart, far apart
    if n_cameras:
        pairs += [(3, 40), (40, 40 + n_cameras - 1)]  # photo-camera, camera-camera
    inv = selected_inverse(N, starts, pairs, method=method)
    assert inv.method == method
    check_blocks(N, inv, pairs)


@pytest.mark.parametrize("method", ROUTES)
@pytest.mark.parametrize("n_cameras", [0, 2])
def test_block_of_strips_equals_dense_inverse(method, n_cameras):
    N, starts = block(4, 9, n_cameras, seed=3)
    pairs = [(0, 9), (10, 11), (4, 31), (35, 0)]  # across strips, along, far, reversed
    inv = selected_inverse(N, starts, pairs, method=method)
    check_blocks(N, inv, pairs)


@pytest.mark.parametrize("method", ROUTES)
@pytest.mark.parametrize("name, free_camera", [("strip8", False), ("block_3x6", False),
                                               ("strip8", True), ("block_3x6", True)])
def test_real_normal_matrices(method, name, free_camera):
    N, layout = real_normal_matrix(name, free_camera)
    assert (layout.camera_cols >= 0).any() == free_camera
    n_photos = len(layout.photo_cols)
    pairs = [(0, 1), (1, 2), (0, n_photos - 1)]
    if free_camera:
        pairs.append((2, n_photos))  # photo 2 with the camera
    inv = for_layout(N, layout, pairs, method=method)
    ref = check_blocks(N, inv, pairs)
    stack = photo_blocks(N, layout, method=method)
    cols = layout.photo_cols
    np.testing.assert_allclose(stack, ref[cols[:, :, None], cols[:, None, :]], rtol=0,
                               atol=RTOL * np.abs(ref).max())


def test_auto_picks_by_pattern():
    assert selected_inverse(strip(5)[0], method="auto").method == "dense"  # 30 unknowns
    assert selected_inverse(strip(40, 1)[0], method="auto").method == "banded"
    N, starts = block(3, 120, 1)  # strips of 120: sidelap 121 photos apart, half-bandwidth 731
    assert selected_inverse(N, starts, method="auto").method == "sparse"
    full = nearly_full_matrix(300)
    assert selected_inverse(full, method="auto").method == "dense"  # beyond DENSE_LIMIT, but full


def nearly_full_matrix(n: int, seed: int = 0) -> sp.csr_matrix:
    """An SPD n x n matrix with every entry nonzero (a close range's N: each target on most photos),
    its diagonal entries 1e-4 to 1e4 apart as N's are (metres and radians)."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((2 * n, n))
    s = 10.0 ** rng.uniform(-2, 2, n)
    return sp.csr_matrix((A.T @ A) * s[:, None] * s[None, :])


@pytest.mark.parametrize("method", ROUTES)
def test_the_whole_inverse_of_every_route(method):
    """SelectedInverse.whole: the dense route's own inverse (LAPACK potri), the others' n solves:
    each the dense inverse, symmetric."""
    N, starts = strip(12, 1, seed=4)
    Q = selected_inverse(N, starts, method=method).whole()
    ref = dense_inverse(N)
    d = np.sqrt(N.diagonal())
    np.testing.assert_allclose(Q * d[:, None] * d[None, :], ref * d[:, None] * d[None, :], rtol=0, atol=RTOL)
    np.testing.assert_array_equal(Q, Q.T)


def test_a_nearly_full_matrix_inverted_dense_equals_the_dense_inverse():
    N = nearly_full_matrix(300, seed=1)
    inv = selected_inverse(N, np.arange(0, 300, 6), method="auto")
    assert inv.method == "dense"
    check_blocks(N, inv)
    d = np.sqrt(N.diagonal())
    np.testing.assert_allclose(inv.whole() * d[:, None] * d[None, :], dense_inverse(N) * d[:, None] * d[None, :],
                               rtol=0, atol=RTOL)


# --------------------------------------------------------------------------- blocks and pairs


@pytest.mark.parametrize("method", ROUTES)
def test_index_array_blocks_with_fixed_and_shared_columns(method):
    """Blocks given as index arrays in any order, -1 (fixed) reading zeros, a column in two blocks
    (an enforced base component), blocks of different sizes."""
    N, _ = strip(12, 1, seed=5)
    n = N.shape[0]
    blocks = [np.array([5, -1, 3, 0]), np.array([6, 7, 5]), np.array([-1, -1]), np.array([n - 1, 2, n - 3]),
              np.arange(60, 66)[::-1], np.array([], dtype=int)]
    pairs = [(0, 1), (3, 0), (2, 4), (4, 1), (5, 0)]
    inv = selected_inverse(N, blocks, pairs, method=method)
    check_blocks(N, inv, pairs)
    assert np.all(inv.block(0)[1] == 0) and np.all(inv.block(0)[:, 1] == 0)
    assert np.all(inv.block(2) == 0) and inv.block(5).shape == (0, 0) and inv.pair(5, 0).shape == (0, 4)


@pytest.mark.parametrize("method", ROUTES)
def test_pairs_asked_later_and_transposed(method):
    N, starts = strip(30, 1, seed=2)
    ref = dense_inverse(N)
    inv = selected_inverse(N, starts, [(3, 4)], method=method)
    for i, j in [(4, 3), (3, 4), (0, 29), (29, 0), (7, 30), (30, 7)]:
        I, J = inv.blocks[i], inv.blocks[j]
        np.testing.assert_allclose(inv.pair(i, j), ref[np.ix_(I, J)], rtol=1e-8,
                                   atol=1e-10 * np.abs(ref[np.ix_(I, J)]).max())


def test_stack_layout_and_solves():
    N, starts = strip(20, 1, seed=7)
    ref = dense_inverse(N)
    inv = selected_inverse(N, starts, method="banded")
    stack = inv.stack(range(20))
    assert stack.shape == (20, 6, 6)
    for i in (0, 7, 19):
        np.testing.assert_array_equal(stack[i], inv.block(i))
    with pytest.raises(ValueError, match="different sizes"):
        inv.stack()
    b = np.random.default_rng(1).normal(size=N.shape[0])
    np.testing.assert_allclose(inv.solve(b), ref @ b, rtol=1e-9, atol=1e-9 * np.abs(ref @ b).max())
    f = np.zeros(N.shape[0])
    f[[0, 6]] = [-1.0, 1.0]  # a base component bx between photos 0 and 1 (Schmid 85)
    assert inv.quadratic_form(f) == pytest.approx(f @ ref @ f, rel=1e-9)
    F = np.column_stack([f, np.roll(f, 6)])  # bx of photos 0-1 and 1-2 at once
    np.testing.assert_allclose(inv.quadratic_form(F), np.einsum("iq,ij,jq->q", F, ref, F), rtol=1e-9)


def test_layout_with_fixed_photo_and_shared_column():
    """for_layout: a held-fixed photo reads zeros; a column shared by two photos appears in both."""
    N, _ = strip(6, 1, seed=4)  # 39 unknowns: photos 0..5, one camera
    cols = np.arange(36).reshape(6, 6)
    photo_cols = np.vstack([cols[:1], -np.ones((1, 6), dtype=int), cols[1:5]])  # photo 1 fixed
    photo_cols = photo_cols.copy()
    photo_cols[3, 0] = photo_cols[2, 0]  # an enforced base component: same X unknown
    layout = UnknownLayout(photo_cols=photo_cols, camera_cols=np.array([[36, 37, 38]]), n_unknowns=39,
                           convention="omega-phi-kappa", angle_fixed=np.zeros((6, 3), bool),
                           fixed_angles=np.zeros((6, 3)))
    ref = np.pad(dense_inverse(N), ((0, 1), (0, 1)))
    for method in ROUTES:
        stack = photo_blocks(N, layout, method=method)
        want = ref[photo_cols[:, :, None], photo_cols[:, None, :]]
        np.testing.assert_allclose(stack, want, rtol=0, atol=1e-10 * np.abs(want).max())
        assert np.all(stack[1] == 0)
        inv = for_layout(N, layout, [(2, 3)], method=method)
        np.testing.assert_allclose(inv.block(6), ref[36:39, 36:39], rtol=1e-9)
        assert inv.pair(2, 3)[0, 0] == pytest.approx(ref[photo_cols[2, 0], photo_cols[2, 0]], rel=1e-9)


# ------------------------------------------------------------------------------- edge cases


@pytest.mark.parametrize("method", METHODS)
def test_zero_size(method):
    inv = selected_inverse(sp.csr_matrix((0, 0)), [np.zeros(0, dtype=int)], [(0, 0)], method=method)
    assert inv.diag().shape == (0,) and inv.block(0).shape == (0, 0) and inv.solve(np.zeros(0)).shape == (0,)


@pytest.mark.parametrize("method", ROUTES)
def test_one_by_one(method):
    inv = selected_inverse(sp.csr_matrix([[4.0]]), [np.array([0])], method=method)
    assert inv.block(0)[0, 0] == pytest.approx(0.25, rel=1e-15)
    assert inv.diag()[0] == pytest.approx(0.25, rel=1e-15)


@pytest.mark.parametrize("method", ROUTES)
def test_singular_raises(method):
    N, starts = strip(30, 1, control=False)  # tie conditions only: a datum defect of 6
    with pytest.raises(SingularNormalMatrix, match="singular"):
        selected_inverse(N, starts, method=method)


@pytest.mark.parametrize("method", ROUTES)
def test_indefinite_raises(method):
    N, starts = strip(20, 0, seed=1)
    N = N.tolil()
    N[50, 50] = -N[50, 50]
    with pytest.raises(SingularNormalMatrix):
        selected_inverse(N.tocsr(), starts, method=method)


def test_bad_arguments():
    N, starts = strip(4)
    with pytest.raises(ValueError, match="unknown method"):
        selected_inverse(N, starts, method="magic")
    with pytest.raises(IndexError):
        selected_inverse(N, starts, [(0, 4)])
    with pytest.raises(IndexError):
        selected_inverse(N, [np.array([24])])
    with pytest.raises(ValueError, match="square"):
        selected_inverse(sp.csr_matrix(np.ones((2, 3))))
    with pytest.raises(ValueError, match="block starts"):
        selected_inverse(N, np.array([1, 6]))


# ----------------------------------------------------------------------- internal parameters


@pytest.mark.parametrize("relaxed, zeros", [(0, 0.0), (48, 0.5), (10**6, 1.0)])
def test_supernodes_fundamental_relaxed_or_whole_chains(monkeypatch, relaxed, zeros):
    """The answer does not depend on how the chains of blocks are cut into supernodes."""
    import striptri.selected_inverse as si

    monkeypatch.setattr(si, "RELAXED_SUPERNODE", relaxed)
    monkeypatch.setattr(si, "RELAXED_ZEROS", zeros)
    N, starts = block(3, 10, 1, seed=8)
    inv = selected_inverse(N, starts, [(0, 10), (5, 6)], method="sparse")
    check_blocks(N, inv, [(0, 10), (5, 6)])


def test_split_into_independent_subtrees():
    """Supernodes.split: the top and the subtrees partition the supernodes; no subtree holds an
    ancestor of another's supernode, the top holds every ancestor of the subtrees' roots, and
    none of the subtrees holds more than its share of their work unless it cannot be split."""
    from striptri.selected_inverse import supernodal

    N, starts = block(12, 20, 0, seed=3)
    inv = selected_inverse(N, starts, method="sparse")
    sym = inv._engine.sym
    assert isinstance(inv._engine, supernodal.SupernodalInverse)
    assert sym.count > 20
    for parts in (2, 3, 8):
        top, subtrees = sym.split(parts)
        assert len(subtrees) >= 2
        everything = np.sort(np.concatenate([top, *subtrees]))
        np.testing.assert_array_equal(everything, np.arange(sym.count))
        owner = np.full(sym.count, -1)
        for i, nodes in enumerate(subtrees):
            owner[nodes] = i
        for i, nodes in enumerate(subtrees):
            for p in nodes:  # every ancestor: in the same subtree or in the top
                q = sym.parent[p]
                while q >= 0:
                    assert owner[q] in (i, -1)
                    q = sym.parent[q]
            root = nodes[-1]
            assert sym.parent[root] == -1 or owner[sym.parent[root]] == -1
        work = [sym.work[nodes].sum() for nodes in subtrees]
        assert max(work) <= sum(work) / parts or len(subtrees[int(np.argmax(work))]) == 1


@pytest.mark.parametrize("threads", [2, 3])
@pytest.mark.parametrize("numeric", ["sparse", "cholmod"])
def test_subtrees_on_threads_equal_dense_inverse(monkeypatch, threads, numeric):
    """The recurrence over independent subtrees on threads (a small N made to take that path)
    gives the dense inverse, the same numbers to the last bit in every run, and a singular pivot
    is still raised."""
    if numeric == "cholmod" and not cholmod_available():
        pytest.skip("scikit-sparse not installed")
    from striptri.selected_inverse import supernodal

    monkeypatch.setattr(supernodal, "PARALLEL_MIN_WORK", 0.0)
    monkeypatch.setattr(supernodal, "chunk_threads", lambda: threads)  # whatever the cores
    used = []
    real = supernodal.run_all
    monkeypatch.setattr(supernodal, "run_all",
                        lambda fn, parts, n: used.append((len(parts), n)) or real(fn, parts, n))
    N, starts = block(6, 15, 1, seed=5)
    pairs = [(0, 15), (40, 41), (7, 89)]
    inv = selected_inverse(N, starts, pairs, method=numeric)
    check_blocks(N, inv, pairs)
    assert used and all(parts >= 2 and n == threads for parts, n in used)
    again = [selected_inverse(N, starts, pairs, method=numeric) for _ in range(3)]
    for other in again:
        np.testing.assert_array_equal(other._engine.Z, inv._engine.Z)
        np.testing.assert_array_equal(other.diag(), inv.diag())
    N, starts = block(6, 15, 0, seed=6)
    N = N.tolil()
    for col in (20, 300):  # two negative pivots, in different subtrees
        N[col, col] = -N[col, col]
    with pytest.raises(SingularNormalMatrix):
        selected_inverse(N.tocsr(), starts, method=numeric)


@pytest.mark.parametrize("threads", [2, 3])
def test_factorisation_on_threads_is_the_one_thread_factorisation(monkeypatch, threads):
    """The supernodal factorisation with its subtrees on threads gives the one-thread factor to the
    last bit (the updates of the top of the tree taken in the one-thread order), and a singular
    pivot names the column one thread names, also when two subtrees fail."""
    from striptri.selected_inverse import supernodal

    monkeypatch.setattr(supernodal, "chunk_threads", lambda: threads)
    N, starts = block(8, 15, 1, seed=9)

    def factor(min_work):
        monkeypatch.setattr(supernodal, "PARALLEL_MIN_WORK", min_work)
        return selected_inverse(N, starts, method="sparse")._engine

    one = factor(np.inf)
    calls = []
    real = supernodal.SupernodalInverse._factor_on_threads
    monkeypatch.setattr(supernodal.SupernodalInverse, "_factor_on_threads",
                        lambda self, L, n: calls.append(n) or real(self, L, n))
    many = factor(0.0)
    assert calls == [threads]
    top, subtrees = many.sym.split(threads)
    assert len(subtrees) >= 2 and len(top)
    np.testing.assert_array_equal(many.L, one.L)
    np.testing.assert_array_equal(many.Z, one.Z)
    bad = N.tolil()
    for col in (30, 500):  # negative pivots in different subtrees
        bad[col, col] = -bad[col, col]
    columns = []
    for min_work in (np.inf, 0.0):
        monkeypatch.setattr(supernodal, "PARALLEL_MIN_WORK", min_work)
        with pytest.raises(SingularNormalMatrix) as caught:
            selected_inverse(bad.tocsr(), starts, method="sparse")
        columns.append(caught.value.column)
    assert columns[0] == columns[1] is not None


def test_supernodes_through_scipys_wrappers(monkeypatch):
    """Without the ctypes kernels (solvers.kernels falls back to scipy's f2py wrappers) the
    supernodal route gives the dense inverse too, on threads as on one."""
    from striptri.selected_inverse import supernodal
    from striptri.solvers import kernels

    monkeypatch.setattr(kernels, "_routine", lambda module, name: None)
    monkeypatch.setattr(supernodal, "PARALLEL_MIN_WORK", 0.0)
    monkeypatch.setattr(supernodal, "chunk_threads", lambda: 2)
    N, starts = block(5, 12, 1, seed=11)
    pairs = [(0, 12), (30, 31)]
    check_blocks(N, selected_inverse(N, starts, pairs, method="sparse"), pairs)


@pytest.mark.parametrize("min_block", [1, 7, 32, 500])
def test_banded_block_size(monkeypatch, min_block):
    """Column blocks of the banded recurrence exactly w wide, wider, or the whole matrix."""
    import striptri.selected_inverse as si

    monkeypatch.setattr(si, "MIN_BAND_BLOCK", min_block)
    N, starts = strip(25, 1, seed=9)
    inv = selected_inverse(N, starts, [(0, 2), (3, 24)], method="banded")
    check_blocks(N, inv, [(0, 2), (3, 24)])


@pytest.mark.parametrize("method", ["banded", "sparse"])
def test_photos_sharing_points_need_no_solves(monkeypatch, method):
    """The blocks of photos that share a point lie in the computed pattern: no columns solved for."""
    import striptri.selected_inverse as si

    N, starts = block(3, 10, 1, seed=6)
    pairs = [(p, p + 1) for p in range(9)] + [(p, p + 2) for p in range(8)] + [(p, p + 10) for p in range(20)]
    pairs += [(p, 30) for p in range(30)]  # every photo with the camera
    engine = si.BandedInverse if method == "banded" else si.SupernodalInverse
    monkeypatch.setattr(engine, "solve", lambda self, B: pytest.fail("solved for columns"))
    if method == "banded":
        monkeypatch.setattr(engine, "_solved_banded", lambda self, r, c: pytest.fail("solved for columns"))
    inv = selected_inverse(N, starts, pairs, method=method)
    check_blocks(N, inv, pairs)


@pytest.mark.parametrize("method", ROUTES)
def test_entries_of_point_groups(method):
    """entries(): N^-1 on the unknowns of every point group at once (triangulation, Qvv), in the
    pattern for photos that share a point; broadcast shapes, -1 reading zero, far entries too."""
    N, starts = strip(30, 1, seed=11)
    ref = np.pad(dense_inverse(N), ((0, 1), (0, 1)))
    inv = selected_inverse(N, starts, method=method)
    photos = np.array([[p, p + 1, p + 2] for p in range(28)])  # triple points
    cols = np.concatenate([6 * photos[:, :, None] + np.arange(6), np.full((28, 3, 3), [180, 181, 182])], 2)
    cols = cols.reshape(28, -1)
    cols[5, 4] = -1  # a fixed element
    got = inv.entries(cols[:, :, None], cols[:, None, :])
    want = ref[cols[:, :, None], cols[:, None, :]]
    assert got.shape == (28, 27, 27)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max())
    far = inv.entries(np.array([0, 3, 179]), np.array([[170], [5]]))  # (2, 3) by broadcasting
    np.testing.assert_allclose(far, ref[np.array([0, 3, 179]), np.array([[170], [5]])], rtol=1e-8,
                               atol=1e-10 * np.abs(ref).max())
    with pytest.raises(IndexError):
        inv.entries(np.array([183]), np.array([0]))


@pytest.mark.parametrize("method", ROUTES)
def test_block_entries_equal_entries(method):
    """block_entries(): the blocks between column sets, the same numbers to the last bit as
    entries() (on the sparse routes one lookup a block): a photo with itself, with another either
    way round, with the camera; a fixed element, a column shared by two photos, columns apart in
    the order and pairs outside the computed pattern go through entries()."""
    N, starts = block(4, 10, 1, seed=8)
    inv = selected_inverse(N, starts, method=method)
    photos = 6 * np.arange(40)[:, None] + np.arange(6)
    rng = np.random.default_rng(5)
    a, b = rng.integers(0, 40, 300), rng.integers(0, 40, 300)
    a[:40] = b[:40] = np.arange(40)
    a[40:70], b[40:70] = np.arange(30), np.arange(30) + 10  # neighbours in the next strip
    ca, cb = photos[a], photos[b]
    ca[80, 2] = -1
    cb[81, 0] = ca[81, 0]
    cb[82] = cb[82][::-1]
    got = inv.block_entries(ca, cb)
    np.testing.assert_array_equal(got, inv.entries(ca[:, :, None], cb[:, None, :]))
    np.testing.assert_array_equal(inv.block_entries(cb, ca), inv.entries(cb[:, :, None], ca[:, None, :]))
    camera = np.tile(240 + np.arange(3), (len(a), 1))
    np.testing.assert_array_equal(inv.block_entries(ca, camera), inv.entries(ca[:, :, None], camera[:, None, :]))
    ref = np.pad(dense_inverse(N), ((0, 1), (0, 1)))
    want = ref[ca[:, :, None], cb[:, None, :]]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    if method in ("sparse", "cholmod"):  # the photo pairs of the pattern were read a block at a time
        _, ok = inv._engine.block_lookup(photos[a[:70]], photos[b[:70]])
        assert ok.all()
        _, ok = inv._engine.block_lookup(ca[80:83], cb[80:83])
        assert not ok.any()


def test_banded_route_passes_once_for_many_requests(monkeypatch):
    """The first request fills the band of the inverse; later requests (the chunks of
    covariance.group_forms) read it without another pass over the factor, and stay exact."""
    import striptri.selected_inverse as si

    calls = []
    original = si.BandedInverse._pass
    monkeypatch.setattr(si.BandedInverse, "_pass", lambda self, band: (calls.append(1), original(self, band)))
    N, starts = strip(40, 1, seed=12)
    ref = dense_inverse(N)
    inv = selected_inverse(N, starts, [(p, p + 1) for p in range(39)], method="banded")
    rng = np.random.default_rng(3)
    for _ in range(5):
        rows = rng.integers(0, N.shape[0], 200)
        cols = np.clip(rows + rng.integers(-20, 21, 200), 0, N.shape[0] - 1)  # within and beyond the band
        np.testing.assert_allclose(inv.entries(rows, cols), ref[rows, cols], rtol=1e-9, atol=1e-12 * abs(ref).max())
    assert len(calls) == 1, len(calls)
