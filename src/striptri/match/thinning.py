"""Thinning the tracks to a well-spread set: a target number per photo in a grid of cells.

Matching finds thousands of tie points per photo where an adjustment needs tens, well spread. Each
photo's format is cut into ``cells`` x ``cells`` cells (3 x 3 puts a cell on each of the six von
Gruber positions of every model the photo belongs to, and on the principal point). In each cell of
each photo the ``per_cell`` observations of the longest tracks are chosen (ties: the better
score, then the order given); a track is kept when it is chosen in any of its photos, and then
with all its rays. Long tracks tie more photos together and are preferred.
"""

from __future__ import annotations

import numpy as np


def thin_tracks(track: np.ndarray, photo: np.ndarray, xy: np.ndarray, half_format: np.ndarray, cells: int = 3,
                per_cell: int = 4, score: np.ndarray | None = None, n_tracks: int | None = None) -> np.ndarray:
    """(n_tracks,) bool: the tracks kept (module doc).

    Per observation (a feature in a track): track (m,) its track (0..n_tracks-1, -1 none), photo
    (m,), xy (m, 2) plate coordinates about the principal point; half_format (n_photos, 2) half
    the format's width and height; score (m,) smaller is better (None: no preference); n_tracks:
    the number of tracks (None: the largest track number given, plus one; give it when the last
    tracks may have no observation here, e.g. after dropping false ones).
    """
    track = np.asarray(track, dtype=np.int64)
    n_tracks = int(track.max(initial=-1)) + 1 if n_tracks is None else int(n_tracks)
    use = np.flatnonzero(track >= 0)
    length = np.bincount(track[use], minlength=n_tracks)
    ph = np.asarray(photo, dtype=np.int64)[use]
    rel = (np.asarray(xy, dtype=float)[use] + half_format[ph]) / (2.0 * half_format[ph])  # 0..1 over the format
    ij = np.clip((rel * cells).astype(np.int64), 0, cells - 1)
    cell = (ph * cells + ij[:, 1]) * cells + ij[:, 0]
    s = np.zeros(len(use)) if score is None else np.asarray(score, dtype=float)[use]
    order = np.lexsort((np.arange(len(use)), s, -length[track[use]], cell))
    sorted_cell = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(sorted_cell)) + 1]
    rank = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    chosen = order[rank < per_cell]
    keep = np.zeros(n_tracks, dtype=bool)
    keep[track[use][chosen]] = True
    return keep
