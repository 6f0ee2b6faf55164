"""Reliability and blunder detection (striptri.reliability; DESIGN section 6).

* delta0 and the critical value from scipy.stats equal Baarda's tabulated 4.13 and 3.29;
* on noise-free data a bias of exactly MDB_i on coordinate i moves w_i to -delta0 (what the MDB
  means), and moves the orientation by no more than the bias-to-noise ratio; both methods;
* on clean data w is standard normal: over many noise realisations (fixed seeds) the mean of w^2
  is 1 and each coordinate's mean w^2 is chi^2(T)/T;
* the issue's target: 2 % of the rows of a block given gross errors of 10-30 sigma (random sign,
  in x, y or both; any row but the check points', which are the reference) are found by data
  snooping (>= 95 %, <= 1 % false alarms, check-point RMS
  within 10 % of the blunder-free adjustment); the robust method likewise;
* what cannot be found is reported so (w nan / MDB inf, or a large MDB), not crashed on.

The block: 3 strips x 6 photos, 2/3 forward overlap and 60 % sidelap (most points in 4 to 9
photos), perimeter control, 3 extra tie points per model, 6 check points; 451 rows, of which
9 get gross errors per seed. Five seeds give 43 gross errors and 30 check points.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm

from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.model import CHECK, HEIGHT, TIE
from striptri.precision.residuals import W_CRITICAL, residual_cofactors
from striptri.reliability import (
    FLAG_DROPPED,
    FLAG_INSEPARABLE,
    FLAG_OK,
    FLAG_REJECTED,
    FLAG_SUSPECT,
    BlunderOptions,
    critical_value,
    detect_blunders,
    noncentrality,
    plate_reliability,
    robust_weight,
    row_statistic,
    select_rejections,
    studentised_gross_errors,
    triangulate_adjusted,
)
from striptri.simulate.truth import make_truth

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("reliability")

SIGMA = 0.005  # plate noise and stated sigma (mm)
BLOCK = sim.SyntheticDesign(
    flight=sim.FlightDesign(n_photos=6, n_strips=3, overlap=2 / 3, sidelap=0.6),
    points=sim.PointDesign(extra_ties_per_model=3),
    control=sim.ControlDesign(layout="perimeter", every_k=2, n_check=6),
)
STRIP = sim.SyntheticDesign(
    flight=sim.FlightDesign(n_photos=6, overlap=0.6),
    points=sim.PointDesign(extra_ties_per_model=2),
    control=sim.ControlDesign(layout="every-k", every_k=2, n_check=2, n_single_photo=2),
)
SEEDS = (1, 2, 3, 4, 5)
BLUNDER_FRACTION = 0.02
METHODS = ("conditions", "bundle")


def simulated(kind, design, seed, sigma_image=SIGMA):
    noise = sim.NoiseOptions(sigma_image=sigma_image, stated_sigma_image=SIGMA)
    return sim.simulate_project(kind, sim.SimulateOptions(design, noise), seed)


def with_blunders(project, rows, dxy):
    """The project with dxy (len(rows), 2) added to the plate coordinates of rows."""
    ip = project.image_points
    xy = ip.xy.copy()
    xy[rows] += dxy
    return replace(project, image_points=replace(ip, xy=xy))


def random_blunders(project, rng):
    """2 % of the rows, 10-30 sigma, random sign, in x, y or both (one third each). Not on the rows
    of check points: they are the independent reference of the RMS, and a gross error in their own
    rays (or the loss of a ray to its rejection) would measure the check point, not the
    adjustment (docs/reliability.md shows the figures with them)."""
    ip = project.image_points
    eligible = np.flatnonzero(project.points.kind[ip.point_index] != CHECK)
    rows = rng.choice(eligible, int(round(BLUNDER_FRACTION * len(ip))), replace=False)
    which = rng.integers(0, 3, len(rows))  # 0: x, 1: y, 2: both
    mask = np.stack([which != 1, which != 0], axis=1)
    size = rng.uniform(10.0, 30.0, (len(rows), 2)) * rng.choice([-1.0, 1.0], (len(rows), 2)) * ip.sigma_xy[rows]
    return with_blunders(project, rows, np.where(mask, size, 0.0)), rows


def drop_rows(project, rows):
    ip = project.image_points
    keep = np.ones(len(ip), dtype=bool)
    keep[rows] = False
    return replace(project, image_points=replace(ip, photo_index=ip.photo_index[keep], point_index=ip.point_index[keep],
                                                 xy=ip.xy[keep], sigma_xy=ip.sigma_xy[keep]))


def check_point_errors(project, result):
    """(n_points, 3) adjusted - given at the check points that are determined, nan elsewhere."""
    tri = triangulate_adjusted(project, result)
    ok = (project.points.kind == CHECK) & tri.determined
    return np.where(ok[:, None], tri.xyz + result.offset - project.points.xyz_given, np.nan)


def row_of(project, truth, point_id, photo=None):
    pid = truth["points.csv"]["point_id"]
    rows = np.flatnonzero(project.image_points.point_index == pid.index(point_id))
    return rows if photo is None else rows[project.image_points.photo_index[rows] == photo][0]


# ------------------------------------------------------------------ delta0, MDB, external reliability


def test_delta0_and_critical_value_match_baardas_tables():
    """Baarda (1968): alpha0 = 0.001 two-sided and beta0 = 0.80 give the critical value 3.29 and
    the non-centrality delta0 = 4.13 (both tabulated to two decimals)."""
    assert critical_value(0.001) == pytest.approx(3.29, abs=0.005)
    assert critical_value(0.001) == pytest.approx(W_CRITICAL, abs=0.005)
    assert noncentrality(0.001, 0.80) == pytest.approx(4.13, abs=0.005)
    # the definition: the two-sided test of size alpha0 rejects N(delta0, 1) with probability beta0
    d, k = noncentrality(0.001, 0.80), critical_value(0.001)
    assert norm.sf(k - d) + norm.cdf(-k - d) == pytest.approx(0.80, abs=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_a_bias_of_one_mdb_moves_w_to_delta0(method):
    """Noise-free plates: w = 0 everywhere. Adding MDB_i to coordinate i makes v_i = -r_i MDB_i, so
    w_i = -MDB_i sqrt(r_i) / sigma_i = -delta0 exactly, up to the nonlinearity of the model
    (the bias is 0.03 mm on 100 mm: relative 1e-4, tolerance 1e-3). Its effect on the
    orientation, dx^T Qxx^-1 dx, is at most the bias-to-noise ratio squared (all estimated
    quantities together reach it; the orientations are a part)."""
    project, _ = simulated("strip", STRIP, 7, sigma_image=0.0)
    options = AdjustmentOptions(method=method)
    clean = adjust(project, options)
    rel = plate_reliability(project, clean, options)
    assert np.nanmax(np.abs(rel.w)) < 1e-4
    sigma = project.image_points.sigma_xy
    checked = rel.redundancy > 0
    # Baarda's tabulated delta0 = 4.13 (two decimals: relative 1.2e-3)
    np.testing.assert_allclose(rel.mdb[checked], (sigma * 4.13 / np.sqrt(rel.redundancy))[checked], rtol=1.5e-3)
    rng = np.random.default_rng(11)
    testable = np.argwhere(rel.redundancy > 0.05)
    for row, axis in testable[rng.choice(len(testable), 3, replace=False)]:
        dxy = np.zeros((1, 2))
        dxy[0, axis] = rel.mdb[row, axis]
        biased = with_blunders(project, [row], dxy)
        res = adjust(biased, options)
        w = plate_reliability(biased, res, options).w
        assert w[row, axis] == pytest.approx(-rel.delta0, rel=1e-3)
        # the orientation's shift in the parametrisation of the unknowns
        e = np.zeros(res.n_unknowns)
        cols = res.layout.photo_cols
        e[cols[:, :3]] = res.state.xyz0 + res.offset - (clean.state.xyz0 + clean.offset)
        e[cols[:, 3:]] = Rotation.from_matrix(np.swapaxes(clean.state.R_ground_from_cam, 1, 2) @ res.state.R_ground_from_cam).as_rotvec()
        assert float(e @ clean.N @ e) <= rel.bnr[row, axis] ** 2 * (1 + 1e-3)


def test_clean_normalised_residuals_are_standard_normal():
    """One true strip, T noise realisations (fixed seeds), plate sigma stated = injected. Each w_i
    is N(0, 1) (to first order): the mean of w^2 over all coordinates and trials is 1 within 4 of
    its standard errors (estimated from the per-trial means, which carries the correlation of
    the w within a trial); for every coordinate T mean(w_i^2) ~ chi^2(T), all within the two-sided
    bounds at probability 1e-3 / n (Bonferroni: under 0.1 % for the whole test); and |w| > 1.96
    occurs in 5 % of the cases (within 20 %: some 360 exceedances, Poisson sd 5 %)."""
    trials = 50
    seeds = np.random.SeedSequence(2025).spawn(trials + 1)
    truth = make_truth(STRIP, np.random.default_rng(seeds[0]))
    noise = sim.NoiseOptions(sigma_image=SIGMA, approx_position_error=0.5, approx_angle_error=0.05)
    w2 = []
    for s in seeds[1:]:
        project = sim.perturb(truth, noise, np.random.default_rng(s))
        result = adjust(project)
        w2.append(plate_reliability(project, result).w ** 2)
    w2 = np.array(w2)  # (T, m, 2)
    testable = np.isfinite(w2).all(axis=0)
    assert testable.sum() > 120
    per_trial = np.array([t[testable].mean() for t in w2])
    assert abs(per_trial.mean() - 1.0) < 4 * per_trial.std(ddof=1) / np.sqrt(trials)
    n = int(testable.sum())
    lo, hi = chi2.ppf(5e-4 / n, trials) / trials, chi2.isf(5e-4 / n, trials) / trials
    per_coordinate = w2.mean(axis=0)[testable]
    assert np.all((per_coordinate > lo) & (per_coordinate < hi)), (per_coordinate.min(), per_coordinate.max())
    rate = float(np.mean(w2[:, testable] > 1.96**2))
    assert rate == pytest.approx(0.05, rel=0.20)


# ------------------------------------------------------------------ the target


def _run_block(method, blunder_method, seeds=SEEDS, **blunder_options):
    found = n_blunders = false_alarms = n_clean = 0
    se_clean = se_after = 0.0
    rounds = []
    for seed in seeds:
        project, _ = simulated("block", BLOCK, seed)
        options = AdjustmentOptions(method=method)
        e_clean = check_point_errors(project, adjust(project, options))
        spoiled, rows = random_blunders(project, np.random.default_rng(1000 + seed))
        out = detect_blunders(spoiled, options, BlunderOptions(method=blunder_method, **blunder_options))
        is_blunder = np.zeros(len(project.image_points), dtype=bool)
        is_blunder[rows] = True
        rejected = (out.flag == FLAG_REJECTED) | (out.flag == FLAG_INSEPARABLE)  # alone or in its group
        found += int(np.sum(rejected & is_blunder))
        n_blunders += len(rows)
        false_alarms += int(np.sum(rejected & ~is_blunder))
        n_clean += int(np.sum(~is_blunder))
        e_after = check_point_errors(out.project, out.result)
        both = np.isfinite(e_clean).all(axis=1) & np.isfinite(e_after).all(axis=1)
        se_clean += float(np.sum(e_clean[both] ** 2))
        se_after += float(np.sum(e_after[both] ** 2))
        rounds.append(len(out.rounds))
    return {"detected": found / n_blunders, "false_alarms": false_alarms / n_clean, "n_blunders": n_blunders,
            "rms_ratio": np.sqrt(se_after / se_clean), "rounds": rounds}


@pytest.fixture(scope="module")
def snooped():
    return _run_block("conditions", "snoop")


def test_data_snooping_finds_the_gross_errors(snooped):
    """Issue target: >= 95 % found, <= 1 % false alarms. Measured: 42 of 43 (the one missed lies in
    the x coordinate of a tie point in two photos, r_x ~ 0: undetectable, see below) and 2 false
    alarms in 2138 clean rows (0.09 %; the test's own type I errors are 0.2 % per row). Over 40
    seeds (docs/reliability.md): 96.0 % found, 0.34 % false alarms."""
    assert snooped["n_blunders"] == 43
    assert snooped["detected"] >= 0.95
    assert snooped["false_alarms"] <= 0.01


def test_data_snooping_restores_the_check_point_accuracy(snooped):
    """Check-point RMS (3D, 30 check points over the five seeds) within 10 % of the adjustment of
    the same measurements without gross errors (measured: +4 %; over 40 seeds +2 %)."""
    assert abs(snooped["rms_ratio"] - 1.0) <= 0.10


def test_several_rejections_per_round_need_fewer_rounds():
    """Measured 3-5 adjustments per seed ("separated") against 9-11 (one row per round); the
    classic procedure, whose rounds are only testing rounds (the separable one adds the rounds after
    a re-admission)."""
    assert max(_run_block("conditions", "snoop", procedure="classic")["rounds"]) <= 6


def test_separated_rounds_reject_what_single_rounds_reject():
    """Data snooping is one-at-a-time in theory; the multi-rejection rounds reject the same rows
    here (bundle method, seed 1; over 20 seeds see docs/reliability.md)."""
    project, _ = simulated("block", BLOCK, 1)
    spoiled, _ = random_blunders(project, np.random.default_rng(1001))
    options = AdjustmentOptions(method="bundle")
    # the classic procedure: the separable one rejects inseparable groups (several rows) per round
    many = detect_blunders(spoiled, options, BlunderOptions(per_round="separated", procedure="classic"))
    one = detect_blunders(spoiled, options, BlunderOptions(per_round="single", procedure="classic"))
    assert set(many.rejected_rows) == set(one.rejected_rows)
    assert len(many.rounds) < len(one.rounds)
    assert all(r.rejected <= 1 for r in one.rounds)


def test_both_methods_reject_the_same_rows():
    """At convergence the bundle and the conditions method have the same residuals and cofactors,
    so the same w and the same decisions."""
    project, _ = simulated("block", BLOCK, 2)
    spoiled, _ = random_blunders(project, np.random.default_rng(1002))
    out = {m: detect_blunders(spoiled, AdjustmentOptions(method=m)) for m in METHODS}
    assert list(out["conditions"].rejected_rows) == list(out["bundle"].rejected_rows)
    a, b = out["conditions"].w, out["bundle"].w
    assert np.array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], atol=1e-5)


def test_robust_reweighting_finds_the_gross_errors():
    """The Danish-type re-weighting (bundle method, same five seeds): measured 41 of 43 found, 3
    false alarms in 2138 (0.14 %), check-point RMS +4 %, 6-7 adjustments per seed; over 40 seeds
    96.9 % found, 0.26 % false alarms. Asserted: >= 90 % found, <= 1 % false alarms, RMS within
    10 %."""
    figures = _run_block("bundle", "robust")
    assert figures["detected"] >= 0.90
    assert figures["false_alarms"] <= 0.01
    assert abs(figures["rms_ratio"] - 1.0) <= 0.10


def test_the_warm_start_changes_only_where_the_adjustment_starts():
    """Each re-adjustment starts from the previous orientations, but observed elements (here GNSS
    centres, sigma 0.2 m) must keep their observed values: the final result equals the adjustment
    of the surviving rows from the original approximations. Rejected rows kept for their other
    coordinate (snooping.readmit_coordinates) keep the rejected one at out.weights (1e-6), which
    the result's v^T P v leaves out."""
    design = replace(STRIP, control=sim.ControlDesign(layout="every-k", every_k=2))
    project, _ = sim.simulate_project("strip", sim.SimulateOptions(design, sim.NoiseOptions(
        sigma_image=SIGMA, sigma_gnss=0.2)), 5)
    spoiled, rows = random_blunders(project, np.random.default_rng(1005))
    spoiled = with_blunders(spoiled, rows[:1], np.array([[0.0, 30.0 * SIGMA]]))  # at least one 2-D error
    out = detect_blunders(spoiled)
    assert len(out.rejected) >= 1
    keep = np.zeros(len(spoiled.image_points), dtype=bool)
    keep[out.rows] = True
    weights = np.ones((len(keep), 2)) if out.weights is None else out.weights
    ip = spoiled.image_points
    scaled = replace(spoiled, image_points=replace(ip, sigma_xy=ip.sigma_xy / np.sqrt(weights)))
    scratch = adjust(drop_rows(scaled, np.flatnonzero(~keep)))
    partial = weights[keep] < 1.0
    vtpv_partial = np.sum((scratch.plate_residuals / scaled.image_points.sigma_xy[keep])[partial] ** 2)
    assert out.result.vtpv == pytest.approx(scratch.vtpv - vtpv_partial, rel=1e-8)
    assert out.result.redundancy == scratch.redundancy - np.count_nonzero(partial)
    np.testing.assert_allclose(out.result.state.xyz0 + out.result.offset, scratch.state.xyz0 + scratch.offset,
                               atol=1e-6)
    np.testing.assert_allclose(out.result.parameter_residuals, scratch.parameter_residuals, atol=1e-6)


# ------------------------------------------------------------------ the weight function and u


def test_robust_weight_function():
    c = 3.0
    u = np.array([0.0, c, c * (1 + 1e-9), 2 * c, 3 * c, np.nan])
    p = robust_weight(u, c)
    np.testing.assert_allclose(p, [1.0, 1.0, 1.0, np.exp(-3.0), np.exp(-8.0), 1.0], rtol=1e-6)


def test_studentised_gross_error_does_not_depend_on_its_own_weight():
    """u_i = |v_i / r'_i| / sqrt(q_i + q'_i (1 - r'_i) / r'_i) is the estimated gross error of
    coordinate i (minus its leave-one-out residual) over its a-priori standard deviation: it does
    not depend on the weight of coordinate i itself (the other coordinates, its partner of the same
    row included, keep theirs). At full weight it is |w_i|; at weight 1e-4 the same, up to the
    nonlinearity of the model (the adjusted point moves by the gross error's share: 1e-4)."""
    project, _ = simulated("block", BLOCK, 3)
    spoiled, rows = random_blunders(project, np.random.default_rng(1003))
    ip = spoiled.image_points
    options = AdjustmentOptions(method="bundle")
    full = adjust(spoiled, options)
    w = plate_reliability(spoiled, full, options).w
    row = rows[0]
    axis = int(np.nanargmax(np.abs(w[row])))
    u = []
    for weight in (1.0, 1e-4):
        sigma = ip.sigma_xy.copy()
        sigma[row, axis] /= np.sqrt(weight)
        weighted = replace(spoiled, image_points=replace(ip, sigma_xy=sigma))
        result = adjust(weighted, options)
        cof = residual_cofactors(weighted, result, options)
        u.append(float(studentised_gross_errors(result.plate_residuals[row, axis], cof.plate[row, axis],
                                                sigma[row, axis] ** 2, ip.sigma_xy[row, axis] ** 2)))
    assert abs(w[row, axis]) > 5
    assert u[0] == pytest.approx(abs(w[row, axis]), rel=1e-9)
    assert u[1] == pytest.approx(u[0], rel=1e-3)


# ------------------------------------------------------------------ what cannot be found, and the flags


def test_undetectable_gross_errors_are_reported_not_crashed_on():
    """A strip (60 % overlap) with coordinates that no condition checks, or hardly:

    * tie point 1001C left in one photo (its other ray removed): no condition, r = 0: w nan,
      MDB inf; a 50 sigma error there changes nothing and is not flagged;
    * the x coordinate of tie point T1003_01 in two photos (base along x: only the y-parallax is
      checked): r ~ 1e-4, MDB of hundreds of sigma; a 20 sigma error in x is not found.

    By contrast a full control point seen by one photo only (1001S) *is* checked, by collinearity
    against that photo's orientation, which the other points determine: r ~ 0.45, MDB ~ 6 sigma.
    """
    project, truth = simulated("strip", STRIP, 3)
    project = drop_rows(project, [row_of(project, truth, "1001C", photo=1)])
    lone = row_of(project, truth, "1001C")[0]
    pair_x = row_of(project, truth, "T1003_01")[0]
    single = row_of(project, truth, "1001S")[0]
    clean = detect_blunders(project)
    spoiled = with_blunders(project, [lone, pair_x], np.array([[50.0, -50.0], [20.0, 0.0]]) * SIGMA)
    out = detect_blunders(spoiled)
    assert np.all(np.isnan(out.w[lone])) and np.all(np.isinf(out.mdb[lone])) and np.isnan(out.row_w[lone])
    assert out.flag[lone] == FLAG_OK and out.redundancy[lone].max() == 0.0
    assert out.mdb[pair_x, 0] > 100 * SIGMA and abs(out.w[pair_x, 0]) < out.critical
    assert out.flag[pair_x] == FLAG_OK
    assert not out.rejected and not clean.rejected
    # the gross error on the lone ray does not reach the adjustment; the other moves it a little
    assert out.result.vtpv == pytest.approx(clean.result.vtpv, rel=0.05)
    assert np.all(out.redundancy[single] > 0.3) and np.all(out.mdb[single] < 8 * SIGMA)


def test_a_point_left_without_conditions_drops_out():
    """Height point 1003L is in three photos; with one ray removed beforehand it has two rays and
    two conditions (coplanarity, height). A gross error of 25 sigma in y of one ray is found; the
    two rays' w differ only slightly (each condition involves both rays alike), so which row goes
    is not asserted by the classic procedure. The point keeps one ray and no condition: the other row
    is flagged "dropped", with w nan and MDB inf. The separable procedure (the default) finds the two
    rays' w-tests correlated beyond separability and rejects both as one group, "inseparable"."""
    project, truth = simulated("strip", STRIP, 3)
    rows = row_of(project, truth, "1003L")
    assert project.points.kind[project.image_points.point_index[rows[0]]] == HEIGHT and len(rows) == 3
    project = drop_rows(project, [rows[2]])
    rows = row_of(project, truth, "1003L")
    spoiled = with_blunders(project, [rows[0]], np.array([[0.0, 25.0 * SIGMA]]))
    grouped = detect_blunders(spoiled)
    assert list(grouped.flag[rows]) == [FLAG_INSEPARABLE] * 2
    assert len(grouped.groups) == 1 and sorted(grouped.groups[0]) == sorted(rows)
    out = detect_blunders(spoiled, blunders=BlunderOptions(procedure="classic"))
    assert sorted(out.flag[rows]) == sorted([FLAG_REJECTED, FLAG_DROPPED])
    gone = rows[out.flag[rows] == FLAG_DROPPED][0]
    assert np.all(np.isnan(out.w[gone])) and np.all(np.isinf(out.mdb[gone]))
    assert len(out.rejected) == 1


def test_two_rays_of_one_condition_are_rejected_together():
    """A tie point in two photos has one condition: the w of its four coordinates are equal in
    magnitude, so a gross error is detected but not located; both rows are rejected."""
    project, truth = simulated("strip", STRIP, 3)
    rows = row_of(project, truth, "T1003_01")
    assert project.points.kind[project.image_points.point_index[rows[0]]] == TIE and len(rows) == 2
    out = detect_blunders(with_blunders(project, [rows[0]], np.array([[0.0, 25.0 * SIGMA]])))
    assert set(out.rejected_rows) == set(rows)
    w = [r.w for r in out.rejected]
    np.testing.assert_allclose(np.abs(w[0]), np.abs(w[1]), rtol=1e-6)


def test_rejection_limit_leaves_suspects():
    project, _ = simulated("block", BLOCK, 1)
    spoiled, rows = random_blunders(project, np.random.default_rng(1001))
    out = detect_blunders(spoiled, AdjustmentOptions(method="bundle"), BlunderOptions(max_rejections=2))
    assert out.stopped == "limit" and len(out.rejected) == 2
    assert set(out.rejected_rows) <= set(rows)
    assert np.count_nonzero(out.flag == FLAG_SUSPECT) >= 1


def test_a_failed_re_adjustment_takes_the_round_back(monkeypatch):
    """If the adjustment after a round of rejections fails (a photo or the datum lost too much),
    the rows of that round are taken back as "suspect" and the previous adjustment is the result."""
    import striptri.reliability.snooping as snooping
    from striptri.errors import NumericalFailure

    project, _ = simulated("block", BLOCK, 1)
    spoiled, rows = random_blunders(project, np.random.default_rng(1001))
    calls = []

    def failing_second(p, options):
        calls.append(len(p.image_points))
        if len(calls) == 2:
            raise NumericalFailure("photo 1003 has too few points")
        return adjust(p, options)

    monkeypatch.setattr(snooping, "adjust", failing_second)
    out = detect_blunders(spoiled, AdjustmentOptions(method="bundle"))
    assert out.stopped == "failure: photo 1003 has too few points"
    assert not out.rejected and len(out.rounds) == 1 and out.rounds[0].rejected == 0
    assert len(out.project.image_points) == len(spoiled.image_points)
    assert calls[1] < calls[0]
    assert np.count_nonzero(out.flag == FLAG_SUSPECT) >= calls[0] - calls[1]


def test_off_only_flags():
    project, _ = simulated("block", BLOCK, 1)
    spoiled, rows = random_blunders(project, np.random.default_rng(1001))
    out = detect_blunders(spoiled, AdjustmentOptions(method="bundle"), BlunderOptions(method="off"))
    assert out.stopped == "off" and not out.rejected and len(out.rounds) == 1
    assert len(out.project.image_points) == len(spoiled.image_points)
    suspect = out.flag == FLAG_SUSPECT
    np.testing.assert_array_equal(suspect, np.abs(np.nan_to_num(out.row_w)) > out.critical)
    assert suspect.sum() >= len(rows) // 2


def test_the_tests_of_every_row_take_the_project_itself(monkeypatch):
    """The first round of the tests (every row kept) adjusts and tests the project object itself,
    not a copy of it: what is kept for that object (its condition groups, groups.build_batches) serves
    the tests. A subset with rows left out is a new project with those rows only."""
    from striptri.equations import groups
    from striptri.reliability.outcome import subset

    project, _ = simulated("block", BLOCK, 1)
    keep = np.ones(len(project.image_points), dtype=bool)
    assert subset(project, keep) is project
    keep[3] = False
    fewer = subset(project, keep)
    assert fewer is not project and len(fewer.image_points) == len(project.image_points) - 1
    np.testing.assert_array_equal(fewer.image_points.xy, project.image_points.xy[keep])
    built = []
    build = groups._build_batches
    monkeypatch.setattr(groups, "_build_batches", lambda p, chains=True: built.append(p) or build(p, chains))
    first = adjust(project, AdjustmentOptions())
    out = detect_blunders(project, AdjustmentOptions(), BlunderOptions(method="off"), first)
    assert out.project is project
    assert sum(p is project for p in built) == 1  # its groups made once, for the adjustment


def test_select_rejections_keeps_groups_and_photos_apart():
    point = np.array([0, 0, 0, 1, 1, 2, 2, 3])
    photo = np.array([0, 1, 2, 1, 2, 3, 4, 0])
    w = np.array([9.0, 5.0, 4.0, 8.0, 3.0, 6.0, 6.0, 4.5])
    # row 0 (largest); row 3 (point 1, photo 1, largest of its point); rows 5 and 6 are twins of
    # point 2; row 7 shares photo 0 with row 0; row 1 is not the largest of point 0
    assert list(select_rejections(point, photo, w, 3.29)) == [0, 3, 5, 6]
    assert list(select_rejections(point, photo, w, 3.29, "single")) == [0]
    # only rows with |w| at least half the largest: 20 -> 10 and above
    w2 = np.where(np.arange(8) == 0, 20.0, w)
    assert list(select_rejections(point, photo, w2, 3.29)) == [0]
    assert len(select_rejections(point, photo, np.full(8, 1.0), 3.29)) == 0


def test_row_statistic_takes_the_larger_magnitude():
    w = np.array([[1.0, -2.0], [np.nan, 0.5], [np.nan, np.nan], [-3.0, 2.0]])
    r = row_statistic(w)
    np.testing.assert_array_equal(r[[0, 1, 3]], [-2.0, 0.5, -3.0])
    assert np.isnan(r[2])
    # a two-ray point's x and y: one statistic; x's sign whichever is larger in the last bits
    tie = np.array([[0.39018144518173, -0.39018144518169], [-0.39018144518169, 0.39018144518173],
                    [0.5, np.nan], [np.nan, -0.5], [1.0, -1.0 - 1e-6]])
    np.testing.assert_array_equal(row_statistic(tie), [0.39018144518173, -0.39018144518169, 0.5, -0.5, -1.0 - 1e-6])
    assert row_statistic(np.zeros((0, 2))).shape == (0,)


@pytest.mark.parametrize("blunder_method", ["off", "snoop", "robust"])
def test_the_procedure_takes_the_callers_first_adjustment(monkeypatch, blunder_method):
    """The pipeline adjusts first and then runs the blunder procedure on that adjustment (two
    visible steps): given the adjustment of all rows, each procedure reaches the outcome it reaches
    alone, with one adjustment fewer of its own."""
    import importlib

    robust_module = importlib.import_module("striptri.reliability.robust")  # the package's robust is the function
    snooping_module = importlib.import_module("striptri.reliability.snooping")

    project, _ = simulated("strip", STRIP, 2)
    spoiled, _ = random_blunders(project, np.random.default_rng(1002))
    options, blunders = AdjustmentOptions(method="conditions"), BlunderOptions(method=blunder_method)
    calls = []

    def counted(p, o):
        calls.append(1)
        return adjust(p, o)

    for module in (robust_module, snooping_module):
        monkeypatch.setattr(module, "adjust", counted)
    alone = detect_blunders(spoiled, options, blunders)
    n_alone = len(calls)
    given = detect_blunders(spoiled, options, blunders, first=adjust(spoiled, options))
    assert len(calls) - n_alone == n_alone - 1
    assert [r.row for r in given.rejected] == [r.row for r in alone.rejected]
    np.testing.assert_array_equal(given.flag, alone.flag)
    assert given.result.vtpv == alone.result.vtpv
    np.testing.assert_array_equal(given.w, alone.w)
