"""The matching stages that need no image library (issue 28): tracks, candidate pairs, thinning.
Each against a brute-force reference or numbers worked by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from striptri import simulate as sim
from striptri.match.pairs import _bilinear, _inside, footprints, overlap_pairs, strip_pairs, GRID
from striptri.match.thinning import thin_tracks
from striptri.match.tracks import build_tracks


# ------------------------------------------------------------------------------------------ tracks

def test_a_chain_of_matches_is_one_track():
    photo = np.array([0, 1, 2, 3])
    t = build_tracks(photo, [0, 1], [1, 2])
    assert t.track.tolist() == [0, 0, 0, -1] and t.n_tracks == 1 and t.split == 0
    assert t.lengths().tolist() == [3]


def test_a_track_with_two_features_in_one_photo_is_split_best_match_first():
    # features: 0, 1 in photo 0; 2 in photo 1; 3 in photo 2. 1-3 is the false match (worst score)
    photo = np.array([0, 0, 1, 2])
    t = build_tracks(photo, [0, 2, 3], [2, 3, 1], score=[0.1, 0.2, 0.9])
    assert t.track.tolist() == [0, -1, 0, 0] and t.split == 1
    # with the false match the best, it is the one kept and 0 is left alone
    t = build_tracks(photo, [0, 2, 3], [2, 3, 1], score=[0.9, 0.2, 0.1])
    assert t.track.tolist() == [-1, 0, 0, 0]


def test_a_match_within_one_photo_is_refused():
    with pytest.raises(ValueError, match="same photo"):
        build_tracks(np.array([0, 0, 1]), [0], [1])


def _reference_tracks(photo, a, b, score):
    """Plain union-find, one match at a time best first, refusing joins that share a photo."""
    parent = list(range(len(photo)))
    photos = [{int(p)} for p in photo]

    def find(x):
        while parent[x] != x:
            x = parent[x]
        return x

    for i in np.argsort(score, kind="stable"):
        rx, ry = find(int(a[i])), find(int(b[i]))
        if rx != ry and not photos[rx] & photos[ry]:
            parent[ry] = rx
            photos[rx] |= photos[ry]
    groups = {}
    for f in range(len(photo)):
        groups.setdefault(find(f), []).append(f)
    return {frozenset(g) for g in groups.values() if len(g) >= 2}


def test_tracks_equal_a_one_at_a_time_union_find_where_components_conflict():
    """Random block: 300 object points in 2-6 of 12 photos, all their matches, 3 % false matches.
    Every track has its features in distinct photos; a component without conflict is one track; a
    split component is split as the plain best-first union-find splits it."""
    rng = np.random.default_rng(28)
    photo, point = [], []
    for p in range(300):
        for ph in rng.choice(12, rng.integers(2, 7), replace=False):
            photo.append(int(ph))
            point.append(p)
    photo, point = np.array(photo), np.array(point)
    a, b, score = [], [], []
    for p in range(300):
        f = np.flatnonzero(point == p)
        for x, y in itertools.combinations(f, 2):
            a.append(x), b.append(y), score.append(rng.uniform(0.0, 0.5))
    n_false = int(0.03 * len(a))
    while n_false:
        x, y = rng.integers(0, len(photo), 2)
        if photo[x] != photo[y] and point[x] != point[y]:
            a.append(x), b.append(y), score.append(rng.uniform(0.5, 1.0))
            n_false -= 1
    a, b, score = np.array(a), np.array(b), np.array(score)
    t = build_tracks(photo, a, b, score)
    assert t.split > 0
    got = {frozenset(np.flatnonzero(t.track == k).tolist()) for k in range(t.n_tracks)}
    for g in got:
        assert len({int(photo[f]) for f in g}) == len(g) >= 2
    assert got == _reference_tracks(photo, a, b, score)


# ------------------------------------------------------------------------------------------ pairs

def test_the_footprint_of_a_vertical_photo_is_its_format_scaled():
    c, H, h = 150.0, 1500.0, 100.0
    fp = footprints(np.eye(3)[None], np.array([[1000.0, 2000.0, H]]), np.array([[c, 0.0, 0.0]]),
                    np.array([[115.0, 115.0]]), h)
    half = 115.0 * (H - h) / c
    np.testing.assert_allclose(fp[0], [[1000 - half, 2000 - half], [1000 + half, 2000 - half],
                                       [1000 + half, 2000 + half], [1000 - half, 2000 + half]])


def test_a_footprint_that_does_not_reach_the_terrain_is_an_error():
    with pytest.raises(ValueError, match="does not reach"):
        footprints(np.eye(3)[None], np.array([[0.0, 0.0, 100.0]]), np.array([[150.0, 0.0, 0.0]]),
                   np.array([[115.0, 115.0]]), 500.0)


def _block():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=8, n_strips=3, overlap=0.6, sidelap=0.3),
                                 control=sim.ControlDesign(layout="perimeter", every_k=2))
    project, _ = sim.simulate_project("block", sim.SimulateOptions(design, sim.NoiseOptions()), 3)
    ph, cams = project.photos, project.cameras
    fp = footprints(ph.R_ground_from_cam, ph.xyz0, cams.interior[ph.camera_index, :3],
                    np.full((len(ph), 2), 115.0), 0.0)
    return project, fp


def test_overlap_pairs_find_every_overlapping_pair_of_a_block():
    """The k-d tree only saves work: against every pair measured the same way, the same pairs."""
    project, fp = _block()
    got = overlap_pairs(fp, 0.1)
    t = (np.arange(GRID) + 0.5) / GRID
    u, v = (x.ravel() for x in np.meshgrid(t, t))
    samples = _bilinear(fp, u, v)
    expect = [(i, j) for i, j in itertools.combinations(range(len(fp)), 2)
              if max(_inside(samples[[i]], fp[[j]]).mean(), _inside(samples[[j]], fp[[i]]).mean()) >= 0.1]
    assert [tuple(p) for p in got.tolist()] == expect
    strips = np.asarray(project.photos.strip_ids)
    same = strips[got[:, 0]] == strips[got[:, 1]]
    assert same.any() and (~same).any()  # along and across the strips (30 % sidelap)
    # 60 % forward overlap: neighbours and next-but-one (20 %) are pairs, three apart (none) are not
    s0 = np.flatnonzero(strips == strips[0])
    pairs = {tuple(p) for p in got.tolist()}
    assert (s0[0], s0[1]) in pairs and (s0[0], s0[2]) in pairs and (s0[0], s0[3]) not in pairs


def test_strip_pairs_without_orientations():
    strips = ["a"] * 4 + ["b"] * 4
    got = {tuple(p) for p in strip_pairs(strips, along=1, across=0).tolist()}
    assert got == {(0, 1), (1, 2), (2, 3), (4, 5), (5, 6), (6, 7), (0, 4), (1, 5), (2, 6), (3, 7)}
    got = {tuple(p) for p in strip_pairs(strips, along=2, across=1).tolist()}
    assert (0, 2) in got and (0, 5) in got and (0, 6) not in got and (0, 3) not in got


# ------------------------------------------------------------------------------------------ thinning

def test_thinning_keeps_the_longest_track_of_each_cell():
    # photo 0: tracks 0 (3 rays), 1 (2 rays), 2 (2 rays) in one cell, track 3 (2 rays) alone in another
    track = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0])
    photo = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2])
    xy = np.array([[-100, -100], [-90, -100], [-95, -90], [100, 100]] * 2 + [[0, 0]], dtype=float)
    keep = thin_tracks(track, photo, xy, np.full((3, 2), 115.0), cells=3, per_cell=1)
    assert keep.tolist() == [True, False, False, True]
    keep = thin_tracks(track, photo, xy, np.full((3, 2), 115.0), cells=3, per_cell=2, score=[0, 1, 0.5, 0] * 2 + [0])
    assert keep.tolist() == [True, False, True, True]  # the second place of the crowded cell: the better score
