"""The covariance of chosen groups and its S-transformation (issue 17, striptri.precision.export).

Evidence: the diagonal blocks equal the mean errors the adjustment reports elsewhere (photos.csv,
cameras.csv, points.csv: a second way through result.photo_mean_errors and the triangulation's
Schmid (90) split); the method of conditions and the bundle method export the same covariance; the
S-transformation is a projector (applied twice = once), puts inner constraints on the datum points
and leaves the mean errors of distances between points unchanged (1e-9 relative)."""

import numpy as np
import pytest

from striptri.precision import export as ce
from striptri.adjustment import adjust
from striptri.pipeline import options_for, triangulate_result

from test_inactive import _block


def _export(method, groups=ce.GROUPS, seed=3):
    p = _block(seed)
    r = adjust(p, options_for(p, method=method))
    tri = triangulate_result(p, r)
    return p, r, tri, ce.joint_covariance(p, r, tri, groups)


def _blocks(e, group):
    idx = [i for i, lab in enumerate(e.labels) if lab.startswith(group + "/")]
    return np.array(idx)


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_diagonal_equals_the_reported_mean_errors(method):
    p, r, tri, e = _export(method)
    sd = np.sqrt(np.diag(e.cov))
    sig_xyz, sig_ang = r.photo_mean_errors(p.settings.rotation)
    ph = _blocks(e, "photos").reshape(len(p.photos), 6)
    np.testing.assert_allclose(sd[ph[:, :3]], sig_xyz, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(sd[ph[:, 3:]], sig_ang, rtol=1e-9, atol=1e-15)
    pts = _blocks(e, "points").reshape(-1, 3)
    s0 = r.sigma0_for_precision
    cov_pts = s0**2 * (tri.cov_measurement + tri.cov_orientation)[tri.determined]
    for i in range(len(pts)):
        np.testing.assert_allclose(e.cov[np.ix_(pts[i], pts[i])], cov_pts[i], rtol=1e-9,
                                   atol=1e-12 * np.abs(cov_pts[i]).max())
    assert len(pts) == tri.determined.sum()
    assert np.all(np.linalg.eigvalsh(e.cov) > -1e-12 * np.abs(e.cov).max())  # a covariance


def test_conditions_and_bundle_export_the_same_covariance():
    *_, a = _export("conditions")
    *_, b = _export("bundle")
    assert a.labels == b.labels
    np.testing.assert_allclose(a.values, b.values, rtol=0, atol=1e-6)
    scale = np.sqrt(np.outer(np.diag(a.cov), np.diag(a.cov)))
    assert np.abs(a.cov - b.cov).max() / scale.max() < 1e-6


def _distance_sigma(e, p1, p2):
    _, f = e.distance(p1, p2)
    return float(np.sqrt(f @ e.cov @ f))


def _ratio_sigma(e, a, b, c, d):
    """Mean error of |a - b| / |c - d| (the gradient of a quotient)."""
    d1, f1 = e.distance(a, b)
    d2, f2 = e.distance(c, d)
    f = f1 / d2 - d1 / d2**2 * f2
    return float(np.sqrt(f @ e.cov @ f))


def test_s_transformation_projector_inner_constraints_and_invariant_distances():
    p, r, tri, e = _export("conditions", groups=("photos", "points"))
    ids = [lab.split("/")[1] for lab in e.labels if lab.startswith("points/") and lab.endswith("/X")]
    datum = ids[2:8]
    s = ce.s_transform(e, datum, scale=False)  # a rigid motion: distances are invariant
    again = ce.s_transform(s, datum, scale=False)
    np.testing.assert_allclose(again.cov, s.cov, rtol=0, atol=1e-12 * np.abs(s.cov).max())
    rows = [e.labels.index(f"points/{pid}/{a}") for pid in datum for a in "XYZ"]
    HD = s.H[rows][:, :6]  # rigid: inner constraints for translation and rotation
    assert np.abs(HD.T @ s.cov[rows]).max() < 1e-10 * np.abs(HD).max() * np.abs(s.cov).max()
    # the datum points' trace is the smallest any datum gives them: smaller than in the control datum
    assert np.trace(s.cov[np.ix_(rows, rows)]) < np.trace(e.cov[np.ix_(rows, rows)])
    for a, b in ((ids[0], ids[-1]), (ids[1], ids[5]), (ids[3], ids[4])):
        assert _distance_sigma(s, a, b) == pytest.approx(_distance_sigma(e, a, b), rel=1e-9)
    # a similarity: the ratio of two distances keeps its mean error, a distance alone does not
    sim7 = ce.s_transform(e, datum)
    assert _ratio_sigma(sim7, ids[0], ids[-1], ids[1], ids[5]) == pytest.approx(
        _ratio_sigma(e, ids[0], ids[-1], ids[1], ids[5]), rel=1e-9)
    assert np.abs(sim7.H[rows].T @ sim7.cov[rows]).max() < 1e-10 * np.abs(sim7.H).max() * np.abs(sim7.cov).max()
    with pytest.raises(ValueError, match="not among the exported points"):
        ce.s_transform(e, ["no-such-point"] + datum)
    with pytest.raises(ValueError, match="at least three points"):
        ce.s_transform(e, datum[:2])


def test_npz_holds_labels_values_and_covariance(tmp_path):
    *_, e = _export("conditions", groups=("camera", "points"))
    path = tmp_path / "covariance.npz"
    path.write_bytes(e.npz_bytes())
    with np.load(path) as z:
        assert list(z["labels"]) == e.labels
        np.testing.assert_array_equal(z["covariance"], e.cov)
        np.testing.assert_array_equal(z["values"], e.values)
        assert str(z["datum"]) == "adjustment"


def test_cli_writes_covariance_npz_matching_points_csv(tmp_path):
    from cli_support import assert_clean_failure, run

    from striptri.io import write_project
    from striptri.io.csvtable import read_csv

    p = _block(3)
    folder = write_project(tmp_path / "proj", p)
    out = tmp_path / "out"
    proc = run("adjust", folder, "--out", out, "--covariance", "photos,camera,points", "--quiet")
    assert proc.returncode == 0, proc.stderr
    pts = read_csv(out / "points.csv")
    ids, sig = pts.strings("point_id"), pts.optional_floats("sigma_X")
    with np.load(out / "covariance.npz") as z:
        labels, cov = list(z["labels"]), z["covariance"]
        assert str(z["datum"]) == "adjustment"
    for pid, s in zip(ids, sig):
        if np.isfinite(s) and s > 0:
            assert np.sqrt(cov[labels.index(f"points/{pid}/X"), labels.index(f"points/{pid}/X")]) == \
                pytest.approx(s, rel=1e-9)
    tie = [pid for pid, s in zip(ids, sig) if np.isfinite(s) and s > 0][:5]
    out2 = tmp_path / "out2"
    proc = run("adjust", folder, "--out", out2, "--covariance", "points", "--covariance-datum", ",".join(tie),
               "--quiet")
    assert proc.returncode == 0, proc.stderr
    with np.load(out2 / "covariance.npz") as z:
        assert str(z["datum"]) == ",".join(tie)
    assert_clean_failure(run("adjust", folder, "--out", tmp_path / "o3", "--covariance-datum", "A,B,C"), 2)
    assert_clean_failure(run("adjust", folder, "--out", tmp_path / "o4", "--covariance", "photos,lenses"), 2)
    assert not (tmp_path / "o3").exists() and not (tmp_path / "o4").exists()


@pytest.mark.parametrize("calibrated", [False, True])
def test_inverse_let_go_before_the_tables_changes_no_file(monkeypatch, calibrated):
    """After the point precision a run lets the selected inverse go when nothing after it reads
    more of Qxx than the photo blocks and the diagonal (no covariance.npz, cameras held, no GNSS, no
    distances): the tables and the summary are those of a run that keeps it, and nothing made the
    inverse again. With an estimated camera element (the report's correlations with the exterior
    elements) it is kept."""
    from dataclasses import replace

    import striptri.pipeline as pipeline
    from striptri.core.runs import RunOptions
    from striptri.selected_inverse.result import _Rebuilt

    p = _block(3)
    if calibrated:
        sigma = np.full_like(p.cameras.interior, np.nan)
        sigma[:, 0] = np.inf  # c estimated
        p = replace(p, cameras=replace(p.cameras, sigma_interior=sigma))
    run = RunOptions(blunders="snoop")
    let_go = pipeline.adjust_products(p, options_for(p), run)
    engine = let_go.result._covariance._inv._engine
    assert isinstance(engine, _Rebuilt) != calibrated
    if not calibrated:
        assert not engine.rebuilt
    monkeypatch.setattr(pipeline, "_reads_covariance_entries", lambda project, result: True)
    kept = pipeline.adjust_products(p, options_for(p), run)
    assert not isinstance(kept.result._covariance._inv._engine, _Rebuilt)
    for name, text in kept.files.items():
        if name.endswith(".csv"):
            assert let_go.files[name] == text, name
    import json

    a, b = (json.loads(x.files["summary.json"]) for x in (let_go, kept))
    for s in (a, b):
        s.pop("timings_s"), s.pop("started")
    assert a == b
