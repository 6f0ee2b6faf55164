"""Object-point groups, batched by shape (DESIGN sections 3 and 5).

A group is one object point: the plate measurements of the point (2 per photo that sees it) and,
for control, its given coordinates. Groups of the same shape (condition family, number of rays k,
given axes) form one batch so that their conditions are evaluated at once.

Chain order: the photos of a point are taken in photo-table order, which for a strip is flight
order and for a block strip after strip (consecutive photos give the long, well-conditioned bases
of DESIGN section 3; a pair from neighbouring strips has the strip spacing as its base). Where two
photos of a chain stand almost at the same place (a re-flown or repeated exposure), the
coplanarity of their nearly parallel rays would degenerate: such chains are reordered so that
consecutive bases stay long (:func:`untangle_chains`).
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
    reference_base = _typical_base(project)
    batches = []
    for kind in (FULL, PLAN, HEIGHT, TIE):
        for k in np.unique(counts[(kinds == kind) & (counts > 0)]):
            k = int(k)
            nc = condition_count(kind, k)
            if nc == 0:
                continue
            sel = np.flatnonzero((kinds == kind) & (counts == k))
            rows = order[starts[sel][:, None] + np.arange(k)[None, :]]
            if k >= 2 and kind != FULL:
                rows = untangle_chains(rows, ip.photo_index, project.photos.xyz0, reference_base)
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


SHORT_BASE = 0.1  # a consecutive base below this fraction of the typical base is degenerate


def _typical_base(project: Project) -> float:
    """Median distance between photos consecutive in the photo table (the strip's base)."""
    xyz0 = project.photos.xyz0
    if len(xyz0) < 2:
        return 0.0
    return float(np.median(np.linalg.norm(np.diff(xyz0, axis=0), axis=1)))


def _near(centres: np.ndarray, limit: float, span: int = 2) -> np.ndarray:
    """(m,) True where two photos at most ``span`` places apart in the chain stand closer than limit."""
    bad = np.zeros(len(centres), dtype=bool)
    for lag in range(1, min(span, centres.shape[1] - 1) + 1):
        d = np.linalg.norm(centres[:, lag:] - centres[:, :-lag], axis=2)
        bad |= (d < limit).any(axis=1)
    return bad


def untangle_chains(rows: np.ndarray, photo_index: np.ndarray, xyz0: np.ndarray, reference_base: float) -> np.ndarray:
    """Reorder the chains (m, k) of image rows in which two photos that stand almost at the same
    place (closer than SHORT_BASE times the typical base) are one or two places apart.

    Neighbours give a coplanarity of nearly parallel rays; two places apart they make the scale
    transfer of the photo between them compare a scale with itself. Both conditions degenerate.
    Such chains are rebuilt greedily, vectorised over them: from each possible first photo in
    turn, take next the first photo (in table order) far from the last two taken, else the one
    farthest from them; keep the first start that gives a chain without close photos nearby.
    """
    limit = SHORT_BASE * reference_base
    if reference_base <= 0 or rows.shape[1] < 2:
        return rows
    centres = xyz0[photo_index[rows]]  # (m, k, 3)
    bad = np.flatnonzero(_near(centres, limit))
    if len(bad) == 0:
        return rows
    rows = rows.copy()
    c = centres[bad]
    m, k, _ = c.shape
    ar = np.arange(m)
    dist = np.linalg.norm(c[:, :, None] - c[:, None, :], axis=3)  # (m, k, k)
    best = np.tile(np.arange(k), (m, 1))
    unresolved = np.ones(m, dtype=bool)
    for start in range(k):
        order = np.zeros((m, k), dtype=int)
        order[:, 0] = start
        taken = np.zeros((m, k), dtype=bool)
        taken[:, start] = True
        for step in range(1, k):
            d_last = dist[ar, order[:, step - 1]]
            d_near = np.minimum(d_last, dist[ar, order[:, step - 2]]) if step >= 2 else d_last
            ok = (d_near >= limit) & ~taken
            first_ok = np.where(ok.any(axis=1), np.argmax(ok, axis=1), -1)
            farthest = np.argmax(np.where(taken, -np.inf, d_near), axis=1)
            nxt = np.where(first_ok >= 0, first_ok, farthest)
            order[:, step] = nxt
            taken[ar, nxt] = True
        good = unresolved & ~_near(np.take_along_axis(c, order[..., None], axis=1), limit)
        best[good] = order[good]
        unresolved &= ~good
        if not unresolved.any():
            break
    rows[bad] = np.take_along_axis(rows[bad], best, axis=1)
    return rows


def rays_per_point(project: Project) -> np.ndarray:
    return np.bincount(project.image_points.point_index, minlength=len(project.points))
