"""Inactive image points (issue 17, striptri.report.inactive): image_points.csv's ``active`` column.

Evidence: inactive rows leave the adjustment identical to one without them (both methods), and
their residuals equal those computed by hand from the adjusted result (collinearity written out,
with the bundle method's point unknowns and, for the method of conditions, the points intersected by
hand from the adjusted rays)."""

from dataclasses import replace

import numpy as np
import pytest

from striptri import model
from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.bundle.adjust import solve_bundle
from striptri.geometry.camera import ray_ground
from striptri.errors import InputError
from striptri.io import read_project, write_project
from striptri.io.csvtable import read_csv
from striptri.pipeline import adjust_products, options_for


def _block(seed=3):
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=4), control=sim.ControlDesign(layout="perimeter"),
                                 points=sim.PointDesign(extra_ties_per_model=10))
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, sim.NoiseOptions(sigma_image=0.005), np.random.default_rng(seed + 100))


def _rows(ip, keep):
    return model.ImagePoints(ip.photo_index[keep], ip.point_index[keep], ip.xy[keep], ip.sigma_xy[keep])


def _split(project, off_rows, blunder=(0.2, -0.15)):
    """project with rows ``off_rows`` inactive, their x, y spoilt by ``blunder`` (mm): an inactive row
    must not matter whatever it holds. Returns (with inactive rows, active rows only)."""
    ip = project.image_points
    keep = np.ones(len(ip), dtype=bool)
    keep[off_rows] = False
    off = _rows(ip, ~keep)
    off = replace(off, xy=off.xy + np.asarray(blunder))
    active = replace(project, image_points=_rows(ip, keep))
    return replace(active, inactive_image_points=off), active


def _tie_rows(project, n):
    """n rows on tie points with at least 3 rays (each keeps >= 2 active rays), distinct points."""
    ip = project.image_points
    rays = np.bincount(ip.point_index, minlength=len(project.points))
    rows, seen = [], set()
    for r in range(len(ip)):
        k = int(ip.point_index[r])
        if project.points.kind[k] == model.TIE and rays[k] >= 3 and k not in seen:
            rows.append(r)
            seen.add(k)
        if len(rows) == n:
            break
    assert len(rows) == n
    return np.array(rows)


def _by_hand(R, O, interior, X, xy):
    """Collinearity (Schmid 14) written out: m = R^T (X - O), x = xp - c m_x / m_z, ... minus l."""
    m = np.einsum("nji,nj->ni", R, X - O)
    c, xp, yp = interior[:, 0], interior[:, 1], interior[:, 2]
    return np.column_stack([xp - c * m[:, 0] / m[:, 2], yp - c * m[:, 1] / m[:, 2]]) - xy


def _intersect(O, u):
    """Least-squares intersection of rays O + t u (k, 3) by hand: sum (I - u u^T) X = sum (I - u u^T) O."""
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    P = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    return np.linalg.solve(P.sum(0), np.einsum("kij,kj->i", P, O))


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_inactive_rows_leave_the_adjustment_identical_and_get_residuals_by_hand(method):
    p = _block()
    off_rows = _tie_rows(p, 4)
    with_off, active = _split(p, off_rows)
    options = options_for(with_off, method=method)
    products = adjust_products(with_off, options)
    plain = adjust(active, options)
    r = products.result
    assert r.vtpv == plain.vtpv and r.redundancy == plain.redundancy and r.n_unknowns == plain.n_unknowns
    np.testing.assert_array_equal(r.state.xyz0, plain.state.xyz0)
    np.testing.assert_array_equal(r.state.R_ground_from_cam, plain.state.R_ground_from_cam)
    np.testing.assert_array_equal(r.plate_residuals, plain.plate_residuals)
    # the residual rows: the active ones first, then the inactive ones flagged "inactive"
    table = products.files["residuals.csv"].splitlines()
    assert len(table) == 1 + len(p.image_points)
    header = table[0].split(",")
    last = [dict(zip(header, line.split(","))) for line in table[-len(off_rows):]]
    assert [row["flag"] for row in last] == ["inactive"] * len(off_rows)
    assert all(row["w"] == "" and row["mdb_x"] == "" for row in last)
    v = np.array([[float(row["vx"]), float(row["vy"])] for row in last])
    # by hand: the adjusted point, projected with the adjusted orientation and camera
    off = with_off.inactive_image_points
    s, ip = r.state, active.image_points
    interior = active.cameras.interior[active.photos.camera_index, :3]
    if method == "bundle":
        X = solve_bundle(active, options).xyz_points[off.point_index]
    else:
        X = np.array([_intersect(s.xyz0[ip.photo_index[ip.point_index == k]],
                                 ray_ground(s.R_ground_from_cam[ip.photo_index[ip.point_index == k]],
                                            r.plate_adjusted[ip.point_index == k],
                                            interior[ip.photo_index[ip.point_index == k]]))
                      for k in off.point_index])
    ph = off.photo_index
    hand = _by_hand(s.R_ground_from_cam[ph], s.xyz0[ph], interior[ph], X, off.xy)
    np.testing.assert_allclose(v, hand, rtol=0, atol=1e-9)  # mm; the blunders are 0.2 mm
    assert np.all(np.abs(v + [0.2, -0.15]) < 0.05)  # about minus the spoiling, plus noise
    info = products.summary["inactive"]
    assert info["n"] == len(off_rows) and info["n_determined"] == len(off_rows)
    assert "Inactive measurements" in products.files["report.html"]


def test_a_point_with_only_inactive_rows_has_no_residual_and_no_effect():
    p = _block(4)
    ip = p.image_points
    k = int(ip.point_index[np.flatnonzero(p.points.kind[ip.point_index] == model.TIE)[0]])
    with_off, active = _split(p, np.flatnonzero(ip.point_index == k))
    products = adjust_products(with_off, options_for(with_off))
    assert products.result.vtpv == adjust(active, options_for(active)).vtpv
    assert products.summary["inactive"]["n_determined"] == 0
    rows = products.files["residuals.csv"].splitlines()[-int(np.sum(ip.point_index == k)):]
    assert all(line.split(",")[2:4] == ["", ""] for line in rows)


def test_active_column_reads_words_and_round_trips(tmp_path):
    p = _block(5)
    with_off, _ = _split(p, _tie_rows(p, 3))
    folder = write_project(tmp_path / "proj", with_off)
    table = read_csv(folder / "image_points.csv")
    assert list(table.strings("active")) == ["1"] * (len(p.image_points) - 3) + ["0"] * 3
    q = read_project(folder)
    assert len(q.image_points) == len(p.image_points) - 3 and len(q.inactive_image_points) == 3
    np.testing.assert_array_equal(q.inactive_image_points.xy, with_off.inactive_image_points.xy)
    np.testing.assert_array_equal(q.image_points.xy, with_off.image_points.xy)
    assert (write_project(tmp_path / "again", q) / "image_points.csv").read_bytes() == \
        (folder / "image_points.csv").read_bytes()
    # words, any case, and an empty field (active)
    text = (folder / "image_points.csv").read_text().splitlines()
    words = ["TRUE", "", "false", "True", "0", "1"]
    lines = [text[0]] + [line.rsplit(",", 1)[0] + "," + words[i % len(words)] for i, line in enumerate(text[1:])]
    (folder / "image_points.csv").write_text("\n".join(lines) + "\n")
    q = read_project(folder)
    expected_off = sum(1 for i in range(len(lines) - 1) if words[i % len(words)] in ("false", "0"))
    assert len(q.inactive_image_points) == expected_off
    # anything else: the file, the line and the reason
    lines[5] = lines[5].rsplit(",", 1)[0] + ",maybe"
    (folder / "image_points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        read_project(folder)
    assert "image_points.csv" in str(err.value) and "line 6" in str(err.value) and "'maybe'" in str(err.value)


def test_source_column_words_and_the_first_bad_line(tmp_path):
    """image_points.csv's source: manual, auto or empty, any case and spaces; anything else names
    the first line that holds it."""
    folder = write_project(tmp_path / "proj", _block(5))
    text = (folder / "image_points.csv").read_text().splitlines()
    words = [" Manual", "auto", "", "AUTO "]
    lines = [text[0] + ",source"] + [line + "," + words[i % len(words)] for i, line in enumerate(text[1:])]
    (folder / "image_points.csv").write_text("\n".join(lines) + "\n")
    assert len(read_project(folder).image_points) == len(lines) - 1
    lines[7] = lines[7].rsplit(",", 1)[0] + ",autox"  # line 8 of the file
    lines[9] = lines[9].rsplit(",", 1)[0] + ",robot"
    (folder / "image_points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        read_project(folder)
    assert "image_points.csv" in str(err.value) and "line 8" in str(err.value) and "'autox'" in str(err.value)


def test_project_without_inactive_rows_writes_no_active_column(tmp_path):
    p = _block(6)
    folder = write_project(tmp_path / "proj", p)
    assert not read_csv(folder / "image_points.csv").has("active")
    assert read_project(folder).inactive_image_points is None


def test_convert_says_it_leaves_inactive_rows_out(tmp_path):
    from striptri.formats.convert import convert

    p = _block(7)
    with_off, _ = _split(p, _tie_rows(p, 2))
    folder = write_project(tmp_path / "proj", with_off)
    out = convert(folder, tmp_path / "bal", "bal", source_format="project")
    assert "inactive measurements (image_points.csv active = 0) left out: 2" in out.notes
    again = convert(folder, tmp_path / "copy", "project", source_format="project")
    assert not any("inactive" in n for n in again.notes)
    assert len(read_project(tmp_path / "copy").inactive_image_points) == 2


def test_an_inactive_row_may_repeat_an_active_measurement(tmp_path):
    """A rejected measurement kept (active = 0) beside its re-measurement of the same point on the
    same photo: read, the adjustment equals the one without it, and its residual is reported; two
    active rows of one photo and point stay an error; notes count the active rays only."""
    p = _block(8)
    r = int(_tie_rows(p, 1)[0])
    ip = p.image_points
    again = _rows(ip, np.array([r]))
    again = replace(again, xy=again.xy + [0.3, -0.2])  # the rejected first measurement
    with_off = replace(p, inactive_image_points=again)
    folder = write_project(tmp_path / "proj", with_off)
    q = read_project(folder)
    assert len(q.inactive_image_points) == 1 and len(q.image_points) == len(ip)
    products = adjust_products(q, options_for(q))
    plain = read_project(write_project(tmp_path / "plain", p))  # the same numbers through the files
    assert products.result.vtpv == adjust(plain, options_for(plain)).vtpv
    last = products.files["residuals.csv"].splitlines()[-1].split(",")
    assert last[:2] == [p.photos.ids[ip.photo_index[r]], p.points.ids[ip.point_index[r]]] and last[5] == "inactive"
    assert abs(float(last[2]) + 0.3) < 0.05 and abs(float(last[3]) - 0.2) < 0.05  # about the spoilt amount
    text = (folder / "image_points.csv").read_text().splitlines()
    (folder / "image_points.csv").write_text("\n".join(text[:-1] + [text[-1].rsplit(",", 1)[0] + ",1"]) + "\n")
    with pytest.raises(InputError) as err:
        read_project(folder)
    assert "duplicate measurement" in str(err.value) and f"line {len(text)}" in str(err.value)


def test_notes_count_active_rays_only(tmp_path):
    """A tie point with two rays, one of them inactive, is a point on one photo for the adjustment."""
    p = _block(9)
    ip = p.image_points
    rays = np.bincount(ip.point_index, minlength=len(p.points))
    two = [k for k in range(len(p.points)) if p.points.kind[k] == model.TIE and rays[k] == 2]
    assert two
    row = int(np.flatnonzero(ip.point_index == two[0])[1])
    with_off, _ = _split(p, np.array([row]))
    q = read_project(write_project(tmp_path / "proj", with_off))
    said = [str(n) for n in q.notes if "measured on one photo only" in str(n)]
    assert len(said) == 1 and f"'{p.points.ids[two[0]]}'" in said[0]
