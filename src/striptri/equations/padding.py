"""Points of neighbouring ray counts computed together, the shorter tracks padded with rays of weight zero.

The per-point work (the bundle's linearisation, the intersection of the adjusted rays, the
residual cofactors of the collinearity form) is batched by the number of rays k, so that a batch
is a few array operations. On long tracks the counts spread widely (close range: 30 to 93 rays per
target), so 150 targets make some 60 batches of two or three points, and each pays numpy's cost
per call 60 times. Here neighbouring counts are joined into one batch of the largest k among them:
a point with fewer rays repeats its last ray, and the caller gives the repeated rays weight zero,
so that they add exact zeros to every sum (and, repeating a real ray, give only finite numbers);
the results are read for the real rays only.

The join: batches of fewer than SMALL_BATCH points (a larger one pays its call overhead already),
in order of k, as long as the padded rays stay within MAX_PADDING of the real ones. Batches of
single rays are never joined: a point on one photo is not intersected but met with its given
coordinates, which a padded second ray would hide.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

# padded rays at most this fraction of the real rays of a joined batch (0.1: measured best at close range)
MAX_PADDING = 0.1
SMALL_BATCH = 64  # batches of fewer points are joined; a larger one pays its call overhead already


def joined(ks: Sequence[int], sizes: Sequence[int]) -> list[list[int]]:
    """Which batches (of ks rays and sizes points each) to compute together: lists of their
    indices, each list in order of k (its last the largest). Batches of SMALL_BATCH points or more,
    empty ones and those of single rays stay alone; the small ones are joined in order of k while
    the padded rays stay within MAX_PADDING of the real rays. Every batch is in exactly one list."""
    out: list[list[int]] = []
    small = []
    for i, (k, n) in enumerate(zip(ks, sizes)):
        if 0 < n < SMALL_BATCH and k >= 2:
            small.append(i)
        else:
            out.append([i])
    small.sort(key=lambda i: ks[i])
    group: list[int] = []
    for i in small:
        rays = sum(sizes[j] * ks[j] for j in group) + sizes[i] * ks[i]
        if group and (sum(sizes[j] for j in group) + sizes[i]) * ks[i] > (1 + MAX_PADDING) * rays:
            out.append(group)
            group = []
        group.append(i)
    if group:
        out.append(group)
    return out


def count_groups(counts: np.ndarray, points: np.ndarray, join: bool = True) -> list[tuple[int, np.ndarray]]:
    """The points (indices into counts, the rays of every point) grouped by their ray count: (k,
    the points of that group), points of neighbouring counts joined (:func:`joined`) under the
    largest k among them unless join is False, in order of k."""
    points = np.asarray(points)
    ks, sizes = np.unique(counts[points], return_counts=True)
    by_count = points[np.argsort(counts[points], kind="stable")]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    parts = [by_count[starts[i]: starts[i + 1]] for i in range(len(ks))]
    if not join:
        return [(int(k), p) for k, p in zip(ks, parts)]
    groups = joined([int(k) for k in ks], [len(p) for p in parts])
    groups.sort(key=lambda g: ks[g[-1]])
    return [(int(ks[g[-1]]), np.concatenate([parts[i] for i in g])) for g in groups]


def padded_rows(order: np.ndarray, starts: np.ndarray, counts: np.ndarray, points: np.ndarray,
                k: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows (m, k) of the rays of the points (m,) of a group of up to k rays, and which are real
    (m, k): ``order[starts[p] + j]`` is ray j of point p (its rays sorted by point), a point of
    fewer rays repeating its last."""
    n = counts[points][:, None]
    j = np.arange(k)[None, :]
    return order[starts[points][:, None] + np.minimum(j, n - 1)], j < n
