"""distances.csv: reading (InputError with file, line and reason), the refusal outside the bundle
method and the output table (striptri.io.distances_reader, striptri.bundle.distances)."""

import json

import numpy as np
import pytest

from striptri.core.runs import RunOptions
from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.core.options import AdjustmentOptions
from striptri.errors import InputError, NumericalFailure
from striptri.io.project_reader import parse_project
from striptri.io.project_writer import project_files
from striptri.pipeline import run_adjust


@pytest.fixture(scope="module")
def files_and_truth():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=2))
    truth = sim.make_truth(design, np.random.default_rng(7))
    project = sim.perturb(truth, sim.NoiseOptions(approx_position_error=1.0, approx_angle_error=0.1),
                          np.random.default_rng(8))
    rays = np.bincount(project.image_points.point_index, minlength=len(project.points))
    ids = [project.points.ids[k] for k in np.flatnonzero(rays >= 2)]
    xyz = {pid: truth.xyz_ground[truth.point_ids.index(pid)] for pid in ids}
    return project_files(project), ids, xyz


def _with(files, text):
    return {**files, "distances.csv": text}


def test_read_distances(files_and_truth):
    files, ids, _ = files_and_truth
    project = parse_project(_with(files, f"point_from,point_to,distance,sigma\n{ids[0]},{ids[1]},12.5,0.002\n"))
    d = project.distances
    assert [project.points.ids[d.point_from[0]], project.points.ids[d.point_to[0]]] == ids[:2]
    assert d.distance[0] == 12.5 and d.sigma[0] == 0.002 and list(d.line) == [2]


@pytest.mark.parametrize("row, reason", [
    ("NOPE,{b},10,0.01", "unknown point_from 'NOPE'"),
    ("{a},{a},10,0.01", "same point"),
    ("{c},{d},-3,0.01", "must be positive"),
    ("{c},{d},0,0.01", "must be positive"),
    ("{c},{d},10,0", "must be positive"),
    ("{c},{d},10,", "column 'sigma' is empty"),
    ("{c},{d},ten,0.01", "column 'distance'"),
    ("{b},{a},10,0.01", "duplicate distance between these two points (first on line 2)"),
])
def test_bad_rows_name_file_line_and_reason(files_and_truth, row, reason):
    files, ids, _ = files_and_truth
    text = f"point_from,point_to,distance,sigma\n{ids[0]},{ids[1]},10,0.01\n" + row.format(a=ids[0], b=ids[1], c=ids[2], d=ids[3]) + "\n"
    with pytest.raises(InputError) as info:
        parse_project(_with(files, text))
    assert info.value.path.endswith("distances.csv") and info.value.line == 3
    assert reason in info.value.reason


def test_missing_column(files_and_truth):
    files, ids, _ = files_and_truth
    with pytest.raises(InputError, match="sigma"):
        parse_project(_with(files, f"point_from,point_to,distance\n{ids[0]},{ids[1]},10\n"))


def test_sequential_method_refuses_distances(files_and_truth):
    files, ids, _ = files_and_truth
    project = parse_project(_with(files, f"point_from,point_to,distance,sigma\n{ids[0]},{ids[1]},10,0.01\n"))
    with pytest.raises(NumericalFailure, match="--method conditions or bundle"):
        adjust(project, AdjustmentOptions(method="sequential"))


@pytest.mark.parametrize("method", ["bundle", "conditions"])
def test_output_table_and_summary(files_and_truth, tmp_path, method):
    files, ids, xyz = files_and_truth
    a, b = ids[1], ids[-2]
    d = np.linalg.norm(xyz[a] - xyz[b])
    folder = tmp_path / "p"
    folder.mkdir()
    for name, text in _with(files, f"point_from,point_to,distance,sigma\n{a},{b},{float(d)!r},0.002\n").items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    run_adjust(folder, tmp_path / "out", RunOptions(method=method))
    lines = (tmp_path / "out" / "distances.csv").read_text().splitlines()
    assert lines[0] == ("point_from,point_to,distance,sigma,adjusted,residual,residual_sigma,sigma_adjusted,"
                        "redundancy,w,flag,mdb")
    row = lines[1].split(",")
    # the tests of the distance: w = v / (sigma sqrt(r)), the adjusted distance's mean error below sigma
    s0 = json.loads((tmp_path / "out" / "summary.json").read_text())["sigma0"]
    r, w = float(row[8]), float(row[9])
    assert 0 < r < 1 and float(row[7]) < s0 * 0.002
    assert w == pytest.approx(float(row[5]) / (0.002 * np.sqrt(r)), rel=1e-6)
    assert row[10] == ("suspect" if abs(w) > 3.29 else "")
    points = {r.split(",")[0]: r.split(",") for r in (tmp_path / "out" / "points.csv").read_text().splitlines()}
    header = points["point_id"]
    X = lambda p: np.array([float(points[p][header.index(c)]) for c in ("X", "Y", "Z")])  # noqa: E731
    assert float(row[4]) == pytest.approx(np.linalg.norm(X(a) - X(b)), abs=1e-6)
    assert float(row[5]) == pytest.approx(float(row[4]) - d, abs=1e-9)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["distances"]["count"] == 1
    assert summary["distances"]["max_abs_residual_sigma"] == pytest.approx(abs(float(row[6])), rel=1e-9)
    assert summary["distances"]["redundancy"] == pytest.approx(r, rel=1e-12)
    assert summary["distances"]["max_abs_w"] == pytest.approx(abs(w), rel=1e-12)
    report = (tmp_path / "out" / "report.html").read_text()
    section = report[report.index("<h2 id='distances'>"):]
    assert "href='#distances'" in report and f"<td class='l'>{a}</td>" in section
    assert f"{1000 * float(row[5]):.2f}" in section


def test_no_distances_no_section(files_and_truth, tmp_path):
    files, _, _ = files_and_truth
    folder = tmp_path / "p"
    folder.mkdir()
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    run_adjust(folder, tmp_path / "out", RunOptions(method="bundle"))
    assert not (tmp_path / "out" / "distances.csv").exists()
    assert "distances" not in json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "id='distances'" not in (tmp_path / "out" / "report.html").read_text()
