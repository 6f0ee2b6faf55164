"""Object-point groups, batched by shape (DESIGN sections 3 and 5).

A group is one object point: the plate measurements of the point (2 per photo that sees it) and,
for control, its given coordinates. Groups of the same shape (condition family, number of rays k,
given axes) form one batch so that their conditions are evaluated at once.

Chain order: the photos of a point are taken in photo-table order, which for a strip is flight
order and for a block strip after strip (consecutive photos give the long, well-conditioned bases
of DESIGN section 3; a pair from neighbouring strips has the strip spacing as its base). Where two
photos of a chain see the point along nearly parallel rays (a re-flown or repeated exposure, two
close-range photos taken from almost the same place), the coplanarity of those rays and the scale
transfer across them would degenerate: such chains are reordered so that rays one or two places
apart in the chain meet at a useful angle (:func:`untangle_chains`). The angles come from the
approximate orientations; without them, from the distances between the projection centres.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import ray_ground
from ..geometry.lens import ideal_xy
from ..model import CHECK, FULL, HEIGHT, PLAN, TIE, Project, given_axes

COLLINEARITY, RAYS = "collinearity", "rays"


@dataclass(frozen=True)
class GroupBatch:
    """m groups of one shape.

    family: COLLINEARITY (full control) or RAYS (tie, height, plan). k: rays per group.
    given_axes: which of X, Y, Z are given (all False for ties). point_index: (m,).
    image_rows: (m, k) rows of the ImagePoints table in chain order. photo_index: (m, k).
    n_conditions: conditions per group. star: the chain's first ray is a hub (conditions.ray_conditions).
    """

    family: str
    k: int
    given_axes: tuple[bool, bool, bool]
    point_index: np.ndarray
    image_rows: np.ndarray
    photo_index: np.ndarray
    n_conditions: int
    star: bool = False

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
                self.photo_index[sl], self.n_conditions, self.star,
            )


def adjusted_kind(kind: np.ndarray) -> np.ndarray:
    """Check points are adjusted as tie points (DESIGN section 10)."""
    return np.where(kind == CHECK, TIE, kind)


def condition_count(kind: int, k: int) -> int:
    """2k - (3 - d) conditions for a point of k rays with d given coordinates (0 if not positive)."""
    d = int(given_axes(kind).sum())
    return max(0, 2 * k - (3 - d))


def points_with_conditions(project: Project) -> np.ndarray:
    """(n_pt,) True for the points that form a group (condition_count > 0 for their kind and rays):
    those build_batches batches, without building the batches."""
    counts = np.bincount(project.image_points.point_index, minlength=len(project.points))
    given = given_axes(adjusted_kind(project.points.kind)).reshape(len(project.points), 3)
    return 2 * counts - (3 - given.sum(axis=1)) > 0


_last: tuple = ()  # (a weak reference to the project, {chains: its batches}) of the last build_batches


def build_batches(project: Project, chains: bool = True) -> list[GroupBatch]:
    """Group the image points by object point and batch the groups by shape.

    chains: order each group's rays into the chain of the conditions method (untangle_chains:
    nearly parallel neighbours moved apart, stars where no order helps). Without (the bundle
    method, which writes no conditions between the rays), a group's rays stay in photo order and
    every shape is one batch: the chain order is O(k^3) per group, 0.42 s of the 2.9 s bundle run
    on the close-range block of tracks up to 93 rays.

    The batches of the last project asked for are kept (weakly: while the project lives) and given
    again for the same project object: the adjustment, the residual cofactors and the point
    precision each ask for them (the chain order alone is 2 s at 100,000 photos). Their arrays are
    read-only, so no caller changes what the next one gets."""
    global _last
    if not (_last and _last[0]() is project):
        _last = (weakref.ref(project), {})
    kept = _last[1]
    if chains not in kept:
        batches = _build_batches(project, chains)
        for b in batches:
            for a in (b.point_index, b.image_rows, b.photo_index):
                a.flags.writeable = False
        kept[chains] = batches
    return list(kept[chains])


def _build_batches(project: Project, chains: bool = True) -> list[GroupBatch]:
    ip = project.image_points
    n_points = len(project.points)
    order = np.lexsort((ip.photo_index, ip.point_index))  # by point, then photo (chain order)
    pts_sorted = ip.point_index[order]
    counts = np.bincount(pts_sorted, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    kinds = adjusted_kind(project.points.kind)
    reference_base = _typical_base(project) if chains else 0.0
    rays = approximate_rays(project) if chains else None
    batches = []
    for kind in (FULL, PLAN, HEIGHT, TIE):
        for k in np.unique(counts[(kinds == kind) & (counts > 0)]):
            k = int(k)
            nc = condition_count(kind, k)
            if nc == 0:
                continue
            sel = np.flatnonzero((kinds == kind) & (counts == k))
            rows = order[starts[sel][:, None] + np.arange(k)[None, :]]
            star = np.zeros(len(sel), dtype=bool)
            if chains and k >= 2 and kind != FULL:
                rows, star = untangle_chains(rows, ip.photo_index, project.photos.xyz0, reference_base, rays)
            for is_star in (False, True):
                pick = star == is_star
                if not pick.any():
                    continue
                batches.append(
                    GroupBatch(
                        family=COLLINEARITY if kind == FULL else RAYS,
                        k=k,
                        given_axes=tuple(given_axes(kind).tolist()),
                        point_index=sel[pick],
                        image_rows=rows[pick],
                        photo_index=ip.photo_index[rows[pick]],
                        n_conditions=nc,
                        star=is_star,
                    )
                )
    return batches


SHORT_BASE = 0.1  # a consecutive base below this fraction of the typical base is degenerate
MIN_RAY_ANGLE = np.radians(2.0)  # rays meeting at a smaller angle are nearly parallel


def approximate_rays(project: Project) -> np.ndarray | None:
    """Unit ground directions (m_ip, 3) of the measurements at the approximate orientations (through
    the camera model), or None when some photo has no approximate orientation."""
    ph, ip, cams = project.photos, project.image_points, project.cameras
    if not (np.isfinite(ph.xyz0).all() and np.isfinite(ph.R_ground_from_cam).all()) or len(ip) == 0:
        return None
    cam = ph.camera_index[ip.photo_index]
    ideal = ideal_xy(ip.xy, cams.interior[cam], cams.convention[cam])
    r = ray_ground(ph.R_ground_from_cam[ip.photo_index], ideal, cams.interior[cam, :3])
    return r / np.linalg.norm(r, axis=1)[:, None]


def _typical_base(project: Project) -> float:
    """Median distance between photos consecutive in the photo table (the strip's base)."""
    xyz0 = project.photos.xyz0
    if len(xyz0) < 2:
        return 0.0
    return float(np.median(np.linalg.norm(np.diff(xyz0, axis=0), axis=1)))


def _separation(rows, photo_index, xyz0, reference_base, rays, places=None) -> np.ndarray | None:
    """(m, k, k) separation of the chains' photos in units of "too close" (below 1 is degenerate):
    the smaller of the rays' angle over MIN_RAY_ANGLE and the centres' distance over SHORT_BASE
    times the typical base, of those available (module doc); None when neither is. places: two
    arrays (p,) of places in the chain; then only those pairs, (m, p)."""
    a, b = (slice(None), None), (None, slice(None))  # every pair, by broadcasting
    if places is not None:
        a, b = (places[0],), (places[1],)
    parts = []
    if rays is not None:
        r = rays[rows]
        cosine = np.sum(r[(slice(None),) + a] * r[(slice(None),) + b], axis=-1)
        parts.append(np.arccos(np.clip(cosine, -1.0, 1.0)) / MIN_RAY_ANGLE)
    if reference_base > 0 and np.isfinite(xyz0).all():
        c = xyz0[photo_index[rows]]
        parts.append(np.linalg.norm(c[(slice(None),) + a] - c[(slice(None),) + b], axis=-1)
                     / (SHORT_BASE * reference_base))
    if not parts:
        return None
    return np.minimum.reduce(parts)


def _nearby_places(k: int, span: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of places at most ``span`` apart in a chain of k: (first, second) (p,)."""
    first = [np.arange(k - lag) for lag in range(1, min(span, k - 1) + 1)]
    second = [f + lag for lag, f in enumerate(first, start=1)]
    return np.concatenate(first), np.concatenate(second)


def _near(sep: np.ndarray, limit: float, span: int = 2) -> np.ndarray:
    """(m,) True where two photos at most ``span`` places apart in the chain are separated by less
    than limit. sep: (m, k, k) in chain order."""
    first, second = _nearby_places(sep.shape[1], span)
    return (sep[:, first, second] < limit).any(axis=1)


def untangle_chains(rows: np.ndarray, photo_index: np.ndarray, xyz0: np.ndarray, reference_base: float,
                    rays: np.ndarray | None = None) -> np.ndarray:
    """Reorder the chains (m, k) of image rows in which two rays one or two places apart are nearly
    parallel: they meet at less than MIN_RAY_ANGLE (rays: unit ground directions per image row,
    approximate_rays), or their photos stand closer than SHORT_BASE times the typical base.

    Neighbours give a coplanarity of nearly parallel rays; two places apart they make the scale
    transfer of the photo between them compare a scale with itself. Both conditions degenerate.
    Such chains are rebuilt greedily, vectorised over them: from each possible first photo in
    turn, take next the first photo (in table order) well separated from the last two taken, else
    the best separated; keep the first start that gives a chain without close photos nearby.
    Chains of three or more rays that no order saves become stars (conditions.ray_conditions).
    Returns the rows (m, k) and star (m,) bool.
    """
    star = np.zeros(len(rows), dtype=bool)
    if rows.shape[1] < 2:
        return rows, star
    # first the pairs one or two places apart of every chain (the test), then every pair of the
    # chains to be rebuilt (a few)
    nearby = _separation(rows, photo_index, xyz0, reference_base, rays, _nearby_places(rows.shape[1]))
    if nearby is None:
        return rows, star
    limit = 1.0
    bad = np.flatnonzero((nearby < limit).any(axis=1))
    if len(bad) == 0:
        return rows, star
    rows = rows.copy()
    dist = _separation(rows[bad], photo_index, xyz0, reference_base, rays)  # (m, k, k)
    m, k = dist.shape[:2]
    ar = np.arange(m)
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
        reordered = np.take_along_axis(np.take_along_axis(dist, order[:, :, None], axis=1), order[:, None, :], axis=2)
        good = unresolved & ~_near(reordered, limit)
        best[good] = order[good]
        unresolved &= ~good
        if not unresolved.any():
            break
    if k >= 3 and unresolved.any():
        # no path avoids them: a star around the photo best separated from all others, its best
        # separated partner second, the rest in table order
        u = np.flatnonzero(unresolved)
        d = dist[u] + np.where(np.eye(k, dtype=bool), np.inf, 0.0)
        hub = np.argmax(d.min(axis=2), axis=1)
        partner = np.argmax(np.where(np.isinf(d[np.arange(len(u)), hub]), -np.inf, d[np.arange(len(u)), hub]), axis=1)
        rank = np.tile(np.arange(k, dtype=float), (len(u), 1)) + 2.0
        rank[np.arange(len(u)), hub] = 0.0
        rank[np.arange(len(u)), partner] = 1.0
        best[u] = np.argsort(rank, axis=1, kind="stable")
        star[bad[u]] = True
    rows[bad] = np.take_along_axis(rows[bad], best, axis=1)
    return rows, star


def sweep_size(batches: list[GroupBatch]) -> int:
    """The size of a sweep for solvers.threads.chunk_threads: the ray pairs of the batches' groups,
    the sum of k^2 over the groups of k rays (a group's whitening and its blocks of N grow like it)."""
    return sum(len(b) * b.k * b.k for b in batches)


def rays_per_point(project: Project) -> np.ndarray:
    return np.bincount(project.image_points.point_index, minlength=len(project.points))
