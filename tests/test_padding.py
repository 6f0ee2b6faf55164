"""equations.padding (issue 29): on long tracks of many lengths, the per-point work (the bundle's
linearisation, the intersection of the rays, the collinearity form's residual cofactors) joins
small batches of neighbouring ray counts, padding the shorter tracks with rays of weight zero. The
padded rays add exact zeros to every sum, so the results equal those batch by batch but for the
order of the sums: to 1e-12 relative here (the round-off of a 3x3 inverse of a well-conditioned
point, a few eps times its condition)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from striptri.adjustment import adjust
from striptri.core.options import AdjustmentOptions
from striptri.equations import padding
from striptri.equations.observations import observations_of
from striptri.equations.triangulation import GivenCoordinates, RayObservations, triangulate
from striptri.io import read_project
from striptri.precision import collinearity_form

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import close_range  # noqa: E402

RTOL = 1e-12


def test_the_rule_joins_small_batches_of_neighbouring_counts_within_the_bound():
    ks = [2, 3, 30, 31, 32, 40, 1, 5, 33]
    sizes = [5, 200, 3, 2, 4, 3, 7, 0, 2]
    groups = padding.joined(ks, sizes)
    assert sorted(i for g in groups for i in g) == list(range(len(ks)))  # every batch exactly once
    assert [1] in groups and [6] in groups and [7] in groups  # large, single-ray and empty: alone
    for g in groups:
        assert [ks[i] for i in g] == sorted(ks[i] for i in g)  # in order of k, the largest last
        real = sum(ks[i] * sizes[i] for i in g)
        assert sum(sizes[i] for i in g) * ks[g[-1]] <= (1 + padding.MAX_PADDING) * real
    assert [2, 3, 4, 8] in groups  # 30 to 33 rays: 5 % padded; with the 40 rays 20 %


def test_count_groups_hold_every_point_once_and_padded_rows_repeat_the_last_ray():
    rng = np.random.default_rng(1)
    counts = rng.integers(1, 60, size=300)
    points = np.flatnonzero(counts != 7)
    groups = padding.count_groups(counts, points)
    exact = padding.count_groups(counts, points, join=False)
    assert len(groups) < len(exact)
    assert all(np.all(counts[p] == k) for k, p in exact)
    assert sorted(np.concatenate([p for _, p in groups]).tolist()) == points.tolist()
    assert all(np.all(counts[p] <= k) for k, p in groups)
    order = rng.permutation(int(counts.sum()))  # the rows of the rays, sorted by point
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k, p = max(groups, key=lambda g: len(g[1]))
    rows, real = padding.padded_rows(order, starts, counts, p, k)
    for i, point in enumerate(p):
        n = counts[point]
        np.testing.assert_array_equal(rows[i, :n], order[starts[point]: starts[point] + n])
        assert real[i, :n].all() and not real[i, n:].any()
        assert (rows[i, n:] == rows[i, n - 1]).all()


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """24 photos, 40 targets, 7 to 20 rays per target (batches of 1 to 6 points), c, xp, yp, k1, k2
    free: adjusted by the bundle."""
    net = close_range.make_close_range(24, 40, seed=3)
    project = read_project(close_range.write_close_range(tmp_path_factory.mktemp("cr") / "p", net))
    result = adjust(project, AdjustmentOptions(method="bundle"))
    assert result.converged
    counts = np.bincount(project.image_points.point_index)
    groups = padding.count_groups(counts, np.flatnonzero(counts > 0))
    assert len(groups) < len(np.unique(counts[counts > 0])) / 2  # the padding is in play
    return project, result


def _unjoined(monkeypatch, compute):
    monkeypatch.setattr(padding, "SMALL_BATCH", 1)  # no batch is small: batch by batch
    out = compute()
    monkeypatch.undo()
    return out


def _assert_close(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    scale = np.max(np.abs(b[ok])) if ok.any() else 1.0
    np.testing.assert_allclose(a[ok], b[ok], rtol=RTOL, atol=RTOL * scale)


def test_triangulation_with_padded_rays_equals_it_batch_by_batch(solved, monkeypatch):
    project, result = solved
    ip = project.image_points
    # the measured plate coordinates: the rays do not meet, the residuals are not zero
    rays = RayObservations(photo_index=ip.photo_index, point_index=ip.point_index, xy_plate=ip.xy,
                           sigma_xy=ip.sigma_xy, xy_measured=ip.xy)
    control = GivenCoordinates(xyz_ground=result.control_adjusted, given=project.points.given_axes,
                               q_given=observations_of(project, result.offset).q_control)

    def compute():
        return triangulate(rays, control, state=result.state, layout=result.layout, Qxx=result.covariance,
                           with_residuals=True)

    padded, plain = compute(), _unjoined(monkeypatch, compute)
    assert padded.determined.all() and np.array_equal(padded.determined, plain.determined)
    assert np.array_equal(padded.weak, plain.weak)
    assert np.abs(plain.residuals).max() > 1e-4  # real residuals, every ray's written
    for name in ("xyz", "cov_measurement", "cov_orientation", "residuals"):
        _assert_close(getattr(padded, name), getattr(plain, name))


def test_residual_cofactors_with_padded_rays_equal_them_batch_by_batch(solved, monkeypatch):
    project, result = solved

    def compute():
        return collinearity_form.residual_cofactors(project, result, plate_blocks=True)

    padded, plain = compute(), _unjoined(monkeypatch, compute)
    assert (plain.plate > 0).all()
    _assert_close(padded.plate, plain.plate)
    _assert_close(padded.control, plain.control)
    assert np.array_equal(padded.imprecise, plain.imprecise)
    _assert_close(padded.points.cov_orientation, plain.points.cov_orientation)

    def by_row(blocks):  # the plate block of each point, keyed by its first row
        return {int(rows[0]): (rows, q) for chunk_rows, chunk_q in blocks for rows, q in zip(chunk_rows, chunk_q)}

    a, b = by_row(padded.plate_blocks), by_row(plain.plate_blocks)
    assert a.keys() == b.keys() and len(a) == len(project.points)
    for key, (rows, q) in b.items():
        np.testing.assert_array_equal(a[key][0], rows)
        _assert_close(a[key][1], q)
