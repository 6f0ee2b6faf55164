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

The inliers' Sampson distances to the epipolar geometry measure how well the features are
located: with independent errors of standard deviation sigma in each image coordinate, a correct
match's Sampson distance is normal with standard deviation sigma (its first-order distance from
the epipolar constraint, whose gradient over the four coordinates it is normalised by).
striptri match estimates sigma from them (:func:`sigma_from_epipolar`), except in a planar scene
(a homography fits PLANAR_SHARE of the inliers): there the fundamental matrix is not unique, the
one found also fits most of the noise, and the distances come out near zero (measured: 0.000 px on
rendered photos of a flat terrain, where MAGSAC++ did return an F).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features import Features, cv2_module

RATIO = 0.8  # Lowe's ratio test
RANSAC_PX = 1.5  # the epipolar distance (full-resolution pixels) of an inlier
ROWS_PER_CHUNK = 2048  # descriptors of the first photo per block of the distance matrix
PLANAR_SHARE = 0.95  # a pair is planar when a homography fits this share of the F inliers
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
    epipolar: np.ndarray | None = None  # (k,) the Sampson distances (px) to the verified F
    planar: bool = False  # the scene was planar (F not unique: its distances say nothing of the accuracy)


def sampson_distances(F: np.ndarray, xy1: np.ndarray, xy2: np.ndarray) -> np.ndarray:
    """Signed Sampson distances (px) of matches xy1 <-> xy2 (k, 2) to the fundamental matrix F
    (x2^T F x1 = 0): the epipolar residual over the norm of its gradient in the four coordinates.
    F (3, 3), or (k, 3, 3) one per match."""
    h1 = np.column_stack([xy1, np.ones(len(xy1))])
    h2 = np.column_stack([xy2, np.ones(len(xy2))])
    F = np.broadcast_to(F, (len(h1), 3, 3))
    Fx1, Ftx2 = np.einsum("nij,nj->ni", F, h1), np.einsum("nji,nj->ni", F, h2)
    e = np.einsum("ij,ij->i", h2, Fx1)
    return e / np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)


def sigma_from_epipolar(distances: np.ndarray) -> float:
    """The standard deviation (px) of an image coordinate, from the verified matches' Sampson
    distances (module doc): the normalised median absolute value, robust against the false
    matches still among them. nan without any."""
    d = np.abs(np.asarray(distances, dtype=float))
    return float(1.4826 * np.median(d)) if len(d) else float("nan")


def match_descriptors(a: Features, b: Features, ratio: float = RATIO) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual nearest neighbours that pass the ratio test -> (i, j, distance), distance the L2
    distance of the descriptors.

    Exhaustive, like OpenCV's brute-force matcher, but both directions come from one distance
    matrix, ``|a|^2 + |b|^2 - 2 a.b`` in single precision (a matrix product: 2,000 x 2,000
    descriptors in about 20 ms on one core, where two knnMatch calls took 160 ms), made
    ROWS_PER_CHUNK rows at a time so that memory stays bounded for large images. OpenCV's SIFT
    descriptors are whole numbers of norm about 512: every product and distance is a whole number
    far below 2^24, exact in single precision whatever the order of the sums."""
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
    if len(a) < 2 or len(b) < 2:
        return empty
    A = np.asarray(a.descriptors, dtype=np.float32)
    B = np.asarray(b.descriptors, dtype=np.float32)
    # the squared distances from one matrix product of the descriptors augmented by their norms:
    # [-2 a, |a|^2, 1] . [b, 1, |b|^2] = |a|^2 + |b|^2 - 2 a.b (no passes over the matrix to add them)
    A = np.hstack([-2.0 * A, np.einsum("ij,ij->i", A, A)[:, None], np.ones((len(A), 1), dtype=np.float32)])
    Bt = np.ascontiguousarray(np.hstack([B, np.ones((len(B), 1), dtype=np.float32),
                                         np.einsum("ij,ij->i", B, B)[:, None]]).T)
    first, d1, d2 = np.empty(len(A), dtype=np.int64), np.empty(len(A)), np.empty(len(A))
    col_min = np.full(len(B), np.inf, dtype=np.float32)
    for s in range(0, len(A), ROWS_PER_CHUNK):
        block = A[s:s + ROWS_PER_CHUNK]
        D = block @ Bt
        np.minimum(col_min, D.min(0), out=col_min)
        r = np.arange(len(block))
        best = D.argmin(1)
        rows = slice(s, s + len(block))
        first[rows], d1[rows] = best, D[r, best]
        D[r, best] = np.inf
        d2[rows] = D.min(1)
    # mutual: the row's nearest neighbour has no nearer row (squared distances, as computed)
    i = np.flatnonzero((d1 < ratio**2 * d2) & (d1 <= col_min[first]))
    d1 = np.sqrt(np.maximum(d1, 0.0))
    return i.astype(np.int64), first[i], d1[i]


def match_pair(a: Features, b: Features, ratio: float = RATIO, ransac_px: float = RANSAC_PX,
               min_verified: int = MIN_VERIFIED, seed: int = 0) -> PairMatches:
    """The verified matches of two photos' features (module doc); empty when the pair does not hold."""
    i, j, d = match_descriptors(a, b, ratio)
    if len(i) < max(min_verified, 8):
        return PairMatches(i[:0], j[:0], d[:0], len(i))
    cv2 = cv2_module()
    cv2.setRNGSeed(seed)
    planar = False
    try:
        F, inlier = cv2.findFundamentalMat(a.xy[i], b.xy[j], cv2.USAC_MAGSAC, ransac_px, 0.9999, 10000)
    except cv2.error:  # a planar scene (module doc): the classic RANSAC still finds an F of the plane
        F, inlier = cv2.findFundamentalMat(a.xy[i], b.xy[j], cv2.FM_RANSAC, ransac_px, 0.9999, 10000)
        planar = True
    ok = np.zeros(len(i), dtype=bool) if inlier is None or F is None else inlier.ravel().astype(bool)
    if ok.sum() < min_verified:
        ok[:] = False
    epipolar = sampson_distances(F[:3], a.xy[i[ok]], b.xy[j[ok]]) if ok.any() else np.zeros(0)
    if not planar and ok.any():  # a homography explaining (nearly) every inlier: a planar scene after all
        _, on_plane = cv2.findHomography(a.xy[i[ok]], b.xy[j[ok]], cv2.RANSAC, ransac_px, maxIters=2000,
                                         confidence=0.999)
        planar = on_plane is not None and on_plane.mean() >= PLANAR_SHARE
    return PairMatches(i[ok], j[ok], d[ok], len(i), epipolar, planar)
