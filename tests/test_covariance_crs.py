"""The covariance export and the standard deviations of a project in map coordinates (issue 17 with
issue 14's [coordinates]): the local frame's covariance carried into the CRS's axes with every
correlation (covariance_export.in_grid, LocalFrame.photo_jacobian_to_grid / point_jacobian_to_grid).

Evidence: the Jacobians against central differences of the whole local -> grid map of the values
(centre-dependence of the grid angles included); the exported diagonal equal to photos.csv's and
points.csv's standard deviations in the CRS; an S-transformation done in the local frame, then
carried over; the npz names the CRS."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from striptri.core.runs import RunOptions
from striptri.cli import main
from striptri.precision.export import CovarianceRequest, in_grid, joint_covariance, s_transform
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.crs.frame import LocalFrame
from striptri.crs.project import in_local_frame
from striptri.core.options import AdjustmentOptions
from striptri.adjustment import adjust
from striptri.io.csvtable import read_csv
from striptri.io.project_reader import read_project
from striptri.model import CoordinateSettings
from striptri.pipeline import run_adjust
from striptri.geometry.rotations import R_from_angles, angles_from_R

UTM33 = "EPSG:32633"
CENTRE = np.array([736000.0, 5320000.0, 0.0])


def _frame(heights="ellipsoidal", n=None):
    return LocalFrame(CoordinateSettings(UTM33, heights, geoid_undulation=n), CENTRE)


def _grid_values(frame, values_local: np.ndarray, convention: str) -> np.ndarray:
    """The photo map (X0, Y0, Z0, three angles) -> grid, written out directly for differencing."""
    xyz, ang = values_local[:, :3], values_local[:, 3:]
    R = frame.rotations_to_grid(xyz, R_from_angles(ang, convention))
    return np.column_stack([frame.from_local(xyz), angles_from_R(R, convention)])


@pytest.mark.parametrize("convention", ["omega-phi-kappa", "phi-omega-kappa"])
def test_photo_jacobian_against_central_differences(convention):
    frame = _frame("orthometric", 47.0)
    rng = np.random.default_rng(3)
    local = np.column_stack([rng.uniform(-9e3, 9e3, (6, 2)), rng.uniform(500, 3000, 6),
                             rng.normal(0, 0.05, (6, 2)), rng.uniform(-3, 3, 6)])
    F = frame.photo_jacobian_to_grid(local[:, :3], R_from_angles(local[:, 3:], convention), convention)
    num = np.zeros_like(F)
    for j, h in enumerate([10.0] * 3 + [1e-7] * 3):  # 10 m: grid values of 5e6 m round at 1e-9 m
        d = np.zeros(6)
        d[j] = h
        diff = _grid_values(frame, local + d, convention) - _grid_values(frame, local - d, convention)
        num[:, :, j] = diff / (2 * h)
    # positions to 1e-8 of a unit Jacobian; angles to 1e-6 rad/rad (steps of 1e-7 rad); the
    # centre-to-angle block (about 2e-7 rad/m: the convergence and the normal turning; taken over
    # +-1 m by the frame, over +-10 m here) to 1e-10 rad/m
    assert np.abs(F[:, :3, :3] - num[:, :3, :3]).max() < 1e-8
    assert np.abs(F[:, 3:, 3:] - num[:, 3:, 3:]).max() < 1e-6
    assert np.abs(F[:, 3:, :3] - num[:, 3:, :3]).max() < 1e-10
    assert 5e-8 < np.abs(F[:, 3:, :3]).max() < 1e-6  # the block is there, of the expected size
    assert np.abs(F[:, :3, 3:]).max() == 0.0


def test_point_jacobian_is_the_inverse_of_the_frames(frame=None):
    frame = _frame()
    local = np.array([[1500.0, -800.0, 300.0], [np.nan, 0.0, 0.0]])
    J = frame.point_jacobian_to_grid(local)
    np.testing.assert_allclose(J[0] @ frame.jacobian(frame.from_local(local[:1]))[0], np.eye(3), atol=1e-12)
    assert np.all(np.isnan(J[1]))


@pytest.fixture(scope="module")
def crs_block(tmp_path_factory):
    """simulate --crs: a 3 x 4 block on the ellipsoid in UTM 33 (the CLI's map-coordinate project)."""
    folder = tmp_path_factory.mktemp("crs") / "p"
    res = CliRunner().invoke(main, ["simulate", "block", "--out", str(folder), "--photos", "4", "--strips", "3",
                                    "--crs", UTM33, "--flying-height", "2000", "--seed", "5"])
    assert res.exit_code == 0, res.output
    return folder


def _adjusted_local(folder):
    framed = in_local_frame(read_project(folder))
    result = adjust(framed.local, AdjustmentOptions(method="bundle"))
    return framed, result


def test_export_in_grid_is_the_local_export_carried_by_the_jacobian(crs_block):
    framed, result = _adjusted_local(crs_block)
    local = joint_covariance(framed.local, result, triangulate_adjusted(framed.local, result), ("photos", "points"))
    grid = in_grid(local, framed.frame)
    assert grid.crs == UTM33 and grid.labels == local.labels
    # values: the labels' own conversions
    n_photo = len(framed.local.photos)
    photo_vals = local.values[: 6 * n_photo].reshape(-1, 6)
    np.testing.assert_allclose(grid.values[: 6 * n_photo].reshape(-1, 6),
                               _grid_values(framed.frame, photo_vals, local.convention), rtol=0, atol=1e-9)
    pts = local.values[6 * n_photo:].reshape(-1, 3)
    np.testing.assert_allclose(grid.values[6 * n_photo:].reshape(-1, 3), framed.frame.from_local(pts), atol=1e-9)
    # covariance: every 6x6 photo block and 3x3 point block, and a cross block, by the Jacobians
    F = framed.frame.photo_jacobian_to_grid(photo_vals[:, :3], R_from_angles(photo_vals[:, 3:], local.convention),
                                            local.convention)
    Jp = framed.frame.point_jacobian_to_grid(pts)
    for i in range(n_photo):
        b = slice(6 * i, 6 * i + 6)
        np.testing.assert_allclose(grid.cov[b, b], F[i] @ local.cov[b, b] @ F[i].T, rtol=1e-12, atol=1e-30)
    k = 6 * n_photo
    for i in (0, len(pts) // 2, len(pts) - 1):
        b = slice(k + 3 * i, k + 3 * i + 3)
        np.testing.assert_allclose(grid.cov[b, b], Jp[i] @ local.cov[b, b] @ Jp[i].T, rtol=1e-12, atol=1e-30)
        np.testing.assert_allclose(grid.cov[b, 0:6], Jp[i] @ local.cov[b, 0:6] @ F[0].T, rtol=1e-10, atol=1e-30)
    # not the identity: the grid scale differs from 1 by the projection's scale (UTM: about 4e-4 here)
    free = np.diag(local.cov)[k::3] > 0  # held control has none
    ratio = np.sqrt(np.diag(grid.cov)[k::3][free] / np.diag(local.cov)[k::3][free])
    assert free.sum() > 10 and np.abs(ratio - 1).max() > 1e-4


def test_cli_writes_the_grid_covariance_matching_the_csv_tables(crs_block, tmp_path):
    out = tmp_path / "o"
    res = CliRunner().invoke(main, ["adjust", str(crs_block), "--out", str(out), "--method", "bundle", "--quiet",
                                    "--covariance", "photos,points"])
    assert res.exit_code == 0, res.output
    with np.load(out / "covariance.npz") as z:
        labels, values, cov = list(z["labels"]), z["values"], z["covariance"]
        assert str(z["crs"]) == UTM33
    sd = dict(zip(labels, np.sqrt(np.diag(cov))))
    val = dict(zip(labels, values))
    pts = read_csv(out / "points.csv")
    n_checked = 0
    for pid, kind, x, sx in zip(pts.strings("point_id"), pts.strings("kind"), pts.floats("X"),
                                pts.optional_floats("sigma_X")):
        if f"points/{pid}/X" in sd and np.isfinite(sx) and sx > 0:
            assert sd[f"points/{pid}/X"] == pytest.approx(sx, rel=1e-9)
            assert val[f"points/{pid}/X"] == pytest.approx(x, abs=1e-6)
            n_checked += 1
    assert n_checked > 10
    photos = read_csv(out / "photos.csv")
    for pid, so, sp_, sk, om in zip(photos.strings("photo_id"), photos.floats("sigma_omega"),
                                    photos.floats("sigma_phi"), photos.floats("sigma_kappa"), photos.floats("omega")):
        deg = np.pi / 180
        assert sd[f"photos/{pid}/omega"] == pytest.approx(so * deg, rel=1e-9)
        assert sd[f"photos/{pid}/phi"] == pytest.approx(sp_ * deg, rel=1e-9)
        assert sd[f"photos/{pid}/kappa"] == pytest.approx(sk * deg, rel=1e-9)
        assert val[f"photos/{pid}/omega"] == pytest.approx(om * deg, abs=1e-9)


def test_s_transformation_happens_in_the_local_frame(crs_block, tmp_path):
    """--covariance-datum with a CRS: the S-transformation of the local frame, then carried into the
    grid (the similarity is one of a Cartesian frame): equal to doing the two steps by hand on the
    pipeline's own adjustment (its partial control refined at the adjusted positions)."""
    framed = in_local_frame(read_project(crs_block))
    first = joint_covariance(framed.local, *_bundle(framed.local), ("points",))
    datum = [label.split("/")[1] for label in first.labels[::3][:6]]
    products = run_adjust(crs_block, tmp_path / "o", RunOptions(method="bundle", covariance=CovarianceRequest(("points",), tuple(datum))))
    local = joint_covariance(products.project, products.result,
                             triangulate_adjusted(products.project, products.result), ("points",))
    expected = in_grid(s_transform(local, datum), framed.frame)
    with np.load(tmp_path / "o" / "covariance.npz") as z:
        assert list(z["labels"]) == expected.labels and str(z["datum"]) == ",".join(datum)
        np.testing.assert_allclose(z["covariance"], expected.cov, rtol=1e-9, atol=1e-12 * np.abs(expected.cov).max())
        np.testing.assert_allclose(z["values"], expected.values, rtol=0, atol=1e-9)


def _bundle(project):
    result = adjust(project, AdjustmentOptions(method="bundle"))
    return result, triangulate_adjusted(project, result)


def test_npz_without_a_crs_says_so(tmp_path):
    out = tmp_path / "o"
    res = CliRunner().invoke(main, ["simulate", "block", "--out", str(tmp_path / "p"), "--photos", "4",
                                    "--strips", "2"])
    assert res.exit_code == 0
    res = CliRunner().invoke(main, ["adjust", str(tmp_path / "p"), "--out", str(out), "--quiet", "--covariance",
                                    "points"])
    assert res.exit_code == 0, res.output
    with np.load(out / "covariance.npz") as z:
        assert str(z["crs"]) == ""
