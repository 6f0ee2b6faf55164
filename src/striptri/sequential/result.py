"""The sequential solution as an AdjustmentResult (method "sequential"), and the sequential result as
approximate values for the simultaneous adjustment (``--init sequential``).

Definitions (docs/sequential.md):

* ``sigma0``, ``redundancy``, ``vtpv``: pooled over the per-photo adjustments, the only steps with
  the plate measurements' stochastic model: procedure 1 the relative orientations (m - 5 each),
  procedure 2 the first relative orientation and then the coplanarity-plus-collinearity adjustments
  (conditions - 6 each). The scale transfers, the absolute orientation and the strip correction are
  fits in metres; their residuals are in ``checks`` (RMS) and in the SequentialSolution.
* ``plate_residuals``: reprojection residuals of the strip model's points (in the ground frame,
  after the absolute orientation and any strip correction) in the final orientations,
  ``v = xy(final orientation, point) - xy measured``; zero for measurements of points that are in no
  model (e.g. single-photo control). ``plate_adjusted = xy + v``.
* ``N``: block diagonal, one 6 x 6 block per photo: the normal matrix of the collinearity equations
  of the photo with its strip-model points held, in the unknown columns of ``build_layout``. Its
  inverse is the precision of each photo *given its points*, a lower bound: the sequential method's
  error propagation (accumulation along the strip) is not in it. Camera columns get a unit diagonal
  (the sequential method holds the interior orientation).
* ``iterations``: every Gauss-Newton iteration of every step (per-photo adjustments, the absolute
  orientation, the resections after a strip correction); ``converged``: all of them converged.
  ``history``: one entry per photo step. ``termination``: "converged" when every step converged,
  else "iteration_limit", with a message naming the first step that did not (its photo, its last
  iterations, whether it was still converging, the likely cause). The steps' own limit is
  max(30, [adjustment] max_iterations) (SequentialOptions.from_adjustment_options).
* Observed or fixed photo elements, weighted control and enforced bases are not used (the method is
  that of the plotters: photographs and control only); control coordinates get zero residuals.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..core import diagnosis, termination
from ..equations.observations import observations_of
from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult, Iteration, SequentialChecks, Timings
from ..errors import NumericalFailure
from ..geometry.camera import project as project_plate
from ..equations.conditions import collinearity
from ..model import Project
from ..equations.parameter_observations import build_parameter_observations
from ..equations.parameters import State, build_layout, with_state
from .strip import SequentialOptions, SequentialSolution, distortion_free, triangulate_strip
from ..equations import weights


def adjust_sequential(project: Project, options: AdjustmentOptions | SequentialOptions | None = None) -> AdjustmentResult:
    """Schut's sequential strip triangulation as an AdjustmentResult (module doc). ``options``: an
    AdjustmentOptions (its ``sequential`` part, SequentialOptions.from_adjustment_options) or a
    SequentialOptions."""
    t0 = time.perf_counter()
    if options is None:
        options = SequentialOptions()
    elif isinstance(options, AdjustmentOptions):
        options = SequentialOptions.from_adjustment_options(options)
    project = distortion_free(project)
    sol = _triangulate_explained(project, options)
    return result_of(project, sol, time.perf_counter() - t0)


def _triangulate_explained(project: Project, options: SequentialOptions) -> SequentialSolution:
    """triangulate_strip, with the likely cause (striptri.core.diagnosis) added to a failure's message."""
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return triangulate_strip(project, options)
    except (NumericalFailure, np.linalg.LinAlgError) as exc:
        with np.errstate(all="ignore"):
            causes = diagnosis.likely_causes(project, "iteration")
        text, reason = (str(exc), exc.reason) if isinstance(exc, NumericalFailure) else (
            f"the sequential triangulation met a singular system of equations ({exc})", "singular")
        if not causes:
            raise NumericalFailure(text, reason) from exc
        raise NumericalFailure(text + "\n" + termination.causes_text(causes), reason) from exc


def sequential_approximations(project: Project, options: SequentialOptions | None = None) -> Project:
    """The project with the approximate orientations replaced by the sequential result (free centres
    and all rotations; observed and fixed elements keep their values, parameters.with_state)."""
    sol = _triangulate_explained(project, options or SequentialOptions())
    state = State(R_ground_from_cam=sol.R_ground, xyz0=sol.xyz0_ground, interior=project.cameras.interior.copy(), convention=project.cameras.convention.copy(),
                  camera_of_photo=project.photos.camera_index.copy())
    return with_state(project, state, sol.offset)


def _reprojection(project: Project, sol: SequentialSolution) -> np.ndarray:
    ip = project.image_points
    interior = project.cameras.interior[project.photos.camera_index, :3]
    X = sol.xyz_ground[ip.point_index]
    ok = np.isfinite(X).all(1)
    v = np.zeros_like(ip.xy)
    ph = ip.photo_index[ok]
    v[ok] = project_plate(sol.R_ground[ph], sol.xyz0_ground[ph], interior[ph], X[ok]) - ip.xy[ok]
    return v


def _conditional_normal_matrix(project: Project, sol: SequentialSolution, layout, state: State) -> sp.csr_matrix:
    """Block-diagonal N (module doc): per photo B^T P B of collinearity with its points held."""
    ip = project.image_points
    interior = project.cameras.interior[project.photos.camera_index, :3]
    X = sol.xyz_ground[ip.point_index]
    ok = np.isfinite(X).all(1)
    T = layout.rotation_maps(state)
    rows, cols, vals = [], [], []
    for j in range(len(project.photos)):
        sel = np.flatnonzero(ok & (ip.photo_index == j))
        if len(sel) == 0:
            continue
        k = len(sel)
        lc = collinearity(ip.xy[sel][:, None], np.broadcast_to(sol.R_ground[j], (k, 1, 3, 3)),
                          np.broadcast_to(sol.xyz0_ground[j], (k, 1, 3)), np.broadcast_to(interior[j], (k, 1, 3)),
                          X[sel])
        B = np.concatenate([lc.d_centre[:, :, 0], lc.d_rot[:, :, 0] @ T[j]], 2).reshape(2 * k, 6)
        Nj = B.T @ weights.weigh(B, ip.sigma_xy[sel].reshape(2 * k)[:, None])
        c = layout.photo_cols[j]
        keep = c >= 0
        cc = c[keep]
        rows.append(np.repeat(cc, len(cc)))
        cols.append(np.tile(cc, len(cc)))
        vals.append(Nj[np.ix_(keep, keep)].ravel())
    cam = layout.camera_cols[layout.camera_cols >= 0]
    rows.append(cam), cols.append(cam), vals.append(np.ones(len(cam)))
    nu = layout.n_unknowns
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nu, nu))


def result_of(project: Project, sol: SequentialSolution, seconds: float = 0.0) -> AdjustmentResult:
    layout = build_layout(project)
    state = State(R_ground_from_cam=sol.R_ground, xyz0=sol.xyz0_ground, interior=project.cameras.interior.copy(), convention=project.cameras.convention.copy(),
                  camera_of_photo=project.photos.camera_index.copy())
    obs = observations_of(project, sol.offset)
    n_pobs = len(build_parameter_observations(project, sol.offset))
    v = _reprojection(project, sol)
    all_steps = list(sol.steps) + list(sol.relative_steps) + list(sol.resections)
    redundancy, vtpv = sol.redundancy, sol.vtpv
    res = sol.control_residuals
    scale_res = np.concatenate([r for r in sol.scale_residuals if len(r)] or [np.zeros((0, 3))]) * sol.similarity.scale

    def rms(a):
        a = a[np.isfinite(a)]
        return float(np.sqrt(np.mean(a * a))) if len(a) else float("nan")

    checks = SequentialChecks(
        absolute_orientation_rms_X_m=rms(res[:, 0]),
        absolute_orientation_rms_Y_m=rms(res[:, 1]),
        absolute_orientation_rms_Z_m=rms(res[:, 2]),
        absolute_orientation_redundancy=float(np.isfinite(res).sum() - 7),
        scale_transfer_rms_m=rms(scale_res),
        reprojection_rms_plate=rms(v),
        procedure=float(sol.options.procedure),
        backward=float(sol.options.direction == "backward"),
    )
    history = [Iteration(vtpv=s.vtpv, max_correction=s.max_correction, seconds=0.0) for s in sol.steps]
    status, message = _termination(project, sol)
    return AdjustmentResult.of(
        project, obs, plate_adjusted=project.image_points.xy + v, control_adjusted=obs.control.copy(), vtpv=vtpv,
        redundancy=redundancy, history=history, layout=layout,
        iterations=int(sum(s.iterations for s in all_steps) + sol.similarity_iterations),
        method="sequential", solver="sequential", state=state, offset=sol.offset,
        n_conditions=int(sum(s.n_conditions for s in sol.steps)), n_observations=2 * len(project.image_points),
        n_parameter_observations=n_pobs, parameter_residuals=np.zeros(n_pobs),
        N=_conditional_normal_matrix(project, sol, layout, state), checks=checks, timings=Timings(total=seconds),
        termination=status, termination_message=message,
    )


SHRINKING = ("Its corrections were still shrinking: raise [adjustment] max_iterations in project.toml (each step of "
             "the sequential method may take max(30, max_iterations) iterations).")


def _termination(project: Project, sol: SequentialSolution) -> tuple[str, str]:
    """("converged", "") when every step converged, else ("iteration_limit", message) for the first
    step that did not: the photo, its last iterations, the trend and the likely cause."""
    ids = project.photos.ids
    order, opts = sol.order, sol.options
    labelled = []
    for s, step in enumerate(sol.steps):
        i, j = ids[order[s]], ids[order[s + 1]]
        kind = "relative orientation" if opts.procedure == 1 or s == 0 else "orientation (procedure 2)"
        labelled.append((f"the {kind} of photo {j} to photo {i}", step))
    labelled += [(f"the resection of photo {ids[j]} after the strip correction", rs) for j, rs in enumerate(sol.resections)]
    for label, step in labelled:
        if step.converged:
            continue
        head = (f"the sequential triangulation did not converge: {label} reached its limit of {step.iterations} "
                f"iterations while its largest correction was still {step.max_correction:.3g} sd (converged means "
                f"below {opts.tolerance:g} sd).")
        history = step.history or [Iteration(vtpv=step.vtpv, max_correction=step.max_correction, seconds=0.0)]
        state, _ = termination.trend(history)
        with np.errstate(all="ignore"):
            causes = diagnosis.likely_causes(project, "iteration")
        if state == "shrinking" and not causes:
            return "iteration_limit", "\n".join([head, termination.table(history, step.redundancy), SHRINKING])
        meaning = ("Its corrections were still shrinking, but:" if state == "shrinking" else
                   "Its corrections no longer shrink: the step is not approaching a solution.")
        return "iteration_limit", "\n".join([head, termination.table(history, step.redundancy), meaning,
                                               termination.causes_text(causes)])
    if not sol.similarity_converged:
        return "iteration_limit", (
            f"the sequential triangulation did not converge: the absolute orientation of the strip (a 3D similarity "
            f"to the control) reached its limit of {sol.similarity_iterations} iterations. "
            + termination.causes_text(diagnosis.likely_causes(project, "iteration"),
                                      "Likely cause: control that hardly fixes the similarity (nearly on a line) or "
                                      "a gross error in the control coordinates."))
    return "converged", ""

