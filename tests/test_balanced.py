"""Balanced radial distortion with a zero-crossing radius r0 (issue 17, striptri.geometry.balanced).

Evidence: conversions both ways to 1e-12; the rays of the balanced and the Gaussian form written out
by hand agree; dr(r0) = 0; the Jacobian against central differences; cameras.csv's r0 read and
written back; a noise-free self-calibration given and reported in the balanced form recovers the
true balanced lens."""

from dataclasses import replace

import numpy as np
import pytest
from test_jacobians import assert_jacobian
from test_self_calibration import calibration_project

from striptri.geometry import balanced, lens
from striptri import model
from striptri import simulate as sim
from striptri.errors import InputError
from striptri.io import read_project, write_project
from striptri.io.csvtable import read_csv
from striptri.geometry.lens import IMAGE, NCP, PLATE
from striptri.pipeline import adjust_products, options_for


def _cameras(rng, n, convention):
    """Random plausible lenses: plate (mm, c ~ 50-150) or image (normalised)."""
    prm = np.zeros((n, NCP))
    if convention == PLATE:
        prm[:, 0] = rng.uniform(50, 150, n)
        prm[:, lens.K1] = rng.normal(0, 5e-5, n)
        prm[:, lens.K2] = rng.normal(0, 1e-8, n)
        prm[:, lens.K3] = rng.normal(0, 1e-12, n)
        prm[:, lens.P1:lens.P2 + 1] = rng.normal(0, 1e-5, (n, 2))
        prm[:, lens.B1:] = rng.normal(0, 1e-4, (n, 2))
        r0 = rng.uniform(5, 20, n)
    else:
        prm[:, 0] = rng.uniform(1000, 4000, n)
        prm[:, lens.K1:lens.K3 + 1] = rng.normal(0, [0.05, 0.02, 0.01], (n, 3))
        prm[:, lens.P1:lens.P2 + 1] = rng.normal(0, 1e-3, (n, 2))
        r0 = rng.uniform(0.2, 0.5, n)
    prm[:, 1:3] = rng.normal(0, 0.1, (n, 2))
    return prm, r0


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_conversions_both_ways_to_1e12(convention):
    rng = np.random.default_rng(1)
    gauss, r0 = _cameras(rng, 200, convention)
    conv = np.full(200, convention)
    bal, _ = balanced.balanced_from_gaussian(gauss, r0, conv)
    np.testing.assert_allclose(balanced.gaussian_from_balanced(bal, r0, conv), gauss, rtol=1e-12, atol=0)
    np.testing.assert_allclose(balanced.balanced_from_gaussian(balanced.gaussian_from_balanced(gauss, r0, conv),
                                                               r0, conv)[0], gauss, rtol=1e-12, atol=0)
    # the unchanged elements and the cameras without r0
    np.testing.assert_array_equal(bal[:, [1, 2, lens.B1, lens.B2]], gauss[:, [1, 2, lens.B1, lens.B2]])
    r0[::2] = np.nan
    bal, J = balanced.balanced_from_gaussian(gauss, r0, conv)
    np.testing.assert_array_equal(bal[::2], gauss[::2])
    np.testing.assert_array_equal(J[::2], np.broadcast_to(np.eye(6), J[::2].shape))


def _ray_plate_balanced(prm_bal, r0, xy):
    """Balanced plate refinement written out: dr = k1' r (r^2 - r0^2) + ..., decentering with p',
    then the ray (x' + b2 y', y', -c')."""
    c, xp, yp, k1, k2, k3, p1, p2, b1, b2 = prm_bal
    x, y = (1 + b1) * (xy[:, 0] - xp), xy[:, 1] - yp
    r2 = x * x + y * y
    f = 1 + k1 * (r2 - r0**2) + k2 * (r2**2 - r0**4) + k3 * (r2**3 - r0**6)
    xr = x * f + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y
    yr = y * f + 2 * p1 * x * y + p2 * (r2 + 2 * y * y)
    return np.column_stack([xr + b2 * yr, yr, np.full(len(x), -c)])


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_balanced_and_gaussian_plate_cameras_give_the_same_rays():
    rng = np.random.default_rng(2)
    gauss, r0 = _cameras(rng, 1, PLATE)
    bal, _ = balanced.balanced_from_gaussian(gauss, r0, [PLATE])
    xy = rng.uniform(-20, 20, (300, 2))
    ideal = lens.ideal_from_observed(xy, gauss[0], PLATE).xy
    ray_gauss = np.column_stack([ideal - gauss[0, 1:3], np.full(len(xy), -gauss[0, 0])])
    np.testing.assert_allclose(_unit(_ray_plate_balanced(bal[0], r0[0], xy)), _unit(ray_gauss), rtol=0, atol=1e-14)
    # the zero crossing: at r = r0 (b1 = 0 to make r the measured radius) the radial correction is 0
    zero = bal[0].copy()
    zero[[lens.P1, lens.P2, lens.B1, lens.B2]] = 0
    at = zero[1:3] + r0[0] * np.array([[np.cos(t), np.sin(t)] for t in (0.3, 2.0)])
    np.testing.assert_allclose(_ray_plate_balanced(zero, r0[0], at)[:, :2], at - zero[1:3], rtol=0, atol=1e-13)


def test_balanced_and_gaussian_image_cameras_project_alike():
    rng = np.random.default_rng(3)
    gauss, r0 = _cameras(rng, 1, IMAGE)
    bal, _ = balanced.balanced_from_gaussian(gauss, r0, [IMAGE])
    n = rng.uniform(-0.5, 0.5, (300, 2))
    ideal = gauss[0, 1:3] + gauss[0, 0] * n  # the ideal plate point of the Gaussian camera
    xy_gauss = lens.observed_from_ideal(ideal, gauss[0], IMAGE)
    c, xp, yp, k1, k2, k3, p1, p2 = bal[0, :8]
    r2 = (n * n).sum(1)
    f = 1 + k1 * (r2 - r0[0]**2) + k2 * (r2**2 - r0[0]**4) + k3 * (r2**3 - r0[0]**6)
    x, y = n[:, 0], n[:, 1]
    by_hand = np.column_stack([xp + c * (x * f + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y),
                               yp + c * (y * f + 2 * p1 * x * y + p2 * (r2 + 2 * y * y))])
    np.testing.assert_allclose(by_hand, xy_gauss, rtol=0, atol=1e-10 * c)


@pytest.mark.parametrize("convention", [PLATE, IMAGE])
def test_jacobian_of_the_balanced_elements(convention):
    rng = np.random.default_rng(4)
    gauss, r0 = _cameras(rng, 20, convention)
    conv = np.full(20, convention)
    _, J = balanced.balanced_from_gaussian(gauss, r0, conv)
    cols = list(balanced.CHANGED)
    scale = np.abs(gauss[:, cols]) + 1e-30
    num = np.zeros_like(J)
    for k, e in enumerate(cols):
        h = 1e-6 * scale[:, k]
        up, down = gauss.copy(), gauss.copy()
        up[:, e] += h
        down[:, e] -= h
        d = (balanced.balanced_from_gaussian(up, r0, conv)[0] - balanced.balanced_from_gaussian(down, r0, conv)[0])
        num[:, :, k] = d[:, cols] / (2 * h[:, None])
    # relative to each entry's size (the elements differ by orders of magnitude)
    assert_jacobian(J * scale[:, None, :], num * scale[:, None, :], 1)


def _write_calibration(tmp_path, convention, r0):
    noise = sim.NoiseOptions(sigma_image=0.0, stated_sigma_image=0.005, sigma_control_xy=0.0, sigma_control_z=0.0)
    project, truth, prm = calibration_project(convention, noise, free=("c", "k1", "k2", "p1", "p2"))
    cams = replace(project.cameras, r0=np.array([r0]))
    return write_project(tmp_path / "proj", replace(project, cameras=cams)), prm


@pytest.mark.parametrize("convention, r0", [(PLATE, 80.0), (IMAGE, 0.4)])
def test_noise_free_self_calibration_in_the_balanced_form(tmp_path, convention, r0):
    folder, prm = _write_calibration(tmp_path, convention, r0)
    table = read_csv(folder / "cameras.csv")
    assert table.has("r0")
    project = read_project(folder)
    products = adjust_products(project, options_for(project))
    out = read_csv_text(products.files["cameras.csv"])
    true_bal, _ = balanced.balanced_from_gaussian(prm[None], [r0], [convention])
    for name, e in zip(balanced.BALANCED_NAMES, balanced.CHANGED):
        if e == lens.K3:
            continue  # held at 0: stays 0 in both forms
        got = float(out[name][0])
        assert abs(got - true_bal[0, e]) <= 1e-7 * abs(true_bal[0, e]), (name, got, true_bal[0, e])
        assert out[f"sigma_{name}"][0] != ""  # determined: a mean error is given
    # the Gaussian columns are the truth too, and the result is the same as the Gaussian input's
    assert abs(float(out["c"][0]) - prm[0]) <= 1e-7 * prm[0]


def read_csv_text(text):
    lines = text.splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:]]
    return {h: [r[j] for r in rows] for j, h in enumerate(header)}


def test_cameras_csv_r0_round_trip_and_refusals(tmp_path):
    rng = np.random.default_rng(5)
    gauss, r0 = _cameras(rng, 1, PLATE)
    folder, _ = _write_calibration(tmp_path, PLATE, 80.0)
    p = read_project(folder)
    cams = model.Cameras(p.cameras.ids, gauss, p.cameras.sigma_interior, p.cameras.convention, r0=r0)
    again = write_project(tmp_path / "again", replace(p, cameras=cams))
    q = read_project(again)
    np.testing.assert_allclose(q.cameras.interior, gauss, rtol=1e-12, atol=0)
    assert q.cameras.r0[0] == r0[0]
    text = (again / "cameras.csv").read_text().splitlines()
    header = text[0].split(",")
    # balanced values on file: c there is c' (not the Gaussian c)
    c_file = float(text[1].split(",")[header.index("c")])
    assert c_file == pytest.approx(balanced.balanced_from_gaussian(gauss, r0, [PLATE])[0][0, 0], rel=1e-15)
    assert abs(c_file - gauss[0, 0]) > 1e-6
    # an observed sigma of k1 with r0: refused, naming the line
    row = text[1].split(",")
    row[header.index("sigma_k1")] = "1e-6"
    (again / "cameras.csv").write_text("\n".join([text[0], ",".join(row)]) + "\n")
    with pytest.raises(InputError, match="line 2.*k1 may be held"):
        read_project(again)
    row[header.index("sigma_k1")] = ""
    row[header.index("r0")] = "-3"
    (again / "cameras.csv").write_text("\n".join([text[0], ",".join(row)]) + "\n")
    with pytest.raises(InputError, match="r0.*must be > 0"):
        read_project(again)
