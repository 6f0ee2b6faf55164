"""Strips: the direction-free scale condition on a strip flown along Y, the refusal of Schmid's
XZ-projected form there, independence of the ground frame's orientation, and the memory shape of
the assembly."""

import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri import simulate as sim
from striptri.adjustment import AdjustmentOptions, Assembly, Sweep, assemble_normals, adjust, observations_of
from striptri.errors import NumericalFailure
from striptri.equations.groups import build_batches
from striptri.equations.linearise import At
from striptri.io import read_project
from striptri.equations.parameter_observations import build_parameter_observations
from striptri.equations.parameters import build_layout, initial_state, reduction_offset
from striptri.geometry.rotations import R_from_opk

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"


def _strip(heading=0.0, n_photos=6, extra_ties=0, seed=0):
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(n_photos=n_photos, heading_deg=heading),
        points=sim.PointDesign(extra_ties_per_model=extra_ties),
        control=sim.ControlDesign(layout="ends"),
    )
    truth = sim.make_truth(design, np.random.default_rng(seed))
    return sim.perturb(truth, sim.NoiseOptions(), np.random.default_rng(seed + 1)), truth


def _rotated(project, angle):
    """The same project in a ground frame turned by `angle` about Z (about the origin)."""
    Rz = R_from_opk(np.array([0.0, 0.0, angle]))
    ph, pts = project.photos, project.points
    xyz0 = ph.xyz0 @ Rz.T
    R = Rz @ ph.R_ground_from_cam
    given = pts.xyz_given.copy()
    full = np.isfinite(given).all(axis=1)  # only points with X and Y given can be turned
    given[full] = given[full] @ Rz.T
    return replace(project, photos=replace(ph, xyz0=xyz0, R_ground_from_cam=R),
                   points=replace(pts, xyz_given=given))


def test_strip_flown_along_y_converges_with_the_3d_form_and_refuses_the_xz_form():
    project, truth = _strip(heading=90.0)
    r = adjust(project)
    assert r.converged
    np.testing.assert_allclose(r.state.xyz0 + r.offset, truth.xyz0, atol=1.0)
    with pytest.raises(NumericalFailure, match="unsuitable"):
        adjust(project, AdjustmentOptions.of(scale_form="xz"))


def test_result_does_not_depend_on_the_orientation_of_the_ground_frame():
    """Turning the ground frame by 90 deg turns the adjusted orientations and changes nothing else."""
    project, _ = _strip(heading=0.0)
    a = adjust(project)
    b = adjust(_rotated(project, np.pi / 2))
    Rz = R_from_opk(np.array([0.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose((b.state.xyz0 + b.offset) @ Rz, a.state.xyz0 + a.offset, atol=1e-6)
    np.testing.assert_allclose(Rz.T @ b.state.R_ground_from_cam, a.state.R_ground_from_cam, atol=1e-10)
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-8)
    assert b.redundancy == a.redundancy


def test_scale_forms_agree_on_a_strip_flown_along_x():
    project = read_project(DATA / "strip8")
    a, b = adjust(project), adjust(project, AdjustmentOptions.of(scale_form="xz"))
    np.testing.assert_allclose(b.state.xyz0, a.state.xyz0, atol=1e-6)
    assert b.vtpv == pytest.approx(a.vtpv, rel=1e-9)


def _assembly_peak_bytes(project, chunk_size):
    offset = reduction_offset(project)
    state, layout = initial_state(project, offset), build_layout(project)
    batches = build_batches(project)
    obs = observations_of(project, offset)
    pobs = build_parameter_observations(project, offset)
    options = AdjustmentOptions(chunk_size=chunk_size)
    assembly = Assembly.of(batches, state, layout, chunk_size)
    sweep = Sweep(batches, At.of(state, layout, obs, obs.plate.copy(), obs.control.copy()), options)
    assemble_normals(sweep, pobs, assembly)  # warm up (imports, caches)
    tracemalloc.start()
    tracemalloc.reset_peak()
    base, _ = tracemalloc.get_traced_memory()
    assemble_normals(sweep, pobs, assembly)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak - base


def test_assembly_memory_does_not_grow_with_the_number_of_points():
    """Schmid: "the amount of memory space needed is almost independent of the number of points".
    Same 20 photos, about twice the points: the assembly's peak memory (beyond what existed before
    it) stays nearly the same, because groups are streamed in chunks."""
    few, _ = _strip(n_photos=20, extra_ties=30, seed=3)
    many, _ = _strip(n_photos=20, extra_ties=60, seed=3)
    assert len(many.points) > 1.8 * len(few.points)
    peak_few = _assembly_peak_bytes(few, chunk_size=100)
    peak_many = _assembly_peak_bytes(many, chunk_size=100)
    assert peak_many < 1.25 * peak_few


def test_gauss_seidel_inner_iterations_are_reported_per_outer_iteration(tmp_path):
    """summary.json's history carries the inner iterations of the relaxation in every outer
    iteration, and the relaxation reached its tolerance each time."""
    import json
    import subprocess

    out = tmp_path / "gs"
    done = subprocess.run(["striptri", "adjust", str(DATA / "strip8"), "--out", str(out), "--solver", "gauss-seidel"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == "gauss-seidel"
    history = summary["history"]
    assert len(history) == summary["iterations"]
    for h in history:
        assert h["solver_inner_iterations"] > 0 and h["solver_converged"]
        assert h["solver_relative_residual"] < 1e-10
