"""Points of different ray counts linearised together, padded with rays of weight zero.

The bundle linearises its points batch by batch, one batch per number of rays k (groups.GroupBatch).
On long tracks the counts spread widely (close range: 30 to 93 rays per target), so 150 targets
make some 60 batches of two or three points, and each linearisation pays numpy's cost per call
60 times. Here neighbouring counts are joined (equations.padding) into one batch of the largest k
among them: a point with fewer rays repeats its last ray, and the repeated rays carry weight zero (``real`` False; the
linearisation zeroes their whitened Jacobians and misclosures, bundle.reduced.linearise_points), so
they add exact zeros to every sum; the back substitution and the final checks read only the real
rays (:func:`real_rays`).

Only where the points' share of the reduced system is summed dense (bundle.dense): there a ray
costs O(w) and the padding at most equations.padding.MAX_PADDING more rays; the ray-pair sums of the other paths
cost O(k^2) per point, and their batches (aerial blocks) are large anyway.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..equations.groups import GroupBatch
from ..equations.padding import joined


@dataclass(frozen=True)
class PaddedBatch(GroupBatch):
    """A GroupBatch of points with up to k rays: real (m, k) bool marks the measured rays; a
    padded ray repeats the point's last real ray (image_rows, photo_index) and has weight zero.
    n_conditions is that of the first joined batch (the bundle counts its observations from the
    batches before joining)."""

    real: np.ndarray | None = None

    def chunks(self, size: int):
        """Sub-batches of at most ``size`` points, each with its part of ``real``."""
        for start in range(0, len(self), size):
            sl = slice(start, start + size)
            yield PaddedBatch(self.family, self.k, self.given_axes, self.point_index[sl], self.image_rows[sl],
                              self.photo_index[sl], self.n_conditions, self.star, self.real[sl])


def real_rays(batch: GroupBatch, *per_ray: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays (m, k, ...) restricted to the real rays of batch: (n_real, ...) for a PaddedBatch,
    unchanged (m, k, ...) otherwise."""
    real = getattr(batch, "real", None)
    if real is None:
        return per_ray
    return tuple(a[real] for a in per_ray)


def pad_batches(batches: list[GroupBatch]) -> list[GroupBatch]:
    """The batches with small ones of one family and given axes joined (equations.padding.joined:
    neighbouring k, the padded rays within MAX_PADDING of the real ones), in the order of their
    first batch; larger and lone batches as they are. Every point stays in exactly one batch."""
    by_shape: dict[tuple, list[int]] = {}
    for i, b in enumerate(batches):
        by_shape.setdefault((b.family, b.given_axes), []).append(i)
    groups = [[idx[j] for j in g] for idx in by_shape.values()
              for g in joined([batches[i].k for i in idx], [len(batches[i]) for i in idx])]
    return [_joined([batches[i] for i in g]) for g in sorted(groups, key=min)]


def _joined(group: list[GroupBatch]) -> GroupBatch:
    """One PaddedBatch of the batches (in order of k; one batch is returned as it is)."""
    if len(group) == 1:
        return group[0]
    k = group[-1].k

    def padded(a: np.ndarray) -> np.ndarray:  # (m, k_b) -> (m, k), the last column repeated
        return np.concatenate([a, np.repeat(a[:, -1:], k - a.shape[1], axis=1)], axis=1)

    real = np.concatenate([np.broadcast_to(np.arange(k) < b.k, (len(b), k)) for b in group])
    first = group[0]
    return PaddedBatch(first.family, k, first.given_axes, np.concatenate([b.point_index for b in group]),
                       np.concatenate([padded(b.image_rows) for b in group]),
                       np.concatenate([padded(b.photo_index) for b in group]), first.n_conditions, False, real)
