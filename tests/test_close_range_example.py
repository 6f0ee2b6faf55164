"""The worked close-range example data/close_range (issue 17): scripts/make_close_range.py's output
(nothing edited by hand), adjusted as users would: self-calibration, no control, the scale from two
scale bars, the datum from inner constraints on all targets. Both methods reach the same result and
recover the true camera and the true shape (distances between targets) within their mean errors."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from striptri.core.runs import RunOptions
from striptri.precision.export import CovarianceRequest
from striptri.pipeline import run_adjust

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "data" / "close_range"
sys.path.insert(0, str(ROOT / "scripts"))
import make_close_range  # noqa: E402

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("close_range_example")

K = 4.0  # bound in standard deviations for single recovered quantities (two-sided 6e-5)


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_the_example_is_the_script_s_output(tmp_path):
    out = make_close_range.write_example(tmp_path / "close_range")
    written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    shipped = sorted(p.relative_to(EXAMPLE) for p in EXAMPLE.rglob("*") if p.is_file())
    assert written == shipped
    for rel in written:
        assert (out / rel).read_bytes() == (EXAMPLE / rel).read_bytes(), rel


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    out = {}
    for method in ("conditions", "bundle"):
        folder = tmp_path_factory.mktemp(method) / "out"
        products = run_adjust(EXAMPLE, folder, RunOptions(method=method, covariance=CovarianceRequest(("camera", "points"))))
        out[method] = (folder, products)
    return out


def test_both_methods_agree(adjusted):
    (fc, pc), (fb, pb) = adjusted["conditions"], adjusted["bundle"]
    assert pb.result.vtpv == pytest.approx(pc.result.vtpv, rel=1e-7)
    xyz = {m: np.array([[float(r[a]) for a in "XYZ"] for r in _rows(f / "points.csv")]) for m, f in
           (("c", fc), ("b", fb))}
    assert np.abs(xyz["c"] - xyz["b"]).max() < 1e-7
    for folder in (fc, fb):
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["datum"]["mode"] == "inner-points" and summary["datum"]["n_datum_points"] == 40
        assert len(summary["datum"]["free_directions"]) == 6  # the bars give the scale
        assert 0.85 < summary["sigma0"] < 1.15  # redundancy 885: sigma0 within 1 +- 0.05 at 3 sigma


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_camera_and_shape_are_recovered_within_their_mean_errors(adjusted, method):
    folder, _ = adjusted[method]
    cam = _rows(folder / "cameras.csv")[0]
    truth = _rows(EXAMPLE / "truth" / "cameras.csv")[0]
    for e in ("c", "xp", "yp", "k1", "k2"):
        assert abs(float(cam[e]) - float(truth[e])) < K * float(cam[f"sigma_{e}"]), e
    # shape: distances between targets (invariant in the free network) against the truth, with their
    # mean errors from covariance.npz (the points' cross-covariances included)
    with np.load(folder / "covariance.npz") as z:
        labels, values, cov = list(z["labels"]), z["values"], z["covariance"]
    true_xyz = {r["point_id"]: np.array([float(r[a]) for a in "XYZ"])
                for r in _rows(EXAMPLE / "truth" / "points.csv")}
    ids = sorted(true_xyz)
    pairs = [(ids[i], ids[j]) for i, j in ((1, 20), (5, 33), (10, 39), (2, 14), (25, 30))]
    z_scores = []
    for p, q in pairs:
        rp = [labels.index(f"points/{p}/{a}") for a in "XYZ"]
        rq = [labels.index(f"points/{q}/{a}") for a in "XYZ"]
        d = values[rp] - values[rq]
        f = np.zeros(len(labels))
        f[rp], f[rq] = d / np.linalg.norm(d), -d / np.linalg.norm(d)
        sigma = np.sqrt(f @ cov @ f)
        z_scores.append((np.linalg.norm(d) - np.linalg.norm(true_xyz[p] - true_xyz[q])) / sigma)
    assert np.all(np.abs(z_scores) < K), z_scores
    bars = _rows(folder / "distances.csv")
    assert len(bars) == 2 and all(abs(float(b["w"])) < 3.29 for b in bars)
