"""Object-point groups, batched by shape (DESIGN sections 3 and 5).

A group is one object point: the plate measurements of the point (2 per photo that sees it) and,
for control, its given coordinates. Groups of the same shape (condition family, number of rays k,
given axes) form one batch so that their conditions are evaluated at once.

Chain order: the photos of a point are taken in photo-table order, which for a strip is flight
order (consecutive photos give the long, well-conditioned bases of DESIGN section 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import CHECK, FULL, GIVEN_AXES, HEIGHT, PLAN, TIE, Project

COLLINEARITY, RAYS = "collinearity", "rays"


@dataclass(frozen=True)
class GroupBatch:
    """m groups of one shape.

    family: COLLINEARITY (full control) or RAYS (tie, height, plan). k: rays per group.
    given_axes: which of X, Y, Z are given (all False for ties). point_index: (m,).
    image_rows: (m, k) rows of the ImagePoints table in chain order. photo_index: (m, k).
    n_conditions: conditions per group.
    """

    family: str
    k: int
    given_axes: tuple[bool, bool, bool]
    point_index: np.ndarray
    image_rows: np.ndarray
    photo_index: np.ndarray
    n_conditions: int

    @property
    def has_control(self) -> bool:
        return any(self.given_axes)

    def __len__(self) -> int:
        return len(self.point_index)

    def chunks(self, size: int):
        """Sub-batches of at most ``size`` groups (assembly streams in chunks)."""
        for start in range(0, len(self), size):
            sl = slice(start, start + size)
            yield GroupBatch(
                self.family, self.k, self.given_axes, self.point_index[sl], self.image_rows[sl],
                self.photo_index[sl], self.n_conditions,
            )


def adjusted_kind(kind: np.ndarray) -> np.ndarray:
    """Check points are adjusted as tie points (DESIGN section 10)."""
    return np.where(kind == CHECK, TIE, kind)


def condition_count(kind: int, k: int) -> int:
    """2k - (3 - d) conditions for a point of k rays with d given coordinates (0 if not positive)."""
    d = sum(GIVEN_AXES[kind])
    return max(0, 2 * k - (3 - d))


def build_batches(project: Project) -> list[GroupBatch]:
    """Group the image points by object point and batch the groups by shape."""
    ip = project.image_points
    n_points = len(project.points)
    order = np.lexsort((ip.photo_index, ip.point_index))  # by point, then photo (chain order)
    pts_sorted = ip.point_index[order]
    counts = np.bincount(pts_sorted, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    kinds = adjusted_kind(project.points.kind)
    batches = []
    for kind in (FULL, PLAN, HEIGHT, TIE):
        for k in np.unique(counts[(kinds == kind) & (counts > 0)]):
            k = int(k)
            nc = condition_count(kind, k)
            if nc == 0:
                continue
            sel = np.flatnonzero((kinds == kind) & (counts == k))
            rows = order[starts[sel][:, None] + np.arange(k)[None, :]]
            batches.append(
                GroupBatch(
                    family=COLLINEARITY if kind == FULL else RAYS,
                    k=k,
                    given_axes=GIVEN_AXES[kind],
                    point_index=sel,
                    image_rows=rows,
                    photo_index=ip.photo_index[rows],
                    n_conditions=nc,
                )
            )
    return batches


def rays_per_point(project: Project) -> np.ndarray:
    return np.bincount(project.image_points.point_index, minlength=len(project.points))
