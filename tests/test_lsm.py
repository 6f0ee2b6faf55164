"""Least-squares matching (match.lsm): tie points refined at full resolution against their
reference ray, in a photo turned by 178 degrees and scaled by 4 % (as a photo of the next strip,
flown the other way): features off by 0.4 px come within a few hundredths of a pixel of the
truth; a ray the template does not match keeps its feature's position."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from scipy.ndimage import gaussian_filter  # noqa: E402

from striptri.match.lsm import MAX_SHIFT, refine  # noqa: E402

N = 600


@pytest.fixture(scope="module")
def turned_pair(tmp_path_factory):
    """Two images of one texture, the second turned by 178 degrees, scaled by 1.04 and shifted:
    colrow2 = M colrow1 + b (pixel coordinates, corner origin); their paths and M, b."""
    rng = np.random.default_rng(1)
    tex = gaussian_filter(rng.normal(size=(N, N)), 2.0) + 0.5 * gaussian_filter(rng.normal(size=(N, N)), 6.0)
    tex = ((tex - tex.min()) / (tex.max() - tex.min()) * 200 + 20).astype(np.float32)
    angle, scale = np.radians(178.0), 1.04
    M = scale * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    b = np.array([590.0, 610.0])
    Minv = np.linalg.inv(M)
    # warpAffine with WARP_INVERSE_MAP maps each output index to an input index (centres at integers)
    A = np.column_stack([Minv, Minv @ (np.array([0.5, 0.5]) - b) - 0.5])
    turned = cv2.warpAffine(tex, A, (N, N), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
    root = tmp_path_factory.mktemp("lsm")
    paths = [root / "a.png", root / "b.png"]
    for path, image in zip(paths, (tex, turned)):
        cv2.imwrite(str(path), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    return paths, M, b


def test_features_off_by_half_a_pixel_are_refined_to_hundredths(turned_pair):
    paths, M, b = turned_pair
    rng = np.random.default_rng(2)
    first = rng.uniform(150, 450, (40, 2))
    truth = first @ M.T + b
    inside = (truth > 40).all(1) & (truth < N - 40).all(1)
    first, truth = first[inside], truth[inside]
    noisy = truth + rng.normal(0.0, 0.4, truth.shape)
    colrow = np.empty((2 * len(first), 2))
    colrow[0::2], colrow[1::2] = first, noisy
    track, photo = np.repeat(np.arange(len(first)), 2), np.tile([0, 1], len(first))
    r = refine(track, photo, colrow, paths, workers=1)
    before = np.linalg.norm(noisy - truth, axis=1)
    after = np.linalg.norm(r.colrow[1::2] - truth, axis=1)
    assert r.refined[1::2].all() and not r.refined[0::2].any()  # the reference rays stay
    np.testing.assert_array_equal(r.colrow[0::2], first)
    assert np.median(before) > 0.3 and np.median(after) < 0.03 and after.max() < 0.08
    assert np.nanmin(r.correlation[1::2]) > 0.95


def test_a_ray_the_template_does_not_match_keeps_its_position(turned_pair):
    paths, M, b = turned_pair
    rng = np.random.default_rng(3)
    first = rng.uniform(200, 400, (12, 2))
    truth = first @ M.T + b
    given = truth.copy()
    given[0] += [25.0, -20.0]  # a false match: another place of the texture
    colrow = np.empty((2 * len(first), 2))
    colrow[0::2], colrow[1::2] = first, given
    track, photo = np.repeat(np.arange(len(first)), 2), np.tile([0, 1], len(first))
    r = refine(track, photo, colrow, paths, workers=2)
    assert not r.refined[1] and np.array_equal(r.colrow[1], given[0])
    assert r.refined[3::2].all() and np.abs(r.colrow[3::2] - truth[1:]).max() < 0.08
    assert (r.shift[1::2] <= MAX_SHIFT).all()
