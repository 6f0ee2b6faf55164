"""Synthetic normal matrices with the structure of a strip or a block, for the solver tests and
benchmarks (scripts/bench/bench_solvers.py). No geometry: only the pattern and the kind of
conditioning of DESIGN section 5.

``N = S G' G S``. Each row of G is a condition of one object point on the photos that see it,
with random 6-vectors ``a_j`` per photo that sum to zero over the photos (like the coplanarity and
scale conditions, which do not change when every photo moves alike: a datum defect), plus small
random entries on the columns of the photos' camera. Control points add full-rank rows on single
photos and remove the defect, so N is positive definite and its condition grows with the distance
between control, as in a real strip. ``S`` gives the columns random units (metres, radians, mm).
Photos are numbered strip after strip, along each strip, so a strip's N has nonzero 6x6 blocks only
within two photos of the diagonal (Schmid Fig. 10) and camera columns (3 per camera) come last.
The Structure names each block's strip (``groups``; cameras -1).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .base import Structure

BLOCK = 6
CAMERA = 3


def _rows(groups: np.ndarray, n_rows_each: int, rng: np.random.Generator):
    """Condition rows on the photos of each group (m, k): (m * n_rows_each, k, 6) coefficients that
    sum to zero over the k photos."""
    m, k = groups.shape
    a = rng.normal(size=(m, n_rows_each, k, BLOCK))
    a -= a.mean(axis=2, keepdims=True)
    photos = np.broadcast_to(groups[:, None, :], (m, n_rows_each, k))
    return a.reshape(-1, k, BLOCK), photos.reshape(-1, k)


def _normal_matrix(n_photos: int, groups: list[np.ndarray], full: np.ndarray, partial: np.ndarray,
                   n_cameras: int, rng: np.random.Generator, unit_spread: float, photos_per_strip: int):
    coeffs, photos = [], []
    for g, n_rows in groups:
        a, p = _rows(g, n_rows, rng)
        coeffs.append(a.reshape(len(a), -1))
        photos.append(p)
    n = BLOCK * n_photos + CAMERA * n_cameras
    data, rows, cols = [], [], []
    row0 = 0
    for a, p in zip(coeffs, photos):
        m, k = p.shape
        r = np.repeat(np.arange(row0, row0 + m), k * BLOCK)
        c = (BLOCK * p[:, :, None] + np.arange(BLOCK)).reshape(-1)
        data.append(a.reshape(-1)), rows.append(r), cols.append(c)
        if n_cameras:  # the photos' camera (photo modulo n_cameras) takes part in every condition
            cam = p[:, 0] % n_cameras
            rows.append(np.repeat(np.arange(row0, row0 + m), CAMERA))
            cols.append((BLOCK * n_photos + CAMERA * cam[:, None] + np.arange(CAMERA)).reshape(-1))
            data.append(0.3 * rng.normal(size=m * CAMERA))
        row0 += m
    # control: 6 independent rows on each fully controlled photo, 2 (like height points) on the others
    # (the same two directions on every photo, as a height point always fixes Z: the other four are
    # held only through the chain of photos from the fully controlled ones)
    height_rows = rng.normal(size=(2, BLOCK))
    for control, n_rows in ((full, BLOCK), (partial, 2)):
        nc = len(control)
        rows.append(np.repeat(np.arange(row0, row0 + n_rows * nc), BLOCK))
        cols.append(np.repeat(BLOCK * control[:, None] + np.arange(BLOCK), n_rows, axis=0).reshape(-1))
        values = rng.normal(size=(nc, n_rows, BLOCK)) if n_rows == BLOCK else np.broadcast_to(height_rows, (nc, 2, BLOCK))
        data.append(np.ravel(values))
        row0 += n_rows * nc
    if n_cameras:  # a weak observation of each camera constant
        rows.append(np.arange(row0, row0 + CAMERA * n_cameras))
        cols.append(np.arange(BLOCK * n_photos, n))
        data.append(np.full(CAMERA * n_cameras, 0.1))
        row0 += CAMERA * n_cameras
    G = sp.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))), shape=(row0, n))
    units = 10.0 ** rng.uniform(-unit_spread, unit_spread, n)
    N = (G @ sp.diags(units)).T @ (G @ sp.diags(units))
    N = sp.csr_matrix((N + N.T) * 0.5)
    N.sort_indices()
    starts = np.concatenate([np.arange(0, BLOCK * n_photos, BLOCK),
                             BLOCK * n_photos + np.arange(0, CAMERA * n_cameras, CAMERA)]).astype(int)
    strip_of_block = np.r_[np.arange(n_photos) // photos_per_strip, -np.ones(n_cameras, dtype=int)]
    return N, Structure(n, starts, strip_of_block.astype(int))


def strip_normal_matrix(n_photos: int, rng: np.random.Generator, *, n_cameras: int = 0,
                        control_every: int = 4, points_per_model: int = 6, unit_spread: float = 2.0,
                        control: bool = True):
    """(N, Structure) of a strip of n_photos >= 2: per model ``points_per_model`` coplanarities
    (photos i, i+1) and as many triple points with 3 conditions each (photos i, i+1, i+2); full
    control on the first and last photo, height-like control (2 rows) on every ``control_every``-th:
    the condition then grows with the length of the strip, as in a real one. ``control=False``
    leaves the datum defect: N is then singular although every 6x6 block is regular."""
    i = np.arange(n_photos - 1)
    pairs = np.column_stack([i, i + 1])
    t = np.arange(n_photos - 2)
    triples = np.column_stack([t, t + 1, t + 2])
    groups = [(np.repeat(pairs, points_per_model, axis=0), 1)]
    if len(triples):
        groups.append((np.repeat(triples, points_per_model, axis=0), 3))
    full = np.unique([0, n_photos - 1]) if control else np.zeros(0, dtype=int)
    partial = np.setdiff1d(np.arange(0, n_photos, control_every), full) if control else full
    return _normal_matrix(n_photos, groups, full, partial, n_cameras, rng, unit_spread, n_photos)


def block_normal_matrix(n_strips: int, photos_per_strip: int, rng: np.random.Generator, *,
                        n_cameras: int = 0, control_every: int = 4, points_per_model: int = 6,
                        unit_spread: float = 2.0):
    """(N, Structure) of a block of parallel strips numbered strip by strip: each strip as in
    :func:`strip_normal_matrix`, plus sidelap points on photos (s, p), (s, p+1), (s+1, p), (s+1, p+1)
    (5 conditions each); full control at the four corners, height-like control every
    ``control_every`` photos on the first and last strip."""
    P = photos_per_strip
    idx = np.arange(n_strips * P).reshape(n_strips, P)
    pairs = np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()])
    triples = np.column_stack([idx[:, :-2].ravel(), idx[:, 1:-1].ravel(), idx[:, 2:].ravel()])
    quads = np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()])
    groups = [(np.repeat(pairs, points_per_model, axis=0), 1)]
    for g, r in ((triples, 3), (quads, 5)):
        if len(g):
            groups.append((np.repeat(g, max(1, points_per_model // 2), axis=0), r))
    full = np.unique(idx[[0, 0, -1, -1], [0, -1, 0, -1]])
    along = np.arange(0, P, control_every)
    partial = np.setdiff1d(np.concatenate([idx[0, along], idx[-1, along]]), full)
    return _normal_matrix(n_strips * P, groups, full, partial, n_cameras, rng, unit_spread, P)
