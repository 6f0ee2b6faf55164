"""The synthetic data generator: geometry of the design, noise, reproducibility, the CLI."""

from __future__ import annotations

import re
import shlex
from dataclasses import replace
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from striptri import model
from striptri.geometry.camera import project, ray_ground
from striptri.cli import main, reports_errors
from striptri.errors import InputError, NumericalFailure
from striptri.io import read_project
from striptri.geometry.rotations import R_from_opk, exp_so3
from striptri.simulate import (
    BLOCK_LAYOUTS,
    ControlDesign,
    FlightDesign,
    NoiseOptions,
    PointDesign,
    SimulateOptions,
    SyntheticDesign,
    TerrainDesign,
    make_truth,
    perturb,
    simulate_project,
)


DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


def rng(seed=0):
    return np.random.default_rng(seed)


def strip_design(n_photos=8, overlap=0.6, **control):
    return SyntheticDesign(
        flight=FlightDesign(n_photos=n_photos, overlap=overlap),
        points=PointDesign(extra_ties_per_model=3),
        control=ControlDesign(layout="every-k", **control),
    )


def ideal(design: SyntheticDesign) -> SyntheticDesign:
    """The same design flown exactly (no deviations) over flat terrain."""
    flight = replace(design.flight, attitude_std_deg=(0, 0, 0), position_std_m=(0, 0, 0))
    return replace(design, flight=flight, terrain=replace(design.terrain, relief=0.0))


def plate_of(truth, photo_id, point_id):
    photo, point = truth.photo_ids.index(photo_id), truth.point_ids.index(point_id)
    row = np.flatnonzero((truth.photo_index == photo) & (truth.point_index == point))
    assert len(row) == 1, f"{point_id} not measured on {photo_id}"
    return truth.xy_plate[row[0]]


# ----------------------------------------------------------------------------- geometry


@pytest.mark.parametrize("overlap", [0.6, 2 / 3])
@pytest.mark.parametrize("heading", [0.0, 90.0, 30.0])
def test_overlap_achieved_on_the_plates(overlap, heading):
    # Flown ideally over flat ground, the nadir of photo k appears on photo k+1 at
    # x = -(1 - overlap) * format (the base on the plate), y = 0, whatever the heading.
    design = ideal(strip_design(n_photos=3, overlap=overlap))
    design = replace(design, flight=replace(design.flight, heading_deg=heading))
    truth = make_truth(design, rng())
    base_on_plate = (1 - overlap) * design.camera.format
    np.testing.assert_allclose(plate_of(truth, "1002", "1001C"), [-base_on_plate, 0.0], atol=1e-9)
    np.testing.assert_allclose(plate_of(truth, "1002", "1003C"), [base_on_plate, 0.0], atol=1e-9)
    # left of the flight direction is +y on the plate
    assert plate_of(truth, "1002", "1002L")[1] > 80 and plate_of(truth, "1002", "1002R")[1] < -80


def test_overlap_with_deviations_is_near_nominal():
    design = strip_design(n_photos=8)
    truth = make_truth(design, rng(3))
    along = np.diff(truth.xyz0[:, 0])  # flown along +X
    achieved = 1 - along / (design.camera.format * design.scale)
    # position_std 5 m per centre against a 908 m base: overlap within 0.6 +/- 0.01
    np.testing.assert_allclose(achieved, 0.6, atol=0.01)


@pytest.mark.parametrize("overlap", [0.6, 2 / 3])
def test_points_seen_by_the_right_number_of_photos(overlap):
    design = strip_design(n_photos=8, overlap=overlap, n_single_photo=2, n_check=3)
    truth = make_truth(design, rng(1))
    rays = dict(zip(truth.point_ids, truth.rays_per_point()))
    photo = {pid: k for k, pid in enumerate(truth.photo_ids)}
    for pid, k in photo.items():
        for position in "LCR":
            expected = 2 if k in (0, 7) else 3  # the von Gruber points: triple overlap inside the strip
            assert rays[f"{pid}{position}"] == expected, f"{pid}{position}"
    assert rays["1001S"] == 1 and rays["1008S"] == 1
    single = np.isin(truth.point_ids, ["1001S", "1008S"])
    assert np.all(truth.rays_per_point()[~single] >= 2)
    # the single-photo control points are seen by the end photos only
    for pid, k in (("1001S", 0), ("1008S", 7)):
        assert truth.photo_index[truth.point_index == truth.point_ids.index(pid)].tolist() == [k]
    assert np.sum(truth.kind == model.CHECK) == 3


def test_image_coordinates_inside_the_format_and_in_front():
    design = strip_design(n_photos=8, n_single_photo=2)
    truth = make_truth(design, rng(2))
    assert np.all(np.abs(truth.xy_plate) <= design.camera.half_usable)
    m = np.einsum(
        "nji,nj->ni", truth.R_ground_from_cam[truth.photo_index], truth.xyz_ground[truth.point_index] - truth.xyz0[truth.photo_index]
    )
    assert np.all(m[:, 2] < 0)
    # every pair of (photo, point) that is measurable is measured: no visible point left out
    all_xy = project(truth.R_ground_from_cam[:, None], truth.xyz0[:, None], truth.interior, truth.xyz_ground[None])
    visible = np.all(np.abs(all_xy) <= design.camera.half_usable, -1)
    assert visible.sum() == len(truth.photo_index)


def test_terrain_relief_bounded_and_points_on_it():
    design = strip_design()
    truth = make_truth(design, rng(4))
    z = truth.xyz_ground[:, 2]
    assert np.all(np.abs(z - design.terrain.mean_z) <= design.terrain.relief)
    np.testing.assert_allclose(truth.terrain.z(truth.xyz_ground[:, :2]), z)
    assert np.ptp(z) > 0.2 * design.terrain.relief  # not flat


def test_noise_free_plates_reproject_exactly():
    truth = make_truth(strip_design(n_single_photo=1), rng(5))
    project_ = perturb(truth, NoiseOptions(sigma_image=0.0), rng(6))
    ip = project_.image_points
    np.testing.assert_array_equal(ip.xy, truth.xy_plate)
    # the ray through each noise-free plate point, from the true centre, passes through the true point
    r = ray_ground(truth.R_ground_from_cam[ip.photo_index], ip.xy, np.broadcast_to(truth.interior, (len(ip), 3)))
    d = truth.xyz_ground[ip.point_index] - truth.xyz0[ip.photo_index]
    miss = np.linalg.norm(np.cross(r / np.linalg.norm(r, axis=1)[:, None], d), axis=1)
    assert miss.max() < 1e-6  # metres
    # noise-free data still carry a finite stated sigma for the weights
    assert np.all(ip.sigma_xy == 0.005) and project_.settings.sigma_image == 0.005


# ----------------------------------------------------------------------------- control layouts


def conditions(truth) -> int:
    """Independent conditions 2k - (3 - d) per point (DESIGN section 3), summed."""
    d = np.array([sum(model.GIVEN_AXES[int(k)]) for k in truth.kind])
    return int(np.maximum(2 * truth.rays_per_point() - (3 - d), 0).sum())


def test_schmid_minimal_pair_has_exactly_twelve_conditions():
    design = SyntheticDesign(control=ControlDesign(layout="schmid-minimal"))
    truth = make_truth(design, rng(7))
    kinds = sorted(model.KIND_NAMES[int(k)] for k in truth.kind)
    assert kinds == sorted(["XYZ", "XYZ", "Z", "tie", "tie"])
    assert np.all(truth.rays_per_point() == 2)
    assert conditions(truth) == 12 == 6 * len(truth.photo_ids)
    # the two full points in the overlap are not on one side: a diagonal of the model
    full = truth.xyz_ground[truth.kind == model.FULL]
    assert abs(full[0, 0] - full[1, 0]) > 500 and abs(full[0, 1] - full[1, 1]) > 500


def test_schmid_minimal_pair_is_exactly_determined():
    # Collinearity with the unknown coordinates as unknowns: 12 exterior elements + 3 per tie point
    # + X, Y of the height point = 20 unknowns for 20 plate coordinates. Schmid: "necessary and
    # sufficient for a unique solution" -> the 20 x 20 Jacobian is regular.
    design = SyntheticDesign(control=ControlDesign(layout="schmid-minimal"))
    truth = make_truth(design, rng(8))
    unknown = np.array([[not g for g in model.GIVEN_AXES[int(k)]] for k in truth.kind])

    def plates(x):
        d = x[:12].reshape(2, 6)
        R = truth.R_ground_from_cam @ exp_so3(d[:, 3:])
        xyz = truth.xyz_ground.copy()
        xyz[unknown] += x[12:]
        return project(R[truth.photo_index], truth.xyz0[truth.photo_index] + d[truth.photo_index, :3],
                       truth.interior, xyz[truth.point_index]).ravel()

    n = 12 + unknown.sum()
    assert n == 20 == 2 * len(truth.photo_index)
    h = 1e-6
    J = np.column_stack([(plates(h * e) - plates(-h * e)) / (2 * h) for e in np.eye(n)])
    s = np.linalg.svd(J, compute_uv=False)
    assert s[-1] / s[0] > 1e-7  # about 1e-5 here; a rank defect would give round-off, 1e-12


def test_schmid_minimal_refuses_extra_points():
    with pytest.raises(ValueError, match="schmid-minimal"):
        SyntheticDesign(control=ControlDesign(layout="schmid-minimal", n_check=1))
    with pytest.raises(ValueError, match="pair"):
        SyntheticDesign(flight=FlightDesign(n_photos=3), control=ControlDesign(layout="schmid-minimal"))


def test_pair_layouts():
    counts = {}
    for layout in ("corners", "mixed"):
        truth = make_truth(SyntheticDesign(control=ControlDesign(layout=layout)), rng(9))
        counts[layout] = sorted(model.KIND_NAMES[int(k)] for k in truth.kind)
    assert counts["corners"] == sorted(["XYZ"] * 4 + ["tie"] * 2)
    assert counts["mixed"] == sorted(["XYZ", "XYZ", "XY", "Z", "tie", "tie"])


def test_strip_layouts():
    ends = make_truth(SyntheticDesign(flight=FlightDesign(n_photos=8), control=ControlDesign(layout="ends")), rng(10))
    full = [pid for pid, k in zip(ends.point_ids, ends.kind) if k == model.FULL]
    assert full == [f"{p}{s}" for p in ("1001", "1002", "1007", "1008") for s in "LR"]
    every = make_truth(strip_design(n_photos=8, every_k=2), rng(10))
    height = [pid for pid, k in zip(every.point_ids, every.kind) if k == model.HEIGHT]
    assert height == ["1003L", "1003R", "1005L", "1005R"]


def test_check_points_spread_along_the_strip():
    truth = make_truth(strip_design(n_photos=8, n_check=4), rng(11))
    x = np.sort(truth.xyz_ground[truth.kind == model.CHECK, 0])
    length = np.ptp(truth.xyz0[:, 0])
    assert len(x) == 4 and np.all(np.diff(x) > 0.1 * length)


# ----------------------------------------------------------------------------- noise


def test_noise_has_the_stated_size():
    design = SyntheticDesign(flight=FlightDesign(n_photos=20), points=PointDesign(extra_ties_per_model=20),
                             control=ControlDesign(layout="every-k", every_k=1, every_k_kind="XYZ"))
    truth = make_truth(design, rng(12))
    noise = NoiseOptions(sigma_image=0.01, sigma_control_xy=0.05, sigma_control_z=0.1, sigma_gnss=0.2)
    p = perturb(truth, noise, rng(13))
    e = p.image_points.xy - truth.xy_plate
    assert len(e) > 1000
    np.testing.assert_allclose(e.std(), 0.01, rtol=0.1)
    assert np.all(p.image_points.sigma_xy == 0.01) and p.settings.sigma_image == 0.01
    control = p.points.kind == model.FULL
    ec = p.points.xyz_given[control] - truth.xyz_ground[control]
    np.testing.assert_allclose(ec.std(axis=0), [0.05, 0.05, 0.1], rtol=0.35)
    np.testing.assert_array_equal(p.points.sigma_given[control], np.tile([0.05, 0.05, 0.1], (control.sum(), 1)))
    assert np.all(np.isnan(p.points.xyz_given[p.points.kind == model.TIE]))
    # GNSS centres: observed with their sigma; angles free
    assert np.all(p.photos.sigma_xyz0 == 0.2) and np.all(np.isnan(p.photos.sigma_angles))
    assert np.abs(p.photos.xyz0 - truth.xyz0).max() < 5 * 0.2


def test_exact_control_is_held_fixed_and_check_points_are_true():
    truth = make_truth(strip_design(n_check=3), rng(14))
    p = perturb(truth, NoiseOptions(), rng(15))
    given = p.points.kind != model.TIE
    assert np.all(np.isnan(p.points.sigma_given))
    for k, axes in model.GIVEN_AXES.items():
        rows = truth.kind == k
        if k == model.CHECK:
            np.testing.assert_array_equal(p.points.xyz_given[rows], truth.xyz_ground[rows])
        else:
            np.testing.assert_array_equal(np.isnan(p.points.xyz_given[rows]), ~np.array(axes)[None].repeat(rows.sum(), 0))
    np.testing.assert_array_equal(p.points.xyz_given[given & (truth.kind == model.FULL)], truth.xyz_ground[truth.kind == model.FULL])


def test_approximate_orientations_are_perturbed_and_free():
    truth = make_truth(strip_design(), rng(16))
    p = perturb(truth, NoiseOptions(approx_position_error=10.0, approx_angle_error=1.0), rng(17))
    dxyz = p.photos.xyz0 - truth.xyz0
    assert 1.0 < np.abs(dxyz).max() < 50.0
    assert np.all(np.isnan(p.photos.sigma_xyz0)) and np.all(np.isnan(p.photos.sigma_angles))
    # the stored angles and the stored rotation agree
    np.testing.assert_allclose(R_from_opk(p.photos.angles), p.photos.R_ground_from_cam, atol=1e-15)


# ----------------------------------------------------------------------------- reproducibility


def same_project(a: model.Project, b: model.Project) -> bool:
    arrays = [
        (a.photos.xyz0, b.photos.xyz0), (a.photos.angles, b.photos.angles),
        (a.image_points.xy, b.image_points.xy), (a.image_points.point_index, b.image_points.point_index),
        (a.points.xyz_given, b.points.xyz_given),
    ]
    return all(x.shape == y.shape and np.array_equal(x, y, equal_nan=True) for x, y in arrays) and a.points.ids == b.points.ids


def test_fixed_seed_reproduces_and_other_seeds_differ():
    options = SimulateOptions(design=strip_design(n_check=2))
    p1, t1 = simulate_project("strip", options, 42)
    p2, t2 = simulate_project("strip", options, 42)
    p3, t3 = simulate_project("strip", options, 43)
    assert same_project(p1, p2)
    np.testing.assert_array_equal(t1["points.csv"]["Z"], t2["points.csv"]["Z"])
    assert not same_project(p1, p3)
    assert not np.array_equal(t1["photos.csv"]["X0"], t3["photos.csv"]["X0"])


def test_same_seed_other_noise_keeps_the_truth():
    design = strip_design()
    _, t1 = simulate_project("strip", SimulateOptions(design, NoiseOptions(sigma_image=0.0)), 5)
    _, t2 = simulate_project("strip", SimulateOptions(design, NoiseOptions(sigma_image=0.02)), 5)
    for table in ("photos.csv", "points.csv"):
        for name, column in t1[table].items():
            assert list(column) == list(t2[table][name])


def test_truth_tables_columns():
    _, tables = simulate_project("pair", SimulateOptions(), 0)
    assert list(tables["photos.csv"]) == ["photo_id", "X0", "Y0", "Z0", "omega", "phi", "kappa"]
    assert list(tables["points.csv"]) == ["point_id", "kind", "X", "Y", "Z"]
    assert np.all(np.abs(np.asarray(tables["photos.csv"]["omega"])) < 10)  # degrees, not radians of a big angle


def test_kind_must_match_the_design():
    with pytest.raises(ValueError, match="pair"):
        simulate_project("pair", SimulateOptions(SyntheticDesign(flight=FlightDesign(n_photos=3),
                                                                 control=ControlDesign(layout="ends"))), 0)
    with pytest.raises(ValueError):
        SyntheticDesign(terrain=TerrainDesign(relief=-1.0))


# ----------------------------------------------------------------------------- blocks


def block_design(n_strips=3, n_photos=6, overlap=0.6, sidelap=0.3, alternate=True, layout="perimeter", extra_ties=3,
                 **control):
    return SyntheticDesign(
        flight=FlightDesign(n_photos=n_photos, n_strips=n_strips, overlap=overlap, sidelap=sidelap, alternate=alternate),
        points=PointDesign(extra_ties_per_model=extra_ties),
        control=ControlDesign(layout=layout, **control),
    )


def kinds_of(truth) -> dict[str, str]:
    return {pid: model.KIND_NAMES[int(k)] for pid, k in zip(truth.point_ids, truth.kind)}


def rays_of(truth) -> dict[str, int]:
    return dict(zip(truth.point_ids, truth.rays_per_point().tolist()))


@pytest.mark.parametrize("alternate", [True, False])
def test_block_photos_strip_after_strip_in_flight_order(alternate):
    design = ideal(block_design(n_strips=3, n_photos=5, alternate=alternate))
    truth = make_truth(design, rng())
    assert truth.photo_ids == [f"{s}{k:03d}" for s in (1, 2, 3) for k in range(1, 6)]
    assert truth.strip_ids == [str(s) for s in (1, 2, 3) for _ in range(5)]
    x = truth.xyz0[:, 0].reshape(3, 5)
    for s in range(3):
        backwards = alternate and s == 1
        assert np.all(np.diff(x[s]) < 0) if backwards else np.all(np.diff(x[s]) > 0)
        np.testing.assert_allclose(np.sort(x[s]), x[0], atol=1e-9)  # the same columns in every strip
        # a strip flown backwards looks the other way: kappa = heading + 180 deg
        np.testing.assert_allclose(truth.R_ground_from_cam[5 * s, :2, 0], [-1, 0] if backwards else [1, 0], atol=1e-12)


@pytest.mark.parametrize("sidelap", [0.2, 0.3, 0.6])
def test_sidelap_achieved(sidelap):
    design = ideal(block_design(n_strips=3, sidelap=sidelap))
    truth = make_truth(design, rng())
    footprint = design.camera.format * design.scale
    y_axis = truth.xyz0[:, 1].reshape(3, -1).mean(axis=1)
    np.testing.assert_allclose(1 - np.diff(y_axis) / footprint, sidelap, atol=1e-12)
    # the sidelap point between strips 1 and 2 at the nadir of 1003 lies half the strip spacing
    # (on the plate) to the left of strip 1, and as far from strip 2's axis (on its left: flown back)
    half = (1 - sidelap) * design.camera.format / 2
    np.testing.assert_allclose(plate_of(truth, "1003", "1003L"), [0, half], atol=1e-9)
    np.testing.assert_allclose(plate_of(truth, "2004", "1003L"), [0, half], atol=1e-9)  # 2004: column 3 of 6, back


def test_sidelap_with_deviations_is_near_nominal():
    design = block_design(n_strips=3, n_photos=8, sidelap=0.3)
    truth = make_truth(design, rng(3))
    footprint = design.camera.format * design.scale
    spacing = np.diff(truth.xyz0[:, 1].reshape(3, -1).mean(axis=1))
    # position_std 5 m across track against a 1589 m strip spacing: sidelap within 0.3 +/- 0.01
    np.testing.assert_allclose(1 - spacing / footprint, 0.3, atol=0.01)


@pytest.mark.parametrize("overlap", [0.6, 2 / 3])
@pytest.mark.parametrize("alternate", [True, False])
def test_rays_in_the_sidelap(overlap, alternate):
    # 30 % sidelap: a point in the middle of the sidelap is in 3 photos of each strip (2 at the
    # block ends): 6 rays (4); no point is in more than two strips.
    design = block_design(n_strips=3, n_photos=6, overlap=overlap, alternate=alternate, layout="none")
    truth = make_truth(design, rng(21))
    rays = rays_of(truth)
    first, last = "1001", "1006"
    for k in range(1, 7):
        expected = 4 if k in (1, 6) else 6
        assert rays[f"100{k}L"] == expected and rays[f"100{k}C"] == expected // 2, k
    assert max(rays.values()) == 6
    # the sidelap point is measured on photos of both strips
    strips = {truth.strip_ids[i] for i in truth.photo_index[truth.point_index == truth.point_ids.index("1003L")]}
    assert strips == {"1", "2"}
    assert rays[f"{first}R"] == 2 and rays[f"{last}R"] == 2


def test_nine_rays_with_60_percent_sidelap():
    # 60 % sidelap: the nadir points of the middle strip are also seen by both neighbouring strips,
    # 3 photos each: 9 rays inside the block
    design = block_design(n_strips=3, n_photos=6, sidelap=0.6, layout="none")
    truth = make_truth(design, rng(22))
    rays = rays_of(truth)
    middle = [f"200{k}C" for k in range(2, 6)]
    assert [rays[p] for p in middle] == [9] * 4
    assert max(rays.values()) == 9
    assert rays["1003C"] == 6 and rays["1003L"] == 6  # strip 1's nadir points: strips 1 and 2


def test_extra_ties_in_the_sidelap_have_more_rays():
    design = block_design(n_strips=2, n_photos=6, layout="none", extra_ties=30)
    truth = make_truth(design, rng(23))
    ties = np.array([pid.startswith("T") for pid in truth.point_ids])
    rays = truth.rays_per_point()[ties]
    assert ties.sum() == 2 * 5 * 30 and rays.min() >= 2 and rays.max() <= 6
    strips_seen = np.zeros(len(truth.point_ids), dtype=int)
    for strip in ("1", "2"):
        in_strip = np.array([truth.strip_ids[i] == strip for i in truth.photo_index])
        strips_seen += np.bincount(truth.point_index[in_strip], minlength=len(truth.point_ids)) > 0
    two = strips_seen[ties] == 2
    # one strip gives a tie point 2 or 3 rays (60 % overlap); the sidelap adds the other strip's
    assert two.sum() > 20 and rays[~two].max() == 3 and rays.max() == 6
    assert rays[two].mean() > rays[~two].mean() + 1


def test_pass_points_named_once_per_sidelap():
    truth = make_truth(ideal(block_design(n_strips=3, n_photos=4, alternate=True, layout="none", extra_ties=0)), rng())
    ids = set(truth.point_ids)
    assert len(ids) == len(truth.point_ids) == 4 * 7  # 4 columns x (2 * 3 + 1) rows
    # strip 1 names R, C, L; strip 2 (flown back) C and R (its L is strip 1's L); strip 3 C and L
    assert {p[-1] for p in ids if p.startswith("1")} == set("LCR")
    assert {p[-1] for p in ids if p.startswith("2")} == set("CR")
    assert {p[-1] for p in ids if p.startswith("3")} == set("CL")
    same = make_truth(ideal(block_design(n_strips=3, n_photos=4, alternate=False, layout="none", extra_ties=0)), rng())
    assert {p[-1] for p in same.point_ids if p.startswith("2")} == set("CL")


def test_block_layout_perimeter():
    truth = make_truth(block_design(n_strips=3, n_photos=6, every_k=2), rng(24))
    kinds = kinds_of(truth)
    # columns 0, 2, 4 and the last (5); lateral rows: strip 1's R, the sidelaps (1L, 2R), strip 3's L
    full = {p for p, k in kinds.items() if k == "XYZ"}
    height = {p for p, k in kinds.items() if k == "Z"}
    outer = {f"100{c + 1}R" for c in (0, 2, 4, 5)} | {f"300{c + 1}L" for c in (0, 2, 4, 5)}
    ends = {"1001L", "1006L", "2006R", "2001R"}  # the sidelap rows at columns 0 and 5 (strip 2 flown back)
    assert full == outer | ends
    assert height == {"1003L", "1005L", "2004R", "2002R"}
    assert len(full) == 2 * 4 + 2 * 2 and len(height) == 2 * 2


def test_block_layout_ends_every_k_sparse_height():
    ends = kinds_of(make_truth(block_design(layout="ends"), rng(25)))
    # the 4 lateral rows at columns 0, 1, 4, 5
    assert sum(k == "XYZ" for k in ends.values()) == 4 * 4 and "Z" not in ends.values()
    every = kinds_of(make_truth(block_design(layout="every-k", every_k=2), rng(25)))
    # plus the lateral rows at column 2 (column 4 is already in the last model)
    assert sum(k == "XYZ" for k in every.values()) == 16 and sum(k == "Z" for k in every.values()) == 4
    sparse = kinds_of(make_truth(block_design(layout="sparse-height", every_k=2), rng(25)))
    assert {p for p, k in sparse.items() if k == "XYZ"} == {"1001R", "1006R", "3001L", "3006L"}
    # Z on the 4 lateral rows at columns 0, 2, 4, 5, except the 4 corners
    assert sum(k == "Z" for k in sparse.values()) == 4 * 4 - 4


def test_strip_layouts_perimeter_and_sparse_height():
    perimeter = kinds_of(make_truth(SyntheticDesign(flight=FlightDesign(n_photos=7),
                                                    control=ControlDesign(layout="perimeter", every_k=3)), rng(26)))
    assert {p for p, k in perimeter.items() if k == "XYZ"} == {f"100{c}{s}" for c in (1, 4, 7) for s in "LR"}
    sparse = kinds_of(make_truth(SyntheticDesign(flight=FlightDesign(n_photos=7),
                                                 control=ControlDesign(layout="sparse-height", every_k=3)), rng(26)))
    assert {p for p, k in sparse.items() if k == "XYZ"} == {"1001L", "1001R", "1007L", "1007R"}
    assert {p for p, k in sparse.items() if k == "Z"} == {"1004L", "1004R"}


def test_block_check_points_shared_out_over_the_strips():
    design = block_design(n_strips=3, n_photos=8, extra_ties=4, n_check=7)
    truth = make_truth(design, rng(27))
    check = truth.kind == model.CHECK
    assert check.sum() == 7
    across = truth.xyz_ground[check, 1] - design.flight.start_xy[1]  # flown along +X, strips towards +Y
    strip = np.clip(np.floor(across / design.strip_spacing + 0.5), 0, 2)  # the nearest strip axis
    assert np.bincount(strip.astype(int), minlength=3).tolist() == [3, 2, 2]
    for s in range(3):  # spread along each strip
        x = np.sort(truth.xyz_ground[check, 0][strip == s])
        assert np.all(np.diff(x) > 0.1 * np.ptp(truth.xyz0[:, 0]))


def test_block_single_photo_control_outside_the_other_strips():
    design = block_design(n_strips=3, n_photos=6, sidelap=0.6, n_single_photo=2)
    truth = make_truth(design, rng(28))
    rays = rays_of(truth)
    assert rays["1001S"] == 1 and rays["1006S"] == 1
    assert kinds_of(truth)["1001S"] == "XYZ"


@pytest.mark.parametrize("layout", BLOCK_LAYOUTS)
def test_block_layouts_are_strip_layouts_too(layout):
    truth = make_truth(SyntheticDesign(flight=FlightDesign(n_photos=6), control=ControlDesign(layout=layout)), rng(29))
    assert np.sum(truth.kind == model.FULL) >= 3


def test_block_reproducible_with_seeds():
    options = SimulateOptions(block_design(n_check=3))
    p1, t1 = simulate_project("block", options, 42)
    p2, _ = simulate_project("block", options, 42)
    p3, _ = simulate_project("block", options, 43)
    assert same_project(p1, p2) and not same_project(p1, p3)
    _, t4 = simulate_project("block", SimulateOptions(options.design, NoiseOptions(sigma_image=0.0, sigma_gnss=0.1)), 42)
    for table in ("photos.csv", "points.csv"):
        for name, column in t1[table].items():
            assert list(column) == list(t4[table][name])


def test_block_with_gnss_centres_and_weighted_control():
    design = block_design(n_strips=2, n_photos=5)
    p, _ = simulate_project("block", SimulateOptions(design, NoiseOptions(sigma_gnss=0.1, sigma_control_xy=0.02,
                                                                          sigma_control_z=0.03)), 7)
    assert np.all(p.photos.sigma_xyz0 == 0.1)
    full = p.points.kind == model.FULL
    np.testing.assert_array_equal(p.points.sigma_given[full], np.tile([0.02, 0.02, 0.03], (full.sum(), 1)))


def test_kind_must_match_the_number_of_strips():
    with pytest.raises(ValueError, match="block"):
        simulate_project("strip", SimulateOptions(block_design(n_strips=2)), 0)
    with pytest.raises(ValueError, match="2 strips or more"):
        simulate_project("block", SimulateOptions(block_design(n_strips=1)), 0)
    with pytest.raises(ValueError, match="pair"):
        block_design(layout="corners")
    with pytest.raises(ValueError, match="sidelap"):
        FlightDesign(n_strips=2, sidelap=0.9)


# ----------------------------------------------------------------------------- CLI


def test_cli_simulate_writes_a_project_folder(tmp_path):
    out = tmp_path / "strip"
    result = CliRunner().invoke(
        main,
        ["simulate", "strip", "--out", str(out), "--photos", "6", "--control", "every-k", "--check-points", "2",
         "--extra-ties", "2", "--seed", "3"],
    )
    assert result.exit_code == 0, result.output
    for name in ("cameras.csv", "photos.csv", "image_points.csv", "control.csv", "truth/photos.csv", "truth/points.csv"):
        assert (out / name).is_file(), name
    read = read_project(out)
    expected, _ = simulate_project(
        "strip",
        SimulateOptions(SyntheticDesign(flight=FlightDesign(n_photos=6), points=PointDesign(extra_ties_per_model=2),
                                        control=ControlDesign(layout="every-k", n_check=2))),
        3,
    )
    assert sorted(read.photos.ids) == sorted(expected.photos.ids)
    assert sorted(read.points.ids) == sorted(expected.points.ids)
    assert len(read.image_points) == len(expected.image_points)
    assert np.sum(read.points.kind == model.CHECK) == 2


def test_cli_bad_options_exit_2(tmp_path):
    result = CliRunner().invoke(main, ["simulate", "strip", "--out", str(tmp_path / "x"), "--overlap", "0.3"])
    assert result.exit_code == 2
    assert "overlap" in result.output
    assert not (tmp_path / "x").exists()


def test_reports_errors_maps_failures_to_exit_status():
    @click.command()
    @click.argument("what")
    @reports_errors
    def fails(what):
        if what == "input":
            raise InputError("photos.csv", 3, "X0 is not a number")
        raise NumericalFailure("datum defect: rotation about the strip axis")

    runner = CliRunner()
    bad_input = runner.invoke(fails, ["input"])
    assert bad_input.exit_code == 2
    assert "striptri: error: photos.csv, line 3: X0 is not a number" in bad_input.output
    numerical = runner.invoke(fails, ["numerical"])
    assert numerical.exit_code == 1
    assert "striptri: error: datum defect" in numerical.output


def test_cli_simulate_block(tmp_path):
    out = tmp_path / "block"
    result = CliRunner().invoke(
        main,
        ["simulate", "block", "--out", str(out), "--strips", "2", "--photos", "4", "--sidelap", "0.3",
         "--same-direction", "--control", "sparse-height", "--gnss-sigma", "0.1", "--sigma-control", "0.02",
         "--check-points", "2", "--extra-ties", "2", "--seed", "5"],
    )
    assert result.exit_code == 0, result.output
    read = read_project(out)
    assert read.photos.ids == [f"{s}00{k}" for s in (1, 2) for k in range(1, 5)]
    assert read.photos.strip_ids == ["1"] * 4 + ["2"] * 4
    assert np.all(read.photos.sigma_xyz0 == 0.1)
    assert np.sum(read.points.kind == model.CHECK) == 2
    full = read.points.kind == model.FULL
    assert full.sum() == 4 and np.all(read.points.sigma_given[full] == 0.02)
    # alternate (the default) flies strip 2 back: its first photo is at the end of strip 1
    back = tmp_path / "back"
    CliRunner().invoke(main, ["simulate", "block", "--out", str(back), "--strips", "2", "--photos", "4"])
    x0 = read_project(back).photos.xyz0[:, 0]
    assert x0[4] > x0[5] and abs(x0[4] - x0[3]) < 100


@pytest.mark.parametrize("args", [["strip", "--strips", "2"], ["block", "--strips", "1"], ["block", "--sidelap", "0.95"],
                                  ["block", "--control", "mixed"], ["strip", "--overlap", "2/0"]])
def test_cli_block_bad_options_exit_2(tmp_path, args):
    result = CliRunner().invoke(main, ["simulate", args[0], "--out", str(tmp_path / "x"), *args[1:]])
    assert result.exit_code == 2, result.output
    assert not (tmp_path / "x").exists()


def readme_commands() -> list[tuple[str, list[str]]]:
    """(folder, arguments) of every `striptri simulate ...` command in data/synthetic_strips/README.md."""
    text = (DATA / "README.md").read_text()
    commands = re.findall(r"`striptri (simulate [^`]+)`", text)
    out = []
    for command in commands:
        args = shlex.split(command)
        folder = Path(args[args.index("--out") + 1]).name
        out.append((folder, args))
    return out


def test_readme_lists_every_data_folder():
    folders = {folder for folder, _ in readme_commands()}
    assert folders == {p.name for p in DATA.iterdir() if p.is_dir()}
    assert {"schmid_fig8", "strip_2_3", "block_3x6"} <= folders


@pytest.mark.parametrize("folder, args", readme_commands(), ids=[f for f, _ in readme_commands()])
def test_readme_commands_regenerate_the_committed_data(tmp_path, folder, args):
    args = list(args)
    args[args.index("--out") + 1] = str(tmp_path / folder)
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    committed = sorted(p.relative_to(DATA / folder) for p in (DATA / folder).rglob("*.csv"))
    made = sorted(p.relative_to(tmp_path / folder) for p in (tmp_path / folder).rglob("*.csv"))
    assert committed == made
    for name in [*committed, Path("project.toml")]:
        assert (tmp_path / folder / name).read_text() == (DATA / folder / name).read_text(), name
