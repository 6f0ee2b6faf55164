"""Candidate pairs of photos to match: never all pairs of a block.

With approximate orientations (GNSS/IMU or a flight plan) each photo's footprint is its format
projected onto the plane Z = terrain height (the four corner rays, :func:`footprints`). Two photos
are a candidate pair when their footprints overlap by at least ``min_overlap`` of the smaller one,
measured on a grid of GRID x GRID points over each footprint (points of one inside the other,
both ways; a convex quadrilateral each). Only photos whose footprint centres lie within the sum
of their footprint radii are compared (a k-d tree): the work grows with the block, not its square.

Without orientations, :func:`strip_pairs`: each photo with the next ``along`` photos of its strip,
and with the photos of the neighbouring strips at about the same place along the strip (flown the
same way or back).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

GRID = 7  # points per side of the grid that measures an overlap (49 points: 2 % resolution)
PAIR_CHUNK = 20_000  # candidate pairs measured at once


def footprints(R_ground_from_cam: np.ndarray, xyz0: np.ndarray, interior: np.ndarray, half_format: np.ndarray,
               terrain_height: float) -> np.ndarray:
    """(n, 4, 2) ground X, Y of the corners of each photo's format projected onto Z = terrain_height
    (counter-clockwise seen from above). R_ground_from_cam (n, 3, 3); xyz0 (n, 3) m; interior (n, 3)
    c, xp, yp; half_format (n, 2) half the format's width and height (plate units, about the
    principal point). ValueError when a corner's ray does not reach the plane (a photo looking up,
    or the plane above the camera)."""
    hx, hy = half_format[:, 0], half_format[:, 1]
    corners = np.stack([np.stack([-hx, -hy], 1), np.stack([hx, -hy], 1), np.stack([hx, hy], 1),
                        np.stack([-hx, hy], 1)], 1)  # (n, 4, 2) plate, counter-clockwise
    p = np.concatenate([corners - interior[:, None, 1:3], -np.broadcast_to(interior[:, None, :1], (len(xyz0), 4, 1))],
                       2)
    r = np.einsum("nij,nkj->nki", R_ground_from_cam, p)
    s = (terrain_height - xyz0[:, None, 2]) / r[..., 2]
    if not np.all(np.isfinite(s) & (s > 0)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(s) & (s > 0), axis=1))[0])
        raise ValueError(f"photo {bad}: a corner ray of its format does not reach the terrain height "
                         f"{terrain_height:g} m (looking up, or the terrain above the camera)")
    ground = xyz0[:, None, :2] + s[..., None] * r[..., :2]
    # counter-clockwise seen from above (Z up): a mirror image (a camera looking down turns the
    # plate's orientation) is reversed
    area = _signed_area(ground)
    return np.where((area < 0)[:, None, None], ground[:, ::-1], ground)


def overlap_pairs(corners: np.ndarray, min_overlap: float = 0.1) -> np.ndarray:
    """(k, 2) pairs i < j of footprints (n, 4, 2) that overlap by at least min_overlap of the smaller
    (module doc), sorted."""
    n = len(corners)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    centre = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
    tree = cKDTree(centre)
    near = tree.query_pairs(2.0 * float(radius.max()), output_type="ndarray")
    if not len(near):
        return np.zeros((0, 2), dtype=np.int64)
    i, j = near[:, 0], near[:, 1]
    close = np.linalg.norm(centre[i] - centre[j], axis=1) <= radius[i] + radius[j]
    i, j = i[close], j[close]
    t = (np.arange(GRID) + 0.5) / GRID
    u, v = (a.ravel() for a in np.meshgrid(t, t))
    samples = _bilinear(corners, u, v)  # (n, GRID^2, 2)
    keep = np.zeros(len(i), dtype=bool)
    for c0 in range(0, len(i), PAIR_CHUNK):  # memory bounded: (chunk, GRID^2, 4) at a time
        ci, cj = i[c0:c0 + PAIR_CHUNK], j[c0:c0 + PAIR_CHUNK]
        inside_ij = _inside(samples[ci], corners[cj]).mean(axis=1)  # share of i's footprint inside j's
        inside_ji = _inside(samples[cj], corners[ci]).mean(axis=1)
        keep[c0:c0 + PAIR_CHUNK] = np.maximum(inside_ij, inside_ji) >= min_overlap
    pairs = np.sort(np.stack([i[keep], j[keep]], 1), axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def strip_pairs(strip_ids, along: int = 2, across: int = 1, both_directions: bool = True) -> np.ndarray:
    """(k, 2) pairs i < j without orientations: each photo with the next ``along`` photos of its
    strip (the order of photos.csv), and with the photos of the next strip (strips in their order
    of first appearance) whose relative place along the strip is within ``across`` photos of its
    own, counted from the same end and, with both_directions (strips flown back and forth, which
    photos.csv cannot tell without orientations), from the other end too: the pairs that do not
    overlap fail the verification. strip_ids: (n,) strings."""
    strip_ids = np.asarray(strip_ids)
    names, first = np.unique(strip_ids, return_index=True)
    names = names[np.argsort(first)]
    members = [np.flatnonzero(strip_ids == s) for s in names]
    out = []
    for idx in members:
        for d in range(1, along + 1):
            out.append(np.stack([idx[:-d], idx[d:]], 1))
    for lower, upper in zip(members[:-1], members[1:]):
        if not len(lower) or not len(upper):
            continue
        # the place of each photo along its strip, 0..1, and the spacing of the upper strip's photos
        pos_l = np.linspace(0.0, 1.0, len(lower)) if len(lower) > 1 else np.zeros(1)
        pos_u = np.linspace(0.0, 1.0, len(upper)) if len(upper) > 1 else np.zeros(1)
        step = 1.0 / max(len(upper) - 1, 1)
        near = np.abs(pos_l[:, None] - pos_u[None, :]) <= (across + 0.5) * step
        if both_directions:
            near |= np.abs(pos_l[:, None] - (1.0 - pos_u[None, :])) <= (across + 0.5) * step
        a, b = np.nonzero(near)
        out.append(np.stack([lower[a], upper[b]], 1))
    pairs = np.sort(np.concatenate(out) if out else np.zeros((0, 2), dtype=np.int64), axis=1).astype(np.int64)
    pairs = np.unique(pairs, axis=0)
    return pairs[pairs[:, 0] != pairs[:, 1]]


def _signed_area(poly: np.ndarray) -> np.ndarray:
    x, y = poly[..., 0], poly[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def _bilinear(corners: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Points (n, g, 2) at (u, v) in [0, 1]^2 of each quadrilateral (n, 4, 2), bilinearly."""
    c0, c1, c2, c3 = (corners[:, k, None, :] for k in range(4))
    u, v = u[None, :, None], v[None, :, None]
    return (1 - u) * (1 - v) * c0 + u * (1 - v) * c1 + u * v * c2 + (1 - u) * v * c3


def _inside(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(m, g) whether each of the points (m, g, 2) lies inside its convex counter-clockwise
    quadrilateral (m, 4, 2)."""
    edge = np.roll(poly, -1, axis=1) - poly  # (m, 4, 2)
    rel = points[:, :, None, :] - poly[:, None, :, :]  # (m, g, 4, 2)
    cross = edge[:, None, :, 0] * rel[..., 1] - edge[:, None, :, 1] * rel[..., 0]
    return np.all(cross >= 0, axis=2)
