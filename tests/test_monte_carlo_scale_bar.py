"""Monte Carlo with a scale bar in the method of conditions (issue 17): over many noise realisations
of a strip whose scale comes from one observed distance alone, the errors of the adjusted distances
scatter as their mean errors say: the distance between two other adjusted points (mean error from
the exported covariance, striptri.precision.export: f^T C f with the two points' cross-covariance,
the scale bar's information coming in through Qxx) and the scale bar's own adjusted distance (mean
error sqrt(sigma^2 - qvv) of distances.csv's sigma_adjusted, joint_groups).

T s^2 / sigma^2 ~ chi^2(T) with s^2 the mean squared error over T trials and sigma^2 from the
cofactors (a-priori sigma0 = 1: the injected plate and bar noise); bounds at a two-sided 1e-4 per
quantity, as tests/test_monte_carlo_distances.py.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from striptri.precision import export as ce
from striptri import model
from striptri import simulate as sim
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.adjustment import adjust
from striptri.bundle.distances import Distances
from striptri.core.options import AdjustmentOptions
from striptri.reliability.distances import distance_table

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("monte_carlo_scale_bar")

TRIALS = 120
SIGMA_BAR = 0.01  # m


@pytest.fixture(scope="module", params=["scale from the bar", "checked bar"])
def trials(request):
    """Scale from the bar: one point and photo 0's angles held, the bar the only scale (its own
    redundancy number is 0); checked bar: the strip's own control and a bar of sigma 0.05 m (its
    redundancy number about 0.3)."""
    checked = request.param == "checked bar"
    sigma_bar = 0.05 if checked else SIGMA_BAR
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=6), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=2))
    truth = sim.make_truth(design, np.random.default_rng(41))
    rng = np.random.default_rng(42)
    first = sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(0))
    rays = np.bincount(first.image_points.point_index, minlength=len(first.points))
    usable = np.flatnonzero(rays >= 2)
    true_xyz = np.array([truth.xyz_ground[truth.point_ids.index(pid)] for pid in first.points.ids])
    ties = usable[first.points.kind[usable] == model.TIE]
    held, bar = ties[0], (ties[1], ties[-1])
    others = [(ties[2], ties[-2]), (ties[3], ties[len(ties) // 2])]
    n = len(first.points)
    kind = np.full(n, model.TIE)
    kind[held] = model.FULL
    xyz_given = np.full((n, 3), np.nan)
    xyz_given[held] = true_xyz[held]
    d_bar = np.linalg.norm(true_xyz[bar[0]] - true_xyz[bar[1]])
    options = AdjustmentOptions(method="conditions")
    errors, variances = [], []
    for _ in range(TRIALS):
        project = sim.perturb(truth, sim.NoiseOptions(approx_position_error=2.0, approx_angle_error=0.2), rng)
        if not checked:
            sa = project.photos.sigma_angles.copy()
            sa[0] = 0.0  # P held and photo 0's angles held: the scale from the bar alone
            project = replace(project, points=replace(project.points, kind=kind, xyz_given=xyz_given,
                                                      sigma_given=np.full((n, 3), np.nan)),
                              photos=replace(project.photos, sigma_angles=sa))
        project = replace(project, distances=Distances(np.array([bar[0]]), np.array([bar[1]]),
                                                       np.array([d_bar + rng.normal(0.0, sigma_bar)]),
                                                       np.array([sigma_bar])))
        r = adjust(project, options)
        tri = triangulate_adjusted(project, r, orientation_part=True)
        e = ce.joint_covariance(project, r, tri, ("points",))
        Q = e.cov / e.sigma0**2  # cofactors
        row_e, row_v = [], []
        for a, b in others:
            length, f = e.distance(project.points.ids[a], project.points.ids[b])
            row_e.append(length - np.linalg.norm(true_xyz[a] - true_xyz[b]))
            row_v.append(f @ Q @ f)
        cols = distance_table(project, r, tri.xyz, options)
        row_e.append(cols["adjusted"][0] - d_bar)
        row_v.append((cols["sigma_adjusted"][0] / r.sigma0_for_precision) ** 2)
        errors.append(row_e)
        variances.append(row_v)
    return np.array(errors), np.array(variances), sigma_bar, checked


def test_adjusted_distances_scatter_as_their_mean_errors_say(trials):
    errors, variances, sigma_bar, checked = trials
    alpha = 1e-4
    lo, hi = chi2.ppf(alpha / 2, TRIALS) / TRIALS, chi2.ppf(1 - alpha / 2, TRIALS) / TRIALS
    ratios = (errors**2).mean(axis=0) / variances.mean(axis=0)
    assert np.all((ratios > lo) & (ratios < hi)), ratios
    if checked:  # the bar's adjusted distance is better than the bar alone: the photogrammetry checks it
        assert np.all(variances[:, -1] < 0.9 * sigma_bar**2)
    else:  # the bar alone gives the scale: its adjusted distance is the observation
        assert np.allclose(variances[:, -1], sigma_bar**2, rtol=1e-6)
