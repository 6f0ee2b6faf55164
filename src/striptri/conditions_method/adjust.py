"""Schmid's simultaneous adjustment by condition equations (DESIGN section 4).

General case of least squares (Helmert), linearised at the adjusted observations (Pope 1972):
``A v + B dx + w = 0`` per group, ``N = sum B^T M^-1 B``, ``u = sum B^T M^-1 w``, ``N dx = -u``,
``k = -M^-1 (w + B dx)``, ``v = Q A^T k``; then ``x^ <- x^ (+) dx``, ``l^ <- l + v``, repeated.
The first linearisation is at observations where the conditions hold (:func:`consistent_start`:
the measurements moved onto the rays of the points intersected at the approximations), not at the
measurements themselves: from rough approximations that first step is the bundle method's
Gauss-Newton step (docs/decisions.md "A consistent first linearisation").

Convergence: core.convergence (``sqrt(dx^T N dx) < tolerance``, the largest correction of any
function of the unknowns in units of its standard deviation).

Each iteration linearises its conditions once, chunk by chunk: the assembly whitens each chunk,
sums it into N and u and keeps the whitened chunk for the back substitution after the solve. Near
the solution the iterations solve on the factor of an earlier N and form u alone (chord steps,
:func:`_iteration`); the final checks form N at the solution.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ..equations import datum, point_datum
from ..core import diagnosis, termination
from .. import progress, solvers
from ..core.convergence import (ROUNDING_FLOOR, chord_correction, correction_in_sigma, energy_floor, has_converged,
                                keeps_factor, largest_correction, round_off_floor, stop_if_diverging)
from ..core.explain import (datum_defect_failure, not_finite_message, reduction_check, singular_message,
                            solve_or_explain, solver_for)
from ..equations.observations import Observations, observations_of
from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult, Checks, Iteration, SolutionSystems, Timings, observation_count
from ..errors import NumericalFailure
from ..precision import collinearity_form
from ..equations.groups import build_batches
from ..equations.joint_groups import JointGroups, whiten_joint
from ..equations.linearise import PRECISION_CHUNK, At, Sweep
from ..model import Project
from ..equations.triangulation import GivenCoordinates, RayObservations, triangulate
from ..equations.block_pattern import BlockPattern, selection_matrix
from ..equations.normal_equations import (NormalAccumulator, PatternAccumulator, group_misclosures, group_products,
                                         sums_camera_columns, whiten)
from ..equations.parameter_observations import ParameterObservations, build_parameter_observations
from ..equations.parameters import State, UnknownLayout, build_layout, initial_state, reduction_offset
from ..equations import weights
from ..solvers.memory import SMALL_RUN_MEASUREMENTS, give_back_free_memory, keeps_freed_memory

METHOD = "conditions"
# From this many plate measurements on, free memory is handed back to the system before and after
# every assembly (solvers.memory.give_back_free_memory): it keeps the products of the chunks out of
# the factorisation's peak (5,000 photos: 393 MB against 414 MB without). Below, the peak is not at
# stake and the trims cost more than they give back: each sweep gets the pages it handed back anew,
# zeroed (close range, 10,022 measurements of 66-ray tracks, whose ray pairs make 190 MB of products
# a sweep: the whole command 3.83 -> 3.44 s, medians of four, the same peak, 360 MB). Nor at any size
# in a process that keeps its freed pages (solvers.memory.keep_freed_memory, the command): there the
# trims cost a fifth of adjust() at 5,000 photos for 5-8 % of the peak (docs/decisions.md "Freed
# pages kept at every size").
TRIM_FROM = SMALL_RUN_MEASUREMENTS
# Gauss-Newton steps of the intersection behind consistent_start after the linear one: any point
# makes the conditions hold, but one step brings back 37 of 54 turned-photo starts of block_3x6
# against 31 without (docs/decisions.md "A consistent first linearisation")
START_ITERATIONS = 1


@dataclass
class _WhitenedChunk:
    """What the back substitution needs of one chunk, kept from the assembly of the same iteration
    (normal_equations.whiten): Bw = L^-1 B (m, nc, nu), ww = L^-1 w (m, nc), the columns (m, nu)
    and Gt = L^-1 A Q (m, nc, no), so that v = -Gt^T (ww + Bw dx). Kept at the solution for the
    residual cofactors (core.result.SolutionSystems): Bw, Gt and clear (m,), whether each group's
    M is clearly regular; nothing but the chunk for a chunk of long tracks (its Bw is dense)."""

    chunk: object
    Bw: np.ndarray | None
    ww: np.ndarray | None
    cols: np.ndarray | None
    Gt: np.ndarray | None
    clear: np.ndarray | None = None


def assemble_normals(sweep: Sweep, pobs: ParameterObservations, assembly: "Assembly", keep: bool | str = False,
                     normals: bool = True):
    """N and u of one sweep: point groups into the block pattern, then the observed elements.
    keep: also keep each chunk's whitened system (acc.kept, _WhitenedChunk) for the back
    substitution (True), so that an iteration linearises its conditions once, or for the residual
    cofactors at the solution ("solution"; not for the joint groups: acc.kept_joint). normals: False forms u, w^T P w and the misclosures
    but not N (acc.N None; a chord step). acc.max_misclosure: the largest |g| of a condition in
    units of its standard deviation (Schmid's final check)."""
    acc = PatternAccumulator(assembly.pattern, assembly.S, normals)
    acc.kept = [] if keep else None
    acc.max_misclosure = 0.0
    cam_of_photo = sweep.state.camera_of_photo

    def products(chunk, system, scatters):  # in the chunk's thread: whitened, its products for N and u
        white = whiten(system, residual_map=bool(keep), regularity=keep == "solution")
        kept = None
        if keep == "solution":
            kept = (_WhitenedChunk(chunk, None, None, None, None) if white.by_ray is not None
                    else _WhitenedChunk(chunk, white.Bw, None, None, white.Gt, white.clear))
        elif keep:
            kept = _WhitenedChunk(chunk, white.Bw, white.ww, system.cols, white.Gt)
        photo = chunk.photo_index
        if not normals:  # a chord step: u alone
            return kept, group_misclosures(assembly.pattern, white.Bw, white.ww, white.gw, photo, cam_of_photo[photo])
        return kept, group_products(assembly.pattern, white.Bw, white.ww, white.gw, photo, cam_of_photo[photo], white,
                                    scatters)

    for (chunk, system, (kept, made)), scatters in zip(sweep.systems(products, assembly.scatters),
                                                       assembly.scatters, strict=True):
        if keep:
            acc.kept.append(kept)
        acc.add_products(made, scatters)
        if system.g.size:
            acc.max_misclosure = max(acc.max_misclosure, float(np.max(np.abs(system.g))))
    acc.kept_joint = [] if keep else None
    for js in sweep.joint_systems():  # the groups joined by distances (joint_groups), one at a time
        Bw, ww, gw, Gt = whiten_joint(js)
        acc.extra.add(Bw[None], ww[None], js.cols[None], gw[None])
        if keep:
            acc.kept_joint.append((js, Bw, ww, Gt))
        acc.max_misclosure = max(acc.max_misclosure, float(np.max(np.abs(js.g), initial=0.0)))
    if len(pobs):
        f, grad, cols = pobs.evaluate(sweep.state, sweep.layout, sweep.T)
        acc.add_rows(grad, cols, pobs.misclosure(f), pobs.sigma)
    return acc.finish()


def _assemble_checked(sweep: Sweep, pobs: ParameterObservations, assembly: "Assembly", project: Project,
                      iteration: int, keep: bool | str = False, normals: bool = True):
    """assemble_normals, with numbers that are not finite (an overflow: wild values, c in another unit)
    explained as a NumericalFailure naming the points whose conditions fail and the likely cause."""
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            acc = assemble_normals(sweep, pobs, assembly, keep, normals)
    except np.linalg.LinAlgError:
        acc = None
    if (acc is not None and np.isfinite(acc.u).all() and (acc.N is None or np.isfinite(acc.N.data).all())
            and np.isfinite(acc.wPw)):
        return acc
    raise NumericalFailure(not_finite_message(project, _non_finite_points(sweep), iteration), reason="not_finite")


def _non_finite_points(sweep: Sweep) -> np.ndarray:
    """Indices of the points whose linearised conditions are not finite or whose M = A Q A^T is not
    positive definite (after a failed assembly; one more sweep)."""
    bad = []
    with np.errstate(all="ignore"):
        for chunk, system in sweep.systems():
            M = np.einsum("mco,mo,mdo->mcd", system.A, system.Q, system.A)
            ok = (np.isfinite(system.B).all(axis=(1, 2)) & np.isfinite(system.w).all(axis=1)
                  & np.isfinite(M).all(axis=(1, 2)))
            ok[ok] &= np.all(np.linalg.eigvalsh(M[ok]) > 0, axis=1)
            bad.append(chunk.point_index[~ok])
    return np.concatenate(bad) if bad else np.zeros(0, dtype=int)


@dataclass(frozen=True)
class Assembly:
    """What the assembly computes once per adjustment: the block pattern of N, the selection S,
    and each chunk's scatters (block_pattern.ChunkScatter; camera-summed for the chunks of long
    one-camera tracks, normal_equations.sums_camera_columns), in the order Sweep.systems yields
    the chunks."""

    pattern: BlockPattern
    S: sp.csr_matrix
    scatters: list

    @staticmethod
    def of(batches, state: State, layout: UnknownLayout, chunk_size: int) -> "Assembly":
        chunks = [
            (c.photo_index, state.camera_of_photo[c.photo_index]) for b in batches for c in b.chunks(chunk_size)
        ]
        pattern = BlockPattern(len(state.xyz0), len(state.interior), bool((layout.camera_cols >= 0).any()), chunks,
                               layout.camera_elements)
        scatters = [pattern.scatters(photo, cam, sums_camera_columns(pattern, cam)) for photo, cam in chunks]
        S = selection_matrix(layout.photo_cols, layout.camera_cols, layout.n_unknowns)
        pattern.reduction(S)
        return Assembly(pattern, S, scatters)


def _back_substitute(kept: list[_WhitenedChunk], sweep: Sweep, pobs: ParameterObservations, dx: np.ndarray,
                     obs: Observations, kept_joint=None):
    """New adjusted observations l + v from the corrections dx, with the whitened systems the
    assembly kept: ``t = L^-1 (w + B dx)``, ``k = -L^-T t``, ``v = Q A^T k = -(L^-1 A Q)^T t`` and
    ``v^T P v = k^T M k = t^T t``. kept_joint: the joint groups' (joint_groups.JointSystem, L^-1 B,
    L^-1 w, L^-1 A Q). Returns plate_hat, control_hat, v_par, vtpv and the adjusted distances
    (None without)."""
    plate_hat = obs.plate.copy()
    control_hat = obs.control.copy()
    dxp = np.concatenate([dx, [0.0]])
    vtpv = 0.0
    for white in kept:
        t = white.ww + np.matmul(white.Bw, dxp[white.cols][..., None])[..., 0]
        v = -np.matmul(np.swapaxes(white.Gt, 1, 2), t[..., None])[..., 0]
        vtpv += float(np.sum(t * t))
        chunk = white.chunk
        m, kk = chunk.image_rows.shape
        plate_hat[chunk.image_rows] = obs.plate[chunk.image_rows] + v[:, : 2 * kk].reshape(m, kk, 2)
        if chunk.has_control:
            control_hat[chunk.point_index] = obs.control[chunk.point_index] + v[:, 2 * kk :]
    distance_hat = None
    if kept_joint:
        distance_hat = sweep.joint.project.distances.distance.copy()
        plate_flat, control_flat = plate_hat.reshape(-1), control_hat.reshape(-1)
        for js, Bw, ww, Gt in kept_joint:
            t = ww + Bw @ dxp[js.cols]
            v = -Gt.T @ t
            vtpv += float(t @ t)
            plate_flat[js.plate_target] = obs.plate.reshape(-1)[js.plate_target] + v[js.plate_pos]
            control_flat[js.control_target] = obs.control.reshape(-1)[js.control_target] + v[js.control_pos]
            distance_hat[js.component.distances] = js.l[js.distance_pos] + v[js.distance_pos]
    v_par = np.zeros(len(pobs))
    if len(pobs):
        f, grad, cols = pobs.evaluate(sweep.state, sweep.layout, sweep.T)
        v_par = -(pobs.misclosure(f) - np.einsum("pi,pi->p", grad, dxp[cols]))
        vtpv += float(np.sum(weights.whiten(v_par, pobs.sigma) ** 2))
    return plate_hat, control_hat, v_par, vtpv, distance_hat


def _solve_free_network(acc, solver: solvers.NormalSolver, fn: datum.FreeNetwork) -> solvers.SolveResult:
    """Minimum constraints, then the S-transformation onto the inner constraints (datum.FreeNetwork,
    with its right-hand side)."""
    dx, solved = fn.solve(solver, acc.N, -acc.u)
    return solvers.SolveResult(dx, solved.solver, solved.info)


def _solve_or_explain(acc: NormalAccumulator, solver: solvers.NormalSolver, state: State, problem: "_Problem",
                      diagnose: bool = True) -> solvers.SolveResult:
    """Solve N dx = -u (core.explain.solve_or_explain); a free network (problem.free_network) by
    minimum constraints and the S-transformation onto its inner constraints, a singular one explained."""
    project, layout, free_network = problem.project, problem.layout, problem.free_network
    if free_network is None:
        return solve_or_explain(acc, -acc.u, solver, state, problem, diagnose=diagnose)
    try:
        return _solve_free_network(acc, solver, free_network)
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:
        raise NumericalFailure(singular_message(
            project, layout, getattr(exc, "column", None),
            "the free network's normal equations are singular beyond the datum", datum_fixed=False),
            reason="singular") from exc


class _Problem:
    """Everything fixed during the adjustment: the reduced frame, the unknowns' layout, the point
    groups and observations, the pattern of N, the redundancy, and the free network's inner
    constraints when the datum is "inner" (on the photos) or "inner-points" (on object points:
    ``point_datum``, the datum points and their approximations)."""

    def __init__(self, project: Project, options: AdjustmentOptions):
        self.project, self.options = project, options
        self.offset = reduction_offset(project)
        self.initial_state = initial_state(project, self.offset)
        self.layout = build_layout(project)
        # the points joined by distances leave their batches for joint groups (joint_groups)
        self.batches, self.joint = JointGroups.of(project, build_batches(project))
        self.obs = observations_of(project, self.offset)
        self.pobs = build_parameter_observations(project, self.offset)
        self.n_conditions = sum(len(b) * b.n_conditions for b in self.batches)
        if self.joint is not None:
            self.n_conditions += self.joint.n_conditions
        self.assembly = Assembly.of(self.batches, self.initial_state, self.layout, options.chunk_size)
        if options.conditions.scale_form == "xz":
            _require_strip_along_x(self.batches, self.initial_state)
        self.free_network = self._free_network() if options.datum != "control" else None
        self.point_datum = None
        if self.free_network is not None and options.datum == "inner-points":
            # every point group, the points joined by distances (the joint groups' members) too
            every = self.batches + (self.joint.member_batches if self.joint is not None else [])
            self.point_datum = point_datum.PointDatum.of(project, options.datum_points, every,
                                                         self.initial_state, self.obs, self.offset)
            point_datum.check_directions(self.point_datum, self.free_network, self.initial_state)
        n_datum = 0 if self.free_network is None else len(self.free_network)
        self.redundancy = self.n_conditions + len(self.pobs) - self.layout.n_unknowns + n_datum
        if self.redundancy < 0:
            self._explain_too_few()

    def sweep(self, state: State, plate_hat: np.ndarray, control_hat: np.ndarray, distance_hat=None) -> Sweep:
        return Sweep(self.batches, At.of(state, self.layout, self.obs, plate_hat, control_hat), self.options,
                     self.joint, distance_hat)

    def assemble(self, sweep: Sweep, iteration: int, keep: bool | str = False, normals: bool = True):
        trim = len(self.obs.plate) >= TRIM_FROM and not keeps_freed_memory()
        if trim:
            give_back_free_memory()  # the last iteration's factor and kept chunks, freed
        acc = _assemble_checked(sweep, self.pobs, self.assembly, self.project, iteration, keep, normals)
        if trim:
            give_back_free_memory()  # the chunk threads' products, before the factorisation
        return acc

    def datum_at(self, state: State, N, plate_hat: np.ndarray, at_solution: bool = False):
        """The free network's constraints at ``state`` (N there; plate_hat: the adjusted plate
        coordinates, whose rays give the datum points), with the right-hand side that makes the
        datum independent of the iteration's path (datum.FreeNetwork.at, point_datum); at_solution:
        the point datum's inner constraints at the adjusted points (its precision)."""
        if self.point_datum is None:
            return self.free_network.at(state, self.layout, N, self.initial_state)
        xyz = self.point_datum.intersection(state, plate_hat, self.obs)
        return self.point_datum.free_network(self.free_network, state, self.layout, self.obs, xyz, at_solution)

    def _at_start(self):
        return self.assemble(self.sweep(self.initial_state, self.obs.plate, self.obs.control), 1)

    def _free_network(self):
        """The inner constraints on the directions the control leaves free (None: none are)."""
        acc = self._at_start()
        free = datum.free_directions(acc, self.initial_state, self.layout)
        return datum.FreeNetwork.of(free, acc.N) if len(free) else None

    def _explain_too_few(self):
        defects = datum.diagnose(self._at_start(), self.initial_state, self.layout, offset=self.offset)
        if defects:
            raise datum_defect_failure(self.project, defects)
        raise NumericalFailure(
            f"too few conditions: {self.n_conditions} condition equations and {len(self.pobs)} observed elements "
            f"for {self.layout.n_unknowns} unknowns. Add control or tie points, or fix elements."
        )


@dataclass
class _Estimate:
    """Where the iteration stands: the unknowns x^, the adjusted observations l^ and what the last
    back substitution gave (residuals of the observed elements, v^T P v)."""

    state: State
    plate_hat: np.ndarray
    control_hat: np.ndarray
    v_par: np.ndarray
    vtpv: float = float("nan")
    distance_hat: np.ndarray | None = None  # (r,) adjusted distances d + v_d (joint_groups); None without


def adjust_conditions(project: Project, options: AdjustmentOptions = AdjustmentOptions()) -> AdjustmentResult:
    """Adjust all photographs of the project simultaneously by Schmid's method of conditions
    (module doc), from the approximate values in the project. Returns the result whether it
    converged or stopped at its iteration limit (``termination``); raises NumericalFailure, with its
    reason, for a datum defect, a singular system, numbers that overflow or divergence."""
    t_start = time.perf_counter()
    problem = _Problem(project, options)
    # not told N's pattern ahead (solver_for): its analysis beside the first linearisation raised the
    # peak by 16-25 MiB, to 1.2x the peer's at 5,000 photos (docs/decisions.md "The analysis prepared")
    solver = solver_for(options, problem.layout, project)
    timings = Timings(conditions=0.0, assembly=0.0, solve=0.0, back_substitution=0.0)
    obs = problem.obs
    t0 = time.perf_counter()
    now = _Estimate(problem.initial_state, *consistent_start(project, problem.initial_state, problem.layout, obs),
                    np.zeros(len(problem.pobs)))
    timings.add("conditions", time.perf_counter() - t0)  # where the first linearisation is taken
    history: list[Iteration] = []
    converged = False
    # only after a failure; large residuals of a settled iteration are named when nothing in the input is
    causes = lambda: (diagnosis.likely_causes(project, "iteration")  # noqa: E731
                      or diagnosis.gross_residuals(project, history, problem.redundancy, now.plate_hat - obs.plate))
    no_unknowns = problem.layout.n_unknowns == 0
    factored = None  # the diagonal of the N whose factor the solver holds, for the next iteration's chord step
    # the converged iteration's factor serves the final checks, and each factor's memory the next one
    with solvers.holding_factor(solver):
        for _ in range(options.max_iterations):
            try:
                now, floor, n_diag = _iteration(problem, solver, now, history, timings, factored)
            except NumericalFailure as exc:  # N singular after regular ones: the iteration, not the datum
                if not history or exc.reason not in ("datum_defect", "singular"):
                    raise
                raise NumericalFailure(termination.became_singular(METHOD, history, problem.redundancy, causes),
                                       reason="diverged") from exc
            stop_if_diverging(history, METHOD, problem.redundancy, causes)
            if has_converged(history, options.tolerance, floor):
                converged = True
                break
            factored = (n_diag if problem.free_network is None and solver.holding() and keeps_factor(history, floor)
                        else None)
            if factored is None:
                solver.release()  # N moves too much for solve_again (its memory serves the next factor)
        if not converged:  # the next correction of a stopped iteration comes from N at the solution
            solver.release()

        t0 = time.perf_counter()
        final = problem.sweep(now.state, now.plate_hat, now.control_hat, now.distance_hat)
        # for the tests' residual cofactors by the conditions form, in chunks of the precision passes' size at most
        solution = (options.conditions.keep_solution_systems and problem.joint is None
                    and options.chunk_size <= PRECISION_CHUNK
                    and not collinearity_form.applies_to(project, METHOD, problem.layout.n_unknowns,
                                                         problem.free_network is not None))
        acc = problem.assemble(final, len(history) + 1, keep="solution" if solution else False)
        free_network = problem.free_network
        if free_network is not None:
            free_network = problem.datum_at(now.state, acc.N, now.plate_hat, at_solution=True)
        checks, next_correction = _final_checks(final, acc, now.vtpv, problem.pobs, now.v_par, free_network, solver)
        timings.final_checks = time.perf_counter() - t0
    timings.total = time.perf_counter() - t_start
    status, message = "converged", ""
    if not converged:
        status = "iteration_limit"
        message = termination.iteration_limit(METHOD, history, int(problem.redundancy), options.max_iterations,
                                              options.tolerance, None if no_unknowns else next_correction, causes)
    return AdjustmentResult.of(
        project, obs, plate_adjusted=now.plate_hat, control_adjusted=now.control_hat, vtpv=now.vtpv,
        redundancy=problem.redundancy, history=history, layout=problem.layout, method=METHOD, solver=solver.name,
        state=now.state, offset=problem.offset, n_conditions=int(problem.n_conditions),
        n_observations=observation_count(project, obs, len(problem.pobs)),
        n_parameter_observations=len(problem.pobs), parameter_residuals=now.v_par, N=acc.N, checks=checks,
        timings=timings, free_network=free_network, termination=status, termination_message=message,
        solution_systems=SolutionSystems(project, acc.kept) if solution else None,
    )


def consistent_start(project: Project, state: State, layout: UnknownLayout, obs: Observations):
    """The adjusted observations l^ of the first linearisation: the plate coordinates and the
    weighted control coordinates moved onto the rays of each point intersected at the approximate
    orientation (triangulation.triangulate, orientation held), so that the conditions hold there
    exactly and the first misclosure is ``A (l - l^)``. Points that the approximations do not
    determine (or only weakly) keep l^ = l. -> (plate_hat (m_ip, 2), control_hat (n_pt, 3))."""
    plate_hat, control_hat = obs.plate.copy(), obs.control.copy()
    ip = project.image_points
    if len(ip) == 0 or not (np.isfinite(state.xyz0).all() and np.isfinite(state.R_ground_from_cam).all()):
        return plate_hat, control_hat
    given = project.points.given_axes
    with np.errstate(all="ignore"):
        tri = triangulate(RayObservations(ip.photo_index, ip.point_index, obs.plate, ip.sigma_xy),
                          GivenCoordinates(obs.control, given, obs.q_control), state=state, layout=layout,
                          iterations=START_ITERATIONS, with_residuals=True)
    good = ~tri.undetermined & np.isfinite(tri.xyz).all(axis=1)  # determined, and not weakly
    moved = good[ip.point_index] & np.isfinite(tri.residuals).all(axis=1)
    plate_hat[moved] -= tri.residuals[moved]
    weighted = given & (obs.q_control > 0) & good[:, None]
    control_hat[weighted] = tri.xyz[weighted]
    return plate_hat, control_hat


def _iteration(problem: _Problem, solver, now: _Estimate, history: list[Iteration], timings: Timings,
               factored=None):
    """One iteration from ``now``: assemble N and u (keeping the whitened chunks), solve, back-
    substitute and update; appends to ``history`` and ``timings``. Returns the new estimate, the
    round-off floor of its correction (core.convergence.energy_floor) and the diagonal of the N it
    solved with.

    factored: the diagonal of an earlier iteration's N whose factor the solver holds (None: none
    may serve). Then this iteration is a chord step: it forms u alone and solves ``dx = -F^-1 u``
    on that factor. Near the solution N moves by terms of the size of the last correction, so the
    step differs from Gauss-Newton's by that fraction of itself, and the iteration converges to the
    same solution: where u vanishes (docs/decisions.md "Chord steps on the last factor"). Its
    correction in the measure of that N, ``sqrt(dx^T N dx)``, is ``sqrt(-dx^T u)``: N itself is not
    kept."""
    t0 = time.perf_counter()
    state, layout = now.state, problem.layout
    sweep = problem.sweep(state, now.plate_hat, now.control_hat, now.distance_hat)
    acc = problem.assemble(sweep, len(history) + 1, keep=True, normals=factored is None)
    t1 = time.perf_counter()
    if factored is not None:
        solved = solvers.SolveResult(solver.solve_again(-acc.u), solver.name, solvers.SolverInfo(held_factor=True))
    else:
        if problem.free_network is not None:
            problem.free_network = problem.datum_at(state, acc.N, now.plate_hat)
        solved = _solve_or_explain(acc, solver, state, problem, diagnose=not history)
    dx = solved.dx
    t2 = time.perf_counter()
    with np.errstate(over="ignore", invalid="ignore"):
        plate_hat, control_hat, v_par, vtpv, distance_hat = _back_substitute(acc.kept, sweep, problem.pobs, dx,
                                                                             problem.obs, acc.kept_joint)
    acc.kept = acc.kept_joint = None  # the whitened systems are not needed beyond the back substitution
    state = state.updated(layout, dx)
    t3 = time.perf_counter()
    timings.add("conditions", sweep.seconds)
    timings.add("assembly", t1 - t0 - sweep.seconds)
    timings.add("solve", t2 - t1)
    timings.add("back_substitution", t3 - t2)
    n_diag = factored if factored is not None else acc.N.diagonal()
    if len(dx):
        crit = correction_in_sigma(dx, acc.N) if factored is None else chord_correction(dx, acc.u)
        if problem.free_network is not None:  # the datum's move, which N does not see (datum.FreeNetwork)
            crit = float(np.hypot(crit, problem.free_network.datum_correction(n_diag)))
        element_floor = round_off_floor(state, layout)
        floor = energy_floor(layout.n_unknowns, element_floor, n_diag)
        element = largest_correction(dx, n_diag, element_floor)
    else:  # no unknowns (every element held): the iteration is over the adjusted observations alone
        crit = element = _observation_change(plate_hat - now.plate_hat, control_hat - now.control_hat, problem.obs,
                                             _distance_change(now.distance_hat, distance_hat, problem.project))
        floor = ROUNDING_FLOOR
    history.append(Iteration(vtpv=vtpv, max_correction=crit, seconds=t3 - t0, solver_info=solved.info,
                             element_correction=element))
    progress.iteration(METHOD, len(history), vtpv, crit, t3 - t0, solved.info)
    return _Estimate(state, plate_hat, control_hat, v_par, vtpv, distance_hat), floor, n_diag


def _distance_change(before, after, project: Project) -> float:
    """The largest change of an adjusted distance in units of its sigma (0 without distances)."""
    if after is None:
        return 0.0
    before = project.distances.distance if before is None else before
    return float(np.max(np.abs(after - before) / project.distances.sigma, initial=0.0))


def _observation_change(d_plate: np.ndarray, d_control: np.ndarray, obs: Observations, d_distance: float = 0.0) -> float:
    """The largest change of an adjusted observation in one iteration, in units of its standard
    deviation: the convergence criterion when there are no unknowns (a pure forward intersection,
    where only the adjusted observations l^ = l + v are iterated)."""
    sig = np.sqrt(obs.q_plate)
    c = np.max(np.abs(d_plate) / np.where(sig > 0, sig, np.inf), initial=0.0)
    qc = obs.q_control
    c_control = np.max(np.abs(d_control) / np.where(qc > 0, np.sqrt(np.where(qc > 0, qc, 1.0)), np.inf), initial=0.0)
    return float(max(c, c_control, d_distance))


def normal_matrix_at_approximations(project: Project, options: AdjustmentOptions = AdjustmentOptions()):
    """N of the first iteration (at the approximate values) and the layout: enough to show the
    structure of the normal equations of any project without adjusting it. A project without
    unknowns gives a 0 x 0 N; numbers that overflow are a NumericalFailure (as in adjust)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        offset = reduction_offset(project)
        state, layout = initial_state(project, offset), build_layout(project)
        batches, joint = JointGroups.of(project, build_batches(project))
        obs = observations_of(project, offset)
        assembly = Assembly.of(batches, state, layout, options.chunk_size)
        sweep = Sweep(batches, At.of(state, layout, obs, obs.plate, obs.control), options, joint)
        acc = _assemble_checked(sweep, build_parameter_observations(project, offset), assembly, project, 1)
    return acc.N, layout


def _require_strip_along_x(batches, state: State, max_angle_deg: float = 30.0) -> None:
    """Schmid's projected scale condition (94) intersects the rays in their XZ projection, which is
    well conditioned only when the bases run along X. Refuse it otherwise rather than return a
    weak or wrong adjustment."""
    worst = 0.0
    for batch in batches:
        if batch.k < 3:
            continue
        b = np.diff(state.xyz0[batch.photo_index], axis=1)  # consecutive bases of every chain
        horiz = np.linalg.norm(b[..., :2], axis=-1)
        angle = np.degrees(np.arccos(np.clip(np.abs(b[..., 0]) / np.maximum(horiz, 1e-300), 0, 1)))
        worst = max(worst, float(angle.max(initial=0.0)))
    if worst > max_angle_deg:
        raise NumericalFailure(
            f"Schmid's projected scale condition (94, --scale-form xz) is unsuitable for these photos: "
            f"some bases make {worst:.0f} deg with the X axis (at most {max_angle_deg:.0f} deg allowed), and the "
            "XZ projection of their rays degenerates for a strip not flown along X. Use the "
            "direction-free form (--scale-form 3d, the default)."
        )


def _final_checks(sweep: Sweep, acc: NormalAccumulator, vtpv: float, pobs, v_par: np.ndarray,
                  free_network=None, solver: solvers.NormalSolver | None = None) -> tuple[Checks, float | None]:
    """Schmid's checks after convergence.

    * every condition holds for the adjusted observations and the final unknowns (his final
      check): the largest misclosure g(l^, x^), in units of its standard deviation;
    * (58) B^T k = 0: at the solution the right-hand side u of the normal equations vanishes;
      reported as max |u_i| / sqrt(N_ii);
    * (59) v^T P v equals [LL.u], the reduced sum w^T M^-1 w - u^T N^-1 u formed in the
      reduction of the normal equations; reported as the relative difference.

    Also returns the largest correction (in standard deviations, as in the history) the next
    iteration would make, a by-product of (59) (None when N is singular): whether an iteration that
    stopped at max_iterations was still converging. After a converged iteration whose factor the
    solver holds (``solver.solve_again``), that factor solves: N at the solution differs from the
    converged iteration's by terms of the size of its last correction, and u is of that size
    itself, so u'dx and the next correction change in their second order only (docs/decisions.md
    "The final checks on the last factor"). Otherwise the adjustment's own solver solves when it
    is a direct one (its analysis of the pattern is reused), else ``auto``: a direct one, or
    ``strip-pcg`` where a direct factor would not fit in memory (docs/solvers.md).
    """
    max_g = acc.max_misclosure  # formed with N in the same sweep (assemble_normals)
    if len(pobs):
        f, _, _ = pobs.evaluate(sweep.state, sweep.layout, sweep.T)
        max_g = max(max_g, float(np.max(np.abs((pobs.misclosure(f) + v_par) / pobs.sigma))))
    d = acc.N.diagonal()
    btk = float(np.max(np.abs(acc.u) / np.sqrt(np.where(d > 0, d, 1.0)))) if len(d) else 0.0
    next_correction = None
    try:
        direct = solver
        if solver is None or solver.iterative:  # auto: a direct factor unless it would not fit in memory
            direct = solvers.make_solver(solvers.SolverOptions(name="auto"), solver.structure if solver else
                                         solvers.Structure(len(d), sweep.layout.block_starts()))
        again = None if solver is None or free_network is not None else solver.solve_again(acc.u)
        if again is not None:
            dx = again
        elif free_network is None:
            dx = direct.solve(acc.N, acc.u).dx
        else:
            dx = -_solve_free_network(acc, direct, replace(free_network, target=None)).dx
        reduced = acc.wPw - float(acc.u @ dx)
        next_correction = correction_in_sigma(dx, acc.N)
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError):
        reduced = float("nan")
    return Checks(max_condition_misclosure_sigma=max_g, max_BTk_sigma=btk,
                  vtpv_reduction_relative_difference=reduction_check(reduced, vtpv)), next_correction
