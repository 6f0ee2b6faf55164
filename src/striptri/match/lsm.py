"""Least-squares matching (Gruen 1985): the automatic tie points refined to subpixel at full
resolution (``striptri match --refine``; docs/matching.md).

Features found at a pyramid level (``--scale 0.25``) carry that level's error into full-resolution
pixels (on the rendered photographs: a median of 0.09 px at half resolution against 0.03 px at
full). Each track is refined against one of its rays, the reference (its photo the track's first):
a template of (2 WINDOW + 1)^2 full-resolution pixels about the reference is found in each other
photo by least squares on the grey values,

    T(u) = g S(A u + t) + o,

with an affine geometric transformation (A, t: 6 parameters, the template's pixel offsets u
mapped to the search image) and a linear radiometric one (g, o), solved by Gauss-Newton with
bilinear interpolation of the search image and its gradients, all rays of a photo in one batch.
A starts as the affine transformation between the two photos fitted to all the tie points they
share (so photos turned by 180 degrees against each other, as alternate strips are, start right),
t at the feature's position. A ray keeps its refined position when the iteration converged (a
step below STEP_TOLERANCE px), moved less than MAX_SHIFT px, and the template and the matched
patch correlate at least MIN_CORRELATION; otherwise it keeps the feature's position. The
reference ray stays where its feature is: the track is then one consistent point, whichever point
of the ground that is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

WINDOW = 10  # template half-size (full-resolution pixels): 21 x 21
MARGIN = 4  # the search window reaches this much beyond the template's footprint
ITERATIONS = 12
STEP_TOLERANCE = 0.005  # px: the iteration has converged when the shift changes less
MAX_SHIFT = 2.0  # px: a refinement that moves a ray further is not trusted
MIN_CORRELATION = 0.7


@dataclass(frozen=True)
class Refined:
    """colrow (m, 2) the rays' positions after refinement; refined (m,) bool: moved by the
    matching (False: the reference rays, and the rays the matching did not accept); shift (m,) px;
    correlation (m,) of the template with the matched patch (nan: not matched)."""

    colrow: np.ndarray
    refined: np.ndarray
    shift: np.ndarray
    correlation: np.ndarray


def refine(track: np.ndarray, photo: np.ndarray, colrow: np.ndarray, paths: list, workers: int | None = None,
           scheduler=None) -> Refined:
    """Refine the rays (track (m,), photo (m,), colrow (m, 2) full-resolution pixels, corner origin
    with the top-left pixel's centre at (0.5, 0.5)) of tracks by least-squares matching against
    each track's reference ray (module doc). paths: the image of each photo. The templates are cut
    from each reference photo's image (read once); then each photo's rays are matched in a task of
    their own (striptri.parallel: workers, scheduler), which reads that photo's image once, so that
    memory holds the templates and one photo's windows per worker."""
    from ..parallel import map_unordered

    track, photo = np.asarray(track), np.asarray(photo)
    colrow = np.asarray(colrow, dtype=float)
    m = len(track)
    order = np.lexsort((photo, track))
    first = np.ones(m, dtype=bool)
    first[1:] = track[order][1:] != track[order][:-1]
    ref_of = np.empty(m, dtype=np.int64)  # each ray's reference ray
    ref_of[order] = order[np.flatnonzero(first)][np.cumsum(first) - 1]
    todo = np.flatnonzero(ref_of != np.arange(m))
    linear = _pair_affines(photo, colrow, ref_of, todo)
    spread = float(np.abs(linear).sum(2).max()) if len(todo) else 1.0  # the template's reach per unit offset
    side = 2 * int(np.ceil(WINDOW * spread + MARGIN + MAX_SHIFT)) + 1
    templates = np.zeros((len(todo), 2 * WINDOW + 1, 2 * WINDOW + 1), dtype=np.float32)
    for k in np.unique(photo[ref_of[todo]]):
        mine = np.flatnonzero(photo[ref_of[todo]] == k)
        templates[mine] = _sample(_read(paths[int(k)]), colrow[ref_of[todo[mine]]])
    tasks, rows = [], []
    for k in np.unique(photo[todo]):
        mine = np.flatnonzero(photo[todo] == k)
        tasks.append(LsmTask(str(paths[int(k)]), colrow[todo[mine]], templates[mine], linear[mine], side))
        rows.append(todo[mine])
    out = colrow.copy()
    shift, corr = np.zeros(m), np.full(m, np.nan)
    refined = np.zeros(m, dtype=bool)
    for i, (position, accept, moved, correlation) in map_unordered(match_in_photo, tasks, workers, scheduler):
        r = rows[i]
        out[r[accept]] = position[accept]
        shift[r] = np.where(accept, moved, 0.0)
        refined[r[accept]] = True
        corr[r] = correlation
    return Refined(out, refined, shift, corr)


def closure_sigma(track: np.ndarray, photo: np.ndarray, refined: Refined, paths: list, workers=None,
                  scheduler=None) -> tuple[float, int]:
    """The standard deviation (px) of one refined image coordinate, from closures: in every track of
    three rays or more, the second ray's refined position is taken as a template once more and its
    third ray matched to it; the difference from the third ray's refined position, e = J e2 + e3 -
    e1 (three independent matching errors, J near a rotation), has variance 3 sigma^2 per
    coordinate, so sigma = 1.4826 median|e| / sqrt(3) (robust against the false matches still
    there). Unlike Sampson distances to a pair's F, it does not see the lens distortion or the
    features' own error. -> (sigma, closures used); nan without any."""
    track, photo = np.asarray(track), np.asarray(photo)
    order = np.lexsort((photo, track))
    t = track[order]
    first = np.r_[True, t[1:] != t[:-1]]
    start = np.flatnonzero(first)
    length = np.diff(np.r_[start, len(t)])
    ok = np.flatnonzero(length >= 3)
    second, third = order[start[ok] + 1], order[start[ok] + 2]
    moved = refined.refined[second] & refined.refined[third]
    second, third = second[moved], third[moved]
    if not len(second):
        return float("nan"), 0
    pair_track = np.repeat(np.arange(len(second)), 2)
    pair_photo = np.column_stack([photo[second], photo[third]]).ravel()
    colrow = np.stack([refined.colrow[second], refined.colrow[third]], 1).reshape(-1, 2)
    again = refine(pair_track, pair_photo, colrow, paths, workers, scheduler)
    used = again.refined[1::2]
    e = (again.colrow[1::2] - refined.colrow[third])[used]
    if not len(e):
        return float("nan"), 0
    return float(1.4826 * np.median(np.abs(e)) / np.sqrt(3.0)), int(len(e))


@dataclass(frozen=True)
class LsmTask:
    """The rays of one photo to match: path its image; colrow (n, 2) the features; templates (n,
    2W+1, 2W+1); linear (n, 2, 2) each template's initial affine part; side of the windows."""

    path: str
    colrow: np.ndarray
    templates: np.ndarray
    linear: np.ndarray
    side: int


def match_in_photo(task: LsmTask):
    """-> (refined colrow (n, 2), accepted (n,), shift (n,) px, correlation (n,)) (module doc)."""
    image = _read(task.path)
    origin = np.floor(task.colrow - 0.5).astype(int) - task.side // 2
    windows = np.stack([_window(image, c0, task.side) for c0 in origin]) if len(origin) else \
        np.zeros((0, task.side, task.side))
    t0 = task.colrow - 0.5 - origin  # the feature in the window's array indices (x = col, y = row)
    t, ok, correlation = _lsm(task.templates.astype(float), windows, task.linear, t0)
    moved = np.linalg.norm(t - t0, axis=1)
    accept = ok & (moved <= MAX_SHIFT) & (correlation >= MIN_CORRELATION)
    return t + 0.5 + origin, accept, moved, correlation


def _read(path) -> np.ndarray:
    from .features import read_grey

    return read_grey(path).astype(np.float32)


def _pair_affines(photo, colrow, ref_of, todo) -> np.ndarray:
    """(todo, 2, 2) the linear part of the affine transformation from each ray's reference photo to
    its photo, fitted robustly (least median of squares: false matches are still among the tie
    points) to every pair of rays of a track in those two photos (at least 3 pairs; else the
    identity)."""
    from .features import cv2_module

    cv2 = cv2_module()
    out = np.tile(np.eye(2), (len(todo), 1, 1))
    pairs = np.column_stack([photo[ref_of[todo]], photo[todo]])
    for (a, b) in np.unique(pairs, axis=0):
        mine = np.flatnonzero((pairs[:, 0] == a) & (pairs[:, 1] == b))
        if len(mine) < 3:
            continue
        src = colrow[ref_of[todo[mine]]].astype(np.float32)
        dst = colrow[todo[mine]].astype(np.float32)
        M, _ = cv2.estimateAffine2D(src, dst, method=cv2.LMEDS)
        if M is not None and np.isfinite(M).all() and 0.25 < abs(np.linalg.det(M[:, :2])) < 4.0:
            out[mine] = M[:, :2]
    return out


def _sample(image: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(n, 2W+1, 2W+1) bilinear samples of image about centres (n, 2) (col, row, corner origin)."""
    u = np.arange(-WINDOW, WINDOW + 1, dtype=float)
    rows = centres[:, 1, None, None] - 0.5 + u[None, :, None]
    cols = centres[:, 0, None, None] - 0.5 + u[None, None, :]
    rows, cols = np.broadcast_arrays(rows, cols)
    return ndimage.map_coordinates(image, [rows.ravel(), cols.ravel()], order=1, mode="nearest").reshape(rows.shape)


def _window(image: np.ndarray, c0: np.ndarray, side: int) -> np.ndarray:
    """image[r0:r0+side, c0:c0+side] with the border repeated where it leaves the image."""
    H, W = image.shape
    r = np.clip(np.arange(c0[1], c0[1] + side), 0, H - 1)
    c = np.clip(np.arange(c0[0], c0[0] + side), 0, W - 1)
    return image[np.ix_(r, c)]


def _lsm(T: np.ndarray, S: np.ndarray, A0: np.ndarray, t0: np.ndarray):
    """Batched Gauss-Newton of T(u) = g S(A u + t) + o: -> (t (n, 2) the template centre in the
    windows' array indices, converged (n,), correlation (n,))."""
    n = len(T)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool), np.zeros(0)
    u = np.arange(-WINDOW, WINDOW + 1, dtype=float)
    uy, ux = (g.ravel() for g in np.meshgrid(u, u, indexing="ij"))  # template offsets: row, col
    A = A0.copy()  # x (col) = A[0] . (ux, uy) + t_x; y (row) = A[1] . (ux, uy) + t_y
    t = t0.copy()
    g, o = np.ones(n), np.zeros(n)
    gy, gx = np.gradient(S, axis=1), np.gradient(S, axis=2)
    Tv = T.reshape(n, -1)
    k = np.repeat(np.arange(n, dtype=float), len(ux)).reshape(n, -1)
    converged = np.zeros(n, dtype=bool)
    for _ in range(ITERATIONS):
        x = A[:, 0, 0, None] * ux + A[:, 0, 1, None] * uy + t[:, 0, None]
        y = A[:, 1, 0, None] * ux + A[:, 1, 1, None] * uy + t[:, 1, None]
        coords = [k.ravel(), y.ravel(), x.ravel()]
        s = ndimage.map_coordinates(S, coords, order=1, mode="nearest").reshape(n, -1)
        sx = ndimage.map_coordinates(gx, coords, order=1, mode="nearest").reshape(n, -1)
        sy = ndimage.map_coordinates(gy, coords, order=1, mode="nearest").reshape(n, -1)
        r = Tv - (g[:, None] * s + o[:, None])
        J = np.stack([g[:, None] * sx * ux, g[:, None] * sx * uy, g[:, None] * sx,
                      g[:, None] * sy * ux, g[:, None] * sy * uy, g[:, None] * sy,
                      s, np.ones_like(s)], -1)  # d(model)/d(a00, a01, tx, a10, a11, ty, g, o)
        N = np.einsum("npi,npj->nij", J, J) + 1e-9 * np.eye(8)
        d = np.linalg.solve(N, np.einsum("npi,np->ni", J, r)[..., None])[..., 0]
        d = np.where(converged[:, None], 0.0, d)
        A[:, 0, 0] += d[:, 0]
        A[:, 0, 1] += d[:, 1]
        t[:, 0] += d[:, 2]
        A[:, 1, 0] += d[:, 3]
        A[:, 1, 1] += d[:, 4]
        t[:, 1] += d[:, 5]
        g += d[:, 6]
        o += d[:, 7]
        converged |= np.hypot(d[:, 2], d[:, 5]) < STEP_TOLERANCE
    x = A[:, 0, 0, None] * ux + A[:, 0, 1, None] * uy + t[:, 0, None]
    y = A[:, 1, 0, None] * ux + A[:, 1, 1, None] * uy + t[:, 1, None]
    s = ndimage.map_coordinates(S, [k.ravel(), y.ravel(), x.ravel()], order=1, mode="nearest").reshape(n, -1)
    a, b = Tv - Tv.mean(1, keepdims=True), s - s.mean(1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1))
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    inside = (t >= WINDOW).all(1) & (t <= np.array(S.shape[2:0:-1]) - 1 - WINDOW).all(1)
    good = converged & np.isfinite(t).all(1) & (np.abs(det) > 0.25) & (np.abs(det) < 4.0) & inside
    return t, good, np.nan_to_num(correlation, nan=-1.0)
