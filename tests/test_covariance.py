"""covariance.Covariance (selected inversion) against dense references: N^-1 with control, and the
inner-constraint inverse of a free network."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.selected_inverse.covariance import Covariance, Slots
from striptri.io import read_project

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


def _scaled_inverse(N):
    d = np.sqrt(N.diagonal())
    return np.linalg.inv((N / d[:, None]) / d[None, :]) / d[:, None] / d[None, :]


def _free(project):
    k = np.where(project.points.kind == model.FULL, model.TIE, project.points.kind)
    g = np.where((project.points.kind == model.FULL)[:, None], np.nan, project.points.xyz_given)
    return replace(project, points=replace(project.points, kind=k, xyz_given=g))


@pytest.fixture(scope="module", params=["strip8", "block_3x6", "free strip8"])
def case(request):
    if request.param.startswith("free"):
        project = _free(read_project(DATA / "strip8"))
        r = adjust(project, AdjustmentOptions(datum="inner"))
        N = r.N.toarray()
        d = np.sqrt(N.diagonal())
        reference = np.linalg.pinv((N / d[:, None]) / d[None, :], rcond=1e-10) / d[:, None] / d[None, :]
    else:
        r = adjust(read_project(DATA / request.param))
        reference = _scaled_inverse(r.N.toarray())
    return r, reference


def test_entries_equal_the_dense_reference(case):
    r, Q = case
    cov = Covariance(r.N, r.layout, r.free_network)
    scale = np.abs(Q).max()
    np.testing.assert_allclose(cov.dense(), Q, atol=1e-9 * scale)
    np.testing.assert_allclose(cov.diag(), np.diag(Q), atol=1e-9 * scale)
    cols = r.layout.photo_cols
    Qp = np.pad(Q, ((0, 1), (0, 1)))
    np.testing.assert_allclose(cov.photo_blocks(), Qp[cols[:, :, None], cols[:, None, :]], atol=1e-9 * scale)


def test_quadratic_form_of_a_function(case):
    r, Q = case
    cov = Covariance(r.N, r.layout, r.free_network)
    f = np.random.default_rng(0).normal(size=r.n_unknowns)
    assert cov.quadratic_form(f) == pytest.approx(f @ Q @ f, rel=1e-8)


def test_release_keeps_photo_blocks_and_diagonal_and_rebuilds_the_rest(case):
    """Covariance.release: the photo blocks and the diagonal stay, read without the inverse; other
    entries and the quadratic form make the inverse again and equal the dense reference. A free
    network is never released (its photo blocks are entries)."""
    r, Q = case
    cov = Covariance(r.N, r.layout, r.free_network)
    before = cov.photo_blocks(), cov.diag()
    released = cov.release()
    assert released == (r.free_network is None)
    scale = np.abs(Q).max()
    np.testing.assert_array_equal(cov.photo_blocks(), before[0])
    np.testing.assert_array_equal(cov.diag(), before[1])
    if released:
        assert not cov._inv._engine.rebuilt  # the blocks and the diagonal needed no inverse
    np.testing.assert_allclose(cov.dense(), Q, atol=1e-9 * scale)
    f = np.random.default_rng(1).normal(size=r.n_unknowns)
    assert cov.quadratic_form(f) == pytest.approx(f @ Q @ f, rel=1e-8)
    if released:
        assert cov._inv._engine.rebuilt


def test_blocks_read_once_and_equal_entries(case):
    """block_entries equals entries to the last bit (a free network reads entries); group_forms
    reads each block of Qxx once: a second batch over the same photos looks them up (no read, and
    no lock) and gives the same numbers, which equal G Q G^T of the dense reference."""
    r, Q = case
    cov = Covariance(r.N, r.layout, r.free_network)
    cols = r.layout.photo_cols
    a, b = np.arange(len(cols)), np.roll(np.arange(len(cols)), 1)
    np.testing.assert_array_equal(cov.block_entries(cols[a], cols[b]),
                                  cov.entries(cols[a][:, :, None], cols[b][:, None, :]))
    reads = []
    real = cov.block_entries
    cov.block_entries = lambda ca, cb: reads.append(len(ca)) or real(ca, cb)
    rng = np.random.default_rng(2)
    sets = np.stack([a, b, np.roll(a, 2)], axis=1)  # three photos a group
    G = rng.normal(size=(len(a), 4, 3, 6))
    first = cov.group_forms([Slots(G, sets, cols)])
    assert reads
    count = len(reads)
    again = cov.group_forms([Slots(G, sets, cols)])
    assert len(reads) == count
    np.testing.assert_array_equal(again, first)
    Qp = np.pad(Q, ((0, 1), (0, 1)))
    g = G.reshape(len(a), 4, 18)
    c = cols[sets].reshape(len(a), 18)
    want = g @ Qp[c[:, :, None], c[:, None, :]] @ np.swapaxes(g, 1, 2)
    np.testing.assert_allclose(first, want, atol=1e-8 * np.abs(want).max())


def test_a_release_keeping_blocks_keeps_those_its_group_forms_have_read(case):
    """Covariance.release(keep_blocks=True) (the pipeline's, before the point precision): group forms over the
    photo pairs read before give the same numbers without making the inverse again; other entries
    make it again and equal the dense reference. A free network is never released."""
    r, Q = case
    cov = Covariance(r.N, r.layout, r.free_network)
    cols = r.layout.photo_cols
    a = np.arange(len(cols))
    sets = np.stack([a, np.roll(a, 1), np.roll(a, 2)], axis=1)
    G = np.random.default_rng(3).normal(size=(len(a), 4, 3, 6))
    first = cov.group_forms([Slots(G, sets, cols)])
    released = cov.release(keep_blocks=True)
    assert released == (r.free_network is None)
    np.testing.assert_array_equal(cov.group_forms([Slots(G[::-1], sets[::-1], cols)]), first[::-1])
    if released:
        assert not cov._inv._engine.rebuilt  # read from the kept blocks
    scale = np.abs(Q).max()
    np.testing.assert_allclose(cov.dense(), Q, atol=1e-9 * scale)
    if released:
        assert cov._inv._engine.rebuilt
