"""The rendered photographs of `striptri simulate --images` (issue 28; simulate.render): the ground
texture is a function of the ground alone, every pixel shows the ground its ray meets, and the
command writes a digital-camera project with its images, whole or not at all."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from striptri import simulate as sim
from striptri.geometry.camera import ray_ground
from striptri.geometry.pixels import plate_from_pixel
from striptri.io.output import MARKER, OutputReservation
from striptri.simulate.render import GroundTexture, Targets, ground_of_rays, render_photo


def _truth():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=3, n_strips=1), control=sim.ControlDesign(layout="ends"))
    return sim.make_truth(design, np.random.default_rng(3))


def test_the_texture_depends_on_the_ground_point_only():
    """The same ground points give the same grey values whatever else is evaluated with them (the
    lattice window of each octave follows the batch), and the values spread as documented."""
    texture = GroundTexture(seed=4, finest=2.0, octaves=6)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-500.0, 500.0, (2000, 2))
    alone = texture.grey(xy[:10, 0], xy[:10, 1])
    together = texture.grey(xy[:, 0], xy[:, 1])[:10]
    far = texture.grey(np.r_[xy[:10, 0], 1500.0], np.r_[xy[:10, 1], -1200.0])[:10]
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-9)
    np.testing.assert_allclose(far, alone, rtol=0, atol=1e-9)
    g = texture.grey(*rng.uniform(-1000.0, 1000.0, (2, 20000)))
    assert abs(g.mean() - 128.0) < 3.0 and 35.0 < g.std() < 50.0
    assert not np.allclose(GroundTexture(seed=5, finest=2.0, octaves=6).grey(xy[:10, 0], xy[:10, 1]), alone)


def test_rays_meet_the_terrain():
    truth = _truth()
    R, O = truth.R_ground_from_cam[0], truth.xyz0[0]
    rays = ray_ground(R, np.random.default_rng(1).uniform(-110.0, 110.0, (50, 2)), truth.interior)
    ground = ground_of_rays(O, rays, truth.terrain)
    np.testing.assert_allclose(ground[:, 2], truth.terrain.z(ground[:, :2]), atol=1e-5)
    along = (ground - O) / rays  # on the ray: the same multiple of the ray in X, Y and Z
    np.testing.assert_allclose(along[:, :2], along[:, 2:].repeat(2, 1), rtol=1e-9)


def test_every_pixel_shows_the_ground_its_ray_meets():
    """The rendered grey value of a pixel is the texture where the exact ray of the pixel centre
    meets the terrain (the rays are followed exactly at nodes and interpolated between them)."""
    truth = _truth()
    n, pixel = 200, 230.0 / 200
    texture = GroundTexture(seed=1, finest=1.5 * pixel * 9.87, octaves=5)
    image = render_photo(truth.R_ground_from_cam[1], truth.xyz0[1], truth.interior, pixel, n, truth.terrain, texture)
    rows, cols = np.random.default_rng(2).integers(0, n, (2, 300))
    plate = plate_from_pixel(np.column_stack([cols + 0.5, rows + 0.5]), np.array([n, n]), pixel)
    ground = ground_of_rays(truth.xyz0[1], ray_ground(truth.R_ground_from_cam[1], plate, truth.interior), truth.terrain)
    np.testing.assert_allclose(image[rows, cols], texture.grey(ground[:, 0], ground[:, 1]), atol=1e-3)


def test_simulate_images_writes_a_digital_camera_project(tmp_path):
    pytest.importorskip("cv2")
    from striptri.cli import main

    out = tmp_path / "p"
    run = CliRunner().invoke(main, ["simulate", "strip", "--photos", "3", "--images", "--image-size", "96",
                                    "--check-points", "1", "--out", str(out)])
    assert run.exit_code == 0, run.output
    photos = [r["photo_id"] for r in csv.DictReader((out / "photos.csv").open())]
    assert sorted(p.name for p in (out / "images").iterdir()) == sorted(f"{p}.png" for p in photos)
    camera = next(csv.DictReader((out / "cameras.csv").open()))
    assert (camera["width_px"], camera["height_px"]) == ("96", "96")
    assert float(camera["pixel_size"]) == pytest.approx(230.0 / 96)
    control = {r["point_id"] for r in csv.DictReader((out / "control.csv").open())}
    measured = {r["point_id"] for r in csv.DictReader((out / "image_points.csv").open())}
    assert measured and measured <= control  # the tie points are left to striptri match
    assert "images/" + photos[0] + ".png" in (out / MARKER).read_text()  # listed in the output's manifest
    import cv2

    assert cv2.imread(str(out / "images" / f"{photos[0]}.png"), cv2.IMREAD_UNCHANGED).shape == (96, 96)
    jpeg = CliRunner().invoke(main, ["simulate", "strip", "--photos", "3", "--images", "--image-size", "96",
                                     "--jpeg-quality", "80", "--image-noise", "2", "--out", str(tmp_path / "j")])
    assert jpeg.exit_code == 0 and (tmp_path / "j" / "images" / f"{photos[0]}.jpg").is_file()


@pytest.mark.parametrize("args", [["--image-size", "96"], ["--images", "--crs", "EPSG:32632"]])
def test_image_options_need_images_and_the_local_frame(tmp_path, args):
    from striptri.cli import main

    run = CliRunner().invoke(main, ["simulate", "strip", "--out", str(tmp_path / "p"), *args])
    assert run.exit_code == 2 and not (tmp_path / "p").exists(), run.output


def test_staged_files_are_part_of_the_output_or_of_nothing(tmp_path):
    with OutputReservation(tmp_path / "out") as reservation:
        reservation.stage({"images/a.bin": b"\x00\x01"})
        reservation.commit({"table.csv": "a\n1\n"})
    assert (tmp_path / "out" / "images" / "a.bin").read_bytes() == b"\x00\x01"
    assert "images/a.bin" in (tmp_path / "out" / MARKER).read_text()
    with pytest.raises(KeyboardInterrupt):
        with OutputReservation(tmp_path / "other") as reservation:
            reservation.stage({"images/a.bin": b"\x00"})
            raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("size", [(300, 300), (330, 220)])
def test_signalised_points_are_painted_where_they_project(size):
    """A target on the ground shows in the photo as a white disc centred (the centroid of its
    brightness) on the control point's projection, within a few hundredths of a pixel; in a
    square image and in a wide one (width 3/2 of the height, as 3,000 x 2,000 px photos)."""
    from striptri.geometry.camera import project as plate_of
    from striptri.geometry.pixels import pixel_from_plate

    truth = _truth()
    (W, H), pixel = size, 230.0 / 300
    gsd = pixel * 9.87
    texture = GroundTexture(seed=2, finest=1.5 * gsd, octaves=5)
    k = 1
    seen = truth.xyz_ground[truth.point_index[truth.photo_index == k]]
    X = seen[np.argmin(np.abs(plate_of(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, seen)[:, 1]))]
    plain = render_photo(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, pixel, (W, H), truth.terrain,
                         texture)
    image = render_photo(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, pixel, (W, H), truth.terrain,
                         texture, Targets(X[None, :2], 3.0 * gsd))
    assert image.shape == (H, W)
    expected = pixel_from_plate(plate_of(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, X), np.array([W, H]),
                                pixel)
    changed = np.argwhere(np.abs(image - plain) > 1e-9)
    assert len(changed) and np.abs(changed[:, ::-1] + 0.5 - expected).max() < 2.0 * 3.0 * 1.1  # only around it
    rows, cols = np.mgrid[0:H, 0:W]
    # inside the black ring (out to 5.4 px) the photo is the disc alone: 255 x its coverage
    near = np.hypot(cols + 0.5 - expected[0], rows + 0.5 - expected[1]) < 4.5
    white = np.where(near, image, 0.0)
    centroid = np.array([(white * (cols + 0.5)).sum(), (white * (rows + 0.5)).sum()]) / white.sum()
    assert np.abs(centroid - expected).max() < 0.05
