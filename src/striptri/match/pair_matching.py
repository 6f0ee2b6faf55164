"""Matching the features of a pair of photos and verifying the matches geometrically.

Descriptors are matched both ways (nearest neighbours, L2); a match is kept when it is mutual and
passes Lowe's ratio test (the nearest neighbour clearly nearer than the second). The survivors are
verified by RANSAC on the fundamental matrix (OpenCV's USAC MAGSAC++): the epipolar geometry of
two central projections, which needs no calibration and no approximate orientation. A pair with
fewer than MIN_VERIFIED inliers is dropped: it does not overlap, or it is a repeated pattern.

Flat terrain under near-vertical photographs is the planar degeneracy of the fundamental matrix:
every match fits a homography, and F is not unique. OpenCV 5.0's USAC estimators then stop with an
assertion instead of a model (measured on rendered photos of a plane, tests/test_match_images.py);
the classic RANSAC (FM_RANSAC) returns one of the F consistent with the plane, whose inliers are
the matches that fit it, which is all verification needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features import Features, cv2_module

RATIO = 0.8  # Lowe's ratio test
RANSAC_PX = 1.5  # the epipolar distance (full-resolution pixels) of an inlier
MIN_VERIFIED = 15  # verified matches a pair needs (the fundamental matrix has 7 degrees of freedom)


@dataclass(frozen=True)
class PairMatches:
    """The verified matches of a pair: i, j (k,) feature numbers in the first and the second photo;
    distance (k,) descriptor distance (smaller is better); candidates: the matches before the
    geometric verification."""

    i: np.ndarray
    j: np.ndarray
    distance: np.ndarray
    candidates: int


def match_descriptors(a: Features, b: Features, ratio: float = RATIO) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual nearest neighbours that pass the ratio test -> (i, j, distance)."""
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
    if len(a) < 2 or len(b) < 2:
        return empty
    cv2 = cv2_module()
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    ab = matcher.knnMatch(a.descriptors, b.descriptors, k=2)
    ba = matcher.knnMatch(b.descriptors, a.descriptors, k=1)
    best_ba = np.full(len(b), -1, dtype=np.int64)
    for m in ba:
        if m:
            best_ba[m[0].queryIdx] = m[0].trainIdx
    rows = [(m[0].queryIdx, m[0].trainIdx, m[0].distance) for m in ab
            if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    if not rows:
        return empty
    i, j, d = (np.array(col) for col in zip(*rows))
    mutual = best_ba[j] == i
    return i[mutual].astype(np.int64), j[mutual].astype(np.int64), d[mutual].astype(float)


def match_pair(a: Features, b: Features, ratio: float = RATIO, ransac_px: float = RANSAC_PX,
               min_verified: int = MIN_VERIFIED, seed: int = 0) -> PairMatches:
    """The verified matches of two photos' features (module doc); empty when the pair does not hold."""
    i, j, d = match_descriptors(a, b, ratio)
    if len(i) < max(min_verified, 8):
        return PairMatches(i[:0], j[:0], d[:0], len(i))
    cv2 = cv2_module()
    cv2.setRNGSeed(seed)
    try:
        _, inlier = cv2.findFundamentalMat(a.xy[i], b.xy[j], cv2.USAC_MAGSAC, ransac_px, 0.9999, 10000)
    except cv2.error:  # a planar scene (module doc): the classic RANSAC still finds an F of the plane
        _, inlier = cv2.findFundamentalMat(a.xy[i], b.xy[j], cv2.FM_RANSAC, ransac_px, 0.9999, 10000)
    ok = np.zeros(len(i), dtype=bool) if inlier is None else inlier.ravel().astype(bool)
    if ok.sum() < min_verified:
        ok[:] = False
    return PairMatches(i[ok], j[ok], d[ok], len(i))
