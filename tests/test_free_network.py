"""Free networks: data without (enough) control adjusted with inner constraints. The datum-invariant
results (v^T P v, residuals, the shape of the block) must equal those of an adjustment whose control
gives exactly the seven datum elements and no more; the cofactor matrix is a generalised inverse of
N orthogonal to the constraints."""

import json
import subprocess
from dataclasses import replace

import numpy as np
import pytest

from striptri import model
from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.errors import NumericalFailure
from striptri.io import write_project


def _strip(seed=5):
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=5), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=5))
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(seed + 1))


def _relabel(project, kinds: dict):
    k, g = project.points.kind.copy(), project.points.xyz_given.copy()
    for i, kind in kinds.items():
        k[i] = kind
        g[i, ~np.array(model.GIVEN_AXES[kind])] = np.nan
    return replace(project, points=replace(project.points, kind=k, xyz_given=g))


@pytest.fixture(scope="module")
def pair_of_runs():
    p = _strip()
    full = np.flatnonzero(p.points.kind == model.FULL)
    # two full points and one height point: exactly the seven datum elements
    minimal = {int(i): model.TIE for i in full}
    minimal.update({int(full[0]): model.FULL, int(full[-1]): model.FULL, int(full[1]): model.HEIGHT})
    ties_only = {int(i): model.TIE for i in full}
    a = adjust(_relabel(p, minimal))
    b = adjust(_relabel(p, ties_only), AdjustmentOptions(datum="inner"))
    return a, b


def test_free_network_equals_minimal_control_in_everything_datum_invariant(pair_of_runs):
    a, b = pair_of_runs
    assert b.converged and len(b.free_network) == 7
    assert b.redundancy == a.redundancy
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-9)
    np.testing.assert_allclose(b.plate_residuals, a.plate_residuals, atol=1e-9)
    # the shape: relative rotations and ratios of distances between projection centres
    for i, j in [(0, 3), (1, 4), (2, 3)]:
        np.testing.assert_allclose(b.state.R_ground_from_cam[i].T @ b.state.R_ground_from_cam[j], a.state.R_ground_from_cam[i].T @ a.state.R_ground_from_cam[j], atol=1e-12)
    da = np.linalg.norm(a.state.xyz0[1:] - a.state.xyz0[0], axis=1)
    db = np.linalg.norm(b.state.xyz0[1:] - b.state.xyz0[0], axis=1)
    np.testing.assert_allclose(db / db[-1], da / da[-1], atol=1e-12)


def test_free_network_cofactors_are_the_inner_constraint_inverse(pair_of_runs):
    _, b = pair_of_runs
    N, Q, C = b.N.toarray(), b.Qxx, b.free_network.C
    assert np.abs(N @ Q @ N - N).max() < 1e-10 * np.abs(N).max()  # a generalised inverse of N
    assert np.abs(C.T @ Q).max() < 1e-10 * np.abs(Q).max()  # orthogonal to the constraints
    np.testing.assert_allclose(Q, Q.T, atol=1e-12 * np.abs(Q).max())
    # and the minimum-norm one: equal to the pseudo-inverse in the metric of the constraints
    d = np.sqrt(N.diagonal())
    pinv = np.linalg.pinv((N / d[:, None]) / d[None, :], rcond=1e-10) / d[:, None] / d[None, :]
    np.testing.assert_allclose(Q, pinv, atol=1e-8 * np.abs(Q).max())


def test_partial_defect_only_the_free_directions_are_constrained():
    """Plan control only leaves translation in Z free: the inner datum fixes that one direction
    and keeps the plan control exactly."""
    p = _strip()
    full = np.flatnonzero(p.points.kind == model.FULL)
    q = _relabel(p, {int(i): model.PLAN for i in full})
    with pytest.raises(NumericalFailure, match="translation in Z"):
        adjust(q)
    r = adjust(q, AdjustmentOptions(datum="inner"))
    assert r.converged and len(r.free_network) == 1
    assert r.redundancy == r.n_conditions - r.n_unknowns + 1


def test_with_full_control_inner_datum_changes_nothing():
    p = _strip()
    a, b = adjust(p), adjust(p, AdjustmentOptions(datum="inner"))
    assert b.free_network is None
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, atol=1e-9)


def test_command_line_datum_inner(tmp_path):
    p = _strip()
    full = np.flatnonzero(p.points.kind == model.FULL)
    write_project(tmp_path / "free", _relabel(p, {int(i): model.TIE for i in full}))
    bad = subprocess.run(["striptri", "adjust", str(tmp_path / "free"), "--out", str(tmp_path / "o1")],
                         capture_output=True, text=True)
    assert bad.returncode == 1 and "datum" in bad.stderr and "--datum inner" in bad.stderr
    ok = subprocess.run(["striptri", "adjust", str(tmp_path / "free"), "--out", str(tmp_path / "o2"),
                         "--datum", "inner"], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    summary = json.loads((tmp_path / "o2" / "summary.json").read_text())
    assert summary["converged"] and summary["redundancy"] > 0


@pytest.mark.parametrize("case, free_count, words", [
    ("no control", 7, ["translation in X", "scale"]),
    ("plan control only", 1, ["translation in Z"]),
    ("height control only", 3, ["translation in X", "translation in Y", "rotation about the Z axis"]),
    ("two full points", 1, ["rotation about an axis"]),
])
def test_each_datum_defect_is_named_and_the_free_network_solves_it(case, free_count, words):
    p = _strip()
    full = [int(i) for i in np.flatnonzero(p.points.kind == model.FULL)]
    kinds = {
        "no control": {i: model.TIE for i in full},
        "plan control only": {i: model.PLAN for i in full},
        "height control only": {i: model.HEIGHT for i in full},
        "two full points": {i: (model.FULL if n < 2 else model.TIE) for n, i in enumerate(full)},
    }[case]
    q = _relabel(p, kinds)
    with pytest.raises(NumericalFailure) as failure:
        adjust(q)
    for word in words:
        assert word in str(failure.value)
    r = adjust(q, AdjustmentOptions(datum="inner"))
    assert r.converged and len(r.free_network) == free_count
    assert r.checks.max_condition_misclosure_sigma < 1e-7


def _shipped_pair_without_control(tmp_path):
    """The shipped pair with a header-only control.csv: nothing but the rays fixes the datum."""
    import shutil
    from pathlib import Path
    source = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "pair"
    folder = tmp_path / "pair"
    shutil.copytree(source, folder)
    header = (source / "control.csv").read_text().splitlines()[0]
    (folder / "control.csv").write_text(header + "\n")
    return folder


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_pair_without_control_meets_its_datum_in_a_handful_of_iterations(tmp_path, method):
    """Issue 26's regression: the pair without control took 31 iterations (the datum's metric diag N
    turns with the block, and the linear datum move slid back by half each time), and the bundle
    took two free directions for determined (their Rayleigh quotients against the reduced diagonal
    reached 2e-12). At the result the inner constraints hold at the adjusted state itself:
    H^T diag(N) (x^ - x0) = 0, H the seven similarity directions there."""
    from striptri.equations import datum
    from striptri.io import read_project
    from striptri.equations.parameters import initial_state
    r = adjust(read_project(_shipped_pair_without_control(tmp_path)),
               AdjustmentOptions(datum="inner", method=method))
    assert r.converged and len(r.free_network) == 7
    assert r.iterations <= 10
    x0 = initial_state(read_project(_shipped_pair_without_control(tmp_path / "again")), r.offset)
    H = r.free_network.H
    D = r.N.diagonal()
    delta = datum.displacement(x0, r.state, r.layout)
    G = H.T @ (D[:, None] * H)
    # the datum's remaining move, in the correction test's units (sd of the elements)
    move = np.linalg.solve(G, H.T @ (D * delta))
    assert np.sqrt(move @ G @ move) < 1e-6


def test_pair_without_control_the_two_methods_agree(tmp_path):
    from striptri.io import read_project
    project = read_project(_shipped_pair_without_control(tmp_path))
    a = adjust(project, AdjustmentOptions(datum="inner"))
    b = adjust(project, AdjustmentOptions(datum="inner", method="bundle"))
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-9)
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, atol=1e-6)
    np.testing.assert_allclose(b.state.R_ground_from_cam, a.state.R_ground_from_cam, atol=1e-9)


def test_command_line_pair_without_control_datum_inner(tmp_path):
    folder = _shipped_pair_without_control(tmp_path)
    for method in ("conditions", "bundle"):
        out = tmp_path / f"out-{method}"
        run = subprocess.run(["striptri", "adjust", str(folder), "--datum", "inner", "--method", method,
                              "--out", str(out)], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        assert json.loads((out / "summary.json").read_text())["converged"]
