"""The collinearity bundle adjustment with the object points as unknowns (DESIGN sections 4, 5),
the independent check of Schmid's method of conditions.

Gauss-Newton on the whitened observation equations: plate coordinates by collinearity (Schmid 14),
weighted control coordinates, and the observations of orientation elements (GNSS, IMU, camera,
base components: parameter_observations). The orientation unknowns, their columns and their
update are those of the method of conditions (parameters.build_layout / State.updated), so the
two results compare element by element. Each iteration:

1. per chunk of points: linearise, eliminate the points (Schur complement) into the reduced
   camera system ``N_rcs dx = b_rcs`` (bundle.reduced);
2. diagnose the datum on N_rcs and solve with the solver object (solvers.make_solver);
3. per chunk again: back-substitute the point corrections, x^ <- x^ (+) dx, X^ <- X^ + dX.

Convergence: as in the method of conditions, ``sqrt(d^T N d) < tolerance`` (core.convergence.correction_in_sigma)
for the whole step d = (dx, dX) of orientations and points, the norm of the change ``J d`` of the
whitened residuals it makes: the largest correction of any function of the orientations and points
in units of its standard deviation.

At convergence both methods minimise the same v^T P v over the same observations, so the
orientations, residuals, v^T P v, redundancy and N^-1 agree: the reduced camera system is the
normal matrix of the conditions method (its conditions span the orthogonal complement of the
points' Jacobian).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..equations import datum, point_datum
from ..core import diagnosis, termination
from .. import progress, solvers
from ..core.convergence import (energy_floor, has_converged, keeps_factor, largest_correction, round_off_floor,
                                stop_if_diverging)
from ..core.explain import (bundle_not_formed_message, datum_defect_failure, singular_message, solve_or_explain,
                            solver_for)
from ..equations.observations import Observations, observations_of
from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult, Iteration, Timings, observation_count
from ..errors import NumericalFailure
from ..equations.groups import GroupBatch, build_batches, sweep_size
from ..model import Project
from ..parallel import map_ordered
from ..solvers.threads import chunk_threads
from ..equations.parameter_observations import ParameterObservations, build_parameter_observations
from ..equations.parameters import State, UnknownLayout, build_layout, initial_state, reduction_offset
from .points import PointUnknowns, initial_points, point_unknowns
from .dense import DenseSchur, dense_scatters
from .checks import final_checks
from .distances import couple, distance_cost, locate_points
from .padding import pad_batches, real_rays
from .damping import COST_ROUND_OFF, LM_MAX, ROUND_OFF, Damping
from .reduced import ReducedNormals, block_pattern, linearise_points, point_corrections, residual_sum_of_squares

METHOD = "bundle"


@dataclass
class BundleSolution:
    """The adjustment result and what only the bundle has: the adjusted object points
    ``xyz_points`` (n_pt, 3), reduced frame (add ``result.offset``), nan for points that take no
    part; ``n_point_unknowns``, the coordinates among the unknowns."""

    result: AdjustmentResult
    xyz_points: np.ndarray
    n_point_unknowns: int
    # residuals (r,) m of the distances (bundle.distances): adjusted minus observed; empty without
    distance_residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))


def adjust_bundle(project: Project, options: AdjustmentOptions = AdjustmentOptions()) -> AdjustmentResult:
    """Adjust all photographs and object points simultaneously by collinearity (method "bundle").

    Same options and result type as the other methods (striptri.core); of the per-method options
    it reads ``options.bundle``. Raises NumericalFailure (datum defect, too few
    observations, divergence) like the method of conditions.
    """
    return solve_bundle(project, options).result


class _Problem:
    """Everything fixed during the adjustment."""

    free_network: datum.FreeNetwork | None = None  # a free network: the datum's constraints (set_datum)
    network: datum.FreeNetwork | None = None  # the constraints of the last solve
    point_datum: point_datum.PointDatum | None = None  # "inner-points": the datum points

    def __init__(self, project: Project, options: AdjustmentOptions):
        self.project, self.options = project, options
        self.offset = reduction_offset(project)
        self.layout: UnknownLayout = build_layout(project)
        self.batches: list[GroupBatch] = build_batches(project, chains=False)  # one batch per shape, rays in photo order
        self.obs: Observations = observations_of(project, self.offset)
        self.pobs: ParameterObservations = build_parameter_observations(project, self.offset)
        self.unknowns: PointUnknowns = point_unknowns(project, self.batches, self.obs)
        n_plate = 2 * sum(len(b) * b.k for b in self.batches)
        # observation equations of the points minus their unknown coordinates: the number of
        # conditions of the method of conditions, 2k - (3 - d) per point
        self.n_conditions = n_plate + self.unknowns.n_control_observations - self.unknowns.n_unknowns
        # a rise of the sum of squares below this is round-off whatever its size relative to the sum:
        # (1e-10 sigma)^2 per observation (noise-free data: a free network's datum still moving)
        self.cost_floor = COST_ROUND_OFF * (n_plate + self.unknowns.n_control_observations)
        self.redundancy = self.n_conditions + len(self.pobs) - self.layout.n_unknowns
        self.initial_state = initial_state(project, self.offset)
        self.pattern, self.S, self.dense, self.scatters = block_pattern(self.batches, self.initial_state, self.layout,
                                                                        options.chunk_size)
        # the batches linearised: summed dense, small ones joined with rays of weight zero (bundle.padding)
        self.linearised: list[GroupBatch] = pad_batches(self.batches) if self.dense else self.batches
        if self.dense:  # where each chunk's numbers go in the dense sum, worked out once
            cam = self.initial_state.camera_of_photo
            self.scatters = dense_scatters(self.pattern, [(c.photo_index, cam[c.photo_index]) for b in self.linearised
                                                          for c in b.chunks(options.chunk_size)])
        self.n_points = sum(len(b) for b in self.batches)
        self.distances = project.distances if project.distances is not None and len(project.distances) else None
        if self.distances is not None:
            self.distance_points = np.unique(np.concatenate([self.distances.point_from, self.distances.point_to]))
            self.where = locate_points([c.point_index for b in self.linearised for c in b.chunks(options.chunk_size)],
                                       self.distance_points)
            if np.any(self.where[0] < 0):
                ids = [str(project.points.ids[p]) for p in self.distance_points[self.where[0] < 0]]
                raise NumericalFailure("distances.csv: the point(s) " + ", ".join(ids) + " take no part in the "
                                       "adjustment (a tie point needs two rays); their distances cannot be adjusted")
            self.redundancy += len(self.distances)
            self.n_conditions += len(self.distances)  # one condition per distance in the conditions form

    def set_datum(self, state: State, normals: ReducedNormals) -> None:
        """A free network (datum "inner" or "inner-points"): the directions the control leaves free
        at the start (datum.free_directions on the reduced camera system), the minimum constraints
        and, for the point datum, the datum points; the redundancy counts the defect."""
        if self.options.datum == "control":
            return
        free = datum.free_directions(normals, state, self.layout)
        if not len(free):
            return
        self.free_network = datum.FreeNetwork.of(free, normals.N)
        if self.options.datum == "inner-points":
            self.point_datum = point_datum.PointDatum.of(self.project, self.options.datum_points, self.batches,
                                                         self.initial_state, self.obs, self.offset)
            point_datum.check_directions(self.point_datum, self.free_network, self.initial_state)
        self.redundancy += len(free)

    def datum_at(self, state: State, xyz: np.ndarray, N, at_solution: bool = False,
                 exact: bool = True) -> datum.FreeNetwork:
        """The free network's constraints at (state, xyz), N the undamped reduced camera system
        there: on the photos (datum.FreeNetwork.at) or on the datum points (point_datum), each with
        the right-hand side that makes the datum independent of the iteration's path. exact: False
        for a damped step, whose N (its points' blocks damped) does not turn with the block as the
        datum's does: the photo datum's linear move (datum.FreeNetwork.at)."""
        if self.point_datum is None:
            return self.free_network.at(state, self.layout, N, self.initial_state, exact)
        return self.point_datum.free_network(self.free_network, state, self.layout, self.obs,
                                             xyz[self.point_datum.index], at_solution)

    def hold_point_datum(self, state: State, xyz: np.ndarray, dx: np.ndarray, step: "_Step") -> np.ndarray:
        """Move a step (dx and step.xyz, in place) along the free similarity directions so that the
        datum points meet their constraint ``sum H_p^T (X_p + dX_p - X0_p) = 0`` exactly (H_p at the
        approximations, point_datum): the distances' coupling and the damping of the points'
        blocks are not in the constraint's C. The linearised residuals do not change (J h = 0): the
        move is a similarity of photos and points, h at the state the step starts from."""
        pd, free = self.point_datum, self.free_network.free
        Hd = pd.similarity(free)
        a = np.linalg.solve(np.einsum("pia,pib->ab", Hd, Hd), pd.misclosure(step.xyz[pd.index], free))
        H = pd.photo_similarity(state, self.layout, free)
        included = self.unknowns.included
        Hp = (point_datum.point_similarity(xyz[included], pd.centroid, free)
              * self.unknowns.free[included][:, :, None])
        step.xyz[included] -= Hp @ a
        weighted = (self.unknowns.weight > 0) & included[:, None]
        step.control_hat = np.where(weighted, step.xyz, step.control_hat)
        return dx - H @ a

    def solve(self, normals: ReducedNormals, solver, state: State, xyz: np.ndarray,
              undamped: ReducedNormals | None = None, target: bool = True, explain: bool = True) -> solvers.SolveResult:
        """Solve the reduced camera system of ``normals`` (a datum defect or a singularity
        explained, _solve_or_explain); a free network by minimum constraints and the
        S-transformation onto its constraints at (state, xyz) (formed with ``undamped``'s N, default
        normals'). target: False solves on the constraints without their right-hand side (the checks);
        explain: False, a plain solve of a control datum (its failures raised as the solver's)."""
        if self.free_network is None:
            if not explain:
                return solver.solve(normals.N, normals.b)
            return _solve_or_explain(normals, solver, state, self)
        undamped = undamped or normals
        fn = self.datum_at(state, xyz, undamped.N, exact=normals is undamped and not undamped.damped)
        fn = fn if target else replace(fn, target=None)
        self.network = fn  # the constraints of this solve (the convergence test reads their datum move)
        try:
            dx, solved = fn.solve(solver, normals.N, normals.b)
        except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:
            raise NumericalFailure(singular_message(
                self.project, self.layout, getattr(exc, "column", None),
                "the free network's reduced normal equations are singular beyond the datum", datum_fixed=False),
                reason="singular") from exc
        return solvers.SolveResult(dx, solved.solver, solved.info)

    def couple(self, normals: ReducedNormals, kept: list, xyz: np.ndarray) -> None:
        """Add the distances' Woodbury correction (bundle.distances) to normals before finish;
        kept: the linearised chunks in assembly order."""
        if self.distances is None:
            normals.coupling = None
            return
        coupling, R, cols, f, ee, growth = couple(self.distances, kept, self.where, self.distance_points, xyz,
                                                  self.unknowns.free, self.layout.n_unknowns)
        normals.rows.append((R, cols, f))
        normals.ee += ee
        normals.reduced += growth
        normals.coupling = coupling

    def chunks(self, state: State, xyz: np.ndarray, damping: float = 0.0, then=None):
        """Linearised point chunks at (state, xyz); damping: Levenberg-Marquardt factor on N_pp.
        then: a function of a linearised chunk and its scatters (self.scatters) that the chunk's
        thread applies too, whose results come instead of the chunks."""
        T = self.layout.rotation_maps(state)
        chunks = (chunk for batch in self.linearised for chunk in batch.chunks(self.options.chunk_size))

        def work(item):
            group_chunk, scatters = item
            chunk = linearise_points(group_chunk, state, self.layout, T, self.obs, self.unknowns, xyz, damping)
            return chunk if then is None else then(chunk, scatters)

        yield from map_ordered(work, zip(chunks, self.scatters, strict=True), chunk_threads(sweep_size(self.linearised)))

    def parameter_rows(self, state: State):
        """Whitened observation equations of the observed elements: J (p, 3), cols, e (p,)."""
        f, grad, cols = self.pobs.evaluate(state, self.layout, self.layout.rotation_maps(state))
        s = self.pobs.sigma
        return grad / s[:, None], cols, self.pobs.misclosure(f) / s

    def cost(self, state: State, xyz: np.ndarray) -> float:
        """The sum of squares e^T e at (state, xyz) (normals.ee without the normals)."""
        chunks = (chunk for batch in self.batches for chunk in batch.chunks(self.options.chunk_size))
        total = sum(map_ordered(lambda chunk: residual_sum_of_squares(chunk, state, self.layout, self.obs,
                                                                      self.unknowns, xyz), chunks,
                                chunk_threads(sweep_size(self.batches))),
                    0.0)
        if len(self.pobs):
            total += float(np.sum(self.parameter_rows(state)[2] ** 2))
        if self.distances is not None:
            total += distance_cost(self.distances, xyz)
        return total

    def normals(self) -> ReducedNormals:
        dense = DenseSchur(self.pattern.n_full, self.n_points) if self.dense else None
        return ReducedNormals(self.pattern, self.S, dense)

    def assemble(self, state: State, xyz: np.ndarray, damping: float = 0.0, lean: bool = False) -> ReducedNormals:
        """The reduced normals at (state, xyz), with the linearised chunks kept (normals.kept) for
        the back substitution of the step they give; lean: b without N, for a chord step (the
        block pattern's sums only; the dense Schur always forms N)."""
        normals = self.normals()
        normals.damped = damping > 0
        normals.lean = lean and normals.dense is None
        cam = state.camera_of_photo
        if normals.dense is None:  # each chunk's share formed in its thread, added up here in order
            for made in self.chunks(state, xyz, damping, lambda chunk, scatters: normals.products(chunk, cam, scatters)):
                normals.add_products(made)
        else:
            for chunk, scatters in zip(self.chunks(state, xyz, damping), self.scatters, strict=True):
                normals.add_points(chunk, cam, scatters)
        if len(self.pobs):
            normals.add_rows(*self.parameter_rows(state))
        self.couple(normals, normals.kept, xyz)
        return normals.finish()


def solve_bundle(project: Project, options: AdjustmentOptions = AdjustmentOptions()) -> BundleSolution:
    """The bundle adjustment (module doc), with the adjusted object points.

    Gauss-Newton, with Levenberg-Marquardt damping only when a step fails (docs/solvers.md): a step
    that raises the sum of squares (or meets a point in a camera's plane, or a numerically singular
    system) is taken again from where it started with lam * diag(N) added to the point blocks and
    to the reduced camera system (Damping)."""
    t_start = time.perf_counter()
    problem = _Problem(project, options)
    obs = problem.obs
    approx = project.points.xyz_approx
    now = _Estimate(problem.initial_state,
                    initial_points(problem.linearised, problem.initial_state, obs, problem.unknowns, options.chunk_size,
                                   None if approx is None else approx - problem.offset),
                    obs.plate.copy(), obs.control.copy(), np.zeros(len(problem.pobs)))
    timings = Timings(initial_points=time.perf_counter() - t_start, linearisation_and_reduction=0.0, solve=0.0,
                      back_substitution=0.0)
    history: list[Iteration] = []
    damping = Damping()
    normals = _assemble_or_none(problem, now.state, now.xyz)
    if normals is None:
        raise NumericalFailure(bundle_not_formed_message(problem.project), reason="not_finite")
    problem.set_datum(now.state, normals)
    if problem.redundancy < 0:
        _explain_too_few(problem, now.state, now.xyz)
    # N's pattern told ahead: CHOLMOD analyses it during the first linearisation (solver_for)
    solver = solver_for(options, problem.layout, project, problem.pattern.reduction(problem.S))
    # only after a failure; large residuals of a settled iteration are named when nothing in the input is
    causes = lambda: (diagnosis.likely_causes(project, "iteration")  # noqa: E731
                      or diagnosis.gross_residuals(project, history, problem.redundancy, now.plate_hat - obs.plate))
    status = "iteration_limit"
    steps = _Steps(damping)
    with solvers.holding_factor(solver):  # each factor made in the memory of the last
        while len(history) < options.max_iterations:
            accepted, normals = _step(problem, solver, now, normals, steps, history, timings, causes)
            if accepted is None:  # a failed step: taken again with more damping
                continue
            now, status = accepted
            if status != "iterating":
                break
            status = "iteration_limit"

        t0 = time.perf_counter()
        at_solution = normals if damping.lam == 0.0 and normals.N is not None else None  # lean: formed there
        normals, checks, next_correction = final_checks(problem, solver, now, at_solution,
                                                        held=steps.chord.usable and status != "iteration_limit")
    free_network = None  # a free network: its inner constraints at the solution (the precision's)
    if problem.free_network is not None:
        free_network = problem.datum_at(now.state, now.xyz, normals.N, at_solution=True)
    timings.final_checks = time.perf_counter() - t0
    timings.total = time.perf_counter() - t_start
    message = ""
    if status == "cost_flat":
        message = termination.cost_flat(METHOD, history, problem.redundancy, options.bundle.cost_tolerance,
                                        options.tolerance)
    elif status == "iteration_limit":
        message = termination.iteration_limit(METHOD, history, problem.redundancy, options.max_iterations,
                                              options.tolerance, next_correction, causes)
    result = AdjustmentResult.of(
        project, obs, plate_adjusted=now.plate_hat, control_adjusted=now.control_hat, vtpv=now.vtpv,
        redundancy=problem.redundancy, history=history, layout=problem.layout, method=METHOD, solver=solver.name,
        state=now.state, offset=problem.offset, n_conditions=int(problem.n_conditions),
        n_observations=observation_count(project, obs, len(problem.pobs)),
        n_parameter_observations=len(problem.pobs), parameter_residuals=now.v_par, N=normals.N, checks=checks,
        timings=timings, termination=status, termination_message=message, free_network=free_network,
    )
    dist = problem.distances
    residuals = (np.zeros(0) if dist is None else
                 np.linalg.norm(now.xyz[dist.point_from] - now.xyz[dist.point_to], axis=1) - dist.distance)
    return BundleSolution(result=result, xyz_points=now.xyz, n_point_unknowns=problem.unknowns.n_unknowns,
                          distance_residuals=residuals)


@dataclass
class _Estimate:
    """Where the iteration stands: orientations and points, the adjusted observations l + v of the
    last step, the residuals of the observed elements and v^T P v."""

    state: State
    xyz: np.ndarray
    plate_hat: np.ndarray
    control_hat: np.ndarray
    v_par: np.ndarray
    vtpv: float = float("nan")


@dataclass
class _Chord:
    """Chord steps in the bundle (docs/decisions.md "Chord steps in the bundle"), as in the method
    of conditions: ``usable`` while the solver holds the factor of an undamped Gauss-Newton step's
    reduced N (a control datum: no free network, no point datum); ``next``: the next step solves on
    it (core.convergence.keeps_factor), with the reduced right-hand side formed where it starts."""

    usable: bool = False
    next: bool = False
    n_diag: np.ndarray | None = None  # the diagonal of the held factor's N (a lean step's floors)


def _next_is_chord(problem: "_Problem", chord: "_Chord", history: list[Iteration], step: "_Step",
                   floor: float) -> bool:
    """Whether the step now taken, if its trial is accepted, is followed by a chord step and not by
    convergence: the trial's normals are then formed without N (lean). The corrections decide it
    before the trial is formed, with the floor and the rules _step applies after it; a step whose
    trial is refused forms its normals whole again."""
    if not chord.usable or problem.options.bundle.cost_tolerance > 0:
        return False
    ahead = history + [Iteration(vtpv=step.vtpv, max_correction=step.correction, seconds=0.0)]
    return keeps_factor(ahead, floor) and not has_converged(ahead, problem.options.tolerance, floor)


@dataclass
class _Steps:
    """How the next step is taken: its Levenberg-Marquardt damping and whether it is a chord step."""

    damping: Damping = field(default_factory=Damping)
    chord: _Chord = field(default_factory=_Chord)


def _step(problem: "_Problem", solver, now: _Estimate, normals: ReducedNormals, steps: "_Steps",
          history: list[Iteration], timings: Timings, causes):
    """One step from ``now`` with the normals formed there (under the present damping).

    Returns ((the new estimate, "iterating" | "converged" | "cost_flat"), the normals at the new
    estimate) for a step taken, appended to ``history``; or (None, the normals formed again with more
    damping) for a failed one (a numerically singular system away from the start, or a step that
    raised the sum of squares). Raises NumericalFailure when damping cannot help."""
    options, layout, state, xyz = problem.options, problem.layout, now.state, now.xyz
    damping, chord = steps.damping, steps.chord
    t0 = time.perf_counter()
    again = solver.solve_again(normals.b) if chord.next and damping.lam == 0.0 else None
    chord.next = False
    if normals.N is None and again is None:  # lean normals without their factor: formed whole
        normals = problem.assemble(state, xyz, damping.lam)
    d = chord.n_diag if normals.N is None else normals.N.diagonal()  # a lean step's: its factor's N
    damped = damping.applied(normals)
    if again is not None:  # a chord step: the factor of an earlier step's N, this point's b
        solved = solvers.SolveResult(again, solver.name, solvers.SolverInfo(held_factor=True))
    else:
        try:
            solved = problem.solve(damped, solver, state, xyz, undamped=normals)
        except NumericalFailure:
            if not history or damping.exhausted():
                raise
            damping.more()  # numerically singular away from the start (a weak direction): damp it more
            chord.usable = False
            return None, problem.assemble(state, xyz, damping.lam)
        chord.usable = (damping.lam == 0.0 and problem.free_network is None and problem.point_datum is None
                        and solver.holding())
        chord.n_diag = d
    dx = solved.dx
    t1 = time.perf_counter()
    step = _back_substitute(problem, state, xyz, dx, damping.lam, kept=normals.kept,
                            coupling=getattr(normals, "coupling", None))
    if problem.point_datum is not None:
        dx = problem.hold_point_datum(state, xyz, dx, step)
    # the kept chunks served their one back substitution (a failed step is assembled afresh): not
    # alive beside the trial's
    normals.kept = damped.kept = None
    trial_state = state.updated(layout, dx)
    # the round-off floor at the trial point: for the lean decision before the trial and the tests after it
    off = round_off_floor(trial_state, layout)
    floor = energy_floor(layout.n_unknowns + problem.unknowns.n_unknowns, off, d)
    t_back = time.perf_counter()  # the back substitution's end; the trial's normals or cost follow
    if damping.lam == 0.0:  # Gauss-Newton: the next normals, kept when the step is good
        lean = _next_is_chord(problem, chord, history, step, floor)
        trial = _assemble_or_none(problem, trial_state, step.xyz, lean=lean)
        trial_ee = trial.ee if trial is not None else np.inf
    else:  # damped: only the sum of squares, the normals follow with the next damping
        trial, trial_ee = None, problem.cost(trial_state, step.xyz)
    ee = normals.ee  # the sum of squares where the step started
    predicted, actual = ee - step.vtpv, ee - trial_ee
    lam_step = damping.lam
    # worse: back to the start, more damping
    if actual < -(ROUND_OFF * ee + problem.cost_floor) or not np.isfinite(actual):
        if damping.exhausted():
            raise NumericalFailure("\n".join([
                f"the bundle adjustment cannot reduce the sum of squares after iteration {len(history)}: "
                f"Levenberg-Marquardt damping grew past {LM_MAX:g} without a better step.",
                termination.table(history, problem.redundancy) if history else "",
                "It is stuck away from a solution (or points are crossing the plane of a camera).",
                termination.causes_text(causes())]).replace("\n\n", "\n"), reason="diverged")
        damping.more()
        again = problem.assemble(state, xyz, damping.lam)
        timings.add("solve", t1 - t0)
        timings.add("back_substitution", t_back - t1)
        timings.add("linearisation_and_reduction", time.perf_counter() - t_back)
        return None, again
    damping.after_good_step(actual, predicted, ROUND_OFF * ee + problem.cost_floor)
    new = _Estimate(trial_state, step.xyz, step.plate_hat, step.control_hat, step.v_par, step.vtpv)
    normals = trial if trial is not None and damping.lam == 0.0 else problem.assemble(new.state, new.xyz, damping.lam)
    t3 = time.perf_counter()
    timings.add("solve", t1 - t0)
    timings.add("back_substitution", t_back - t1)
    timings.add("linearisation_and_reduction", t3 - t_back)  # the trial's normals, or those formed after it
    if problem.free_network is not None:  # the datum's move, which N does not see (datum.FreeNetwork)
        step.correction = float(np.hypot(step.correction, problem.network.datum_correction(d)))
    history.append(Iteration(vtpv=new.vtpv, max_correction=step.correction, seconds=t3 - t0,
                             solver_info=solved.info.merged(damping=damping.lam or None),
                             element_correction=max(largest_correction(dx, d, off),  # new.state is trial_state
                                                    step.max_point_correction)))
    progress.iteration(METHOD, len(history), new.vtpv, step.correction, t3 - t0, history[-1].solver_info)
    if damping.lam == 0.0:
        stop_if_diverging(history, METHOD, problem.redundancy, causes)
    # a damped step is shortened: its small corrections alone do not show convergence, the undamped
    # Gauss-Newton correction from where it ended must be small too
    if has_converged(history, options.tolerance, floor) and (lam_step == 0.0 or has_converged(
            history[:-1] + [replace(history[-1], max_correction=_undamped_correction(problem, solver, new.state,
                                                                                     new.xyz))],
            options.tolerance, floor)):
        return (new, "converged"), normals
    if options.bundle.cost_tolerance > 0 and 0 <= actual <= options.bundle.cost_tolerance * ee:
        return (new, "cost_flat"), normals
    chord.next = chord.usable and damping.lam == 0.0 and keeps_factor(history, floor)
    return (new, "iterating"), normals


def _assemble_or_none(problem: "_Problem", state: State, xyz: np.ndarray, lean: bool = False):
    """The reduced normals (lean: without N, _Problem.assemble), or None where the linearisation is
    not finite (a point in the plane of a camera makes its 3x3 block singular)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        try:
            normals = problem.assemble(state, xyz, lean=lean)
        except np.linalg.LinAlgError:
            return None
    finite_N = normals.N is None or np.isfinite(normals.N.data).all()
    if not (np.isfinite(normals.ee) and finite_N and np.isfinite(normals.b).all()):
        return None
    return normals


def _undamped_correction(problem: "_Problem", solver, state: State, xyz: np.ndarray) -> float:
    """The correction (core.convergence.correction_in_sigma, orientations and points together) of an
    undamped Gauss-Newton step from (state, xyz); inf when it cannot be formed."""
    normals = _assemble_or_none(problem, state, xyz)
    if normals is None:
        return float("inf")
    try:
        dx = problem.solve(normals, solver, state, xyz, explain=False).dx
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError, NumericalFailure):
        return float("inf")
    return _back_substitute(problem, state, xyz, dx, kept=normals.kept,
                            coupling=getattr(normals, "coupling", None)).correction


@dataclass
class _Step:
    xyz: np.ndarray
    plate_hat: np.ndarray
    control_hat: np.ndarray
    v_par: np.ndarray
    vtpv: float
    correction: float  # core.convergence.correction_in_sigma of the step: sqrt of the sum of (J [dx; dX])^2
    max_point_correction: float  # the largest |dX_i| sqrt(N_pp,ii) (core.convergence.largest_correction's kind)


def _back_substitute(problem: _Problem, state: State, xyz: np.ndarray, dx: np.ndarray, damping: float = 0.0,
                     kept: list | None = None, coupling=None) -> _Step:
    """Point corrections and the adjusted observations l + v of the linearised step (v from
    ``Jc dx + Jp dX - e``, like the conditions method's ``v = Q A^T k``), and the step's size as
    core.convergence.correction_in_sigma measures it: ``sqrt(d^T N d)`` for the whole step d = (dx, dX),
    the norm of the change ``J d = v + e`` of the whitened residuals it makes. kept: the chunks the
    assembly of these normals linearised at (state, xyz) with this damping (ReducedNormals.kept);
    linearised again when not given. coupling: the distances' correction of these normals
    (bundle.distances.Coupling; required with distances)."""
    obs = problem.obs
    xyz_new = xyz.copy()
    plate_hat, control_hat = obs.plate.copy(), obs.control.copy()
    vtpv, energy, crit = 0.0, 0.0, 0.0
    chunks = list(kept if kept is not None else problem.chunks(state, xyz, damping))
    shift = {}
    if problem.distances is not None:  # the distance points' dX' - dX (bundle.distances)
        if coupling is None:
            coupling = couple(problem.distances, chunks, problem.where, problem.distance_points, xyz,
                              problem.unknowns.free, problem.layout.n_unknowns)[0]
        dX0 = np.array([point_corrections(chunks[c], dx)[0][row] for c, row in zip(*problem.where)])
        ddX = coupling.point_shift(dX0)
        for c, row, dd in zip(*problem.where, ddX):
            shift.setdefault(int(c), np.zeros((len(chunks[c].N_pp), 3)))[row] = dd
        v_dist = coupling.residuals(dX0 + ddX)
        vtpv += float(v_dist @ v_dist)
        energy += float(np.sum((v_dist + coupling.e) ** 2))
    for c, chunk in enumerate(chunks):
        dX, v_plate, v_control = point_corrections(chunk, dx, shift.get(c))
        pt = chunk.batch.point_index
        xyz_new[pt] = xyz[pt] + dX
        rows, v_real, sigma = real_rays(chunk.batch, chunk.batch.image_rows, v_plate, chunk.sigma)
        plate_hat[rows] = obs.plate[rows] + v_real * sigma
        weighted = chunk.weight > 0
        control_hat[pt] = np.where(weighted, xyz_new[pt], obs.control[pt])
        vtpv += float(np.sum(v_plate**2) + np.sum(v_control**2))
        energy += float(np.sum((v_plate + chunk.e) ** 2) + np.sum(chunk.weight * dX**2))
        d = np.einsum("mii->mi", chunk.N_pp)
        if dX.size:
            crit = max(crit, float(np.max(np.where(chunk.free, np.abs(dX) * np.sqrt(d), 0.0))))
    v_par = np.zeros(len(problem.pobs))
    if len(problem.pobs):
        J, cols, e = problem.parameter_rows(state)
        dxp = np.concatenate([dx, [0.0]])
        v_white = np.einsum("pi,pi->p", J, dxp[cols]) - e
        v_par = v_white * problem.pobs.sigma
        vtpv += float(np.sum(v_white**2))
        energy += float(np.sum((v_white + e) ** 2))
    return _Step(xyz_new, plate_hat, control_hat, v_par, vtpv, float(np.sqrt(energy)), crit)


def _solve_or_explain(normals: ReducedNormals, solver, state: State, problem: _Problem) -> solvers.SolveResult:
    """Solve the reduced camera system N_rcs dx = b_rcs (core.explain.solve_or_explain: a datum
    defect or a singularity explained); numbers that are not finite explained first."""
    if not (np.isfinite(normals.N.data).all() and np.isfinite(normals.b).all()):
        raise NumericalFailure(bundle_not_formed_message(problem.project, "at the current values"), reason="not_finite")
    return solve_or_explain(normals, normals.b, solver, state, problem,
                            "the reduced normal equations of the bundle adjustment are singular")


def _explain_too_few(problem: _Problem, state: State, xyz: np.ndarray):
    normals = _assemble_or_none(problem, state, xyz)
    if normals is None:
        raise NumericalFailure(bundle_not_formed_message(problem.project), reason="not_finite")
    defects = datum.diagnose(normals, state, problem.layout, offset=problem.offset)
    if defects:
        raise datum_defect_failure(problem.project, defects)
    raise NumericalFailure(
        f"too few observations: {problem.n_conditions} observation equations beyond the "
        f"{problem.unknowns.n_unknowns} point coordinates, and {len(problem.pobs)} observed elements, "
        f"for {problem.layout.n_unknowns} orientation unknowns. Add control or tie points, or fix elements."
    )
