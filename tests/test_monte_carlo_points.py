"""Monte Carlo of the ground points (DESIGN section 6): over many noise realisations of one strip,
the errors of tie and check points scatter as points.csv's mean errors say, and sigma0 averages 1.

For each point coordinate the error e (triangulated - true) is normal with variance sigma^2 from
the reported cofactor (a-priori sigma0 = 1, the injected plate noise); T s^2 / sigma^2 ~ chi^2(T)
with s^2 the mean squared error over T trials. Bounds at a two-sided probability of 1e-4 per
coordinate (Bonferroni over the coordinates tested: under 0.5 % for the whole test).
"""

import numpy as np
import pytest
from scipy.stats import chi2

from striptri import model
from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.pipeline import triangulate_result

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("monte_carlo_points")

TRIALS = 150


@pytest.fixture(scope="module")
def trials():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=6), control=sim.ControlDesign(layout="ends", n_check=2),
                                 points=sim.PointDesign(extra_ties_per_model=2))
    truth = sim.make_truth(design, np.random.default_rng(21))
    rng = np.random.default_rng(22)
    errors, variances, s0sq, redundancy = [], [], [], None
    for _ in range(TRIALS):
        project = sim.perturb(truth, sim.NoiseOptions(approx_position_error=2.0, approx_angle_error=0.2), rng)
        r = adjust(project)
        tri = triangulate_result(project, r)
        order = [truth.point_ids.index(pid) for pid in project.points.ids]
        errors.append(tri.xyz + r.offset - truth.xyz_ground[order])
        variances.append(np.einsum("nii->ni", tri.cov_measurement + tri.cov_orientation))
        s0sq.append(r.sigma0**2)
        redundancy = r.redundancy
        kinds = project.points.kind
        rays = np.bincount(project.image_points.point_index, minlength=len(project.points))
    return np.array(errors), np.array(variances), np.array(s0sq), redundancy, kinds, rays


def test_sigma0_averages_one(trials):
    _, _, s0sq, r, _, _ = trials
    assert abs(s0sq.mean() - 1.0) < 4 * np.sqrt(2 / (r * TRIALS))


def test_point_errors_scatter_as_reported(trials):
    errors, variances, _, _, kinds, rays = trials
    tested = np.flatnonzero(np.isin(kinds, [model.TIE, model.CHECK]) & (rays >= 2))[:12]
    assert len(tested) >= 8 and {2, 3} <= set(rays[tested].tolist())
    alpha = 1e-4
    lo, hi = chi2.ppf(alpha / 2, TRIALS) / TRIALS, chi2.ppf(1 - alpha / 2, TRIALS) / TRIALS
    ratios = (errors[:, tested] ** 2).mean(axis=0) / variances[:, tested].mean(axis=0)  # (points, 3)
    assert np.all((ratios > lo) & (ratios < hi)), ratios
    # the means of the errors vanish (unbiased to first order): within 4.5 sigma / sqrt(T)
    mean = errors[:, tested].mean(axis=0)
    assert np.all(np.abs(mean) < 4.5 * np.sqrt(variances[:, tested].mean(axis=0) / TRIALS))
