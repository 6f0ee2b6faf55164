"""bundle.padding (issue 11): on long tracks of many different lengths the bundle joins small
batches into few, padding the shorter tracks with rays of weight zero. The joined batches hold
every point once with its own rays in order; the adjustment gives what it gives unpadded (the
padded rays add exact zeros; only the order of the sums changes), and the back substitution and the
final checks read only the real rays."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from striptri.adjustment import adjust
from striptri.bundle import adjust as bundle_adjust
from striptri.bundle import padding
from striptri.equations import padding as join_rule
from striptri.core.options import AdjustmentOptions
from striptri.equations.groups import build_batches
from striptri.io import read_project

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import close_range  # noqa: E402


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """24 photos, 40 targets, 7 to 20 rays per target, c, xp, yp, k1, k2 free: summed dense."""
    net = close_range.make_close_range(24, 40, seed=3)
    return read_project(close_range.write_close_range(tmp_path_factory.mktemp("cr") / "p", net))


def test_joined_batches_hold_every_point_once_with_its_rays(project):
    batches = build_batches(project, chains=False)
    joined = padding.pad_batches(batches)
    assert len(joined) < len(batches)  # small batches of neighbouring k were joined
    assert any(isinstance(b, padding.PaddedBatch) for b in joined)
    rows_of = {int(p): r for b in batches for p, r in zip(b.point_index, b.image_rows)}
    seen = np.concatenate([b.point_index for b in joined])
    assert sorted(seen.tolist()) == sorted(rows_of)  # every point exactly once
    real_rays = padded_rays = 0
    for b in joined:
        real = b.real if isinstance(b, padding.PaddedBatch) else np.ones(b.image_rows.shape, dtype=bool)
        for p, rows, ok in zip(b.point_index, b.image_rows, real):
            own = rows_of[int(p)]
            n = len(own)
            assert ok[:n].all() and not ok[n:].any()  # the real rays first
            np.testing.assert_array_equal(rows[:n], own)  # in their chain order
            assert (rows[n:] == own[-1]).all()  # the padding repeats the last ray
            real_rays += n
            padded_rays += len(rows) - n
        np.testing.assert_array_equal(b.photo_index, project.image_points.photo_index[b.image_rows])
        if isinstance(b, padding.PaddedBatch):
            assert b.real.sum() * (1 + join_rule.MAX_PADDING) >= b.real.size
    assert 0 < padded_rays <= join_rule.MAX_PADDING * real_rays


def test_large_batches_are_kept_as_they_are(project, monkeypatch):
    batches = build_batches(project, chains=False)
    monkeypatch.setattr(join_rule, "SMALL_BATCH", 1)  # no batch is small
    assert padding.pad_batches(batches) == batches


def test_chunks_of_a_padded_batch_keep_their_mask(project):
    joined = [b for b in padding.pad_batches(build_batches(project, chains=False))
              if isinstance(b, padding.PaddedBatch) and len(b) > 2]
    assert joined
    b = joined[0]
    parts = list(b.chunks(2))
    assert all(isinstance(c, padding.PaddedBatch) for c in parts)
    np.testing.assert_array_equal(np.concatenate([c.real for c in parts]), b.real)
    np.testing.assert_array_equal(np.concatenate([c.image_rows for c in parts]), b.image_rows)


def _adjusted(project, monkeypatch, padded: bool):
    if not padded:
        monkeypatch.setattr(bundle_adjust, "pad_batches", lambda batches: batches)
    result = adjust(project, AdjustmentOptions(method="bundle", chunk_size=7))
    monkeypatch.undo()
    return result


def test_the_adjustment_padded_equals_the_adjustment_unpadded(project, monkeypatch):
    """Orientations, interior orientation, points' residuals, v^T P v and Schmid's checks to
    round-off. The checks would show padded rays read as real ones: their misclosure
    e + v / sigma is the real ray's v / sigma, not zero."""
    calls = []
    original = bundle_adjust.linearise_points
    monkeypatch.setattr(bundle_adjust, "linearise_points",
                        lambda batch, *a, **k: calls.append(batch) or original(batch, *a, **k))
    padded = adjust(project, AdjustmentOptions(method="bundle", chunk_size=7))
    assert any(isinstance(b, padding.PaddedBatch) for b in calls)  # the padded path ran
    monkeypatch.undo()
    plain = _adjusted(project, monkeypatch, padded=False)
    assert padded.iterations == plain.iterations
    for a, b in ((padded.state.xyz0, plain.state.xyz0), (padded.state.interior, plain.state.interior),
                 (padded.state.R_ground_from_cam, plain.state.R_ground_from_cam)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    scale = np.abs(plain.plate_residuals).max()
    np.testing.assert_allclose(padded.plate_residuals, plain.plate_residuals, rtol=0, atol=1e-9 * scale)
    assert padded.vtpv == pytest.approx(plain.vtpv, rel=1e-10)
    assert padded.checks.max_condition_misclosure_sigma < 1e-6
    assert padded.checks.max_point_gradient_sigma < 1e-6
    assert padded.checks.max_BTk_sigma < 1e-6
