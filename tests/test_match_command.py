"""striptri match end to end (issue 28): a 2 x 3 block of rendered digital photographs of a
textured flat terrain, approximate orientations and GNSS centres; the matched project adjusts,
with snooping, to the true orientations."""

from __future__ import annotations

import csv
import functools

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.ndimage import gaussian_filter

cv2 = pytest.importorskip("cv2")

from striptri.cli import main  # noqa: E402
from striptri.core.runs import RunOptions  # noqa: E402
from striptri.pipeline import run_adjust  # noqa: E402

W, H, PIXEL, C, Z0 = 800, 600, 0.01, 50.0, 5000.0  # px, px, mm, mm, m: 1 m on the ground per pixel
NX, NY = 1600, 1200  # the terrain texture, 1 m per texel
CENTRES = [(x, y) for y in (300.0, 720.0) for x in (400.0, 720.0, 1040.0)]  # 60 % forward, 30 % side overlap


@functools.lru_cache(maxsize=1)
def _texture(seed: int = 11) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.normal(size=(NY, NX)), 1.5) + 0.6 * gaussian_filter(rng.normal(size=(NY, NX)), 5.0)
    return (255 * (t - t.min()) / (t.max() - t.min())).astype(np.uint8)


def _photo(x0, y0):
    """The vertical photo over (x0, y0): ground X, Y -> plate x = c (X - x0)/Z0, y = c (Y - y0)/Z0
    -> pixel (corner origin); the texture's row v (corner origin) is Y = NY - v."""
    k = C / (Z0 * PIXEL)
    M = np.array([[k, 0.0, W / 2 - k * x0], [0.0, k, H / 2 - k * (NY - y0)], [0.0, 0.0, 1.0]])
    shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # OpenCV pixel centres at integers
    return cv2.warpPerspective(_texture(), np.linalg.inv(shift) @ M @ shift, (W, H), flags=cv2.INTER_CUBIC)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("match")
    project, images = root / "project", root / "images"
    project.mkdir(), images.mkdir()
    (project / "cameras.csv").write_text(f"camera_id,c,xp,yp,width_px,height_px,pixel_size\nC,{C},0,0,{W},{H},{PIXEL}\n")
    rng = np.random.default_rng(2)
    with (project / "photos.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["photo_id", "camera_id", "strip_id", "X0", "Y0", "Z0", "omega", "phi", "kappa",
                    "sigma_X0", "sigma_Y0", "sigma_Z0"])
        for k, (x, y) in enumerate(CENTRES):
            gnss = np.array([x, y, Z0]) + rng.normal(0.0, 0.3, 3)
            w.writerow([f"P{k}", "C", "S1" if k < 3 else "S2", *gnss.round(3), *rng.normal(0, 0.3, 3).round(3),
                        0.3, 0.3, 0.3])
    for k, (x, y) in enumerate(CENTRES):
        cv2.imwrite(str(images / f"P{k}.png"), _photo(x, y))
    return root


def test_a_matched_block_adjusts_to_the_true_orientations(block):
    out = block / "matched"
    run = CliRunner().invoke(main, ["match", str(block / "project"), "--images", str(block / "images"), "--out",
                                    str(out), "--scale", "0.5", "--features", "2000"])
    assert run.exit_code == 0, run.output
    assert (out / "cameras.csv").read_bytes() == (block / "project" / "cameras.csv").read_bytes()
    report = (out / "match_report.html").read_text()
    for section in ("Time per stage", "Pairs", "Photos", "Track lengths", "features", "pair matching"):
        assert section in report
    assert report.count("data:image/png;base64,") == 3  # the pair graph, the maps, the track lengths
    assert "0.300 px" in report and "planar" in report  # a flat terrain: the default sigma, said why
    rows = list(csv.DictReader((out / "image_points.csv").open()))
    assert rows and {r["source"] for r in rows} == {"auto"}
    n_points = len({r["point_id"] for r in rows})
    assert n_points >= 6 * 9  # every photo's 3 x 3 cells
    adjusted = run_adjust(out, block / "adjusted", RunOptions(blunders="snoop"))
    assert adjusted.result.converged
    # the photos are vertical (every true angle 0) and over the true centres: the adjusted values
    # are the truth within their a-priori standard errors (photos.csv's scaled by sigma0 a posteriori,
    # which is small: the matches are far better than sigma_px, while the datum, GNSS centres of
    # 0.3 m, is as noisy as stated)
    photos = list(csv.DictReader((block / "adjusted" / "photos.csv").open()))
    sigma0 = adjusted.summary["sigma0"]
    for names, truth in ((("omega", "phi", "kappa"), np.zeros((6, 3))), (("X0", "Y0", "Z0"),
                                                                         [(x, y, Z0) for x, y in CENTRES])):
        value = np.array([[float(r[a]) for a in names] for r in photos])
        sigma = np.array([[float(r[f"sigma_{a}"]) for a in names] for r in photos]) / sigma0
        assert np.all(np.abs(value - np.asarray(truth)) < 4.0 * sigma), (names, value, sigma)
    assert adjusted.summary["sigma0"] < 0.2  # matched to a few hundredths of a pixel, sigma_px 0.5


def test_a_missing_image_and_a_film_camera_are_input_errors(block, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    run = CliRunner().invoke(main, ["match", str(block / "project"), "--images", str(images), "--out",
                                    str(tmp_path / "o")])
    assert run.exit_code == 2 and "no image of photo 'P0'" in run.output and not (tmp_path / "o").exists()
    film = tmp_path / "film"
    film.mkdir()
    (film / "cameras.csv").write_text(f"camera_id,c,xp,yp\nC,{C},0,0\n")
    (film / "photos.csv").write_bytes((block / "project" / "photos.csv").read_bytes())
    run = CliRunner().invoke(main, ["match", str(film), "--images", str(block / "images"), "--out",
                                    str(tmp_path / "o")])
    assert run.exit_code == 2 and "digital frame cameras" in run.output and not (tmp_path / "o").exists()


def test_photos_csv_names_the_images(block, tmp_path):
    """photos.csv's column image: a path inside --images, relative to it; outside or missing is an
    error naming the line."""
    from striptri.errors import InputError
    from striptri.io import read_project
    from striptri.match.pipeline import _image_paths

    project = tmp_path / "p"
    project.mkdir()
    (project / "cameras.csv").write_bytes((block / "project" / "cameras.csv").read_bytes())
    rows = list(csv.reader((block / "project" / "photos.csv").open()))
    images = tmp_path / "images"
    (images / "sub").mkdir(parents=True)
    for k, r in enumerate(rows[1:]):
        (images / "sub" / f"frame_{k}.png").write_bytes((block / "images" / f"{r[0]}.png").read_bytes())

    def write(names):
        with (project / "photos.csv").open("w", newline="") as f:
            csv.writer(f).writerows([rows[0] + ["image"]] + [r + [n] for r, n in zip(rows[1:], names)])
        return read_project(project, plate_measurements_optional=True)

    got = _image_paths(write([f"sub/frame_{k}.png" for k in range(6)]), images, project)
    assert [p.name for p in got] == [f"frame_{k}.png" for k in range(6)]
    with pytest.raises(InputError, match="inside --images") as err:
        _image_paths(write(["../x.png"] + [f"sub/frame_{k}.png" for k in range(1, 6)]), images, project)
    assert err.value.line == 2
    with pytest.raises(InputError, match="is not in") as err:
        _image_paths(write([f"sub/frame_{k}.png" for k in range(5)] + ["sub/none.png"]), images, project)
    assert err.value.line == 7


def test_image_points_source_must_be_manual_or_auto(block, tmp_path):
    from striptri.errors import InputError
    from striptri.io import read_project

    project = tmp_path / "p"
    project.mkdir()
    for name in ("cameras.csv", "photos.csv"):
        (project / name).write_bytes((block / "project" / name).read_bytes())
    (project / "image_points.csv").write_text("photo_id,point_id,x,y,source\nP0,a,0,0,auto\nP1,a,1,0,machine\n")
    with pytest.raises(InputError, match="'machine' is not one of") as err:
        read_project(project)
    assert err.value.line == 3


def _colmap_database(path, project, feats, pairs_matches):
    """A COLMAP database (the tables striptri reads, as COLMAP's database.cc creates them): images
    1.. in photo order named <photo_id>.png, keypoints as float32 (x, y, scale, orientation),
    verified matches as uint32 pairs, config 2 (CALIBRATED)."""
    import sqlite3

    db = sqlite3.connect(path)
    db.executescript("""
        CREATE TABLE images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, name TEXT NOT NULL UNIQUE,
                             camera_id INTEGER NOT NULL);
        CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
                                data BLOB);
        CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
                                          cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL, F BLOB, E BLOB,
                                          H BLOB, qvec BLOB, tvec BLOB);""")
    for k, pid in enumerate(project.photos.ids):
        kp = np.column_stack([feats[k].xy, np.ones(len(feats[k])), np.zeros(len(feats[k]))]).astype(np.float32)
        db.execute("INSERT INTO images VALUES (?, ?, 1)", (k + 1, f"images/{pid}.png"))
        db.execute("INSERT INTO keypoints VALUES (?, ?, 4, ?)", (k + 1, len(kp), kp.tobytes()))
    for (p, q), (i, j) in pairs_matches:
        m = np.column_stack([i, j]).astype(np.uint32)
        db.execute("INSERT INTO two_view_geometries (pair_id, rows, cols, data, config) VALUES (?, ?, 2, ?, 2)",
                   ((p + 1) * 2147483647 + q + 1, len(m), m.tobytes()))
    db.commit()
    db.close()


def test_a_colmap_database_gives_the_matchers_own_tracks(block, tmp_path):
    """The features and verified matches of striptri's matcher written into a COLMAP database: read
    back, they make the same tracks as the matcher's own matches joined in the same order (the
    database has no descriptor distances), and `striptri match --colmap-database` writes the project."""
    from striptri.io import read_project
    from striptri.match.colmap_database import matches_for_project
    from striptri.match.frames import digital_frames
    from striptri.match.pair_matching import match_pair
    from striptri.match.pipeline import MatchOptions, _image_paths, _pairs, _terrain_height
    from striptri.match.stages import FeatureTask, find_features, load_features
    from striptri.match.tracks import build_tracks

    project_dir = block / "project"
    project = read_project(project_dir, plate_measurements_optional=True)
    options = MatchOptions(scale=0.5, max_features=2000)
    paths = _image_paths(project, block / "images", project_dir)
    size = tuple(project.cameras.size_px[0])
    for k, path in enumerate(paths):
        find_features(FeatureTask(k, str(path), str(tmp_path), options.scale, options.max_features, size))
    feats = [load_features(tmp_path, k) for k in range(len(paths))]
    pairs_matches = []
    half = digital_frames(project).half
    for p, q in sorted(map(tuple, _pairs(project, _terrain_height(project, options), half).tolist())):
        m = match_pair(feats[p], feats[q])
        if len(m.i):
            pairs_matches.append(((p, q), (m.i, m.j)))
    database = tmp_path / "database.db"
    _colmap_database(database, project, feats, pairs_matches)

    found = matches_for_project(database, project, project_dir)
    offsets = np.cumsum([0] + [len(f) for f in feats])
    a = np.concatenate([offsets[p] + i for (p, _), (i, _) in pairs_matches])
    b = np.concatenate([offsets[q] + j for (_, q), (_, j) in pairs_matches])
    photo_of = np.repeat(np.arange(len(feats)), [len(f) for f in feats])
    ours, theirs = build_tracks(photo_of, a, b, np.zeros(len(a))), build_tracks(photo_of, found.a, found.b, found.score)

    def partition(tracks):
        groups = {}
        for f, t in enumerate(tracks.track.tolist()):
            if t >= 0:
                groups.setdefault(t, set()).add(f)
        return sorted(map(sorted, groups.values()))

    np.testing.assert_array_equal(np.concatenate(found.xy), np.concatenate([f.xy for f in feats]).astype(np.float32))
    assert ours.n_tracks > 100 and partition(ours) == partition(theirs)
    run = CliRunner().invoke(main, ["match", str(project_dir), "--colmap-database", str(database), "--out",
                                    str(tmp_path / "out"), "--sigma-px", "0.3"])
    assert run.exit_code == 0, run.output
    rows = list(csv.DictReader((tmp_path / "out" / "image_points.csv").open()))
    assert len({r["point_id"] for r in rows if r["source"] == "auto"}) >= 6 * 9
    both = CliRunner().invoke(main, ["match", str(project_dir), "--colmap-database", str(database), "--images",
                                     str(block / "images"), "--out", str(tmp_path / "o2")])
    assert both.exit_code == 2 and not (tmp_path / "o2").exists()


def test_control_points_get_image_chips_at_their_predicted_positions(block, tmp_path):
    """Two control points on the flat terrain (Z = 0) and a height point: every photo whose image
    the approximate orientation puts a plan point in gets a chip, cut from the image around the
    prediction (chips.csv's col0, row0 place it), the prediction marked; the height point gets none."""
    import shutil

    from striptri.geometry.camera import project as plate_of
    from striptri.geometry.pixels import pixel_from_plate
    from striptri.io import read_project

    project_dir = tmp_path / "project"
    shutil.copytree(block / "project", project_dir)
    (project_dir / "control.csv").write_text("point_id,kind,X,Y,Z\nA,XYZ,560,420,0\nB,XY,880,700,0\nH,Z,,,0\n")
    run = CliRunner().invoke(main, ["match", str(project_dir), "--images", str(block / "images"), "--out",
                                    str(tmp_path / "out"), "--scale", "0.5", "--features", "1000"])
    assert run.exit_code == 0, run.output
    listed = list(csv.DictReader((tmp_path / "out" / "chips" / "chips.csv").open()))
    project = read_project(project_dir, plate_measurements_optional=True)
    ph = project.photos
    expected = set()
    for point, X in (("A", [560.0, 420.0, 0.0]), ("B", [880.0, 700.0, 0.0])):
        plate = plate_of(ph.R_ground_from_cam, ph.xyz0, project.cameras.interior[0, :3], np.array(X))
        colrow = pixel_from_plate(plate, np.array([W, H]), PIXEL)
        for k in np.flatnonzero(((colrow >= 0) & (colrow <= [W, H])).all(1)):
            expected.add((point, ph.ids[k], *colrow[k].round(6)))
    assert {(r["point_id"], r["photo_id"], round(float(r["col"]), 6), round(float(r["row"]), 6)) for r in listed} == expected
    assert len(expected) >= 4
    cv2_ = pytest.importorskip("cv2")
    for r in listed:
        chip = cv2_.imread(str(tmp_path / "out" / "chips" / r["chip"]), cv2_.IMREAD_COLOR)
        image = cv2_.imread(str(block / "images" / f"{r['photo_id']}.png"), cv2_.IMREAD_GRAYSCALE)
        assert chip.shape[:2] == (201, 201)
        c0, r0 = int(r["col0"]), int(r["row0"])
        grey = chip[:, :, 0] == chip[:, :, 2]  # the red mark aside, the chip is the image
        window = np.zeros((201, 201), dtype=np.uint8)
        a0, b0, a1, b1 = max(c0, 0), max(r0, 0), min(c0 + 201, W), min(r0 + 201, H)
        window[b0 - r0:b1 - r0, a0 - c0:a1 - c0] = image[b0:b1, a0:a1]
        assert grey.mean() > 0.97 and np.array_equal(chip[:, :, 0][grey], window[grey])
        u, v = float(r["col"]) - c0, float(r["row"]) - r0
        assert 100 <= u <= 101 and 100 <= v <= 101  # the prediction in the chip's middle pixel
        assert (chip[int(v), int(u) + 10, 2] > chip[int(v), int(u) + 10, 0])  # the mark's arm, red


def test_the_tie_points_do_not_depend_on_where_the_work_runs(block, tmp_path):
    """Features and pairs in this process, in two local processes and on a Dask cluster: the same
    image_points.csv, byte for byte (the pairs' results are put in the pairs' order); the work
    folder with the features (beside OUT) is gone afterwards, also after a failed run."""
    distributed = pytest.importorskip("distributed")
    from striptri.errors import InputError
    from striptri.match.pipeline import MatchOptions, run_match

    options = MatchOptions(scale=0.5, max_features=1000)
    outputs = []
    for n, where in enumerate([{"workers": 1}, {"workers": 2}, "dask"]):
        out = tmp_path / f"out{n}"
        if where == "dask":
            with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                          dashboard_address=None) as cluster, distributed.Client(cluster) as client:
                run_match(block / "project", block / "images", out, options.__class__(
                    **{**options.__dict__, "scheduler": client}))
        else:
            run_match(block / "project", block / "images", out, options.__class__(**{**options.__dict__, **where}))
        outputs.append((out / "image_points.csv").read_bytes())
    assert outputs[0] == outputs[1] == outputs[2] and outputs[0].count(b"\n") > 100
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out0", "out1", "out2"]  # no work folder left
    broken = tmp_path / "broken"
    broken.mkdir()
    for p in (block / "images").iterdir():
        (broken / p.name).write_bytes(b"not an image" if p.name == "P3.png" else p.read_bytes())
    with pytest.raises(InputError, match="not an image"):
        run_match(block / "project", broken, tmp_path / "out3", options)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken", "out0", "out1", "out2"]
