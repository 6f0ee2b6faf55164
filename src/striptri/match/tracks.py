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


def two_view_consistent(track: np.ndarray, photo: np.ndarray, xy: np.ndarray, a: np.ndarray, b: np.ndarray,
                        n_tracks: int, tolerance_px: float) -> np.ndarray:
    """(n_tracks,) bool: the tracks whose rays agree with the two-view geometry of every pair of
    their photos that has verified matches. Without approximate orientations (match.unoriented)
    this is the check of a track: union-find joins two points into one track through a chain of
    false matches, and such a track has rays in two photos of a matched pair that do not correspond.

    Each pair's geometry is fitted again to its verified matches (a, b: feature numbers, in pairs
    of photos), by least median of squares (a false match among them does not bend it): a
    homography where one explains PLANAR_SHARE of them (a flat scene, whose fundamental matrix is
    not unique), else the fundamental matrix. A track
    is inconsistent when two of its rays in such a pair are further apart than tolerance_px (the
    homography's transfer distance, or the Sampson distance to F). track (n_features,) -1: none;
    photo, xy (n_features, ...) full-resolution pixels."""
    from .features import cv2_module
    from .pair_matching import PLANAR_SHARE, sampson_distances

    cv2 = cv2_module()
    cv2.setRNGSeed(0)  # least median of squares samples at random: the same tracks on every run
    n_photos = int(photo.max()) + 1 if len(photo) else 0
    pa, pb = photo[a], photo[b]
    swap = pa > pb
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    key = photo[a] * n_photos + photo[b]
    keys, first, count = np.unique(key, return_index=True, return_counts=True)
    order = np.argsort(key, kind="stable")
    models, planar = np.zeros((len(keys), 3, 3)), np.zeros(len(keys), dtype=bool)
    usable = np.zeros(len(keys), dtype=bool)
    start = 0
    for k, c in enumerate(count):  # one small fit per matched pair
        rows = order[start:start + c]
        start += c
        if c < 8:
            continue
        p1, p2 = xy[a[rows]].astype(np.float64), xy[b[rows]].astype(np.float64)
        H, _ = cv2.findHomography(p1, p2, cv2.LMEDS)
        if H is not None and np.mean(_transfer(H, p1, p2) <= tolerance_px) >= PLANAR_SHARE:
            models[k], planar[k], usable[k] = H, True, True
            continue
        F, _ = cv2.findFundamentalMat(p1, p2, cv2.FM_LMEDS)
        if F is not None and F.shape == (3, 3):
            models[k], usable[k] = F, True
    ok = np.ones(n_tracks, dtype=bool)
    rays = np.flatnonzero(track >= 0)
    rays = rays[np.lexsort((photo[rays], track[rays]))]
    t = track[rays]
    for d in range(1, int(np.bincount(t).max()) if len(t) else 1):  # every two rays of a track
        same = t[:-d] == t[d:]
        r1, r2 = rays[:-d][same], rays[d:][same]
        k = np.searchsorted(keys, photo[r1] * n_photos + photo[r2])
        k = np.minimum(k, len(keys) - 1)
        matched = (keys[k] == photo[r1] * n_photos + photo[r2]) & usable[k]
        r1, r2, k = r1[matched], r2[matched], k[matched]
        e = np.empty(len(k))
        h = planar[k]
        e[h] = _transfer(models[k[h]], xy[r1[h]], xy[r2[h]])
        with np.errstate(divide="ignore", invalid="ignore"):
            e[~h] = np.nan_to_num(np.abs(sampson_distances(models[k[~h]], xy[r1[~h]], xy[r2[~h]])), nan=np.inf)
        ok[track[r1[e > tolerance_px]]] = False
    return ok


def _transfer(H: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Distances between H p1 and p2 (H (3, 3) or (n, 3, 3))."""
    q = np.concatenate([p1, np.ones((len(p1), 1))], 1)
    Hq = (q @ H.T) if H.ndim == 2 else np.einsum("nij,nj->ni", H, q)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.linalg.norm(Hq[:, :2] / Hq[:, 2:] - p2, axis=1)
    return np.nan_to_num(d, nan=np.inf)

