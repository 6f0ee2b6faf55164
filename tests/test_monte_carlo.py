"""Monte Carlo: the adjustment's statistics match the injected noise (DESIGN section 6).

For one true pair, many independent noise realisations (fixed seeds) are adjusted. With the
a-priori standard deviations equal to the injected noise (sigma0 a priori = 1):

* v^T P v ~ chi^2(r), so sigma0^2 = v^T P v / r has mean 1 and variance 2 / r; the mean over T
  trials has standard deviation sqrt(2 / (r T)); we allow 4 of them.
* each orientation element's error (estimate - truth) is normal with mean 0 and the variance
  sigma^2 = Qxx_ii (photo_mean_errors / sigma0): T s^2 / sigma^2 ~ chi^2(T) with s^2 the mean
  squared error (the truth is known, so T degrees of freedom). Bounds at the two-sided
  probability 1e-4 per element (Bonferroni over 12 elements: under 0.2 % for the whole test);
  the mean error within 4.5 sigma / sqrt(T).
* jointly, the Mahalanobis distance e^T Qxx^-1 e of the 12-vector of errors (centres and the
  rotation vector of R_true^T R_est, the parametrisation of the unknowns) ~ chi^2(12); its mean
  over T trials within 4 sqrt(2 * 12 / T) of 12. This also checks the correlations in Qxx.

The model is nonlinear, so the distributions hold to first order; with plate noise of 0.005 mm on
100 mm the neglected terms are of relative size 1e-4, far inside the tolerances.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from synthetic_pairs import NoiseOptions, PairOptions, PointSpec, make_truth, observe

from striptri import model
from striptri.adjustment import adjust
from striptri.geometry.rotations import angles_from_R

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("monte_carlo")

TRIALS = 200
OPK = "omega-phi-kappa"

# control at von Gruber's places (plate mm in photo 0; the plate base is 92 mm), so that the
# geometry is strong and Qxx hardly changes between noise realisations
FIXED_CONTROL = (
    PointSpec(model.FULL, (0, 1), xy_plate=(5.0, 90.0)),
    PointSpec(model.FULL, (0, 1), xy_plate=(87.0, -90.0)),
    PointSpec(model.HEIGHT, (0, 1), xy_plate=(5.0, -90.0)),
    PointSpec(model.HEIGHT, (0, 1), xy_plate=(87.0, 90.0)),
) + tuple(PointSpec(model.TIE, (0, 1)) for _ in range(18))

WEIGHTED_WITH_GNSS = (
    PointSpec(model.FULL, (0, 1), weighted=True),
    PointSpec(model.FULL, (0, 1), weighted=True),
    PointSpec(model.HEIGHT, (0, 1), weighted=True),
    PointSpec(model.PLAN, (0, 1), weighted=True),
    PointSpec(model.FULL, (0,), weighted=True),
) + tuple(PointSpec(model.TIE, (0, 1)) for _ in range(16))

CASES = {
    "fixed control, plate noise": (
        PairOptions(points=FIXED_CONTROL), NoiseOptions(approx_position=1.0, approx_angle_deg=0.05)
    ),
    "weighted control and GNSS centres": (
        PairOptions(points=WEIGHTED_WITH_GNSS),
        NoiseOptions(sigma_control=0.1, sigma_gnss=0.2, approx_angle_deg=0.05),
    ),
}


def _run(name):
    geometry, noise = CASES[name]
    seeds = np.random.SeedSequence(2024).spawn(TRIALS + 1)
    truth = make_truth(geometry, np.random.default_rng(seeds[0]))
    true_angles = angles_from_R(truth.R_ground_from_cam, OPK)
    out = {"s02": [], "err_xyz": [], "err_ang": [], "var_xyz": [], "var_ang": [], "maha": [], "r": None}
    for s in seeds[1:]:
        project = observe(truth, noise, np.random.default_rng(s))
        res = adjust(project)
        assert res.converged
        out["r"] = res.redundancy
        out["s02"].append(res.sigma0**2)
        err_xyz = res.state.xyz0 + res.offset - truth.xyz0
        err_ang = np.angle(np.exp(1j * (angles_from_R(res.state.R_ground_from_cam, OPK) - true_angles)))
        sig_xyz, sig_ang = res.photo_mean_errors(OPK)
        out["err_xyz"].append(err_xyz)
        out["err_ang"].append(err_ang)
        out["var_xyz"].append((sig_xyz / res.sigma0) ** 2)  # a priori: sigma0 = 1
        out["var_ang"].append((sig_ang / res.sigma0) ** 2)
        # errors in the parametrisation of the unknowns: centre, rotation vector (R_est = R_true Exp(e))
        e_rot = Rotation.from_matrix(np.swapaxes(truth.R_ground_from_cam, 1, 2) @ res.state.R_ground_from_cam).as_rotvec()
        e = np.zeros(res.n_unknowns)
        cols = res.layout.photo_cols
        assert np.all(cols >= 0)
        e[cols[:, :3]] = err_xyz
        e[cols[:, 3:]] = e_rot
        out["maha"].append(float(e @ np.linalg.solve(res.Qxx, e)))
    return {k: (np.array(v) if isinstance(v, list) else v) for k, v in out.items()}


@pytest.fixture(scope="module", params=list(CASES))
def trials(request):
    return request.param, _run(request.param)


def test_mean_sigma0_squared_is_one(trials):
    name, t = trials
    r = t["r"]
    assert r >= 15
    sd = np.sqrt(2.0 / (r * TRIALS))
    mean = t["s02"].mean()
    assert abs(mean - 1.0) < 4 * sd, f"{name}: mean sigma0^2 = {mean:.4f}, r = {r}, 4 sd = {4 * sd:.4f}"


def test_empirical_scatter_matches_mean_errors(trials):
    name, t = trials
    lo, hi = chi2.ppf(5e-5, TRIALS) / TRIALS, chi2.isf(5e-5, TRIALS) / TRIALS
    for err, var, what in ((t["err_xyz"], t["var_xyz"], "centre"), (t["err_ang"], t["var_ang"], "angle")):
        sigma2 = var.mean(axis=0)  # (n, 3); it barely changes between trials
        assert np.all(var.std(axis=0) < 0.01 * sigma2)
        ratio = (err**2).mean(axis=0) / sigma2
        message = f"{name}: {what} variance ratios {ratio} not in [{lo:.3f}, {hi:.3f}]"
        assert np.all((ratio > lo) & (ratio < hi)), message
        z = err.mean(axis=0) / np.sqrt(sigma2 / TRIALS)
        assert np.all(np.abs(z) < 4.5), f"{name}: {what} mean errors in units of sigma/sqrt(T): {z}"


def test_joint_errors_follow_Qxx(trials):
    name, t = trials
    n = 12
    mean = t["maha"].mean()
    assert abs(mean - n) < 4 * np.sqrt(2.0 * n / TRIALS), f"{name}: mean Mahalanobis distance {mean:.3f}"
