"""The bundle's residual cofactors and point cofactors in the collinearity form (bundle.precision,
issue 11) equal the conditions form's (precision.residual_cofactors, form="conditions") in every
quantity the products consume: qvv of the plate, control and observed elements, the points' plate
blocks of Qvv (separability), the redundancy numbers, w, MDB and bias-to-noise ratios, the points'
(90) cofactors, and the output tables. At convergence both are the same linear model (module doc of
bundle.precision), so the tolerance is round-off: 1e-9 relative (the numbers agree to ~1e-11)."""

from __future__ import annotations

import csv
import io
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri.core.runs import RunOptions
from striptri import simulate as sim
from striptri.core.adjusted_points import triangulate_adjusted
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.precision import collinearity_form
from striptri.io import read_project
from striptri.geometry.lens import IMAGE, PLATE
from striptri.pipeline import adjust_products
from striptri.precision.residuals import residual_cofactors
from striptri.reliability import plate_reliability

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import close_range  # noqa: E402
from test_bundle import CASES  # noqa: E402
from test_normal_equations import _two_cameras  # noqa: E402
from test_self_calibration import calibration_project  # noqa: E402

RTOL = 1e-9
# The collinearity form alone subtracts, qvv = q - J Qxx J^T, exact to a few eps of q: a coordinate
# with a tiny redundancy number r agrees to RTOL + FLOOR / r relative (the x of a two-ray point along
# the base, r ~ 1e-8, to ~1e-6). residual_cofactors takes the points with r < R_SUBTRACTION from the
# conditions form, so that what the products consume agrees to RTOL everywhere.
FLOOR = 1e-14
BUNDLE = AdjustmentOptions(method="bundle")
WEIGHTED_BLOCK = sim.SyntheticDesign(
    flight=sim.FlightDesign(n_photos=6, n_strips=3, overlap=2 / 3, sidelap=0.6),
    points=sim.PointDesign(extra_ties_per_model=3),
    control=sim.ControlDesign(layout="perimeter", every_k=2, n_check=6),
)


def _close_range(tmp_path_factory, cameras: int):
    net = close_range.make_close_range(24, 40, seed=3)  # 7 to 20 rays per target; c, xp, yp, k1, k2 free
    path = close_range.write_close_range(tmp_path_factory.mktemp("cr") / "p", net)
    return read_project(_two_cameras(path) if cameras == 2 else path)


PROJECTS = {
    "strip, held control, single-photo and check points": lambda f: CASES["strip, plan points, check points"](),
    "strip, single-photo weighted control": lambda f: CASES["strip, single-photo weighted control"](),
    "strip, IMU, held angle, bases, interior": lambda f: CASES["strip, IMU, held angle, bases, interior"](),
    "strip, GNSS centres": lambda f: CASES["strip, GNSS centres"](),
    "pair, one-photo points of every kind": lambda f: CASES["pair, one-photo points of every kind"](),
    "block, weighted control": lambda f: sim.simulate_project("block", sim.SimulateOptions(
        WEIGHTED_BLOCK, sim.NoiseOptions(sigma_control_xy=0.05, sigma_control_z=0.08)), 1)[0],
    "self-calibration, plate convention": lambda f: calibration_project(PLATE, sim.NoiseOptions(), seed=5)[0],
    "self-calibration, image convention": lambda f: calibration_project(IMAGE, sim.NoiseOptions(), seed=5)[0],
    "close range": lambda f: _close_range(f, 1),
    "close range, two cameras": lambda f: _close_range(f, 2),
}


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    cache = {}

    def get(name):
        if name not in cache:
            project = PROJECTS[name](tmp_path_factory)
            result = adjust(project, BUNDLE)
            assert result.converged
            cache[name] = (project, result)
        return cache[name]

    return get


def _block_entries(blocks, n_rows):
    """The plate blocks of Qvv as (keys, values) sorted by key: key (row_i * 2 + c) * 2 n_rows +
    (row_j * 2 + d) of coordinate c of row i and d of row j, whatever the order of rows in a block."""
    keys, values = [], []
    for rows, q in blocks:
        m, k = rows.shape
        coord = (2 * rows[:, :, None] + np.arange(2)).reshape(m, 2 * k)
        keys.append((coord[:, :, None] * (2 * n_rows) + coord[:, None, :]).ravel())
        values.append(q.ravel())
    keys, values = np.concatenate(keys), np.concatenate(values)
    order = np.argsort(keys)
    return keys[order], values[order]


def _assert_same_qvv(col, ref) -> None:
    """qvv of every plate coordinate elementwise (rows of points without conditions: zero in both),
    of the weighted control coordinates and of the observed elements, to RTOL."""
    has = ref.plate > 0
    assert has.any() and np.array_equal(col.plate[~has], ref.plate[~has])
    np.testing.assert_allclose(col.plate[has], ref.plate[has], rtol=RTOL, atol=0)
    weighted = ref.control > 0
    np.testing.assert_allclose(col.control[weighted], ref.control[weighted], rtol=RTOL, atol=0)
    np.testing.assert_allclose(col.parameters, ref.parameters, rtol=RTOL, atol=0)


def _assert_same_blocks(col, ref, n_rows: int) -> None:
    """The plate blocks of Qvv: the same entries, each to RTOL of sqrt(qvv_ii qvv_jj) (the
    correlations to RTOL)."""
    keys_ref, q_ref = _block_entries(ref.plate_blocks, n_rows)
    keys_col, q_col = _block_entries(col.plate_blocks, n_rows)
    np.testing.assert_array_equal(keys_col, keys_ref)
    d = ref.plate.ravel()
    assert np.all(np.abs(q_col - q_ref) <= RTOL * np.sqrt(d[keys_ref // (2 * n_rows)] * d[keys_ref % (2 * n_rows)]))


def result_cofactors(project, result) -> dict:
    """The a-priori cofactors q of the plate (m, 2) and control (n, 3) observations."""
    from striptri.equations.observations import observations_of

    obs = observations_of(project, result.offset)
    return {"plate": obs.q_plate, "control": obs.q_control}


@pytest.mark.parametrize("name", list(PROJECTS))
def test_the_collinearity_form_equals_the_conditions_form(solved, name):
    project, result = solved(name)
    assert collinearity_form.applies(project, result)
    ref = residual_cofactors(project, result, plate_blocks=True, form="conditions")
    col = residual_cofactors(project, result, plate_blocks=True, form="collinearity")
    _assert_same_qvv(col, ref)
    assert not col.control[~(ref.control > 0)].any()
    _assert_same_blocks(col, ref, len(project.image_points))
    # the redundancy numbers add up to the redundancy
    r = col.redundancy_numbers(project, result)
    total = r["plate"].sum() + r["control"].sum() + r["parameters"].sum()
    assert total == pytest.approx(result.redundancy, rel=1e-9)


@pytest.mark.parametrize("name", list(PROJECTS))
def test_the_product_route_equals_the_conditions_form(solved, monkeypatch, name):
    """Small systems with long tracks take Qcc G^T as one product with the whole Qcc
    (collinearity_form._by_products) instead of gathering Qcc among each point's sets; here every
    project takes it (PRODUCT_RATIO infinite): qvv of the plate and control observations, of the
    observed elements and the points' orientation parts equal the conditions form's and the
    gathering route's."""
    project, result = solved(name)
    ref = residual_cofactors(project, result, form="conditions")
    monkeypatch.setattr(collinearity_form, "PRODUCT_RATIO", 0.0)
    gathered = collinearity_form.residual_cofactors(project, result)
    monkeypatch.setattr(collinearity_form, "PRODUCT_RATIO", np.inf)
    col = residual_cofactors(project, result, form="collinearity")
    products = collinearity_form.residual_cofactors(project, result)
    _assert_same_qvv(col, ref)
    # against the gathering route, where both subtract alike: to round-off of q
    q = result_cofactors(project, result)
    assert np.all(np.abs(products.plate - gathered.plate) <= 1e-12 * np.abs(gathered.plate) + FLOOR * q["plate"])
    assert np.all(np.abs(products.control - gathered.control) <= 1e-12 * np.abs(gathered.control)
                  + FLOOR * q["control"])
    cov = gathered.points.cov_orientation
    np.testing.assert_allclose(products.points.cov_orientation, cov, rtol=0, atol=1e-12 * np.abs(cov).max())
    np.testing.assert_array_equal(products.imprecise, gathered.imprecise)


def test_long_tracks_of_a_small_system_take_the_product_route(solved, monkeypatch):
    """The route is chosen by its cost (PRODUCT_RATIO): the close-range block's tracks take the
    product, the short tracks of a block with more unknowns gather."""
    calls = []
    real = collinearity_form._by_products
    monkeypatch.setattr(collinearity_form, "_by_products", lambda *a: calls.append(1) or real(*a))
    project, result = solved("close range")
    collinearity_form.residual_cofactors(project, result)
    assert calls
    calls.clear()
    design = replace(WEIGHTED_BLOCK, flight=sim.FlightDesign(n_photos=12, n_strips=5, overlap=2 / 3, sidelap=0.6))
    project = sim.simulate_project("block", sim.SimulateOptions(design, sim.NoiseOptions()), 1)[0]
    result = adjust(project, BUNDLE)  # 60 photos, 360 unknowns, tracks of 2 to 9 rays
    assert result.layout.n_unknowns <= collinearity_form.DENSE_UNKNOWNS
    collinearity_form.residual_cofactors(project, result)
    assert not calls


@pytest.mark.parametrize("name", list(PROJECTS))
def test_the_collinearity_form_of_a_conditions_result_equals_its_conditions_form(tmp_path_factory, name):
    """A result of the method of conditions, where it takes the collinearity form (a small system):
    the same qvv of the plate, control and observed elements and the same plate blocks of Qvv as its
    conditions form, and the points' (90) cofactors of its triangulation."""
    project = PROJECTS[name](tmp_path_factory)
    result = adjust(project, AdjustmentOptions(method="conditions"))
    assert result.converged and collinearity_form.applies(project, result)
    ref = residual_cofactors(project, result, plate_blocks=True, form="conditions")
    col = residual_cofactors(project, result, plate_blocks=True)
    _assert_same_qvv(col, ref)
    _assert_same_blocks(col, ref, len(project.image_points))
    tri = collinearity_form.points_of(project, result)
    ref_points = triangulate_adjusted(project, result, orientation_part=True)
    ok = ref_points.determined
    np.testing.assert_array_equal(tri.determined, ok)
    scale = np.sqrt(np.einsum("nii->ni", ref_points.cov_measurement + ref_points.cov_orientation))
    scale = scale[:, :, None] * scale[:, None, :]
    assert np.all(np.abs(tri.cov_orientation - ref_points.cov_orientation) <= RTOL * scale)


@pytest.mark.parametrize("name", list(PROJECTS))
def test_the_subtraction_loses_digits_only_where_it_says(solved, name):
    """bundle.precision alone: qvv to RTOL + FLOOR / r of the conditions form's; beyond RTOL only on
    the points it marks imprecise (a redundancy number below R_SUBTRACTION)."""
    project, result = solved(name)
    ref = residual_cofactors(project, result, form="conditions")
    raw = collinearity_form.residual_cofactors(project, result)
    q = result_cofactors(project, result)
    assert np.all(np.abs(raw.plate - ref.plate) <= RTOL * ref.plate + FLOOR * q["plate"])
    assert np.all(np.abs(raw.control - ref.control) <= RTOL * ref.control + FLOOR * q["control"])
    beyond = np.abs(raw.plate - ref.plate) > RTOL * ref.plate
    assert raw.imprecise[project.image_points.point_index[beyond.any(axis=1)]].all()
    if name == "strip, held control, single-photo and check points":  # two-ray points along the base
        assert raw.imprecise.any()
    if name.startswith("close range"):  # long tracks: no small redundancy, no point for the conditions form
        assert not raw.imprecise.any() and (ref.plate / q["plate"]).min() > 1e-2


@pytest.mark.parametrize("name", ["block, weighted control", "self-calibration, image convention", "close range",
                                  "close range, two cameras", "pair, one-photo points of every kind"])
def test_the_reliability_measures_are_those_of_the_conditions_form(solved, monkeypatch, name):
    """plate_reliability (the w-tests, MDB, bias-to-noise ratios and the blocks snooping reads) takes
    the collinearity form for a bundle result; forced onto the conditions form it gives the same."""
    project, result = solved(name)
    fast = plate_reliability(project, result, cofactor_blocks=True)
    monkeypatch.setattr(collinearity_form, "applies", lambda *a: False)
    ref = plate_reliability(project, result, cofactor_blocks=True)
    for field in ("redundancy", "w", "mdb", "bnr"):
        a, b = getattr(fast, field), getattr(ref, field)
        np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
        ok = np.isfinite(b)
        np.testing.assert_allclose(a[ok], b[ok], rtol=RTOL, atol=0, err_msg=field)
    assert len(fast.cofactor_blocks) and len(ref.cofactor_blocks)


@pytest.mark.parametrize("name", list(PROJECTS))
@pytest.mark.parametrize("kept", [False, True])
def test_the_points_equal_the_triangulation_with_schmid_90(solved, monkeypatch, name, kept):
    """points_of, from a pass of its own or kept from the residual cofactors' pass."""
    project, result = solved(name)
    ref = triangulate_adjusted(project, result, orientation_part=True)
    monkeypatch.setattr(collinearity_form, "_last", {})
    if kept:
        passed = collinearity_form.residual_cofactors(project, result)
    tri = collinearity_form.points_of(project, result)
    assert (tri is passed.points) if kept else collinearity_form._last["points"] is tri
    np.testing.assert_array_equal(tri.determined, ref.determined)
    ok = ref.determined
    np.testing.assert_array_equal(tri.xyz[ok], ref.xyz[ok])
    np.testing.assert_array_equal(tri.cov_measurement, ref.cov_measurement)
    scale = np.sqrt(np.einsum("nii->ni", ref.cov_measurement + ref.cov_orientation))
    scale = scale[:, :, None] * scale[:, None, :]
    assert np.all(np.abs(tri.cov_orientation - ref.cov_orientation) <= RTOL * scale)
    assert not tri.cov_orientation[~ok].any()
    assert np.einsum("nii->n", ref.cov_orientation[ok]).max() > 0  # the orientation part is there


@pytest.mark.parametrize("name", ["close range", "close range, two cameras", "strip, GNSS centres"])
def test_qcc_read_by_blocks_equals_qcc_read_whole(solved, monkeypatch, name):
    """Large systems read Qcc by blocks of set pairs (Covariance.set_blocks), small ones whole
    (Covariance.dense_solved): the same numbers."""
    project, result = solved(name)
    whole = collinearity_form.residual_cofactors(project, result, plate_blocks=True)
    monkeypatch.setattr(collinearity_form, "DENSE_UNKNOWNS", 0)
    by_blocks = collinearity_form.residual_cofactors(project, result, plate_blocks=True)
    q = result_cofactors(project, result)["plate"]
    assert np.all(np.abs(by_blocks.plate - whole.plate) <= 1e-12 * whole.plate + FLOOR * q)
    for (rows_a, qa), (rows_b, qb) in zip(whole.plate_blocks, by_blocks.plate_blocks):
        np.testing.assert_array_equal(rows_a, rows_b)
        np.testing.assert_allclose(qb, qa, rtol=0, atol=1e-12 * np.abs(qa).max())
    np.testing.assert_allclose(by_blocks.points.cov_orientation, whole.points.cov_orientation, rtol=0,
                               atol=1e-12 * np.abs(whole.points.cov_orientation).max())


def _parsed(text: str) -> dict:
    rows = list(csv.reader(io.StringIO(text)))
    return {h: [r[i] for r in rows[1:]] for i, h in enumerate(rows[0])}


def _assert_close_tree(a, b, path="") -> None:
    """JSON-like trees equal, their floats to RTOL relative."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and a.keys() == b.keys(), path
        for key in b:
            _assert_close_tree(a[key], b[key], f"{path}/{key}")
    elif isinstance(b, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_close_tree(x, y, f"{path}/{i}")
    elif isinstance(b, float):
        assert a == pytest.approx(b, rel=RTOL, nan_ok=True), path
    else:
        assert a == b, path


def _numbers(values):
    try:
        return np.array([v if v != "" else "nan" for v in values], dtype=float)
    except ValueError:
        return None


def _assert_same_table(a: str, b: str, rtol) -> None:
    """The same columns; text equal, numbers to ``rtol`` relative (a scalar or one per row)."""
    ta, tb = _parsed(a), _parsed(b)
    assert ta.keys() == tb.keys()
    for col in ta:
        va, vb = _numbers(ta[col]), _numbers(tb[col])
        if va is None or vb is None:
            assert ta[col] == tb[col], col
            continue
        np.testing.assert_array_equal(np.isnan(va), np.isnan(vb), err_msg=col)
        if col == "w":  # the w of the larger |w| of x and y: of a group with one condition |w_x| = |w_y|
            va, vb = np.abs(va), np.abs(vb)  # and rounding picks the sign
        ok = np.isfinite(vb)
        tol = np.broadcast_to(rtol, vb.shape)[ok] * np.abs(vb[ok]) + 1e-15 * np.abs(vb[ok]).max(initial=0)
        assert np.all(np.abs(va[ok] - vb[ok]) <= tol), col


@pytest.mark.parametrize("name", ["block, weighted control", "close range"])
@pytest.mark.parametrize("blunders", ["off", "snoop"])
def test_the_output_tables_are_those_of_the_conditions_form(solved, monkeypatch, name, blunders):
    """The whole products (points.csv sigmas, residuals.csv w and flags, summary.json's blunders)
    with the collinearity form equal those with the conditions form; the point precision is the
    reliability pass's (no second pass)."""
    project, _ = solved(name)
    calls = []
    real = collinearity_form.residual_cofactors
    monkeypatch.setattr(collinearity_form, "residual_cofactors", lambda *a, **k: calls.append(1) or real(*a, **k))
    fast = adjust_products(project, BUNDLE, RunOptions(blunders=blunders))
    passes = len(calls)
    assert passes == 1 if blunders == "off" else passes >= 1  # one per adjustment; none more for the points
    monkeypatch.setattr(collinearity_form, "applies", lambda *a: False)
    ref = adjust_products(project, BUNDLE, RunOptions(blunders=blunders))
    assert len(calls) == passes
    for file in ("points.csv", "photos.csv", "residuals.csv"):
        _assert_same_table(fast.files[file], ref.files[file], RTOL)
    _assert_close_tree(fast.summary["blunders"], ref.summary["blunders"])


def test_the_form_is_chosen_automatically(solved, monkeypatch):
    """Bundle results without distances or free network take the collinearity form, and so do
    results of the method of conditions whose Qcc is read whole (a small system); a larger one of
    the conditions method, and results with a free-network datum or with distances, keep the
    conditions form."""
    project, result = solved("block, weighted control")
    auto = residual_cofactors(project, result, plate_blocks=True)
    col = residual_cofactors(project, result, plate_blocks=True, form="collinearity")
    np.testing.assert_array_equal(auto.plate, col.plate)
    conditions = adjust(project, AdjustmentOptions(method="conditions"))
    assert collinearity_form.applies(project, conditions)
    np.testing.assert_array_equal(residual_cofactors(project, conditions).plate,
                                  residual_cofactors(project, conditions, form="collinearity").plate)
    monkeypatch.setattr(collinearity_form, "DENSE_UNKNOWNS", conditions.layout.n_unknowns - 1)
    assert not collinearity_form.applies(project, conditions)
    assert collinearity_form.applies(project, result)
    np.testing.assert_array_equal(residual_cofactors(project, conditions).plate,
                                  residual_cofactors(project, conditions, form="conditions").plate)
    assert not collinearity_form.applies(replace(project, distances=object()), result)
    with pytest.raises(ValueError):
        residual_cofactors(project, result, form="other")


def test_a_free_network_keeps_the_conditions_form():
    """The free network's Qxx is the inner-constraint inverse, not the reduced system's: a result
    with a free network does not take the collinearity form, whatever its method. (The bundle does
    not carry a free network yet: the conditions method's result stands in, labelled a bundle's.)"""
    from test_free_network import _relabel, _strip

    from striptri.model import FULL, TIE

    p = _strip()
    free = _relabel(p, {int(i): TIE for i in np.flatnonzero(p.points.kind == FULL)})
    result = adjust(free, AdjustmentOptions(datum="inner"))
    assert result.converged and result.free_network is not None
    as_bundle = replace(result, method="bundle")
    assert not collinearity_form.applies(free, as_bundle)
    np.testing.assert_array_equal(residual_cofactors(free, as_bundle).plate,
                                  residual_cofactors(free, as_bundle, form="conditions").plate)


@pytest.mark.parametrize("name", ["strip, held control, single-photo and check points",
                                  "pair, one-photo points of every kind", "close range"])
def test_points_with_conditions_are_those_build_batches_batches(solved, name):
    from striptri.equations.groups import build_batches, points_with_conditions

    project, _ = solved(name)
    batched = np.zeros(len(project.points), dtype=bool)
    for batch in build_batches(project):
        batched[batch.point_index] = True
    np.testing.assert_array_equal(points_with_conditions(project), batched)
    if name.startswith("pair, one-photo"):
        assert not batched.all()  # one-photo tie and height points have no conditions


def test_covariance_read_whole_by_solves_equals_its_entries(solved):
    """Covariance.dense_solved (n solves with the factor) and Covariance.set_blocks (blocks of set
    pairs) read the same Qxx as Covariance.entries."""
    from striptri.selected_inverse.covariance import Slots

    _, result = solved("close range, two cameras")
    cov = result.covariance
    dense = cov.dense()
    np.testing.assert_allclose(cov.dense_solved(), dense, rtol=0, atol=1e-12 * np.abs(dense).max())
    lay = result.layout
    photos = np.array([[0, 3, 5], [7, 7, 2]])
    cams = np.array([[0], [1]])
    parts = [Slots(None, photos, lay.photo_cols), Slots(None, cams, lay.camera_cols[:, lay.camera_elements])]
    idx = np.concatenate([lay.photo_cols[photos].reshape(2, -1), lay.camera_cols[:, lay.camera_elements][cams].reshape(2, -1)], 1)
    Q = np.zeros((len(dense) + 1,) * 2)
    Q[:-1, :-1] = dense
    np.testing.assert_allclose(cov.set_blocks(parts), Q[idx[:, :, None], idx[:, None, :]], rtol=0,
                               atol=1e-12 * np.abs(dense).max())
