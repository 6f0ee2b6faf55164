"""DBAT script reader (striptri.formats.dbat) on the DBAT demo projects and on malformed input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from striptri.geometry import lens
from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.errors import InputError
from striptri.formats.dbat import (
    dbat_to_project,
    pixels_to_plate,
    read_dbat,
    read_dbat_camera,
    striptri_camera,
)

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
CAMCAL = REAL / "dbat_camcal" / "script"
ROMA = REAL / "dbat_roma" / "script"
needs_camcal = pytest.mark.skipif(not (CAMCAL / "camcaldemo.xml").exists(), reason="DBAT camcal data absent")
needs_roma = pytest.mark.skipif(not (ROMA / "romabundledemo.xml").exists(), reason="DBAT roma data absent")


@needs_camcal
def test_camcal_counts_and_camera():
    d = read_dbat(CAMCAL / "camcaldemo.xml")
    assert (d.n_images, d.n_points, d.n_image_points, d.n_control) == (21, 100, 2074, 4)
    assert d.image_names[0] == "P8250021.JPG"
    assert np.all(d.ip_sigma == 0.1)
    assert d.ctrl_ids == ["1001", "1002", "1003", "1004"]
    assert np.all(np.isnan(d.ctrl_sigma))  # fixed
    assert d.ctrl_xyz[1].tolist() == [1.0, 1.0, 0.0]
    c = d.camera
    # script camera: focal 7.5, sensor auto,5.43764 for 2272 x 1704 px, default pp = sensor centre
    assert c.cc == 7.5 and c.image_size == (2272, 1704)
    assert c.pixel_size[1] == pytest.approx(0.0031911, abs=5e-8)
    assert c.pp == pytest.approx((2272 / 2 * c.pixel_size[0], 1704 / 2 * c.pixel_size[1]))
    assert c.principal_point_pixels == pytest.approx((1136.0, 852.0))
    assert all(c.estimated[n] for n in ("cc", "px", "py", "as", "K1", "K2", "K3", "P1", "P2"))
    assert not c.estimated["sk"]
    assert d.datum is None and "fixed control points" in d.datum_note


@needs_camcal
def test_camcal_result_camera_equals_report():
    c = read_dbat_camera(CAMCAL / "result" / "c4040z.xml")  # values of result/report.txt
    assert c.cc == pytest.approx(7.457, abs=5e-4)
    assert c.pp == pytest.approx((3.61546, 2.61329), abs=5e-6)
    assert c.sensor == pytest.approx((7.25301, 5.43764), abs=5e-6)
    assert c.pixel_size == pytest.approx((0.00319235, 0.0031911), abs=5e-9)
    assert c.distortion() == pytest.approx({"K1": 0.00458861, "K2": -4.51351e-05, "K3": -2.05253e-06,
                                            "P1": -6.12803e-05, "P2": -4.41171e-05}, rel=1e-5)


@needs_roma
def test_roma_counts_camera_prior_and_datum():
    d = read_dbat(ROMA / "romabundledemo.xml")
    assert (d.n_images, d.n_points, d.n_image_points, d.n_control) == (60, 26321, 90561, 0)
    assert np.all(d.ip_sigma == 1.0)  # sxy="1" attribute
    c = d.camera
    assert (c.cc, c.pp, c.sensor, c.image_size) == (24.3581, (18.1143, 12.0), (36.0, 24.0), (5616, 3744))
    assert c.pixel_size == pytest.approx((0.00641026, 0.00641026), abs=5e-9)
    assert c.distortion() == {"K1": 2.174e-4, "K2": -1.518e-7, "K3": 0.0, "P1": 0.0, "P2": 0.0}
    est = {n for n, v in c.estimated.items() if v}
    assert est == {"cc", "px", "py", "K1", "K2"}  # report: "Calibration: yes (cc px py K1 K2)"
    assert d.datum == {"type": "depend", "ref_cam": "1", "ref_base": "longest"}
    assert len(d.prior_ids) == 60
    assert np.degrees(d.prior_angles[0]) == pytest.approx([39.43, 7.46, 99.59])
    r = read_dbat_camera(ROMA / "result" / "EOS5DMarkII.xml")  # result/report.txt values
    assert r.cc == pytest.approx(24.5425, abs=5e-5)
    assert r.pp == pytest.approx((18.0816, 12.0164), abs=5e-5)
    assert (r.distortion()["K1"], r.distortion()["K2"]) == pytest.approx((0.000221523, -1.86985e-07), rel=1e-5)


@needs_roma
def test_roma_conversion_keeps_the_camera_model_and_the_datum():
    d = read_dbat(ROMA / "romabundledemo.xml")
    scene = dbat_to_project(d)
    p = scene.project
    assert isinstance(p, model.Project)
    assert len(p.photos) == 60 and len(p.points) == 26321 and len(p.image_points) == 90561
    # c, principal point at the origin of the plate frame, K1, K2 of the camera file; plate convention
    assert p.cameras.interior[0].tolist() == [24.3581, 0.0, 0.0, 2.174e-4, -1.518e-7, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert p.cameras.convention.tolist() == [0]
    # the script estimates c, xp, yp, K1, K2 (aspect, skew, P and K3 held)
    assert np.isinf(p.cameras.sigma_interior[0, :5]).all() and np.isnan(p.cameras.sigma_interior[0, 5:]).all()
    assert p.photos.xyz0[0].tolist() == [1.86, -19.22, -6.49]
    # DBAT's datum "depend": the first camera held, one coordinate of the camera farthest from it
    assert (p.photos.sigma_xyz0[0] == 0).all() and (p.photos.sigma_angles[0] == 0).all()
    assert np.sum(p.photos.sigma_xyz0 == 0) == 4 and np.sum(p.photos.sigma_angles == 0) == 3
    far = int(np.argmax(np.linalg.norm(p.photos.xyz0 - p.photos.xyz0[0], axis=1)))
    axis = int(np.argmax(np.abs(p.photos.xyz0[far] - p.photos.xyz0[0])))
    assert p.photos.sigma_xyz0[far, axis] == 0
    assert any("depend" in n for n in scene.notes)
    dropped = dbat_to_project(d, drop_distortion=True)
    assert dropped.project.cameras.interior[0, 3:].tolist() == [0.0] * 7
    assert any("dropped" in n for n in dropped.notes)


def _camera(**kw):
    from striptri.formats.dbat import DbatCamera
    base = {"id": "1", "name": "t", "unit": "mm", "cc": 10.0, "pp": (5.0, 4.0), "sensor": (10.0, 8.0),
            "image_size": (1000, 800), "aspect": 1.0, "skew": 0.0, "K": np.zeros(3), "P": np.zeros(2),
            "model": 3, "estimated": {}}
    base.update(kw)
    return DbatCamera(**base)


def test_pixel_to_plate_hand_example():
    # 1000 x 800 px on a 10 x 8 mm sensor: 0.01 mm pixels; pp (5.2, 3.9) mm = pixel (520, 390).
    cam = _camera(pp=(5.2, 3.9))
    xy = pixels_to_plate(cam, np.array([[520.0, 390.0], [0.0, 0.0], [1000.0, 800.0], [620.5, 290.25]]))
    expected = [[0.0, 0.0], [-5.2, 3.9], [4.8, -4.1], [1.005, 0.9975]]
    assert xy == pytest.approx(np.array(expected), abs=1e-12)
    # aspect 0.8 (pixel height / width): ph 0.01 mm on the plate; the camera model scales x by
    # 1/0.8 about the principal point (6.0, 4.0) mm (b1 = 0.25)
    cam = _camera(pp=(6.0, 4.0), sensor=(12.5, 8.0), aspect=0.8)
    xy = pixels_to_plate(cam, np.array([[600.0, 400.0], [700.0, 300.0]]))
    assert xy == pytest.approx(np.array([[0.0, 0.0], [1.0, 1.0]]), abs=1e-12)
    assert cam.pixel_size == pytest.approx((0.0125, 0.01))
    prm = striptri_camera(cam)
    assert prm[lens.B1] == pytest.approx(0.25) and prm[lens.XP] == 0.0 and prm[lens.YP] == 0.0
    ideal = lens.ideal_from_observed(xy, prm, lens.PLATE).xy
    assert ideal == pytest.approx(np.array([[0.0, 0.0], [1.25, 1.0]]), abs=1e-12)


def _write_project(tmp: Path, *, script_extra="", pts="1,7,10.5,20.5,0.5\n", camera_xml=None):
    (tmp / "images.txt").write_text("# id, path\n1, a/IMG1.JPG\n2, a/IMG2.JPG\n")
    (tmp / "pts.txt").write_text("# im,id,x,y,sxy\n" + pts)
    cam = camera_xml or ("<camera><id>1</id><unit>mm</unit><sensor>10,8</sensor><image>1000,800</image>"
                         "<focal>10</focal></camera>")
    (tmp / "s.xml").write_text(
        '<?xml version="1.0"?>\n<document>\n<input base_dir="$HERE">\n'
        '<images><file format="id,path">images.txt</file></images>\n'
        '<image_pts><file format="im,id,x,y,sxy">pts.txt</file></image_pts>\n'
        f"<cameras>{cam}</cameras>\n{script_extra}</input>\n</document>\n")
    return tmp / "s.xml"


def test_small_project_converts(tmp_path):
    s = _write_project(tmp_path, pts="1,7,500,400,0.5\n2,7,600,300,0.5\n")
    d = read_dbat(s)
    assert d.image_names == ["IMG1.JPG", "IMG2.JPG"]
    scene = dbat_to_project(d)
    assert scene.project.image_points.xy == pytest.approx(np.array([[0.0, 0.0], [1.0, 1.0]]))
    assert scene.project.image_points.sigma_xy[0] == pytest.approx(np.array([0.005, 0.005]))
    assert math.isnan(scene.project.photos.xyz0[0, 0])
    assert any("must come from elsewhere" in n for n in scene.notes)  # no control to resect from


def test_malformed_xml_names_line(tmp_path):
    s = _write_project(tmp_path)
    s.write_text(s.read_text().replace("</cameras>", "</camera>"))
    with pytest.raises(InputError) as e:
        read_dbat(s)
    assert e.value.line == 6 and "XML" in e.value.reason


def test_malformed_measurement_names_line(tmp_path):
    s = _write_project(tmp_path, pts="1,7,10,20,0.5\n2,7,abc,20,0.5\n")
    with pytest.raises(InputError) as e:
        read_dbat(s)
    assert e.value.path.endswith("pts.txt") and e.value.line == 3 and "not a number" in e.value.reason
    s = _write_project(tmp_path, pts="1,7,10,20\n")
    with pytest.raises(InputError) as e:
        read_dbat(s)
    assert e.value.line == 2 and "fields" in e.value.reason
    s = _write_project(tmp_path, pts="9,7,10,20,1\n")
    with pytest.raises(InputError, match="not in the image list"):
        read_dbat(s)


def test_bad_camera_and_missing_file(tmp_path):
    s = _write_project(tmp_path, camera_xml="<camera>\n<sensor>10</sensor><image>1000,800</image><focal>1</focal></camera>")
    with pytest.raises(InputError) as e:
        read_dbat(s)
    assert e.value.line == 7 and "sensor" in e.value.reason
    s = _write_project(tmp_path)
    (tmp_path / "pts.txt").unlink()
    with pytest.raises(InputError, match="file not found"):
        read_dbat(s)


@needs_camcal
def test_pixel_convention_reproduces_dbat_result():
    """DBAT's result camera and camera stations reproject camcal's fixed control points onto their
    measured pixels through pixels_to_plate (no half-pixel shift), striptri_camera (DBAT's
    parameters in the plate convention) and R_from_opk without bias; the alternatives leave one:
    a 0.5 px shift, a sign change of P2, the aspect applied before the principal point."""
    from striptri.geometry.rotations import R_from_opk

    d = read_dbat(CAMCAL / "camcaldemo.xml")
    cam = read_dbat_camera(CAMCAL / "result" / "c4040z.xml")
    # camera_stations.txt: x, y, z, omega, phi, kappa (radians, although its header says degrees)
    eo = np.loadtxt(CAMCAL / "result" / "camera_stations.txt", delimiter=",", usecols=range(2, 8))
    R = R_from_opk(eo[:, 3:])
    ctrl = dict(zip(d.ctrl_ids, d.ctrl_xyz))
    keep = [k for k, p in enumerate(d.ip_point) if p in ctrl]
    im = np.array([d.image_ids.index(d.ip_image[k]) for k in keep])
    X = np.array([ctrl[d.ip_point[k]] for k in keep])
    Pc = np.einsum("nji,nj->ni", R[im], X - eo[im, :3])
    ph = cam.pixel_size[1]

    def bias(shift=0.0, p2=1.0, aspect_first=False):
        prm = striptri_camera(cam, reference=d.camera)
        prm[lens.P2] *= p2
        if aspect_first:  # (1 + as) col ph - px instead of (1 + as)(col ph - px)
            prm[lens.XP] += cam.pp[0] * (1 - cam.aspect)
        xy = pixels_to_plate(d.camera, d.ip_xy[keep] + shift)
        ideal = lens.ideal_from_observed(xy, prm, lens.PLATE).xy
        res = (ideal - (prm[1:3] - cam.cc * Pc[:, :2] / Pc[:, 2:3])) / ph
        return np.abs(res.mean(0)).max()

    assert len(keep) == 84
    assert bias() < 0.01
    assert bias(shift=0.5) > 0.4 and bias(p2=-1.0) > 0.3 and bias(aspect_first=True) > 0.3


def _half_unit(text: str) -> float:
    """Half a unit in the last printed digit of a number ("18.0816" -> 5e-5, "-4.5e-05" -> 5e-7)."""
    mantissa, _, exponent = text.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (-decimals + (int(exponent) if exponent else 0))


def _dbat_report(path: Path) -> dict:
    """sigma0, redundancy and the camera's (value, deviation) pairs of a DBAT report file."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out: dict = {"camera": {}}
    name = None
    for i, line in enumerate(lines):
        t = line.strip()
        if t.startswith("Sigma0:") and "sigma0" not in out:
            out["sigma0"] = float(t.split(":")[1])
        elif t.startswith("Redundancy") and "redundancy" not in out:
            out["redundancy"] = int(t.split()[1])
        elif t.startswith(("Camera Constant:", "px - ", "py - ", "K1 - ", "K2 - ", "K3 - ", "P1 - ", "P2 - ", "as - ")):
            name = {"Camera": "cc"}.get(t.split()[0], t.split()[0])
        elif name and t.startswith("Value:"):
            out["camera"][name] = [float(t.split()[1]), None, _half_unit(t.split()[1])]
        elif name and t.startswith("Deviation:"):
            out["camera"][name][1] = float(t.split()[1])
            name = None
        elif t.startswith("Precisions / Standard Deviations"):
            break
        elif t.endswith(":"):  # another parameter's heading
            name = None
    return out


def _dbat_elements(d, prm) -> dict:
    """DBAT's names and values of striptri's camera elements (inverse of striptri_camera)."""
    x0, y0 = d.camera.pp
    return {"cc": prm[lens.C], "px": x0 + prm[lens.XP], "py": y0 - prm[lens.YP], "K1": prm[lens.K1],
            "K2": prm[lens.K2], "K3": prm[lens.K3], "P1": prm[lens.P1], "P2": prm[lens.P2], "as": prm[lens.B1]}


@needs_camcal
@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_camcal_reproduces_dbat(method):
    """DBAT's camera calibration: sigma0 1.6148 and redundancy 3725 of its report, every estimated
    camera parameter within a hundredth of its standard deviation of DBAT's value and the standard
    deviations within 1 %. Approximations by resection (the script has none)."""
    d = read_dbat(CAMCAL / "camcaldemo.xml")
    want = _dbat_report(CAMCAL / "result" / "report.txt")
    result = adjust(dbat_to_project(d).project, AdjustmentOptions(method=method))
    assert result.converged
    assert result.redundancy == want["redundancy"] == 3725
    assert f"{result.sigma0:.4f}" == f"{want['sigma0']:.4f}" == "1.6148"
    got = _dbat_elements(d, result.state.interior[0])
    sig = result.camera_mean_errors()[0]
    sig_of = dict(zip(["cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "as"], sig[[0, 1, 2, 3, 4, 5, 6, 7, 8]]))
    assert set(want["camera"]) == set(got)
    for name, (value, deviation, printed) in want["camera"].items():
        # DBAT prints six significant digits: the value agrees to that or to 1 % of its deviation
        assert abs(got[name] - value) <= max(0.01 * deviation, printed), (name, got[name], value, deviation)
        assert sig_of[name] == pytest.approx(deviation, rel=0.01), name
    # DBAT's report: "K2 ... Correlations over 95%: K3:-97.9%", the only pair over 95 %
    from striptri.precision.residuals import camera_correlations

    (block,) = camera_correlations(result)
    names = [lens.CAMERA_ELEMENTS[e] for e in block["elements"]]
    high = {(names[i], names[j]): round(100 * block["matrix"][i, j], 1) for i in range(len(names))
            for j in range(i + 1, len(names)) if abs(block["matrix"][i, j]) > 0.95}
    assert high == {("k2", "k3"): -97.9}


@needs_roma
def test_roma_reproduces_dbat():
    """DBAT's 60-image block: sigma0 0.582769 px and redundancy 101,801 with self-calibration of c,
    xp, yp, K1, K2 and DBAT's datum (first camera and one coordinate of the longest base), by the
    default method; c, px, py, K1, K2 within a hundredth of their standard deviations
    (or DBAT's printed digits), and the standard deviations within 1 %."""
    d = read_dbat(ROMA / "romabundledemo.xml")
    want = _dbat_report(ROMA / "result" / "report.txt")
    result = adjust(dbat_to_project(d).project)
    assert result.converged
    assert result.redundancy == want["redundancy"] == 101801
    # sxy = 1 px: sigma0 is in pixels; DBAT prints six significant digits
    assert f"{result.sigma0:.6f}" == f"{want['sigma0']:.6f}" == "0.582769"
    got = _dbat_elements(d, result.state.interior[0])
    sig = result.camera_mean_errors()[0]
    sig_of = dict(zip(["cc", "px", "py", "K1", "K2"], sig[:5]))
    for name, (value, deviation, printed) in want["camera"].items():
        if deviation is None:  # held by the script
            assert got[name] == value, name
            continue
        assert abs(got[name] - value) <= max(0.01 * deviation, printed), (name, got[name], value, deviation)
        assert sig_of[name] == pytest.approx(deviation, rel=0.01), name


@needs_camcal
def test_convert_and_adjust_camcal_from_the_command_line(tmp_path):
    """striptri convert (DBAT detected from the .xml) then striptri adjust: the same sigma0, and
    cameras.csv carries the camera model (plate convention) in and out."""
    import json

    from click.testing import CliRunner

    from striptri.cli import main
    from striptri.io import read_project

    runner = CliRunner()
    conv = runner.invoke(main, ["convert", str(CAMCAL / "camcaldemo.xml"), "--to", "project", "--out",
                                str(tmp_path / "p")])
    assert conv.exit_code == 0, conv.output
    assert "project from dbat" in conv.output
    p = read_project(tmp_path / "p")
    assert p.cameras.convention.tolist() == [lens.PLATE]
    assert np.isinf(p.cameras.sigma_interior[0, :9]).all() and np.isnan(p.cameras.sigma_interior[0, 9])
    run = runner.invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(tmp_path / "o")])
    assert run.exit_code == 0, run.output
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert f"{summary['sigma0']:.4f}" == "1.6148" and summary["redundancy"] == 3725
    header = (tmp_path / "o" / "cameras.csv").read_text().splitlines()[0].split(",")
    assert header[:6] == ["camera_id", "c", "xp", "yp", "k1", "k2"] and "b1" in header and "distortion" in header


@needs_camcal
@needs_roma
@pytest.mark.parametrize("which", ["camcal", "roma"])
def test_dbat_round_trip_through_a_project(tmp_path, which):
    """DBAT -> project -> DBAT (striptri convert --to dbat, at DBAT's pixel size) -> project: the same
    measurements (plate), sigmas, camera elements and their estimated flags, approximate
    orientations, control and datum; camcal adjusted again gives DBAT's sigma0."""
    from click.testing import CliRunner

    from striptri.cli import main
    from striptri.io import read_project

    script = CAMCAL / "camcaldemo.xml" if which == "camcal" else ROMA / "romabundledemo.xml"
    ph = read_dbat(script).camera.pixel_size[1]
    runner = CliRunner()
    for args in (["convert", str(script), "--to", "project", "--out", str(tmp_path / "p")],
                 ["convert", str(tmp_path / "p"), "--to", "dbat", "--out", str(tmp_path / "d"), "--pixel-size", repr(ph)],
                 ["convert", str(tmp_path / "d" / "project.xml"), "--to", "project", "--out", str(tmp_path / "q")]):
        out = runner.invoke(main, args)
        assert out.exit_code == 0, out.output
    p, q = read_project(tmp_path / "p"), read_project(tmp_path / "q")
    assert q.photos.ids == p.photos.ids and sorted(q.points.ids) == sorted(p.points.ids)
    order = [q.points.ids.index(pid) for pid in p.points.ids]
    np.testing.assert_allclose(q.image_points.xy, p.image_points.xy, rtol=0, atol=1e-9)
    np.testing.assert_allclose(q.image_points.sigma_xy, p.image_points.sigma_xy, rtol=1e-12)
    np.testing.assert_allclose(q.cameras.interior, p.cameras.interior, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(np.isinf(q.cameras.sigma_interior), np.isinf(p.cameras.sigma_interior))
    np.testing.assert_allclose(q.photos.xyz0, p.photos.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(q.photos.R_ground_from_cam, p.photos.R_ground_from_cam, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(q.photos.sigma_xyz0 == 0, p.photos.sigma_xyz0 == 0)
    np.testing.assert_array_equal(q.points.kind[order], p.points.kind)
    np.testing.assert_allclose(q.points.xyz_given[order], p.points.xyz_given, rtol=0, atol=1e-12)
    if which == "camcal":
        assert f"{adjust(q).sigma0:.4f}" == "1.6148"


@pytest.mark.parametrize("plate", ["mm", "px"])
def test_dbat_writer_keeps_the_plate_unit(tmp_path, plate):
    """A project whose plate coordinates are pixels ([units] plate = "px") is written to DBAT with
    the camera's <unit> px (not mm), and read back as a px project; a mm project stays mm."""
    import shutil

    from click.testing import CliRunner

    from striptri.cli import main
    from striptri.io import read_project

    src = tmp_path / "p"
    shutil.copytree(Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8", src)
    (src / "project.toml").unlink(missing_ok=True)
    (src / "project.toml").write_text(f'[units]\nplate = "{plate}"\n')
    runner = CliRunner()
    for args in (["convert", str(src), "--to", "dbat", "--out", str(tmp_path / "d")],
                 ["convert", str(tmp_path / "d" / "project.xml"), "--to", "project", "--out", str(tmp_path / "q")]):
        out = runner.invoke(main, args)
        assert out.exit_code == 0, out.output
    assert f"<unit>{plate}</unit>" in (tmp_path / "d" / "project.xml").read_text()
    assert read_project(tmp_path / "q").settings.plate_unit == plate
