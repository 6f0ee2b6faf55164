"""Tracks from verified matches: one object point per set of features that show it.

Features are numbered globally (0..n_features-1); ``photo`` (n_features,) names the photo of each.
A verified match joins two features of two photos. The tracks are the connected components of
the match graph (union-find, scipy.sparse.csgraph) with at least two features. A component that
holds two different features of one photo cannot be one object point: a false match (or a
repeated pattern) has joined two tracks. Such a component is split by joining its matches again
one by one, best first (``score``, e.g. the descriptor distance, smaller is better), refusing any
join that would put two features of one photo in one track (the consistent union of COLMAP's and
OpenMVG's track builders). Only the conflicting components are re-joined one match at a time:
they are few, and everything else is vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


@dataclass(frozen=True)
class Tracks:
    """track (n_features,) the track of each feature, -1 for none (unmatched, or left alone by a
    split); n_tracks; split: how many conflicting components were split."""

    track: np.ndarray
    n_tracks: int
    split: int

    def lengths(self) -> np.ndarray:
        """(n_tracks,) the number of features (rays) of each track."""
        return np.bincount(self.track[self.track >= 0], minlength=self.n_tracks)


def build_tracks(photo: np.ndarray, a: np.ndarray, b: np.ndarray, score: np.ndarray | None = None) -> Tracks:
    """The tracks of the matches (a[i], b[i]) between features of different photos (module doc).

    photo: (n_features,) photo of each feature; a, b: (m,) feature numbers; score: (m,) match
    quality, smaller is better (None: the order given). ValueError for a match within one photo.
    """
    photo = np.asarray(photo, dtype=np.int64)
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    n = len(photo)
    if np.any(photo[a] == photo[b]):
        raise ValueError("a match joins two features of the same photo")
    graph = sp.coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    label = label.astype(np.int64)
    size = np.bincount(label)
    label = np.where(size[label] >= 2, label, -1)
    # a component with two features in one photo: (label, photo) pairs that occur more than once
    member = np.flatnonzero(label >= 0)
    key = label[member] * (int(photo.max(initial=0)) + 1) + photo[member]
    uniq, count = np.unique(key, return_counts=True)
    bad_labels = np.unique(uniq[count > 1] // (int(photo.max(initial=0)) + 1))
    if len(bad_labels):
        bad = np.isin(label, bad_labels)
        label[bad] = -1
        edges = np.flatnonzero(np.isin(a, np.flatnonzero(bad)))
        order = edges if score is None else edges[np.argsort(np.asarray(score)[edges], kind="stable")]
        fresh = _consistent_union(photo, a[order], b[order], int(label.max(initial=-1)) + 1)
        for feature, track in fresh.items():
            label[feature] = track
    uniq_labels, track = np.unique(label, return_inverse=True)
    track = track.astype(np.int64) - (1 if uniq_labels[0] == -1 else 0)
    track[label < 0] = -1
    return Tracks(track=track, n_tracks=int(track.max(initial=-1)) + 1, split=len(bad_labels))


def _consistent_union(photo: np.ndarray, a: np.ndarray, b: np.ndarray, first: int) -> dict[int, int]:
    """Union-find over the matches in order, refusing a join of two sets that share a photo.
    -> feature -> track number (from ``first``) of the features in sets of two or more."""
    parent: dict[int, int] = {}
    photos: dict[int, set] = {}
    members: dict[int, list] = {}

    def find(x: int) -> int:
        root = x
        while parent.get(root, root) != root:
            root = parent[root]
        while parent.get(x, x) != root:  # path compression
            parent[x], x = root, parent[x]
        return root

    for x, y in zip(a.tolist(), b.tolist()):
        for f in (x, y):
            if f not in parent:
                parent[f], photos[f], members[f] = f, {int(photo[f])}, [f]
        rx, ry = find(x), find(y)
        if rx == ry or photos[rx] & photos[ry]:
            continue
        if len(members[rx]) < len(members[ry]):
            rx, ry = ry, rx
        parent[ry] = rx
        photos[rx] |= photos.pop(ry)
        members[rx] += members.pop(ry)
    out: dict[int, int] = {}
    track = first
    for root, group in members.items():
        if len(group) >= 2:
            for f in group:
                out[f] = track
            track += 1
    return out


def same_place(photo: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(n,) for every feature the first feature of its photo at exactly the same position. SIFT
    gives a keypoint one descriptor per dominant orientation, at the same place: on rendered
    photographs about a fifth of the features are such twins. Matches through twins are one
    measurement of one point; joined under the first twin (match = canonical[match]) they give one
    track, not two tracks with the same ray, nor a track split because a photo holds it twice."""
    photo = np.asarray(photo, dtype=np.int64)
    xy = np.asarray(xy, dtype=float)
    n = len(photo)
    if not n:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((np.arange(n), xy[:, 1], xy[:, 0], photo))
    p, x, y = photo[order], xy[order, 0], xy[order, 1]
    new = np.ones(n, dtype=bool)
    new[1:] = (p[1:] != p[:-1]) | (x[1:] != x[:-1]) | (y[1:] != y[:-1])
    first = order[np.flatnonzero(new)][np.cumsum(new) - 1]  # the lowest index of each group (stable order)
    canonical = np.empty(n, dtype=np.int64)
    canonical[order] = first
    return canonical
