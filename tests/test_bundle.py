"""The collinearity bundle adjustment (method "bundle", object points eliminated per point) equals
Schmid's method of conditions (DESIGN section 4).

Both minimise the same v^T P v over the same observations with the same orientation unknowns,
so at convergence they give the same orientations, residuals, v^T P v, sigma0 and redundancy, and
the reduced camera system of the bundle is the conditions method's normal matrix (same N^-1).
Both stop when every correction is below 1e-8 of the standard deviation the element would have if
all others were known, so two converged solutions differ by far less than the brief's figures:
positions 1e-6 of the flying height, rotation matrices 1e-9, v^T P v relative 1e-7, plate
residuals 1e-6 of their sigma, N^-1 relative 1e-5 on the diagonal.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri import model, solvers
from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.bundle import adjust_bundle, solve_bundle
from striptri.geometry.camera import project as camera_project
from striptri.errors import NumericalFailure
from striptri.io import read_project
from striptri.equations.parameter_observations import build_parameter_observations
from striptri.pipeline import triangulate_result

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
H = 1500.0  # flying height of the shipped and generated projects (m)
NATIONAL_GRID = (512345.0, 5412345.0)


def _generated_with_truth(n_photos=2, layout="corners", seed=1, noise=sim.NoiseOptions(),
                          start_xy=(5000.0, 5000.0), mean_z=100.0, extra=6, **control):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=n_photos, start_xy=start_xy),
        terrain=sim.TerrainDesign(mean_z=mean_z),
        points=sim.PointDesign(extra_ties_per_model=extra),
        control=sim.ControlDesign(layout=layout, **control),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, noise, np.random.default_rng(seed + 1000)), truth


def _generated(**kw):
    return _generated_with_truth(**kw)[0]


def _strip(**kw):
    return _generated(n_photos=6, layout="every-k", **kw)


WEIGHTED = sim.NoiseOptions(sigma_control_xy=0.05, sigma_control_z=0.1)


def _with_elements(project):
    """IMU attitudes of every photo, one angle held, an enforced and an observed base component,
    and observed interior orientation (camera columns in N)."""
    ph, n = project.photos, len(project.photos)
    sigma_angles = np.full((n, 3), np.radians(0.5))
    sigma_angles[2, 2] = 0.0
    bases = model.BaseComponents(np.array([0, 1]), np.array([1, 2]), np.array([2, 2]), np.array([3.0, -2.0]),
                                 np.array([np.nan, 0.05]))
    return replace(project, photos=replace(ph, sigma_angles=sigma_angles), bases=bases,
                   cameras=replace(project.cameras, sigma_interior=np.full((1, 3), 0.01)))


def _single_photo_points(weighted: bool):
    """The generated pair plus a tie, a height, a plan and a full point, each measured on the first
    photo only (true ground points 100 m behind the first nadir, exact plates), their control exact
    and held or weighted (0.2 m)."""
    project, truth = _generated_with_truth()
    ip, pts = project.image_points, project.points
    nadir = truth.xyz0[0]
    xyz = nadir + np.array([[-100.0, -200.0, 0.0], [-100.0, 0.0, 0.0], [-100.0, 200.0, 0.0], [-150.0, 100.0, 0.0]])
    xyz[:, 2] = 100.0 + np.arange(4)
    xy = camera_project(truth.R_ground_from_cam[0], truth.xyz0[0], truth.interior, xyz)
    kinds = np.array([model.TIE, model.HEIGHT, model.PLAN, model.FULL])
    axes = np.array([model.GIVEN_AXES[int(k)] for k in kinds])
    n_pt = len(pts)
    points = model.ObjectPoints(
        ids=pts.ids + [f"S{i}" for i in range(4)],
        kind=np.concatenate([pts.kind, kinds]),
        xyz_given=np.concatenate([pts.xyz_given, np.where(axes, xyz, np.nan)]),
        sigma_given=np.concatenate([pts.sigma_given, np.where(axes & weighted, 0.2, np.nan)]),
    )
    image_points = model.ImagePoints(
        photo_index=np.concatenate([ip.photo_index, np.zeros(4, dtype=int)]),
        point_index=np.concatenate([ip.point_index, n_pt + np.arange(4)]),
        xy=np.concatenate([ip.xy, xy]),
        sigma_xy=np.concatenate([ip.sigma_xy, np.full((4, 2), ip.sigma_xy[0, 0])]),
    )
    return replace(project, points=points, image_points=image_points)


CASES = {
    "pair": lambda: read_project(DATA / "pair"),
    "pair_minimal": lambda: read_project(DATA / "pair_minimal"),
    "strip8": lambda: read_project(DATA / "strip8"),
    "schmid_fig8": lambda: read_project(DATA / "schmid_fig8"),
    "strip_2_3": lambda: read_project(DATA / "strip_2_3"),
    "block_3x6": lambda: read_project(DATA / "block_3x6"),
    "pair, weighted control": lambda: _generated(layout="mixed", noise=WEIGHTED),
    "strip, weighted control": lambda: _strip(noise=WEIGHTED),
    "strip, GNSS centres": lambda: _strip(noise=sim.NoiseOptions(sigma_gnss=0.1)),
    "strip, GNSS centres, no control": lambda: _generated(n_photos=6, layout="none",
                                                          noise=sim.NoiseOptions(sigma_gnss=0.1)),
    "pair, single-photo control": lambda: _generated(n_single_photo=2),
    "strip, single-photo weighted control": lambda: _strip(n_single_photo=2, noise=WEIGHTED),
    "strip, plan points, check points": lambda: _strip(every_k_kind="XY", n_check=3),
    "strip, national grid": lambda: _strip(start_xy=NATIONAL_GRID, mean_z=850.0),
    "strip, IMU, held angle, bases, interior": lambda: _with_elements(_strip()),
    "pair, one-photo points of every kind": lambda: _single_photo_points(weighted=False),
    "pair, one-photo weighted points": lambda: _single_photo_points(weighted=True),
}


@pytest.fixture(scope="module")
def solved():
    """Both methods on every case, computed once."""
    cache = {}

    def get(name):
        if name not in cache:
            project = CASES[name]()
            cache[name] = (project, adjust(project), solve_bundle(project))
        return cache[name]

    return get


def _assert_same_adjustment(project, a, b):
    """a: the conditions method, b: the bundle (module doc for the tolerances)."""
    assert a.converged and b.converged
    assert b.method == "bundle"
    assert (b.redundancy, b.n_conditions, b.n_observations, b.n_unknowns, b.n_parameter_observations) == (
        a.redundancy, a.n_conditions, a.n_observations, a.n_unknowns, a.n_parameter_observations)
    np.testing.assert_allclose(b.offset, a.offset)
    assert np.abs(b.state.xyz0 - a.state.xyz0).max() < 1e-6 * H
    assert np.abs(b.state.R_ground_from_cam - a.state.R_ground_from_cam).max() < 1e-9
    np.testing.assert_allclose(b.state.interior, a.state.interior, rtol=0, atol=1e-9)
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-7, abs=1e-12)
    if a.redundancy > 0:
        assert b.sigma0 == pytest.approx(a.sigma0, rel=1e-7)
    else:
        assert np.isnan(b.sigma0) and np.isnan(a.sigma0)
    sigma_xy = project.image_points.sigma_xy
    assert np.all(np.abs(b.plate_residuals - a.plate_residuals) < 1e-6 * sigma_xy)
    np.testing.assert_array_equal(b.plate_adjusted, project.image_points.xy + b.plate_residuals)
    weighted = np.isfinite(project.points.sigma_given)
    d_control = np.abs(b.control_residuals - a.control_residuals)
    assert np.all(d_control[weighted] < 1e-6 * project.points.sigma_given[weighted])
    assert np.all(d_control[~weighted] == 0.0)
    sigma_par = build_parameter_observations(project, a.offset).sigma
    assert np.all(np.abs(b.parameter_residuals - a.parameter_residuals) < 1e-6 * sigma_par)
    np.testing.assert_allclose(np.diag(b.Qxx), np.diag(a.Qxx), rtol=1e-5)


@pytest.mark.parametrize("name", list(CASES))
def test_bundle_equals_conditions(solved, name):
    project, a, bundle = solved(name)
    _assert_same_adjustment(project, a, bundle.result)


@pytest.mark.parametrize("name", list(CASES))
def test_checks_after_convergence(solved, name):
    """The observation equations hold at the adjusted observations, the reduced and the point
    gradients vanish, and v^T P v equals the reduced sum (Schmid 58, 59 in the bundle's form)."""
    _, _, bundle = solved(name)
    checks = bundle.result.checks
    assert checks.max_condition_misclosure_sigma < 1e-8
    assert checks.max_BTk_sigma < 1e-8
    assert checks.max_point_gradient_sigma < 1e-8
    assert checks.vtpv_reduction_relative_difference < 1e-8


@pytest.mark.parametrize("name", ["pair", "strip8", "strip, weighted control", "pair, one-photo points of every kind"])
def test_adjusted_points_are_the_triangulated_points(solved, name):
    """The bundle's object points equal the points triangulated from the conditions method's
    adjusted rays (DESIGN section 4: "the triangulated points agree")."""
    project, a, bundle = solved(name)
    tri = triangulate_result(project, a)
    xyz = bundle.xyz_points
    taking_part = np.isfinite(xyz).all(axis=1)
    # triangulation also places a height point seen by one photo, which takes no part
    assert np.all(tri.determined[taking_part])
    assert np.abs(xyz[taking_part] - tri.xyz[taking_part]).max() < 1e-6 * H
    kinds = project.points.kind
    given = np.array([model.GIVEN_AXES[int(k)] for k in kinds])
    free = ~given | np.isfinite(project.points.sigma_given)
    assert bundle.n_point_unknowns == int(free[taking_part].sum())


def test_one_photo_points_follow_the_condition_count(solved):
    """A tie or height point on one photo takes no part; a plan point on one photo has its Z
    from the ray (1 condition); a full point on one photo gives 2 (DESIGN section 3)."""
    for name in ("pair, one-photo points of every kind", "pair, one-photo weighted points"):
        project, a, bundle = solved(name)
        new = slice(len(project.points) - 4, None)
        taking_part = np.isfinite(bundle.xyz_points[new]).all(axis=1)
        assert taking_part.tolist() == [False, False, True, True]
        rows = project.image_points.point_index >= len(project.points) - 4
        v = bundle.result.plate_residuals[rows]
        assert np.all(v[:2] == 0.0) and np.any(v[2:] != 0.0)
        assert bundle.result.n_conditions == adjust(_generated()).n_conditions + 1 + 2


@pytest.mark.parametrize("solver", [s for s in solvers.SOLVERS if s != "auto"])
@pytest.mark.parametrize("name", ["strip8", "block_3x6", "strip, GNSS centres", "strip, IMU, held angle, bases, interior"])
def test_every_solver_gives_the_conditions_result(solved, name, solver):
    if solver == "cholmod":
        pytest.importorskip("sksparse")
    if solver == "cvxopt":
        pytest.importorskip("cvxopt.cholmod")
    project, a, _ = solved(name)
    b = adjust_bundle(project, AdjustmentOptions(solver=solver))
    assert b.solver == solver
    _assert_same_adjustment(project, a, b)


def test_chunks_do_not_change_the_result(solved):
    """Streaming the points in chunks of 3 gives the result of one chunk per batch."""
    project, _, whole = solved("strip8")
    chunked = solve_bundle(project, AdjustmentOptions(chunk_size=3))
    assert chunked.result.iterations == whole.result.iterations
    assert chunked.result.vtpv == pytest.approx(whole.result.vtpv, rel=1e-10)
    np.testing.assert_allclose(chunked.result.state.xyz0, whole.result.state.xyz0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(chunked.xyz_points, whole.xyz_points, rtol=0, atol=1e-9)
    np.testing.assert_allclose(chunked.result.N.toarray(), whole.result.N.toarray(), rtol=1e-12,
                               atol=1e-12 * abs(whole.result.N).max())


def _two_full_points_only(project):
    """The 'corners' pair with only two of its full points left as control (the others tie)."""
    kind, given = project.points.kind.copy(), project.points.xyz_given.copy()
    full = np.flatnonzero(kind == model.FULL)
    kind[full[2:]] = model.TIE
    given[full[2:]] = np.nan
    return replace(project, points=replace(project.points, kind=kind, xyz_given=given))


@pytest.mark.parametrize("make", [
    lambda: _generated(n_photos=4, layout="none"),
    lambda: _two_full_points_only(_generated()),
], ids=["no control", "two full points"])
def test_datum_defects_are_named_as_by_the_conditions_method(make):
    """datum.diagnose on the reduced camera system (ug = gPg = 0: collinearity is exactly
    invariant under a similarity of photos and points) names the same free similarity elements."""
    project = make()
    with pytest.raises(NumericalFailure) as conditions:
        adjust(project)
    with pytest.raises(NumericalFailure) as bundle:
        adjust_bundle(project)
    assert "datum undetermined" in str(bundle.value)
    assert str(bundle.value) == str(conditions.value)


def test_adjust_command_with_method_bundle_matches_conditions(tmp_path):
    """`striptri adjust --method bundle` writes the same photos as the conditions method."""
    import csv
    import json
    import subprocess

    data = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8"
    photos = {}
    for method in ("conditions", "bundle"):
        out = tmp_path / method
        done = subprocess.run(["striptri", "adjust", str(data), "--out", str(out), "--method", method],
                              capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        assert json.loads((out / "summary.json").read_text())["method"] == method
        with open(out / "photos.csv", newline="") as f:
            photos[method] = np.array([[float(r[c]) for c in ("X0", "Y0", "Z0")] for r in csv.DictReader(f)])
    np.testing.assert_allclose(photos["bundle"], photos["conditions"], atol=1e-6 * 1500)
