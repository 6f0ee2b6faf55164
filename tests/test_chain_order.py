"""Chain order of a point's photos (DESIGN section 3): a repeated exposure at almost the same station
must not make a coplanarity or a scale transfer degenerate."""

import numpy as np
import pytest
from dataclasses import replace

from striptri import model
from striptri import simulate as sim
from striptri.geometry.camera import project as proj
from striptri.geometry.rotations import R_from_opk, opk_from_R
from striptri.adjustment import adjust, AdjustmentOptions
import striptri.equations.groups as G

def duplicated_strip(seed=0, shift=(0.3, 0.2, 0.1)):
    d = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=6), control=sim.ControlDesign(layout="ends"),
                            points=sim.PointDesign(extra_ties_per_model=4))
    t = sim.make_truth(d, np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    p = sim.perturb(t, sim.NoiseOptions(), rng)
    j = 2  # duplicate the third photo
    O = t.xyz0[j] + np.array(shift)
    R = t.R_ground_from_cam[j] @ R_from_opk(np.radians([0.2, -0.1, 0.3]))
    seen = np.unique(p.image_points.point_index[p.image_points.photo_index == j])
    pid_truth = [t.point_ids.index(p.points.ids[i]) for i in seen]
    X = t.xyz_ground[pid_truth]
    xy = proj(np.broadcast_to(R, (len(seen), 3, 3)), np.broadcast_to(O, (len(seen), 3)),
              np.broadcast_to(p.cameras.interior[0, :3], (len(seen), 3)), X) + rng.normal(0, 0.005, (len(seen), 2))
    n = len(p.photos)
    ph = p.photos
    Rapprox = R @ R_from_opk(np.radians(rng.normal(0, 0.5, 3)))
    photos = replace(ph, ids=ph.ids + ["dup"], camera_index=np.append(ph.camera_index, 0), strip_ids=ph.strip_ids + [ph.strip_ids[0]],
                     xyz0=np.vstack([ph.xyz0, O + rng.normal(0, 3, 3)]), R_ground_from_cam=np.concatenate([ph.R_ground_from_cam, Rapprox[None]]),
                     angles=np.vstack([ph.angles, opk_from_R(Rapprox)]), sigma_xyz0=np.vstack([ph.sigma_xyz0, np.full(3, np.nan)]),
                     sigma_angles=np.vstack([ph.sigma_angles, np.full(3, np.nan)]))
    ip = p.image_points
    ips = model.ImagePoints(np.append(ip.photo_index, np.full(len(seen), n)), np.append(ip.point_index, seen),
                            np.vstack([ip.xy, xy]), np.vstack([ip.sigma_xy, np.full((len(seen), 2), 0.005)]))
    return replace(p, photos=photos, image_points=ips), t

def test_repeated_exposure_is_kept_apart_in_the_chain():
    q, _ = duplicated_strip()
    rows_per_batch = G.build_batches(q)
    dup = len(q.photos) - 1
    checked = 0
    for batch in rows_per_batch:
        # a chain of two or three photos cannot keep them apart, and full control has no chain
        if batch.family != G.RAYS or batch.k < 4:
            continue
        chain = batch.photo_index
        checked += int(np.isin(chain, [2]).any(axis=1).sum())
        for lag in (1, 2):
            if chain.shape[1] > lag:
                close = {frozenset((2, dup))}
                pairs = {frozenset(p) for p in zip(chain[:, :-lag].ravel(), chain[:, lag:].ravel())}
                assert not (pairs & close), f"photos 2 and {dup} are {lag} apart in a chain"
    assert checked > 0


def test_repeated_exposure_converges_and_equals_the_bundle():
    q, _ = duplicated_strip()
    # three-ray points seen by the photo and its repeat cannot be ordered: they become stars
    assert sum(len(b) for b in G.build_batches(q) if b.star) == 3
    r = adjust(q)
    b = adjust(q, AdjustmentOptions(method="bundle"))
    assert r.converged and r.iterations <= 10
    np.testing.assert_allclose(r.state.xyz0, b.state.xyz0, atol=1e-6 * 1500)
    assert r.vtpv == pytest.approx(b.vtpv, rel=1e-7)


def test_without_reordering_the_same_data_converges_badly(monkeypatch):
    """The reason for the reordering: left in table order the chain (.., 1003, 1004, repeat of 1003)
    compares the scale of 1004's ray with itself, and the iteration crawls."""
    q, _ = duplicated_strip()
    monkeypatch.setattr(G, "SHORT_BASE", 0.0)
    monkeypatch.setattr(G, "MIN_RAY_ANGLE", 0.0)
    r = adjust(q, AdjustmentOptions(max_iterations=10, keep_unconverged=True))
    assert not r.converged


def test_the_batches_of_a_project_are_built_once_and_cannot_be_changed():
    """build_batches gives the same batches again for the same project object (the adjustment, the
    residual cofactors and the point precision all ask), read-only so that no caller changes
    another's; another project (even an equal one) gets its own, and the kept batches do not keep
    their project alive."""
    import gc
    import weakref

    q, _ = duplicated_strip()
    first = G.build_batches(q)
    again = G.build_batches(q)
    assert again is not first and all(a is b for a, b in zip(first, again))
    with pytest.raises(ValueError):
        first[0].image_rows[0, 0] = 0
    other = replace(q)
    rebuilt = G.build_batches(other)
    assert all(a is not b for a, b in zip(first, rebuilt))
    assert [np.array_equal(a.image_rows, b.image_rows) for a, b in zip(first, rebuilt)] == [True] * len(first)
    gone = weakref.ref(other)
    del other, rebuilt
    gc.collect()
    assert gone() is None


@pytest.mark.parametrize("with_rays", [True, False])
def test_the_separation_of_nearby_places_is_that_of_the_whole_matrix(with_rays):
    """untangle_chains tests every chain on its pairs one or two places apart only, and forms the
    whole (k, k) separation for the chains it rebuilds: the pairs' numbers are those entries of the
    whole matrix, for rays and centres and for centres alone."""
    rng = np.random.default_rng(3)
    n_rows, n_photos, m, k = 200, 40, 30, 7
    photo_index = rng.integers(0, n_photos, n_rows)
    xyz0 = rng.normal(0, 100, (n_photos, 3))
    rays = rng.normal(size=(n_rows, 3)) if with_rays else None
    if rays is not None:
        rays /= np.linalg.norm(rays, axis=1)[:, None]
    rows = np.stack([rng.choice(n_rows, k, replace=False) for _ in range(m)])
    whole = G._separation(rows, photo_index, xyz0, 25.0, rays)
    first, second = G._nearby_places(k)
    assert sorted(zip(first.tolist(), second.tolist())) == [(a, b) for a in range(k) for b in range(a + 1, min(a + 3, k))]
    pairs = G._separation(rows, photo_index, xyz0, 25.0, rays, (first, second))
    np.testing.assert_allclose(pairs, whole[:, first, second], rtol=1e-14, atol=0)
    np.testing.assert_array_equal(G._near(whole, 1.0), (pairs < 1.0).any(axis=1))
