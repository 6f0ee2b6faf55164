"""The synthetic data generator: geometry of the design, noise, reproducibility, the CLI."""

from __future__ import annotations

from dataclasses import replace

import click
import numpy as np
import pytest
from click.testing import CliRunner

from striptri import model
from striptri.camera import project, ray_ground
from striptri.cli import main, reports_errors
from striptri.errors import InputError, NumericalFailure
from striptri.io import read_project
from striptri.rotations import R_from_opk, exp_so3
from striptri.simulate import (
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
