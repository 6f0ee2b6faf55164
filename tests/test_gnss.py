"""GNSS-supported triangulation (striptri.model (GnssModel)): lever arm, boresight, per-strip shift and
drift in both methods.

* the observation equations' gradients against central differences of f(x (+) dx);
* conditions == bundle with the new unknowns free (both minimise the same v^T P v: agreement to
  round-off, required to 1e-6 of a standard deviation as in test_conditions_vs_bundle);
* recovery of the simulated lever arm, shift and drift: the Mahalanobis distance of the estimate
  from the truth, ``d^2 = e^T Q^-1 e / sigma0^2`` over all k estimated GNSS unknowns, is chi^2(k)
  distributed for a correct adjustment (linear model, normal noise); we require d^2 below its
  0.999 quantile, and every element within 4 of its mean errors;
* Monte Carlo of the drift (test_drift_mean_errors_match_scatter);
* default projects unchanged: a project whose GNSS model is the default (lever arm 0 held) gives
  exactly today's result.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from striptri.adjustment import AdjustmentOptions, adjust
from striptri.model import default_gnss
from striptri.precision.gnss import gnss_precision
from striptri.equations.parameter_observations import ANGLE, CENTRE, GNSS_ELEMENT, build_parameter_observations
from striptri.equations.parameters import build_layout, initial_state, reduction_offset
from striptri.geometry.rotations import exp_so3
from striptri.simulate.design import ControlDesign, FlightDesign, SyntheticDesign
from striptri.simulate.gnss import GnssOptions
from striptri.simulate.noise import NoiseOptions
from striptri.simulate.pipeline import SimulateOptions, simulate_project

STAT = 1e-6


def gnss_block(seed: int, gnss: GnssOptions, n_strips: int = 3, n_photos: int = 6, layout: str = "perimeter"):
    """(project, truth tables) of a simulated GNSS block."""
    design = SyntheticDesign(flight=FlightDesign(n_strips=n_strips, n_photos=n_photos),
                             control=ControlDesign(layout=layout))
    options = SimulateOptions(design=design, noise=NoiseOptions(sigma_gnss=0.05), gnss=gnss)
    return simulate_project("block", options, seed)


def _truth(tables, group: str) -> np.ndarray:
    if group == "lever":
        t = tables["cameras_gnss.csv"]
        return np.column_stack([t[f"lever_{a}"] for a in "xyz"])
    t = tables["strips.csv"]
    return np.column_stack([t[f"{group}_{a}"] for a in "XYZ"])


ALL_FREE = GnssOptions(boresight=(0.05, -0.03, 0.1), sigma_imu=0.005, lever_mode="free", boresight_mode="free",
                       shift_mode="free", drift_mode="free")
ALL_OBSERVED = GnssOptions(boresight=(0.05, -0.03, 0.1), sigma_imu=0.005, lever_mode="observed",
                           boresight_mode="observed", shift_mode="observed", drift_mode="observed")


@pytest.mark.parametrize("gnss", [ALL_FREE, ALL_OBSERVED], ids=["free", "observed"])
def test_gradients_match_central_differences(gnss):
    project, _ = gnss_block(3, gnss)
    offset = reduction_offset(project)
    layout = build_layout(project)
    pobs = build_parameter_observations(project, offset)
    assert {CENTRE, ANGLE}.issubset(set(pobs.what.tolist()))
    if gnss is ALL_OBSERVED:
        assert GNSS_ELEMENT in pobs.what
    state0 = initial_state(project, offset)
    rng = np.random.default_rng(0)
    # away from the start: nonzero lever arm, boresight, shift, drift and rotated photos
    state = state0.updated(layout, rng.normal(0.0, 0.05, layout.n_unknowns))
    f, grad, cols = pobs.evaluate(state, layout, layout.rotation_maps(state))
    assert grad.shape[1] == 9
    numeric = np.zeros((len(pobs), layout.n_unknowns))
    h = 1e-6
    for k in range(layout.n_unknowns):
        dx = np.zeros(layout.n_unknowns)
        dx[k] = h
        sp, sm = state.updated(layout, dx), state.updated(layout, -dx)
        fp = pobs.evaluate(sp, layout, layout.rotation_maps(sp))[0]
        fm = pobs.evaluate(sm, layout, layout.rotation_maps(sm))[0]
        numeric[:, k] = (fp - fm) / (2 * h)
    analytic = np.zeros_like(numeric)
    rows = np.broadcast_to(np.arange(len(pobs))[:, None], cols.shape)
    valid = cols >= 0
    np.add.at(analytic, (rows[valid], cols[valid]), grad[valid])
    # central differences: error O(h^2 f''') ~ 1e-12 plus round-off eps |f| / h ~ 1e-16 * 1e3 / 1e-6
    np.testing.assert_allclose(analytic, numeric, atol=2e-6, rtol=1e-6)
    # every new group has columns and appears in some gradient
    for name in ("lever", "boresight", "shift", "drift"):
        c = layout.gnss_cols.group(name)
        assert (c >= 0).all()
        assert np.abs(analytic[:, c.ravel()]).sum(axis=0).min() > 0


def test_conditions_equal_bundle_with_gnss_unknowns():
    project, _ = gnss_block(5, ALL_FREE)
    tight = dict(tolerance=1e-10)
    a = adjust(project, AdjustmentOptions.of(method="conditions", **tight))
    b = adjust(project, AdjustmentOptions.of(method="bundle", **tight))
    assert a.layout.gnss_cols is not None and a.redundancy == b.redundancy
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-6)
    pa = gnss_precision(a, project.cameras.ids, project.gnss.strip_ids)
    pb = gnss_precision(b, project.cameras.ids, project.gnss.strip_ids)
    for group in ("lever", "boresight", "shift", "drift"):
        np.testing.assert_array_less(np.abs(pa.values[group] - pb.values[group]), STAT * pa.sigma[group])
        np.testing.assert_allclose(pa.sigma[group], pb.sigma[group], rtol=1e-6)
    np.testing.assert_allclose(pa.correlation, pb.correlation, atol=1e-6)


def _mahalanobis(result, project, tables, groups) -> tuple[float, int, np.ndarray]:
    """d^2 (module doc), k, and the errors in mean errors of the groups."""
    cols, err, z = [], [], []
    p = gnss_precision(result, project.cameras.ids, project.gnss.strip_ids)
    for group in groups:
        c = result.layout.gnss_cols.group(group)
        e = p.values[group] - _truth(tables, group)
        cols.append(c.ravel())
        err.append(e.ravel())
        z.append((e / p.sigma[group]).ravel())
    cols, err = np.concatenate(cols), np.concatenate(err)
    Q = result.covariance.entries(cols[:, None], cols[None, :]) * result.sigma0_for_precision**2
    return float(err @ np.linalg.solve(Q, err)), len(cols), np.concatenate(z)


@pytest.mark.parametrize("seed", [11, 12])
def test_recovers_lever_arm_shift_and_drift(seed):
    gnss = GnssOptions(lever_arm=(0.2, -0.4, 1.8), shift_std=0.5, drift_std=0.003)
    project, tables = gnss_block(seed, gnss)
    result = adjust(project, AdjustmentOptions.of(method="conditions"))
    assert result.converged
    d2, k, z = _mahalanobis(result, project, tables, ("lever", "shift", "drift"))
    assert k == 3 + 2 * 3 * 3
    assert d2 < stats.chi2.ppf(0.999, k), (d2, k)
    assert np.abs(z).max() < 4.0, z
    # the free lever arm started at 0: it moved to the truth
    assert np.abs(result.state.gnss.lever[0] - gnss.lever_arm).max() < 4 * np.nanmax(
        gnss_precision(result, project.cameras.ids, project.gnss.strip_ids).sigma["lever"])


@pytest.mark.parametrize("seed", [11, 12])
def test_recovers_lever_arm_and_drift_without_shift(seed):
    """Without shifts (none simulated, none estimated) the lever arm is separable from the drift
    (the drift is 0 at each strip's first exposure): recovered to a few centimetres."""
    gnss = GnssOptions(lever_arm=(0.2, -0.4, 1.8), shift_std=0.0, drift_std=0.003, shift_mode="none")
    project, tables = gnss_block(seed, gnss)
    result = adjust(project, AdjustmentOptions.of(method="bundle"))
    d2, k, z = _mahalanobis(result, project, tables, ("lever", "drift"))
    assert k == 3 + 3 * 3
    assert d2 < stats.chi2.ppf(0.999, k), (d2, k)
    assert np.abs(z).max() < 4.0, z
    sigma = gnss_precision(result, project.cameras.ids, project.gnss.strip_ids).sigma["lever"]
    assert sigma.max() < 0.1  # against ~1 m with free shifts (test_recovers_lever_arm_shift_and_drift)


def test_recovers_boresight():
    gnss = GnssOptions(boresight=(0.05, -0.03, 0.1), sigma_imu=0.003, lever_mode="observed", boresight_mode="free",
                       shift_mode="free", drift_mode="none")
    project, tables = gnss_block(21, gnss)
    result = adjust(project, AdjustmentOptions.of(method="bundle"))
    p = gnss_precision(result, project.cameras.ids, project.gnss.strip_ids)
    z = (p.values["boresight"][0] - np.radians(gnss.boresight)) / p.sigma["boresight"][0]
    assert np.abs(z).max() < 4.0, z
    assert p.sigma["boresight"].max() < np.radians(0.01)  # determined far better than its size


MC_TRIALS = 100


def test_drift_mean_errors_match_scatter():
    """Monte Carlo: the reported mean errors of the drift match the scatter of its estimates.

    In trial t the normalised error of drift component j is ``z_tj = (d^_tj - d_tj) / m_tj``, m the
    reported mean error. For a correct adjustment z_tj ~ N(0, 1) (sigma0 a posteriori instead of
    the true 1 changes this by a factor of relative spread 1/sqrt(2 r), r ~ 70: negligible beside
    the tolerance). The trials are independent (fixed, distinct seeds), so for each component
    ``S_j = sum_t z_tj^2 ~ chi^2(T)`` and the ratio of the scatter to the reported variance,
    ``S_j / T``, lies in ``[chi2.ppf(a/2, T) / T, chi2.ppf(1 - a/2, T) / T]`` with probability 1 - a.
    With T = 100 and a = 0.001 per component (6 components, Bonferroni 0.006 in all): [0.60, 1.53].
    Mean errors that were too small or too large by a factor of 1.3 (variance 1.69 or 0.59) would
    fail. The truth varies per trial (seed), so the drifts themselves are random.
    """
    gnss = GnssOptions(lever_mode="observed", sigma_lever=0.02, shift_mode="free", drift_mode="free")
    z = []
    for t in range(MC_TRIALS):
        project, tables = gnss_block(1000 + t, gnss, n_strips=2, n_photos=5)
        result = adjust(project, AdjustmentOptions.of(method="conditions"))
        p = gnss_precision(result, project.cameras.ids, project.gnss.strip_ids)
        z.append(((p.values["drift"] - _truth(tables, "drift")) / p.sigma["drift"]).ravel())
    z = np.array(z)
    ratio = np.mean(z**2, axis=0)
    a = 0.001
    lo, hi = stats.chi2.ppf(a / 2, MC_TRIALS) / MC_TRIALS, stats.chi2.ppf(1 - a / 2, MC_TRIALS) / MC_TRIALS
    assert np.all((ratio > lo) & (ratio < hi)), (ratio, lo, hi)


def test_default_gnss_model_changes_nothing():
    """A project with the default GNSS model (lever arm and boresight 0 held, no shift or drift) is
    the project without one: the same unknowns and the same numbers."""
    project, _ = gnss_block(7, GnssOptions())
    plain = replace(project, gnss=None)
    default = replace(project, gnss=replace(default_gnss(len(project.cameras), project.photos.strip_ids),
                                            time=project.gnss.time))
    a = adjust(plain, AdjustmentOptions())
    b = adjust(default, AdjustmentOptions())
    assert b.layout.gnss_cols is None and b.state.gnss is None
    assert a.vtpv == b.vtpv
    np.testing.assert_array_equal(a.state.xyz0, b.state.xyz0)


def test_lever_arm_enters_as_R_e():
    """The antenna equation's value: A = O + R e (+ shift + drift dt) at the state."""
    project, _ = gnss_block(3, ALL_FREE)
    offset = reduction_offset(project)
    layout = build_layout(project)
    pobs = build_parameter_observations(project, offset)
    state = initial_state(project, offset)
    g = state.gnss
    state = replace(state, gnss=replace(g, lever=np.array([[1.0, 2.0, 3.0]]), shift=g.shift + 0.5,
                                        drift=g.drift + 0.01, R_cam_from_imu=exp_so3(np.zeros((1, 3)))))
    f = pobs.evaluate(state, layout, layout.rotation_maps(state))[0]
    s = np.flatnonzero(pobs.what == CENTRE)
    i, a = pobs.index[s], pobs.element[s]
    expect = (state.xyz0 + state.R_ground_from_cam @ np.array([1.0, 2.0, 3.0]) + 0.5
              + 0.01 * g.dt[:, None])[i, a]
    np.testing.assert_allclose(f[s], expect, atol=1e-9)


def test_free_shift_without_control_is_a_datum_defect_of_translation():
    """A free shift per strip takes the GNSS datum (docs/decisions.md): without control the three
    translations are free, and the adjustment says so; as a free network it is adjusted."""
    from striptri.errors import NumericalFailure
    project, _ = gnss_block(3, GnssOptions(lever_mode="held"), layout="none")
    for method in ("conditions", "bundle"):
        with pytest.raises(NumericalFailure) as info:
            adjust(project, AdjustmentOptions.of(method=method))
        assert info.value.reason == "datum_defect"
        text = str(info.value)
        assert all(f"translation in {a}" in text for a in "XYZ") and "rotation" not in text
    inner = adjust(project, AdjustmentOptions.of(method="conditions", datum="inner"))
    assert inner.converged
    # with the shift held (none) the GNSS centres give the datum
    assert adjust(replace(project, gnss=replace(project.gnss, shift="none"))).converged


def test_sequential_method_refuses_the_gnss_model():
    from striptri.errors import NumericalFailure
    project, _ = gnss_block(3, GnssOptions())
    with pytest.raises(NumericalFailure, match="sequential method does not carry the GNSS model"):
        adjust(project, AdjustmentOptions.of(method="sequential"))


def test_redundancy_numbers_add_up_with_gnss_unknowns():
    """sum r_i = redundancy (trace of the projector I - A N^-1 A^T P): checks the 9-wide rows'
    Qxx terms in the residual cofactors (precision.residual_cofactors)."""
    from striptri.precision.residuals import residual_cofactors
    project, _ = gnss_block(5, ALL_OBSERVED)
    result = adjust(project, AdjustmentOptions())
    r = residual_cofactors(project, result).redundancy_numbers(project, result)
    total = r["plate"].sum() + r["control"].sum() + r["parameters"].sum()
    assert total == pytest.approx(result.redundancy, rel=1e-8)
    assert np.all((r["parameters"] > 0) & (r["parameters"] < 1))
