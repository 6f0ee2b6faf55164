"""Monte Carlo of distances between adjusted points (issue 17): over many noise realisations of one
strip, the error of the distance between two tie points scatters as the exported covariance says
(striptri.precision.export: f^T C f with the cross-covariance of the two points), which is not what
their 3x3 blocks alone say.

T s^2 / sigma^2 ~ chi^2(T) with s^2 the mean squared error over T trials and sigma^2 from the
cofactors (a-priori sigma0 = 1, the injected plate noise); bounds at a two-sided 1e-4 per distance.
"""

import numpy as np
import pytest
from scipy.stats import chi2

from striptri.precision import export as ce
from striptri import model
from striptri import simulate as sim
from striptri.adjustment import adjust
from striptri.pipeline import triangulate_result

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("monte_carlo_distances")

TRIALS = 150


@pytest.fixture(scope="module")
def trials():
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=6), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=2))
    truth = sim.make_truth(design, np.random.default_rng(31))
    rng = np.random.default_rng(32)
    first = sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(0))
    rays = np.bincount(first.image_points.point_index, minlength=len(first.points))
    ties = [first.points.ids[k] for k in np.flatnonzero((first.points.kind == model.TIE) & (rays >= 2))]
    pairs = [(ties[0], ties[-1]), (ties[1], ties[len(ties) // 2]), (ties[2], ties[3])]
    true_xyz = {pid: truth.xyz_ground[truth.point_ids.index(pid)] for pid in ties}
    errors, full, blocks = [], [], []
    for _ in range(TRIALS):
        project = sim.perturb(truth, sim.NoiseOptions(approx_position_error=2.0, approx_angle_error=0.2), rng)
        r = adjust(project)
        e = ce.joint_covariance(project, r, triangulate_result(project, r), ("points",))
        Q = e.cov / e.sigma0**2  # cofactors: a-priori sigma0 = 1
        row_e, row_f, row_b = [], [], []
        for a, b in pairs:
            length, f = e.distance(a, b)
            i, j = e.point_rows(a), e.point_rows(b)
            row_e.append(length - np.linalg.norm(true_xyz[a] - true_xyz[b]))
            row_f.append(f @ Q @ f)
            no_cross = Q.copy()
            no_cross[np.ix_(i, j)] = 0.0
            no_cross[np.ix_(j, i)] = 0.0
            row_b.append(f @ no_cross @ f)
        errors.append(row_e)
        full.append(row_f)
        blocks.append(row_b)
    return np.array(errors), np.array(full), np.array(blocks)


def test_distance_errors_scatter_as_the_exported_covariance_says(trials):
    errors, full, blocks = trials
    alpha = 1e-4
    lo, hi = chi2.ppf(alpha / 2, TRIALS) / TRIALS, chi2.ppf(1 - alpha / 2, TRIALS) / TRIALS
    ratios = (errors**2).mean(axis=0) / full.mean(axis=0)
    assert np.all((ratios > lo) & (ratios < hi)), ratios
    # the cross-covariance of the two points matters: without it the variance is off by more than
    # the Monte Carlo's own uncertainty for at least one pair
    wrong = (errors**2).mean(axis=0) / blocks.mean(axis=0)
    assert np.any((wrong < lo) | (wrong > hi)), wrong
