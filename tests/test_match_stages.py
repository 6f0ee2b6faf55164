"""The matching stages that need no image library (issue 28): tracks, candidate pairs, thinning.
Each against a brute-force reference or numbers worked by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from striptri import simulate as sim
from striptri.match.pairs import _bilinear, _inside, footprints, overlap_pairs, strip_pairs, GRID
from striptri.match.thinning import thin_tracks
from striptri.match.tracks import build_tracks, same_place, two_view_consistent


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


def test_twin_keypoints_at_one_place_give_one_track_not_two_nor_a_split():
    """SIFT's keypoint with two orientations is two features at one place: matched through both
    twins, the point is one track of two rays (without joining the twins: a split track, or two
    tracks with the same ray)."""
    photo = np.array([0, 0, 1, 1, 2])
    xy = np.array([[10.0, 20.0], [10.0, 20.0], [30.0, 40.0], [30.0, 40.0], [5.0, 5.0]])
    twin = same_place(photo, xy)
    np.testing.assert_array_equal(twin, [0, 0, 2, 2, 4])
    a, b = np.array([0, 1]), np.array([2, 3])  # twin 0 <-> twin 2, twin 1 <-> twin 3
    apart = build_tracks(photo, a, b)
    assert apart.n_tracks == 2  # the same ray twice, as two points
    joined = build_tracks(photo, twin[a], twin[b])
    assert joined.n_tracks == 1 and (joined.track >= 0).sum() == 2 and joined.split == 0
    crossed = build_tracks(photo, np.array([0, 1]), np.array([2, 2]))  # both twins to one feature
    assert crossed.split == 1  # without joining: a track with photo 0 twice
    # another photo's feature at the same pixel is not a twin
    assert same_place(np.array([0, 1]), np.array([[1.0, 1.0], [1.0, 1.0]])).tolist() == [0, 1]


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
    got = {tuple(p) for p in strip_pairs(strips, along=1, across=0, both_directions=False).tolist()}
    assert got == {(0, 1), (1, 2), (2, 3), (4, 5), (5, 6), (6, 7), (0, 4), (1, 5), (2, 6), (3, 7)}
    got = {tuple(p) for p in strip_pairs(strips, along=2, across=1, both_directions=False).tolist()}
    assert (0, 2) in got and (0, 5) in got and (0, 6) not in got and (0, 3) not in got
    # strip b flown back: photo 0 lies beside b's last photo (7), as well as beside its first
    got = {tuple(p) for p in strip_pairs(strips, along=1, across=0).tolist()}
    assert got == {(0, 1), (1, 2), (2, 3), (4, 5), (5, 6), (6, 7), (0, 4), (1, 5), (2, 6), (3, 7),
                   (0, 7), (1, 6), (2, 5), (3, 4)}


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


def test_descriptor_matching_equals_opencvs_brute_force_matcher():
    """The distance-matrix matcher against the reference, OpenCV's BFMatcher (L2, knnMatch both
    ways): the same mutual, ratio-tested matches and distances, also across row chunks."""
    cv2 = pytest.importorskip("cv2")
    from striptri.match import pair_matching
    from striptri.match.features import Features

    rng = np.random.default_rng(3)
    base = rng.integers(0, 120, (1500, 128)).astype(np.float32)
    a = Features(rng.uniform(0, 100, (1500, 2)), base, np.ones(1500))
    b_desc = np.vstack([base[:900] + rng.normal(0, 6.0, (900, 128)), rng.integers(0, 120, (700, 128))]).astype(np.float32)
    b = Features(rng.uniform(0, 100, (1600, 2)), b_desc[rng.permutation(1600)], np.ones(1600))
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    ab, ba = matcher.knnMatch(a.descriptors, b.descriptors, k=2), matcher.knnMatch(b.descriptors, a.descriptors, k=1)
    back = {m[0].queryIdx: m[0].trainIdx for m in ba}
    expected = sorted((m.queryIdx, m.trainIdx) for m, n in ab if m.distance < 0.8 * n.distance and back[m.trainIdx] == m.queryIdx)
    assert len(expected) > 500
    for chunk in (2048, 256):
        pair_matching.ROWS_PER_CHUNK, saved = chunk, pair_matching.ROWS_PER_CHUNK
        try:
            i, j, d = pair_matching.match_descriptors(a, b)
        finally:
            pair_matching.ROWS_PER_CHUNK = saved
        assert sorted(zip(i.tolist(), j.tolist())) == expected
        np.testing.assert_allclose(d, np.linalg.norm(a.descriptors[i] - b.descriptors[j], axis=1), rtol=1e-4)


def test_sampson_distances_measure_the_image_noise():
    """Two cameras seeing random points in depth, image coordinates with noise sigma: the Sampson
    distances to the true F are N(0, sigma^2) (first order), and the estimate is sigma within its
    sampling error (2,000 matches: about 3 % for the median-based estimator)."""
    from striptri.match.pair_matching import sampson_distances, sigma_from_epipolar

    rng = np.random.default_rng(5)
    K = np.array([[800.0, 0, 400], [0, 800.0, 300], [0, 0, 1]])
    X = np.column_stack([rng.uniform(-4, 4, 2000), rng.uniform(-3, 3, 2000), rng.uniform(8, 16, 2000)])
    t, angle = np.array([1.0, 0.2, 0.1]), 0.1
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    x1 = (X @ K.T)[:, :2] / X[:, 2:]
    Y = X @ R.T + t
    x2 = (Y @ K.T)[:, :2] / Y[:, 2:]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = np.linalg.inv(K).T @ tx @ R @ np.linalg.inv(K)
    np.testing.assert_allclose(sampson_distances(F, x1, x2), 0.0, atol=1e-6)
    sigma = 0.4
    d = sampson_distances(F, x1 + rng.normal(0, sigma, x1.shape), x2 + rng.normal(0, sigma, x2.shape))
    assert abs(np.std(d) / sigma - 1) < 0.05 and abs(sigma_from_epipolar(d) / sigma - 1) < 0.1


def test_tracks_whose_rays_do_not_meet_near_the_ground_are_dropped():
    """The consistency check of striptri match (match.ground_check.ground_consistent) on a simulated strip with its
    exact orientations: the true tie points pass; a false match whose rays meet 500 m above the
    ground (as one along the epipolar line of a flat scene does: 0.33 of the 1,500 m flying
    height, beyond HEIGHT_RANGE) and one whose second ray passes 250 m from the first are dropped."""
    from dataclasses import replace

    from striptri.geometry.camera import project as plate_of
    from striptri.match.ground_check import ground_consistent

    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4, n_strips=1), control=sim.ControlDesign(layout="ends"))
    truth = sim.make_truth(design, np.random.default_rng(4))
    project, _ = sim.simulate_project("strip", sim.SimulateOptions(design, sim.NoiseOptions()), None)
    project = replace(project, photos=replace(project.photos, xyz0=truth.xyz0, R_ground_from_cam=truth.R_ground_from_cam))
    track, photo, plate = truth.point_index.copy(), truth.photo_index.copy(), truth.xy_plate.copy()
    n = len(truth.point_ids)
    h = float(np.mean(truth.xyz_ground[:, 2]))
    # a false track: photo 0's ray of a point it shares with photo 1, paired with photo 1's view of
    # the point 500 m above the true one on that ray
    k = next(q for q in range(n) if {0, 1} <= set(photo[track == q].tolist()))
    X, O0 = truth.xyz_ground[k], truth.xyz0[0]
    high = O0 + (X - O0) * (X[2] + 500.0 - O0[2]) / (X[2] - O0[2])
    far = plate_of(truth.R_ground_from_cam[1], truth.xyz0[1], truth.interior, high)
    # a track whose second ray is moved across the base: 2 x 250 m apart at the ground
    shifted = plate[(track == k) & (photo == 1)][0] + [0.0, 500.0 * truth.interior[0] / 1500.0]
    track = np.r_[track, n, n, n + 1, n + 1]
    photo = np.r_[photo, 0, 1, 0, 1]
    plate = np.vstack([plate, plate[(track[:-4] == k) & (photo[:-4] == 0)], far[None],
                       plate[(track[:-4] == k) & (photo[:-4] == 0)], shifted[None]])
    ok = ground_consistent(project, track, photo, plate, h, 0.10, n + 2)
    assert ok[:n].all()
    assert not ok[n] and not ok[n + 1]


def test_thinning_answers_for_every_track_when_the_last_ones_have_no_rays_left():
    """After the consistency check drops the last tracks, their observations are gone: the answer
    still has one entry per track (the command broadcast a shorter one against the check's)."""
    track = np.array([0, 0, 1, 1])
    keep = thin_tracks(track, np.array([0, 1, 0, 1]), np.zeros((4, 2)), np.ones((2, 2)), n_tracks=4)
    assert keep.tolist() == [True, True, False, False]


# ------------------------------------------------------------------- two-view check of the tracks

@pytest.mark.parametrize("relief", [0.0, 300.0])  # a flat scene (homography), and one with relief (F)
def test_a_track_joined_by_a_false_match_breaks_a_pairs_geometry(relief):
    """Three vertical photos one base apart over 40 points; the matches of every pair are true but
    one: point 1 in photo 1 is matched to point 2 in photo 2 (point 2 has no other match), so the
    union makes one track of point 1 (photos 0, 1) and point 2 (photo 2). It is the only track
    whose rays break a pair's two-view geometry."""
    rng = np.random.default_rng(4)
    n = 40
    X = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(-300, 300, n), rng.uniform(0, relief, n)])
    xy = []
    for p in range(3):  # c 1000 px, flying height 2000 m, base 300 m, principal point (500, 400)
        xy.append(np.column_stack([500 + 1000 * (X[:, 0] - 300 * p) / (2000 - X[:, 2]),
                                   400 + 1000 * X[:, 1] / (2000 - X[:, 2])]))
    xy = np.concatenate(xy)
    photo = np.repeat(np.arange(3), n)
    f = lambda p, k: p * n + k  # noqa: E731  feature of point k in photo p
    a, b = [], []
    for p, q in ((0, 1), (1, 2), (0, 2)):
        for k in range(n):
            if k == 2 or (k == 1 and q == 2):
                continue
            a.append(f(p, k)), b.append(f(q, k))
    a.append(f(1, 1)), b.append(f(2, 2))  # the false match
    a, b = np.array(a), np.array(b)
    tracks = build_tracks(photo, a, b)
    ok = two_view_consistent(tracks.track, photo, xy, a, b, tracks.n_tracks, 1.5)
    joined = tracks.track[f(0, 1)]
    assert tracks.track[f(2, 2)] == joined and tracks.split == 0
    assert not ok[joined] and ok.sum() == tracks.n_tracks - 1
