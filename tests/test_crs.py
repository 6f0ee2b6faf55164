"""Map coordinates (striptri.crs): the local frame against central differences, round trips, the
[coordinates] InputErrors, and a 20 km block on the ellipsoid adjusted naively, with its CRS and
in its local frame (docs/decisions.md, "Map coordinates")."""

from __future__ import annotations

import csv
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from striptri.core.runs import RunOptions
from striptri import simulate as sim
from striptri.cli import main
from striptri.crs.frame import LocalFrame, angle_sigmas
from striptri.errors import InputError
from striptri.io.project_reader import parse_settings, read_project
from striptri.io.project_writer import write_project
from striptri.model import CoordinateSettings
from striptri.pipeline import run_adjust
from striptri.geometry.rotations import R_from_opk, angles_jacobian, exp_so3
from striptri.simulate.map_coordinates import central_meridian, to_map_coordinates

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from demo_crs import block_design, check_errors  # noqa: E402

UTM33 = "EPSG:32633"
CENTRE = np.array([736000.0, 5320000.0, 0.0])  # about 3 deg east of 15 E, 48 N


@pytest.fixture(params=[("ellipsoidal", None), ("orthometric", 47.25)], ids=["ellipsoidal", "orthometric"])
def frame(request):
    heights, n = request.param
    return LocalFrame(CoordinateSettings(UTM33, heights, geoid_undulation=n), CENTRE)


def _grid_points(rng, n=20):
    return CENTRE + rng.uniform([-12e3, -12e3, -100.0], [12e3, 12e3, 3000.0], (n, 3))


def test_points_round_trip_to_1e6_m(frame):
    g = _grid_points(np.random.default_rng(1))
    local = frame.to_local(g)
    assert np.abs(frame.from_local(local) - g).max() < 1e-6
    assert np.all(np.isnan(frame.to_local(np.array([[np.nan, 1.0, 2.0]]))))


def test_orthometric_heights_are_ellipsoidal_minus_the_undulation():
    ell = LocalFrame(CoordinateSettings(UTM33, "ellipsoidal"), CENTRE)
    ort = LocalFrame(CoordinateSettings(UTM33, "orthometric", geoid_undulation=47.25), CENTRE)
    g = _grid_points(np.random.default_rng(2))
    h = g + [0.0, 0.0, 47.25]  # h = H + N
    assert np.abs(ort.to_local(g) - ell.to_local(h)).max() < 1e-6


def test_local_frame_is_topocentric_at_the_centre(frame):
    # the centre on the ellipsoid is the origin; 1 m up the normal there is (0, 0, 1); X along grid east
    n = frame.geoid_undulation([frame.origin.lon], [frame.origin.lat])[0]
    assert np.abs(frame.to_local(CENTRE - [0.0, 0.0, n])).max() < 1e-6
    up = frame.to_local(CENTRE + [0.0, 0.0, 1.0 - n])[0]
    assert np.abs(up - [0.0, 0.0, 1.0]).max() < 1e-6
    east = frame.to_local(CENTRE + [1.0, 0.0, -n])[0]
    assert abs(east[1]) < 1e-6 and abs(east[2]) < 1e-6


def _central_jacobian(frame, g, h=0.5):
    return np.stack([(frame.to_local(g + h * e) - frame.to_local(g - h * e)) / (2 * h) for e in np.eye(3)], -1)


def test_jacobian_and_rotation_against_central_differences(frame):
    g = _grid_points(np.random.default_rng(3))
    J = _central_jacobian(frame, g)
    assert np.abs(J - frame.jacobian(g)).max() < 1e-7  # central differences are good to h^2 f''' ~ 1e-9
    U, _, Vt = np.linalg.svd(J)
    R = frame.R_local_from_grid(g)
    assert np.abs(U @ Vt - R).max() < 1e-7  # the orthonormalised Jacobian (polar factor)
    assert np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max() < 1e-12
    # the rotation is not the identity away from the centre: the vertical tilts by d / R
    tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1, 1)))
    assert tilt.max() > 0.05


def test_photo_rotation_maps_directions_like_the_points(frame):
    """A short displacement along a camera ray maps with the Jacobian (central differences); the
    photo rotation is its orthonormal part, so a ray's direction differs from the mapped one only by
    the projection's scale k in plan against 1 in height: at most |1 - 1/k| sin(2 tilt) / 2 rad
    (tilt from the vertical); and rotations round trip."""
    rng = np.random.default_rng(4)
    O = _grid_points(rng, 10)
    R_grid = R_from_opk(rng.normal(0.0, 0.05, (10, 3)) + [0.0, 0.0, 1.0])
    R_local = frame.rotations_to_local(O, R_grid)
    ray_cam = np.array([0.01, -0.02, -1.0])
    d_grid = R_grid @ ray_cam
    d_local = (frame.to_local(O + d_grid) - frame.to_local(O - d_grid)) / 2  # 1 m: round-off 1e-9 m
    assert np.abs(d_local - np.einsum("nij,nj->ni", frame.jacobian(O), d_grid)).max() < 1e-7
    d_local = np.einsum("nij,nj->ni", frame.jacobian(O), d_grid)
    u_mapped = d_local / np.linalg.norm(d_local, axis=1)[:, None]
    u_rotated = (R_local @ ray_cam) / np.linalg.norm(ray_cam)
    k = np.linalg.norm(d_grid[:, :2], axis=1) / np.linalg.norm(d_local[:, :2], axis=1)  # about the point scale
    tilt = np.arccos(np.abs(u_rotated[:, 2]))
    bound = np.abs(1 - 1 / k) * np.sin(2 * tilt) / 2 * 1.01 + 1e-9
    assert np.all(np.linalg.norm(u_mapped - u_rotated, axis=1) < bound)
    back = frame.rotations_to_grid(frame.to_local(O), R_local)
    assert np.abs(back - R_grid).max() < 1e-12


def test_angle_sigmas_against_central_differences():
    rng = np.random.default_rng(5)
    R_from = R_from_opk(rng.normal(0.0, 0.1, (6, 3)))
    C = exp_so3(rng.normal(0.0, 0.05, (6, 3)))
    R_to = C @ R_from
    sig = np.full((6, 3), 1e-4)
    # d angles_to / d angles_from by central differences in angle space
    from striptri.geometry.rotations import opk_from_R
    a = opk_from_R(R_from)
    h = 1e-6
    J = np.stack([(opk_from_R(C @ R_from_opk(a + h * e)) - opk_from_R(C @ R_from_opk(a - h * e))) / (2 * h)
                  for e in np.eye(3)], -1)
    expected = np.sqrt(np.einsum("nij,nj->ni", J**2, sig**2))
    assert np.abs(angle_sigmas(R_from, R_to, sig, "omega-phi-kappa") - expected).max() < 1e-10
    assert angles_jacobian(R_from, "omega-phi-kappa").shape == (6, 3, 3)


def test_sigmas_round_trip_and_keep_held_and_free(frame):
    g = _grid_points(np.random.default_rng(6), 4)
    sig = np.array([[0.05, 0.05, 0.1], [np.nan] * 3, [0.0] * 3, [0.02, np.nan, 0.1]])
    local = frame.sigmas_to_local(g, sig)
    assert np.isnan(local[1]).all() and np.all(local[2] == 0) and np.array_equal(local[3], sig[3], equal_nan=True)
    # not exact: each way drops the correlations J creates (of order tilt * (sigma_Z^2 - sigma_XY^2))
    assert np.abs(frame.sigmas_to_grid(frame.to_local(g), local)[0] - sig[0]).max() < 1e-6


# ------------------------------------------------------------------------------------- project.toml

TOML_OK = '[coordinates]\ncrs = "EPSG:32633"\nheights = "ellipsoidal"\n'


@pytest.mark.parametrize("body, line, reason", [
    ('[coordinates]\ncrs = "EPSG:99999"\nheights = "ellipsoidal"\n', 2, "not a CRS PROJ knows"),
    ('[coordinates]\ncrs = "EPSG:4326"\nheights = "ellipsoidal"\n', 2, "geographic"),
    ('[coordinates]\ncrs = "EPSG:4978"\nheights = "ellipsoidal"\n', 2, "geocentric"),
    ('[coordinates]\ncrs = "EPSG:2229"\nheights = "ellipsoidal"\n', 2, "metres"),
    ('[coordinates]\nheights = "ellipsoidal"\n', None, "missing"),
    ('[coordinates]\ncrs = "EPSG:32633"\n', 2, "needs heights"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "normal"\n', 3, "is not one of"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "orthometric"\n', 3, "geoid undulation"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "ellipsoidal"\ngeoid_undulation = 40\n', 4, "ellipsoidal"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "orthometric"\ngeoid_undulation = 400\n', 4, "geoid undulation"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "orthometric"\ngeoid_grid = "nothing.gtx"\n', 4, "not found"),
    ('[coordinates]\ncrs = "EPSG:32633"\nheights = "ellipsoidal"\ndatum = "x"\n', 4, "unknown key"),
])
def test_bad_coordinates_are_input_errors(tmp_path, body, line, reason):
    with pytest.raises(InputError) as err:
        parse_settings(tmp_path / "project.toml", body)
    assert err.value.line == line and reason in err.value.reason and err.value.path.endswith("project.toml")


def test_good_coordinates_are_read(tmp_path):
    s = parse_settings(tmp_path / "project.toml", TOML_OK).coordinates
    assert (s.crs, s.heights, s.geoid_undulation) == ("EPSG:32633", "ellipsoidal", None)
    s = parse_settings(tmp_path / "project.toml", TOML_OK.replace('"ellipsoidal"', '"orthometric"')
                       + "geoid_undulation = 47\n").coordinates
    assert s.geoid_undulation == 47.0


def test_geoid_grid_through_proj(tmp_path):
    """A PROJ .gtx grid (constant 30 m over 10..25 E, 40..55 N) gives h = H + 30 like the constant."""
    header = np.array([40.0, 10.0, 1.0, 1.0], dtype=">f8").tobytes() + np.array([16, 16], dtype=">i4").tobytes()
    (tmp_path / "geoid.gtx").write_bytes(header + np.full(16 * 16, 30.0, dtype=">f4").tobytes())
    s = parse_settings(tmp_path / "project.toml", TOML_OK.replace('"ellipsoidal"', '"orthometric"')
                       + 'geoid_grid = "geoid.gtx"\n').coordinates
    grid = LocalFrame(s, CENTRE)
    const = LocalFrame(CoordinateSettings(UTM33, "orthometric", geoid_undulation=30.0), CENTRE)
    g = _grid_points(np.random.default_rng(7))
    assert np.abs(grid.to_local(g) - const.to_local(g)).max() < 1e-6
    with pytest.raises(InputError, match="does not cover"):
        grid.to_local(np.array([[500000.0, 1000000.0, 0.0]]))


def test_cli_bad_crs_exits_2(tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2"])
    assert res.exit_code == 0, res.output
    (tmp_path / "p" / "project.toml").write_text('[coordinates]\ncrs = "EPSG:4326"\nheights = "ellipsoidal"\n')
    res = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "o"), "--quiet"])
    assert res.exit_code == 2 and "project.toml, line 2" in res.output and "geographic" in res.output
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------- whole projects


@pytest.mark.parametrize("heights, n", [("ellipsoidal", None), ("orthometric", -12.5)])
def test_held_control_and_centres_written_back_unchanged(tmp_path, heights, n):
    """simulate --crs, centres held (sigma 0): points.csv's control and photos.csv's centres are the
    input's to 1e-6 m."""
    runner = CliRunner()
    args = ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2", "--crs", UTM33, "--heights", heights, "--flying-height", "2000"]
    if n is not None:
        args += ["--geoid-undulation", str(n)]
    assert runner.invoke(main, args).exit_code == 0
    # hold the photo centres at their given values
    photos = list(csv.DictReader((tmp_path / "p" / "photos.csv").open()))
    for row in photos:
        for a in ("X0", "Y0", "Z0"):
            row[f"sigma_{a}"] = "0"
    with (tmp_path / "p" / "photos.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(photos[0]))
        w.writeheader()
        w.writerows(photos)
    project = read_project(tmp_path / "p")
    assert project.settings.coordinates.heights == heights
    run_adjust(tmp_path / "p", tmp_path / "o", RunOptions(method="bundle"))
    given = {r["point_id"]: [float(r[a]) for a in "XYZ"] for r in csv.DictReader((tmp_path / "p" / "control.csv").open())
             if r["kind"] == "XYZ"}
    out = {r["point_id"]: [float(r[a]) for a in "XYZ"] for r in csv.DictReader((tmp_path / "o" / "points.csv").open())
           if r["kind"] == "XYZ"}
    assert out and max(np.abs(np.subtract(out[k], given[k])).max() for k in out) < 1e-6
    centres_in = np.array([[float(r[a]) for a in ("X0", "Y0", "Z0")] for r in photos])
    centres_out = np.array([[float(r[a]) for a in ("X0", "Y0", "Z0")]
                            for r in csv.DictReader((tmp_path / "o" / "photos.csv").open())])
    assert np.abs(centres_out - centres_in).max() < 1e-6
    frame = json.loads((tmp_path / "o" / "summary.json").read_text())["frame"]
    assert frame["crs"] == UTM33 and frame["heights"] == heights
    assert "coordinate frame" in (tmp_path / "o" / "report.html").read_text()


def test_project_without_coordinates_has_no_frame_key(tmp_path):
    runner = CliRunner()
    assert runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2"]).exit_code == 0
    assert "[coordinates]" not in (tmp_path / "p" / "project.toml").read_text()
    run_adjust(tmp_path / "p", tmp_path / "o")
    assert "frame" not in json.loads((tmp_path / "o" / "summary.json").read_text())


def test_20km_block_naive_grid_is_biased_crs_matches_local_frame(tmp_path):
    """A 20 km x 20 km block on the ellipsoid, 3 deg east of the central meridian of UTM 33 at 48 N,
    perimeter control (full and height points), 64 check points. Adjusted in grid coordinates
    without [coordinates] its check points are off by a systematic height error (about 0.19 m at
    this noise: over 5 standard errors of the mean); with the CRS set, each check point agrees with
    the adjustment in the simulator's local frame to a millimetre (the bundle is invariant to the
    change of frame), so the RMS agrees within 10 % and the mean error lies within 3 standard errors.
    The perimeter's height points need the pipeline's re-conversion at their adjusted position:
    converted only at the intersection of the approximate rays they differ by 3.6 cm."""
    design = block_design(20.0, 3000.0)
    noise = sim.NoiseOptions(sigma_image=0.003, approx_position_error=10.0, approx_angle_error=0.5)
    local, truth_local = sim.simulate_project("block", sim.SimulateOptions(design, noise), 11)
    coordinates = CoordinateSettings(crs=UTM33, heights="ellipsoidal")
    grid, truth_grid = to_map_coordinates(local, truth_local, coordinates, 48.0, central_meridian(UTM33) + 3.0)
    naive = replace(grid, settings=replace(grid.settings, coordinates=None))
    errors = {}
    for name, project, truth in (("local", local, truth_local), ("crs", grid, truth_grid), ("naive", naive, truth_grid)):
        write_project(tmp_path / name, project, truth_tables=truth)
        run_adjust(tmp_path / name, tmp_path / f"out-{name}", RunOptions(method="bundle"))
        errors[name] = check_errors(tmp_path / f"out-{name}", truth)
    e_local, e_crs, e_naive = errors["local"], errors["crs"], errors["naive"]
    n = len(e_local)
    assert n == 64
    rms = {k: np.sqrt(np.mean(e**2, axis=0)) for k, e in errors.items()}
    # CRS set: the local frame's result, point by point (the grid's scale 1.0005 on 0.1 m: 5e-5 m)
    assert np.abs(e_crs - e_local).max() < 2e-3
    assert np.all(np.abs(rms["crs"] / rms["local"] - 1.0) < 0.10)
    se = np.std(e_crs, axis=0, ddof=1) / np.sqrt(n)
    assert np.all(np.abs(e_crs.mean(axis=0)) < 3 * se)
    # naive: a systematic height error of many standard errors, and a worse RMS in Z
    se_naive = np.std(e_naive, axis=0, ddof=1) / np.sqrt(n)
    assert abs(e_naive[:, 2].mean()) > 5 * se_naive[2]
    assert rms["naive"][2] > 1.3 * rms["local"][2]


def test_bases_csv_with_coordinates_is_an_input_error(tmp_path):
    runner = CliRunner()
    assert runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2",
                                "--crs", UTM33]).exit_code == 0
    (tmp_path / "p" / "bases.csv").write_text("photo_from,photo_to,component,value,sigma\n1001,1002,bz,0.0,0.5\n")
    res = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "o"), "--quiet"])
    assert res.exit_code == 2 and "bases.csv" in res.output and "project.toml, line" in res.output
    assert not (tmp_path / "o").exists()


def test_simulate_naive_writes_the_same_numbers_without_coordinates(tmp_path):
    runner = CliRunner()
    base = ["simulate", "block", "--photos", "4", "--strips", "2", "--crs", UTM33, "--seed", "3"]
    assert runner.invoke(main, base + ["--out", str(tmp_path / "crs")]).exit_code == 0
    assert runner.invoke(main, base + ["--out", str(tmp_path / "naive"), "--naive"]).exit_code == 0
    for name in ("control.csv", "photos.csv", "image_points.csv", "truth/points.csv"):
        assert (tmp_path / "crs" / name).read_text() == (tmp_path / "naive" / name).read_text()
    assert "[coordinates]" in (tmp_path / "crs" / "project.toml").read_text()
    assert "[coordinates]" not in (tmp_path / "naive" / "project.toml").read_text()
    res = runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "x"), "--naive"])
    assert res.exit_code == 2 and "need --crs" in res.output


def test_gnss_and_imu_observations_agree_with_the_local_frame(tmp_path):
    """Centres observed by GNSS (0.05 m) and angles by an IMU (0.005 deg), given in the grid's axes:
    the CRS adjustment has the local frame's vTPv (the same observations and weights, converted) to
    0.1 % and its check points to a millimetre; wrong angles (the grid's taken as local, i.e. the
    convergence and the tilt of the vertical ignored) would make the IMU observations disagree by
    up to 2 deg and multiply vTPv."""
    design = block_design(12.0, 3000.0)
    noise = sim.NoiseOptions(sigma_image=0.003, sigma_gnss=0.05, approx_angle_error=0.005)
    local, truth_local = sim.simulate_project("block", sim.SimulateOptions(design, noise), 5)
    n = len(local.photos)
    local = replace(local, photos=replace(local.photos, sigma_angles=np.full((n, 3), np.radians(0.005))))
    coordinates = CoordinateSettings(crs=UTM33, heights="orthometric", geoid_undulation=44.0)
    grid, truth_grid = to_map_coordinates(local, truth_local, coordinates, 48.0, central_meridian(UTM33) + 3.0)
    results = {}
    for name, project, truth in (("local", local, truth_local), ("crs", grid, truth_grid)):
        write_project(tmp_path / name, project, truth_tables=truth)
        products = run_adjust(tmp_path / name, tmp_path / f"out-{name}", RunOptions(method="bundle"))
        results[name] = (products.result.vtpv, check_errors(tmp_path / f"out-{name}", truth))
    (v_local, e_local), (v_crs, e_crs) = results["local"], results["crs"]
    assert abs(v_crs / v_local - 1.0) < 1e-3
    assert np.abs(e_crs - e_local).max() < 1e-3


def test_wkt_crs_is_read(tmp_path):
    import pyproj

    wkt = pyproj.CRS("EPSG:32633").to_wkt()
    s = parse_settings(tmp_path / "project.toml", f"[coordinates]\ncrs = '''{wkt}'''\nheights = \"ellipsoidal\"\n")
    frame = LocalFrame(s.coordinates, CENTRE)
    g = _grid_points(np.random.default_rng(8), 5)
    assert np.abs(frame.to_local(g) - LocalFrame(CoordinateSettings(UTM33, "ellipsoidal"), CENTRE).to_local(g)).max() < 1e-9


@pytest.mark.filterwarnings("error::RuntimeWarning")  # the domain check, not numpy's warnings, says it
def test_coordinates_outside_the_projection_are_an_input_error(tmp_path):
    runner = CliRunner()
    assert runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2",
                                "--crs", UTM33]).exit_code == 0
    rows = (tmp_path / "p" / "photos.csv").read_text().splitlines()
    cells = rows[1].split(",")
    cells[3] = "1e8"  # X0 of the first photo: 100,000 km east
    (tmp_path / "p" / "photos.csv").write_text("\n".join([rows[0], ",".join(cells), *rows[2:]]) + "\n")
    res = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "o"), "--quiet"])
    assert res.exit_code == 2 and "cannot be converted" in res.output and "photos.csv" in res.output


def test_simulate_refuses_a_geographic_crs(tmp_path):
    res = CliRunner().invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--crs", "EPSG:4326"])
    assert res.exit_code == 2 and "geographic" in res.output and not (tmp_path / "p").exists()


def test_earth_curvature_correction_with_a_crs_is_refused(tmp_path):
    """In the local frame the Earth's curvature is in the coordinates: the plate correction for it
    ([corrections] earth_curvature, or --earth-curvature over project.toml) would count it twice. It
    is an InputError naming project.toml (and the line, when project.toml asks for it), exit 2,
    nothing written; refraction alone is accepted."""
    with pytest.raises(InputError) as err:
        parse_settings(tmp_path / "project.toml", TOML_OK + "\n[corrections]\nearth_curvature = true\n")
    assert err.value.line == 6 and "count it twice" in err.value.reason
    assert parse_settings(tmp_path / "project.toml", TOML_OK + "\n[corrections]\nrefraction = true\n").refraction
    runner = CliRunner()
    res = runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4", "--strips", "2",
                               "--crs", "EPSG:32633"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "o"), "--quiet",
                               "--earth-curvature"])
    assert res.exit_code == 2 and "project.toml" in res.output and "count it twice" in res.output
    assert not (tmp_path / "o").exists()
    res = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "r"), "--quiet", "--refraction"])
    assert res.exit_code == 0, res.output


def test_gnss_block_in_a_crs_recovers_the_truth_like_the_local_block(tmp_path):
    """simulate --crs of a GNSS block (lever arm, per-strip shift and drift) writes truth/strips.csv
    in grid axes; adjusted with its CRS, the shifts and drifts differ from that truth by what the
    same block in the simulator's local frame gives, in units of their mean errors (to 0.01): the
    frame conversion neither loses nor distorts the GNSS unknowns."""
    import csv

    runner = CliRunner()
    common = ["--photos", "6", "--strips", "2", "--gnss-sigma", "0.05", "--gnss-lever", "0.1,-0.2,1.5", "--seed", "4"]
    normalised = {}
    for name, extra in (("local", []), ("crs", ["--crs", "EPSG:32633"])):
        res = runner.invoke(main, ["simulate", "block", "--out", str(tmp_path / name), *common, *extra])
        assert res.exit_code == 0, res.output
        res = runner.invoke(main, ["adjust", str(tmp_path / name), "--out", str(tmp_path / f"{name}_out"), "--quiet"])
        assert res.exit_code == 0, res.output
        truth = list(csv.DictReader(open(tmp_path / name / "truth" / "strips.csv")))
        est = list(csv.DictReader(open(tmp_path / f"{name}_out" / "strips.csv")))
        keys = [f"{k}_{a}" for k in ("shift", "drift") for a in "XYZ"]
        normalised[name] = np.array([[(float(e[k]) - float(t[k])) / float(e[f"sigma_{k}"]) for k in keys]
                                     for t, e in zip(truth, est)])
    assert normalised["crs"].shape == (2, 6)
    np.testing.assert_allclose(normalised["crs"], normalised["local"], rtol=0, atol=0.01)
