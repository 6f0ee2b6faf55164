"""Features and pair matching on rendered photographs (issue 28): a textured flat terrain seen by
vertical photographs of known orientation. The second photo flies higher and is turned by 90
degrees, so that an error in the pixel convention or in carrying features back from a reduced
image does not cancel between the two; the verified matches must agree with the true geometry
to the accuracy of SIFT's localisation."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

cv2 = pytest.importorskip("cv2")

from striptri.match.features import detect  # noqa: E402
from striptri.match.pair_matching import match_pair  # noqa: E402
from striptri.match.tracks import build_tracks  # noqa: E402

W, H = 800, 600  # image size (px)
FEATURES = 1500  # per image: enough for the statistics, and quick to match


@functools.lru_cache(maxsize=1)
def _texture(n: int = 1400, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.normal(size=(n, n)), 1.5) + 0.6 * gaussian_filter(rng.normal(size=(n, n)), 5.0)
    t = (t - t.min()) / (t.max() - t.min())
    return (255 * t).astype(np.uint8)


def _ground_to_pixel(centre, height, kappa_deg, ground_per_px):
    """The homography (3, 3) of a vertical photo from ground X, Y (m; the texture's texel edges at
    integers, 1 m per texel, Y along the texture's rows) to pixel column, row (top-left corner origin)."""
    k = np.radians(kappa_deg)
    Rk = np.array([[np.cos(k), np.sin(k)], [-np.sin(k), np.cos(k)]])
    s = 1.0 / (ground_per_px * height)
    A = s * Rk
    M = np.eye(3)
    M[:2, :2] = A
    M[:2, 2] = np.array([W / 2, H / 2]) - A @ np.asarray(centre, dtype=float)
    return M


def _render(texture, M):
    """The photo of homography M (edge convention) rendered by OpenCV (pixel centres at integers)."""
    shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # OpenCV -> edge coordinates
    to_cv = np.linalg.inv(shift) @ M @ shift
    return cv2.warpPerspective(texture, to_cv, (W, H), flags=cv2.INTER_CUBIC)


def _apply(M, xy):
    p = np.column_stack([xy, np.ones(len(xy))]) @ M.T
    return p[:, :2] / p[:, 2:]


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_verified_matches_agree_with_the_true_geometry(scale):
    texture = _texture()
    M1 = _ground_to_pixel((700.0, 700.0), 1.0, 0.0, 1.0)  # 1 m per pixel
    M2 = _ground_to_pixel((760.0, 690.0), 1.3, 90.0, 1.0)  # 1.3 m per pixel, turned by 90 degrees
    img1, img2 = _render(texture, M1), _render(texture, M2)
    f1, f2 = detect(img1, scale, FEATURES), detect(img2, scale, FEATURES)
    assert len(f1) > 300 and len(f2) > 300
    pair = match_pair(f1, f2)
    assert len(pair.i) > 100
    predicted = _apply(M2 @ np.linalg.inv(M1), f1.xy[pair.i])
    error = np.linalg.norm(predicted - f2.xy[pair.j], axis=1)
    # SIFT localises to a few hundredths of a pixel on noise-free texture at the level it runs on
    # (a pixel there is 1/scale here); 0.1 px leaves room for interpolation in the rendering
    assert np.median(error) < 0.1 / scale
    assert np.mean(error < 1.5 / scale) > 0.98  # the verification leaves next to no false matches
    # the conventions matter: OpenCV's pixel centres at integers taken for corners, or its SIFT's
    # default upscaling (keypoints 0.25 px off on the level it runs on), would shift every feature
    for shift in (-0.5 / scale, 0.25 / scale):
        wrong = _apply(M2 @ np.linalg.inv(M1), f1.xy[pair.i] + shift)
        assert np.median(np.linalg.norm(wrong - (f2.xy[pair.j] + shift), axis=1)) > 2 * np.median(error)


def test_three_photos_give_tracks_of_three_rays():
    texture = _texture()
    Ms = [_ground_to_pixel((600.0 + 120.0 * k, 700.0), 1.0, 0.0, 1.0) for k in range(3)]
    feats = [detect(_render(texture, M), 1.0, FEATURES) for M in Ms]
    offsets = np.cumsum([0] + [len(f) for f in feats])
    photo = np.repeat(np.arange(3), [len(f) for f in feats])
    a, b, score = [], [], []
    for p, q in ((0, 1), (1, 2), (0, 2)):
        m = match_pair(feats[p], feats[q])
        a.append(offsets[p] + m.i), b.append(offsets[q] + m.j), score.append(m.distance)
    t = build_tracks(photo, np.concatenate(a), np.concatenate(b), np.concatenate(score))
    lengths = t.lengths()
    assert (lengths == 3).sum() > 50
    # every track's rays meet one ground point
    for k in np.flatnonzero(lengths == 3)[:200]:
        rows = np.flatnonzero(t.track == k)
        ground = [_apply(np.linalg.inv(Ms[photo[r]]), feats[photo[r]].xy[[r - offsets[photo[r]]]])[0] for r in rows]
        assert np.ptp(np.array(ground), axis=0).max() < 2.0


def test_a_large_image_is_worked_on_in_tiles_with_the_same_features(monkeypatch):
    """SIFT over tiles (match.features.TILE, with TILE_MARGIN of context) against SIFT over the
    whole image, 2,000 x 2,000 px (4 tiles): the same strongest 8,000 features. Measured on 2,600
    px: 99.975 % of either set in the other (the same place within 0.01 px and descriptor within 5
    %); the rest are large keypoints at a tile's border, whose window the margin does not hold."""
    from scipy.spatial import cKDTree

    from striptri.match import features

    rng = np.random.default_rng(3)
    t = gaussian_filter(rng.normal(size=(2000, 2000)), 2.0) + 0.5 * gaussian_filter(rng.normal(size=(2000, 2000)), 8.0)
    image = (255 * (t - t.min()) / np.ptp(t)).astype(np.uint8)
    tiled = features.detect(image, 1.0, 8000)
    monkeypatch.setattr(features, "TILE", 10 ** 6)
    whole = features.detect(image, 1.0, 8000)

    def share_in(a, b):
        d, i = cKDTree(b.xy).query(a.xy, k=4, distance_upper_bound=0.01)
        same = np.zeros(len(a), dtype=bool)
        for k in range(4):
            near = np.isfinite(d[:, k])
            other = b.descriptors[i[near, k]]
            same[near] |= np.linalg.norm(a.descriptors[near] - other, axis=1) < 0.05 * np.linalg.norm(other, axis=1)
        return same.mean()

    assert abs(len(tiled) - 8000) <= 2 and abs(len(whole) - 8000) <= 2
    assert share_in(tiled, whole) >= 0.995 and share_in(whole, tiled) >= 0.995


def test_an_8_bit_grey_tiff_is_read_by_tifffile_as_opencv_reads_it(tmp_path):
    """read_grey: an 8-bit grey TIFF in strips through tifffile (one full-size array, not OpenCV's
    two: scripts/bench/bench_scan_memory.py) gives OpenCV's pixels; a 16-bit one goes to OpenCV."""
    pytest.importorskip("tifffile")
    from striptri.match import features

    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, size=(300, 200), dtype=np.uint8)
    path = tmp_path / "scan.tif"
    cv2.imwrite(str(path), grey, [cv2.IMWRITE_TIFF_ROWSPERSTRIP, 16])  # LZW: tifffile decodes it with imagecodecs
    assert features._tiff_grey(path) is not None
    assert np.array_equal(features.read_grey(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    deep = tmp_path / "scan16.tif"
    cv2.imwrite(str(deep), grey.astype(np.uint16) * 257)
    assert features._tiff_grey(deep) is None
    assert np.array_equal(features.read_grey(deep), cv2.imread(str(deep), cv2.IMREAD_GRAYSCALE))
