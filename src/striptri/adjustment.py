"""Schmid's simultaneous adjustment by condition equations (DESIGN section 4).

General case of least squares (Helmert), linearised at the adjusted observations (Pope 1972):
``A v + B dx + w = 0`` per group, ``N = sum B^T M^-1 B``, ``u = sum B^T M^-1 w``, ``N dx = -u``,
``k = -M^-1 (w + B dx)``, ``v = Q A^T k``; then ``x^ <- x^ (+) dx``, ``l^ <- l + v``, repeated.

Convergence criterion: the correction is below ``tolerance`` times the standard deviation in every
function of the unknowns, ``sqrt(dx^T N dx) < tolerance`` with N in units of the a-priori weights
(:func:`correction_in_sigma`): the largest change of any element, distance or angle, each in units
of its own standard deviation. It means the same on a 10-photo strip and a 100,000-photo one.

Each iteration makes two passes over the groups, chunk by chunk: one forms N and u, the other,
after the solve, recomputes the same linearisation and back-substitutes the residuals. Memory
therefore does not grow with the number of points.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from . import datum, diagnosis, progress, solvers, termination
from .covariance import Covariance
from .errors import NumericalFailure
from .groups import build_batches
from .linearise import Observations, linearise
from .model import Project
from .normal_equations import BlockPattern, NormalAccumulator, PatternAccumulator, selection_matrix, whiten
from .parameter_observations import ParameterObservations, build_parameter_observations
from .parameters import State, UnknownLayout, build_layout, initial_state, reduction_offset
from .rotations import angles_jacobian

METHODS = ("conditions", "bundle", "sequential")
# approximate values: as given in photos.csv, or from the sequential method (rough values suffice)
INITS = ("given", "sequential")
DENSE_QXX_LIMIT = 5000  # unknowns up to which AdjustmentResult.Qxx forms the dense N^-1
# "control": the datum comes from control and observed elements (a defect is an error);
# "inner": a free network, the directions the control leaves free fixed by inner constraints.
DATUMS = ("control", "inner")
# Why an iteration stopped (summary.json "termination"). "converged": the corrections fell below
# the tolerance (or the round-off floor); "cost_flat": the bundle's cost tolerance was met (also a
# success); "iteration_limit": max_iterations reached first; "diverged": non-finite numbers or
# corrections growing without bound. Only the first two are results; the others are failures
# unless the user keeps them (--keep-unconverged).
TERMINATIONS = ("converged", "cost_flat", "iteration_limit", "diverged")
SUCCESSFUL_TERMINATIONS = ("converged", "cost_flat")


@dataclass(frozen=True)
class AdjustmentOptions:
    """Options of the simultaneous adjustment.

    scale_form: "3d" (direction-free closest-approach scales) or "xz" (Schmid 94).
    condition_transform: optional callable(GroupBatch) -> (m, nc, nc) invertible matrices that
    rescale/recombine each group's conditions (the result must not depend on it).
    tolerance: converged when every correction is below this fraction of its standard deviation.
    cost_tolerance: bundle method only, 0 = off: also converged when a step lowers the sum of
    squares by less than this fraction (Ceres' function tolerance; for problems with directions
    so weak that corrections stay large while the cost no longer changes, e.g. BAL problems).
    keep_unconverged: return an adjustment that stopped without converging (iteration limit) as a
    result, with ``converged`` False; by default it is a NumericalFailure (an unconverged
    adjustment is not a result).
    """

    method: str = "conditions"
    solver: str = "auto"
    max_iterations: int = 30
    tolerance: float = 1e-8
    cost_tolerance: float = 0.0
    chunk_size: int = 4096
    scale_form: str = "3d"
    condition_transform: object = None
    datum: str = "control"
    init: str = "given"
    procedure: int = 1
    direction: str = "forward"
    polynomial_degree: int | None = None
    keep_unconverged: bool = False

    def __post_init__(self):
        if self.init not in INITS:
            raise ValueError(f"unknown init {self.init!r}; choose one of {', '.join(INITS)}")
        if self.method == "sequential" or self.init == "sequential":
            from .sequential import SequentialOptions

            SequentialOptions.from_adjustment_options(self)  # validates procedure, direction, degree
        if self.method == "sequential" and self.datum != "control":
            raise ValueError("the sequential method takes its datum from control; --datum inner is not for it")
        if self.datum not in DATUMS:
            raise ValueError(f"unknown datum {self.datum!r}; choose one of {', '.join(DATUMS)}")
        if self.datum != "control" and self.method == "bundle":
            raise ValueError("the free-network datum (inner) is available with the conditions method only; "
                             "use --method conditions")
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        solvers.resolve_solver(self.solver, 0)
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be at least 1")


@dataclass
class Iteration:
    """One outer iteration. max_correction: the convergence measure, in standard deviations (the
    simultaneous adjustments: correction_in_sigma, the largest correction of any function of the
    unknowns; the sequential method: largest_correction). element_correction: the simultaneous
    adjustments' largest_correction besides, the divergence test's figure (it grows without bound
    when an iteration diverges, while correction_in_sigma stays below sqrt(v^T P v))."""

    vtpv: float
    max_correction: float
    seconds: float
    solver_info: dict = field(default_factory=dict)  # e.g. inner iterations of an iterative solver
    element_correction: float = float("nan")


@dataclass
class AdjustmentResult:
    """Everything a report needs. Ground coordinates are in the reduced frame; add ``offset``."""

    method: str
    solver: str
    state: State
    layout: UnknownLayout
    offset: np.ndarray
    sigma0: float
    redundancy: int
    vtpv: float
    iterations: int
    converged: bool
    history: list[Iteration]
    n_conditions: int
    n_observations: int
    n_unknowns: int
    n_parameter_observations: int
    plate_residuals: np.ndarray  # (m_ip, 2) v of every plate measurement
    plate_adjusted: np.ndarray  # (m_ip, 2) l + v
    control_residuals: np.ndarray  # (n_pt, 3) v of weighted control coordinates (0 elsewhere)
    control_adjusted: np.ndarray  # (n_pt, 3) reduced frame
    parameter_residuals: np.ndarray  # (p,)
    N: sp.csr_matrix
    checks: dict
    timings: dict = field(default_factory=dict)
    free_network: datum.FreeNetwork | None = None
    # why the iteration stopped (summary.json "termination", one of TERMINATIONS) and, for every
    # reason but "converged", a message with the last figures of the history and the likely cause
    termination: str = "converged"
    termination_message: str = ""
    # (photo ids, camera ids) of the project: names the unknowns in messages (None: by column)
    ids: tuple | None = None
    _covariance: Covariance | None = None

    @property
    def covariance(self) -> Covariance:
        """Selected entries of Qxx = N^-1 (covariance.Covariance), computed once. Raises
        NumericalFailure, naming the first element that is not determined, when N is singular."""
        if self._covariance is None:
            if not np.isfinite(sp.csr_matrix(self.N).data).all():
                raise NumericalFailure(self._precision_failure(None))
            try:
                self._covariance = Covariance(self.N, self.layout, self.free_network)
            except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:
                raise NumericalFailure(self._precision_failure(exc)) from exc
        return self._covariance

    def _precision_failure(self, exc: Exception | None) -> str:
        """Why Qxx cannot be formed: a singular N (naming the first element that is not determined)
        or one with numbers that are not finite; with the adjustment's own failure when it had one."""
        status = "" if self.termination in SUCCESSFUL_TERMINATIONS else (
            f"\nThe adjustment itself ended with \"{self.termination}\": " + self.termination_message)
        if exc is None:
            return ("the precision of the result cannot be computed: the normal matrix at the adjusted values has "
                    "numbers that are not finite (an overflow)." + status)
        column = getattr(exc, "column", None)
        where = ""
        if column is not None and self.ids is not None and 0 <= column < self.n_unknowns:
            where = f" (first at {self.layout.column_labels(*self.ids)[column]})"
        return ("the precision of the result cannot be computed: the normal matrix at the adjusted values is "
                f"singular{where}, so that element is not determined by the measurements (too few or badly "
                "distributed points on a photograph, an undetermined camera constant, or values that are not "
                "plausible)." + status)

    @property
    def Qxx(self) -> np.ndarray:
        """The dense N^-1, the weight coefficients of the unknowns (Schmid 53); for a free network
        the inverse under its inner constraints. For small problems and tests: large ones use
        ``covariance``."""
        if self.n_unknowns > DENSE_QXX_LIMIT:
            raise MemoryError(f"a dense Qxx of {self.n_unknowns} unknowns; use result.covariance")
        return self.covariance.dense()

    @property
    def sigma0_for_precision(self) -> float:
        """sigma0 a posteriori, or 1 (a priori) when there is no redundancy."""
        return self.sigma0 if self.redundancy > 0 else 1.0

    def mean_error(self, f: np.ndarray) -> float:
        """Mean error of a function of the unknowns with gradient f (Schmid 81-84):
        ``m_F = sigma0 sqrt(f^T N^-1 f)``."""
        return float(self.sigma0_for_precision * np.sqrt(max(self.covariance.quadratic_form(f), 0.0)))

    def gradient_of_element(self, photo: int, element: int) -> np.ndarray:
        """Gradient of one photo element (0-2 centre, 3-5 rotation unknown) w.r.t. the unknowns."""
        f = np.zeros(self.n_unknowns)
        col = self.layout.photo_cols[photo, element]
        if col >= 0:
            f[col] = 1.0
        return f

    def base_component_mean_error(self, photo_from: int, photo_to: int, axis: int) -> float:
        """Mean error of b = O[to, axis] - O[from, axis] (Schmid 85-86)."""
        f = self.gradient_of_element(photo_to, axis) - self.gradient_of_element(photo_from, axis)
        return self.mean_error(f)

    def photo_mean_errors(self, convention: str) -> tuple[np.ndarray, np.ndarray]:
        """Mean errors of the centres (n, 3) and of the angles in ``convention`` (n, 3, radians)."""
        s0 = self.sigma0_for_precision
        Qphoto = self.covariance.photo_blocks()  # (n, 6, 6), fixed elements zero
        sig_xyz = s0 * np.sqrt(np.maximum(np.einsum("nii->ni", Qphoto[:, :3, :3]), 0))
        T = self.layout.rotation_maps(self.state)
        J = angles_jacobian(self.state.R, convention) @ T
        Qang = J @ Qphoto[:, 3:, 3:] @ np.swapaxes(J, 1, 2)
        sig_ang = s0 * np.sqrt(np.maximum(np.einsum("nii->ni", Qang), 0))
        return sig_xyz, sig_ang

    def camera_mean_errors(self) -> np.ndarray:
        s0 = self.sigma0_for_precision
        diag = np.concatenate([self.covariance.diag(), [0.0]])
        return s0 * np.sqrt(np.maximum(diag[self.layout.camera_cols], 0))


def observations_of(project: Project, offset: np.ndarray) -> Observations:
    pts = project.points
    given = np.isfinite(pts.xyz_given) & _given_mask(project)
    control = np.where(given, pts.xyz_given - offset, 0.0)
    q_control = np.where(given & np.isfinite(pts.sigma_given), np.nan_to_num(pts.sigma_given) ** 2, 0.0)
    ip = project.image_points
    return Observations(plate=ip.xy.copy(), q_plate=ip.sigma_xy**2, control=control, q_control=q_control)


def _given_mask(project: Project) -> np.ndarray:
    from .model import GIVEN_AXES

    return np.array([GIVEN_AXES[int(k)] for k in project.points.kind], dtype=bool).reshape(-1, 3)


class Sweep:
    """One sweep over all groups at a fixed (x^, l^)."""

    def __init__(self, batches, state, layout, obs, plate_hat, control_hat, options):
        self.batches, self.state, self.layout = batches, state, layout
        self.obs, self.plate_hat, self.control_hat, self.options = obs, plate_hat, control_hat, options
        self.T = layout.rotation_maps(state)
        self.seconds = 0.0  # time spent evaluating and linearising the conditions

    def systems(self):
        for batch in self.batches:
            for chunk in batch.chunks(self.options.chunk_size):
                t0 = time.perf_counter()
                system = linearise(
                    chunk, self.state, self.layout, self.T, self.obs, self.plate_hat, self.control_hat,
                    self.options.scale_form, self.options.condition_transform,
                )
                self.seconds += time.perf_counter() - t0
                yield chunk, system


@dataclass
class _WhitenedChunk:
    """What the back substitution needs of one chunk, kept from the assembly of the same iteration
    (normal_equations.whiten): Bw = L^-1 B (m, nc, nu), ww = L^-1 w (m, nc), the columns (m, nu)
    and Gt = L^-1 A Q (m, nc, no), so that v = -Gt^T (ww + Bw dx)."""

    chunk: object
    Bw: np.ndarray
    ww: np.ndarray
    cols: np.ndarray
    Gt: np.ndarray


def _assemble(sweep: Sweep, pobs: ParameterObservations, assembly: "Assembly", keep: bool = False):
    """N and u of one sweep: point groups into the block pattern, then the observed elements.
    keep: also keep each chunk's whitened system for the back substitution (acc.kept), so that an
    iteration linearises its conditions once. acc.max_misclosure: the largest |g| of a condition
    in units of its standard deviation (Schmid's final check)."""
    acc = PatternAccumulator(assembly.pattern, assembly.S)
    acc.kept = [] if keep else None
    acc.max_misclosure = 0.0
    cam_of_photo = sweep.state.camera_of_photo
    for (chunk, system), scatters in zip(sweep.systems(), assembly.scatters):
        if keep:
            Bw, ww, gw, _, Gt = whiten(system, residual_map=True)
            acc.kept.append(_WhitenedChunk(chunk, Bw, ww, system.cols, Gt))
        else:
            Bw, ww, gw, _ = whiten(system)
        acc.add_groups(Bw, ww, gw, chunk.photo_index, cam_of_photo[chunk.photo_index], scatters)
        if system.g.size:
            acc.max_misclosure = max(acc.max_misclosure, float(np.max(np.abs(system.g))))
    if len(pobs):
        f, grad, cols = pobs.evaluate(sweep.state, sweep.layout, sweep.T)
        acc.add_rows(grad, cols, pobs.misclosure(f), pobs.sigma)
    return acc.finish()


def _assemble_checked(sweep: Sweep, pobs: ParameterObservations, assembly: "Assembly", project: Project,
                      iteration: int, keep: bool = False):
    """_assemble, with numbers that are not finite (an overflow: wild values, c in another unit)
    explained as a NumericalFailure naming the points whose conditions fail and the likely cause."""
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            acc = _assemble(sweep, pobs, assembly, keep)
    except np.linalg.LinAlgError:
        acc = None
    if acc is not None and np.isfinite(acc.u).all() and np.isfinite(acc.N.data).all() and np.isfinite(acc.wPw):
        return acc
    raise NumericalFailure(not_finite_message(project, _non_finite_points(sweep), iteration))


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


def not_finite_message(project: Project, points: np.ndarray, iteration: int) -> str:
    """The NumericalFailure text for conditions (or observation equations) that are not finite numbers."""
    names = [project.points.ids[i] for i in points[: diagnosis.LIST_MAX]]
    where = (f" for {len(points)} point{'s' if len(points) != 1 else ''} ({', '.join(names)}"
             f"{' ...' if len(points) > len(names) else ''})" if len(points) else "")
    return ("the equations of the adjustment cannot be formed at iteration "
            f"{iteration}: their numbers overflow (they are not finite){where}.\n"
            + termination.causes_text(diagnosis.likely_causes(project, "overflow"),
                                      "Likely cause: values far outside the block or in another unit in the input "
                                      "(photos.csv, cameras.csv, image_points.csv, control.csv)."))


@dataclass(frozen=True)
class Assembly:
    """What the assembly computes once per adjustment: the block pattern of N, the selection S,
    and each chunk's scatter (normal_equations.ChunkScatter), in the order Sweep.systems yields
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
        scatters = [pattern.scatters(photo, cam) for photo, cam in chunks]
        S = selection_matrix(layout.photo_cols, layout.camera_cols, layout.n_unknowns)
        pattern.reduction(S)
        return Assembly(pattern, S, scatters)


def _back_substitute(kept: list[_WhitenedChunk], sweep: Sweep, pobs: ParameterObservations, dx: np.ndarray,
                     obs: Observations):
    """New adjusted observations l + v from the corrections dx, with the whitened systems the
    assembly kept: ``t = L^-1 (w + B dx)``, ``k = -L^-T t``, ``v = Q A^T k = -(L^-1 A Q)^T t`` and
    ``v^T P v = k^T M k = t^T t``."""
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
    v_par = np.zeros(len(pobs))
    if len(pobs):
        f, grad, cols = pobs.evaluate(sweep.state, sweep.layout, sweep.T)
        v_par = -(pobs.misclosure(f) - np.einsum("pi,pi->p", grad, dxp[cols]))
        vtpv += float(np.sum((v_par / pobs.sigma) ** 2))
    return plate_hat, control_hat, v_par, vtpv


def _solve_free_network(acc, solver: solvers.NormalSolver, fn: datum.FreeNetwork) -> solvers.SolveResult:
    """Minimum constraints, then the S-transformation onto the inner constraints (datum.FreeNetwork)."""
    N_min, mask = fn.minimum_constraint_system(acc.N)
    solved = solver.solve(N_min, -acc.u * (1.0 - mask))
    return solvers.SolveResult(fn.transform(solved.dx), solved.solver, solved.info)


def _solve_or_explain(acc: NormalAccumulator, solver: solvers.NormalSolver, state: State, layout: UnknownLayout,
                      project: Project, offset, free_network=None, diagnose: bool = True) -> solvers.SolveResult:
    """Solve N dx = -u; a datum defect (tested before the first solve and whenever the solver
    finds N singular) or any other singularity is explained as a NumericalFailure."""
    if free_network is not None:
        try:
            return _solve_free_network(acc, solver, free_network)
        except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:
            raise NumericalFailure(singular_message(
                project, layout, getattr(exc, "column", None),
                "the free network's normal equations are singular beyond the datum", datum_fixed=False)) from exc
    defects = datum.diagnose(acc, state, layout, offset=offset) if diagnose else []
    if defects:
        raise NumericalFailure(datum_defect_message(project, defects))
    try:
        return solver.solve(acc.N, -acc.u)
    except solvers.SingularNormalMatrix as exc:
        defects = datum.diagnose(acc, state, layout, datum.LOOSE_TOLERANCE, offset)
        if defects:
            raise NumericalFailure(datum_defect_message(project, defects)) from exc
        raise NumericalFailure(singular_message(project, layout, exc.column,
                                                "the normal equations are singular")) from exc


def datum_defect_message(project: Project, defects: list[str]) -> str:
    """datum.explain, unless weights beyond double precision fool the datum test (they are named
    instead); with photos in several groups that share no points, the groups are named too."""
    with np.errstate(all="ignore"):
        weights = diagnosis.extreme_weights(project)
        if weights:
            return ("the normal equations cannot be trusted: " + " ".join(weights)
                    + " (With such weights the datum test reports directions as free that are not.)")
        groups = diagnosis.photo_groups(project).explain()
        values = diagnosis.implausible_values(project) + diagnosis.camera_units(project)
    if values:  # numbers that make the normal equations meaningless fool the datum test too
        return ("the normal equations cannot be trusted: " + " ".join(values)
                + " (With such values the datum test reports directions as free that are not.)")
    return "\n".join([datum.explain(defects)] + groups)


def singular_message(project: Project, layout: UnknownLayout, column: int | None, what: str,
                     datum_fixed: bool = True) -> str:
    """The NumericalFailure text of a singular normal matrix: where it broke down and the likely
    cause (striptri.diagnosis: weights beyond double precision, photo groups without a datum,
    wild values, the unit of c); without one, the usual causes of an undetermined element."""
    labels = layout.column_labels(project.photos.ids, project.cameras.ids)
    where = f" (first at {labels[column]})" if column is not None and 0 <= column < len(labels) else ""
    with np.errstate(all="ignore"):
        causes = diagnosis.likely_causes(project, "singular")
    if causes:
        return f"{what}{where}: some element is not determined by the measurements.\n" + termination.causes_text(causes)
    datum_fixed = " although the control fixes the datum" if datum_fixed else ""
    return (f"{what}{datum_fixed}{where}: some orientation element is not determined by the measurements. Check "
            "that every photograph has enough well-distributed points (at least three, not on a line) and that "
            "each free camera constant is determined.")


def adjust(project: Project, options: AdjustmentOptions = AdjustmentOptions()) -> AdjustmentResult:
    """Adjust all photographs of the project simultaneously: Schmid's method of conditions, or with
    ``options.method == "bundle"`` the collinearity bundle adjustment (striptri.bundle), or the
    sequential method.

    The result's ``termination`` says why the iteration stopped (TERMINATIONS; "converged" and
    "cost_flat" are results, "iteration_limit" a failure) and ``termination_message`` says it in
    words with the last figures of the history and the likely cause. An adjustment that stops
    without converging raises NumericalFailure with that message unless
    ``options.keep_unconverged``. Raises NumericalFailure for everything that gives no result: a
    datum defect, a singular normal matrix, numbers that overflow, divergence; never a bare
    SingularNormalMatrix or LinAlgError."""
    result = _adjust_explained(project, options)
    if not options.keep_unconverged and termination_of(result) not in SUCCESSFUL_TERMINATIONS:
        raise NumericalFailure(failure_message(result))
    return result


def termination_of(result: AdjustmentResult) -> str:
    """The reason the iteration stopped (TERMINATIONS); a result marked converged=False whose
    method did not say why stopped at its iteration limit."""
    if result.termination in SUCCESSFUL_TERMINATIONS and not result.converged:
        return "iteration_limit"
    return result.termination


def failure_message(result: AdjustmentResult) -> str:
    """What to tell the user about an adjustment that did not converge: the method's own message
    or, failing that, the last figures of the iteration history."""
    if result.termination_message:
        return result.termination_message
    last = result.history[-3:]
    figures = "; ".join(f"v^T P v {h.vtpv:.6g}, largest correction {h.max_correction:.3g} sigma" for h in last)
    return (f"the {result.method} adjustment did not converge in {result.iterations} iterations (last: {figures}). "
            "Raise [adjustment] max_iterations in project.toml if the corrections were still shrinking; "
            "otherwise check the approximate orientations, the angle convention and the units of c and of the "
            "plate coordinates.")


def _adjust_explained(project: Project, options: AdjustmentOptions) -> AdjustmentResult:
    """One adjustment by options.method, returned whether it converged or not; singular systems
    without words of their own explained."""
    with np.errstate(all="ignore"):
        weights = diagnosis.extreme_weights(project)
    if weights:  # the normal equations cannot carry them: refuse before iterating into nonsense
        raise NumericalFailure("the adjustment cannot be carried out in double precision: " + " ".join(weights))
    try:
        # the adjustment tests its numbers for finiteness itself and explains what overflows, so
        # numpy's floating-point warnings would only repeat it on stderr
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return _adjust(project, options)
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:  # a path without its own words
        with np.errstate(all="ignore"):
            causes = diagnosis.likely_causes(project, "singular")
        raise NumericalFailure(f"{termination.what_of(options.method)} met a singular system of equations ({exc}); "
                               "some element is not determined by the measurements.\n"
                               + termination.causes_text(causes)) from exc


def _adjust(project: Project, options: AdjustmentOptions) -> AdjustmentResult:
    if options.init == "sequential" and options.method != "sequential":
        from .sequential import SequentialOptions, sequential_approximations

        project = sequential_approximations(project, SequentialOptions.from_adjustment_options(options))
    if options.method == "sequential":
        from .sequential import adjust_sequential

        return adjust_sequential(project, options)
    if options.method == "bundle":
        from .bundle import adjust_bundle  # striptri.bundle imports this module

        return adjust_bundle(project, options)
    t_start = time.perf_counter()
    offset = reduction_offset(project)
    state = initial_state(project, offset)
    layout = build_layout(project)
    batches = build_batches(project)
    obs = observations_of(project, offset)
    pobs = build_parameter_observations(project, offset)
    n_conditions = sum(len(b) * b.n_conditions for b in batches)
    assembly = Assembly.of(batches, state, layout, options.chunk_size)
    if options.scale_form == "xz":
        _require_strip_along_x(batches, state)
    free_network = None
    if options.datum == "inner":
        sweep = Sweep(batches, state, layout, obs, obs.plate, obs.control, options)
        acc0 = _assemble_checked(sweep, pobs, assembly, project, 1)
        free = datum.free_directions(acc0, state, layout)
        if len(free):
            free_network = datum.FreeNetwork.of(free, acc0.N)
    n_datum = 0 if free_network is None else len(free_network)
    redundancy = n_conditions + len(pobs) - layout.n_unknowns + n_datum
    if redundancy < 0:
        sweep = Sweep(batches, state, layout, obs, obs.plate, obs.control, options)
        defects = datum.diagnose(_assemble_checked(sweep, pobs, assembly, project, 1), state, layout, offset=offset)
        if defects:
            raise NumericalFailure(datum_defect_message(project, defects))
        raise NumericalFailure(
            f"too few conditions: {n_conditions} condition equations and {len(pobs)} observed elements "
            f"for {layout.n_unknowns} unknowns. Add control or tie points, or fix elements."
        )
    solver = solvers.make_solver(
        solvers.SolverOptions(name=options.solver), solvers.Structure(layout.n_unknowns, layout.block_starts(),
                                                          layout.block_groups(project.photos.strip_ids))
    )
    timings = {"conditions": 0.0, "assembly": 0.0, "solve": 0.0, "back_substitution": 0.0}

    plate_hat, control_hat = obs.plate.copy(), obs.control.copy()
    history: list[Iteration] = []
    converged = False
    v_par = np.zeros(len(pobs))
    vtpv = np.nan
    causes = lambda: diagnosis.likely_causes(project, "iteration")  # noqa: E731  (only after a failure)
    for _ in range(options.max_iterations):
        t0 = time.perf_counter()
        sweep = Sweep(batches, state, layout, obs, plate_hat, control_hat, options)
        acc = _assemble_checked(sweep, pobs, assembly, project, len(history) + 1, keep=True)
        t1 = time.perf_counter()
        t_conditions = sweep.seconds
        if free_network is not None:
            free_network = free_network.at(state, layout, acc.N)
        solved = _solve_or_explain(acc, solver, state, layout, project, offset, free_network,
                                   diagnose=not history)
        dx = solved.dx
        t2 = time.perf_counter()
        previous_plate, previous_control = plate_hat, control_hat
        with np.errstate(over="ignore", invalid="ignore"):
            plate_hat, control_hat, v_par, vtpv = _back_substitute(acc.kept, sweep, pobs, dx, obs)
        acc.kept = None  # the whitened systems are not needed beyond the back substitution
        state = state.updated(layout, dx)
        t3 = time.perf_counter()
        timings["conditions"] += t_conditions
        timings["assembly"] += t1 - t0 - t_conditions
        timings["solve"] += t2 - t1
        timings["back_substitution"] += t3 - t2
        if len(dx):
            crit = correction_in_sigma(dx, acc.N)
            element_floor, n_diag = round_off_floor(state, layout), acc.N.diagonal()
            floor = energy_floor(layout.n_unknowns, element_floor, n_diag)
            element = largest_correction(dx, n_diag, element_floor)
        else:  # no unknowns (every element held): the iteration is over the adjusted observations alone
            crit = element = _observation_change(plate_hat - previous_plate, control_hat - previous_control, obs)
            floor = ROUNDING_FLOOR
        history.append(Iteration(vtpv=vtpv, max_correction=crit, seconds=t3 - t0, solver_info=solved.info,
                                 element_correction=element))
        progress.iteration("conditions", len(history), vtpv, crit, t3 - t0, solved.info)
        acc = solved = None  # this iteration's N and u are not needed by the next one
        stop_if_diverging(history, "conditions", redundancy, causes)
        if has_converged(history, options.tolerance, floor):
            converged = True
            break

    t0 = time.perf_counter()
    final = Sweep(batches, state, layout, obs, plate_hat, control_hat, options)
    acc = _assemble_checked(final, pobs, assembly, project, len(history) + 1)
    if free_network is not None:
        free_network = free_network.at(state, layout, acc.N)
    checks, next_correction = _final_checks(final, acc, vtpv, pobs, v_par, free_network, solver)
    timings["final_checks"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    if not len(dx) and not converged:
        next_correction = None  # no unknowns: the final checks make no correction
    status, message = "converged", ""
    if not converged:
        status = "iteration_limit"
        message = termination.iteration_limit(options.method, history, int(redundancy), options.max_iterations,
                                              options.tolerance, next_correction, causes)

    ip_count = len(project.image_points)
    n_weighted_control = int(np.count_nonzero(obs.q_control > 0))
    sigma0 = float(np.sqrt(vtpv / redundancy)) if redundancy > 0 else float("nan")
    return AdjustmentResult(
        method=options.method,
        solver=solver.name,
        state=state,
        layout=layout,
        offset=offset,
        sigma0=sigma0,
        redundancy=int(redundancy),
        vtpv=float(vtpv),
        iterations=len(history),
        converged=converged,
        history=history,
        n_conditions=int(n_conditions),
        n_observations=2 * ip_count + n_weighted_control + len(pobs),
        n_unknowns=layout.n_unknowns,
        n_parameter_observations=len(pobs),
        plate_residuals=plate_hat - obs.plate,
        plate_adjusted=plate_hat,
        control_residuals=control_hat - obs.control,
        control_adjusted=control_hat,
        parameter_residuals=v_par,
        N=acc.N,
        checks=checks,
        timings=timings,
        free_network=free_network,
        termination=status,
        termination_message=message,
        ids=(project.photos.ids, project.cameras.ids),
    )


def _observation_change(d_plate: np.ndarray, d_control: np.ndarray, obs: Observations) -> float:
    """The largest change of an adjusted observation in one iteration, in units of its standard
    deviation: the convergence criterion when there are no unknowns (a pure forward intersection,
    where only the adjusted observations l^ = l + v are iterated)."""
    sig = np.sqrt(obs.q_plate)
    c = np.max(np.abs(d_plate) / np.where(sig > 0, sig, np.inf), initial=0.0)
    qc = obs.q_control
    c_control = np.max(np.abs(d_control) / np.where(qc > 0, np.sqrt(np.where(qc > 0, qc, 1.0)), np.inf), initial=0.0)
    return float(max(c, c_control))


def normal_matrix_at_approximations(project: Project, options: AdjustmentOptions = AdjustmentOptions()):
    """N of the first iteration (at the approximate values) and the layout: enough to show the
    structure of the normal equations of any project without adjusting it. A project without
    unknowns gives a 0 x 0 N; numbers that overflow are a NumericalFailure (as in adjust)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        offset = reduction_offset(project)
        state, layout = initial_state(project, offset), build_layout(project)
        batches = build_batches(project)
        obs = observations_of(project, offset)
        assembly = Assembly.of(batches, state, layout, options.chunk_size)
        sweep = Sweep(batches, state, layout, obs, obs.plate, obs.control, options)
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


ROUNDING_FLOOR = 1e-6  # corrections below this (in standard deviations) that stop shrinking are round-off
# the same per unknown for the measure of the simultaneous adjustments (energy_floor), measured: a
# 10,000-photo strip held at its ends stalls at 2e-9 per unknown, a 100,000-photo strip (coordinates
# of 5e7 m in the reduced frame) at 2e-8
ROUND_OFF_PER_UNKNOWN = 1e-7


ROUND_OFF_ULPS = 64.0  # a correction below this many units in the last place of its element's value is round-off


def round_off_floor(state: State, layout: UnknownLayout) -> np.ndarray:
    """(n_unknowns,) the smallest correction each unknown can meaningfully take in double precision:
    ROUND_OFF_ULPS units in the last place of its value (a centre's largest coordinate in the
    reduced frame; 1 rad for a rotation; a camera element's value). A correction below it is
    round-off however small the element's standard deviation: an element held by a very heavy
    weight (an angle observed with sigma 1e-10 rad) otherwise never shows convergence."""
    eps = ROUND_OFF_ULPS * np.finfo(float).eps
    floor = np.zeros(layout.n_unknowns + 1)  # the last slot takes the -1 columns of held elements
    centre = eps * np.max(np.abs(state.xyz0), axis=1)
    floor[layout.photo_cols[:, :3]] = centre[:, None]
    floor[layout.photo_cols[:, 3:]] = eps
    floor[layout.camera_cols] = eps * np.abs(state.interior)
    return floor[:-1]


def largest_correction(dx: np.ndarray, n_diag: np.ndarray, floor: np.ndarray) -> float:
    """The largest |dx_i| sqrt(N_ii): a correction in units of the standard deviation its element
    would have if all others were known, over the corrections above their element's round-off
    floor (round_off_floor). The sequential method's measure; the simultaneous adjustments use
    :func:`correction_in_sigma`."""
    if not len(dx):
        return 0.0
    size = np.abs(dx)
    return float(np.max(np.where(size > floor, size * np.sqrt(np.maximum(n_diag, 0.0)), 0.0)))


def correction_in_sigma(dx: np.ndarray, N: sp.spmatrix) -> float:
    """The convergence measure of the simultaneous adjustments: ``sqrt(d^T N d)``, the largest
    correction of any function of the unknowns in units of that function's standard deviation.

    For a function ``f^T x`` the correction is ``f^T d`` and the standard deviation (a-priori
    weights) ``sqrt(f^T N^-1 f)``; by the Cauchy-Schwarz inequality in the metric of N
    ``max_f |f^T d| / sqrt(f^T N^-1 f) = sqrt(d^T N d)``, reached for ``f = N d``. So the measure
    bounds every element's correction in units of its true standard deviation, ``sqrt(Qxx_ii)``,
    however strongly the elements are correlated: unlike ``|dx_i| sqrt(N_ii)`` (the standard
    deviation if all other elements were known), which on a long strip is thousands of times
    smaller than the true one and demands corrections along its weak directions far below their
    precision - beyond double precision at 10,000 photos. It is also the decrease of v^T P v (in
    units of sigma0^2) the linearised step brings, its square one matrix-vector product.

    Round-off is a small vector of its own in every direction; it is not masked element by
    element (setting the small corrections of correlated elements to zero breaks the cancellation
    between them and raises the measure tenfold, measured on a 10,000-photo strip), but accepted as
    a whole by has_converged below energy_floor. For a free network (singular N, dx with inner
    constraints) the measure covers the estimable functions."""
    if not len(dx):
        return 0.0
    return float(np.sqrt(max(float(dx @ (N @ dx)), 0.0)))


def energy_floor(n_unknowns: int, element_floor: np.ndarray | None = None, n_diag: np.ndarray | None = None) -> float:
    """The round-off floor of :func:`correction_in_sigma`, below which a correction that no longer
    halves is accepted as converged (has_converged): ROUND_OFF_PER_UNKNOWN standard deviations in
    each of the n unknowns, independent, so added in quadrature; or, when larger, the largest
    round-off floor of one element (round_off_floor) in units of its standard deviation if all
    others were known, ``max_i floor_i sqrt(N_ii)``: an element held by a very heavy weight (an
    angle observed with sigma 1e-10 rad) cannot be computed to better than that."""
    floor = ROUND_OFF_PER_UNKNOWN * float(np.sqrt(max(n_unknowns, 1)))
    if element_floor is not None and len(element_floor):
        floor = max(floor, float(np.max(element_floor * np.sqrt(np.maximum(n_diag, 0.0)))))
    return floor


CONTRACTION_MAX = 0.5  # the rate below which the next correction is predicted from the last two


def has_converged(history: list[Iteration], tolerance: float, floor: float = ROUNDING_FLOOR) -> bool:
    """The stated criterion: the last correction is below ``tolerance`` (in the history's measure:
    standard deviations); or the correction the next iteration would make, predicted as the last
    one times the slower of the last two rates of contraction (``c_k max(c_k / c_(k-1),
    c_(k-1) / c_(k-2))``, both below CONTRACTION_MAX), is below it, so that the iteration that
    would only confirm convergence is saved (the final checks still form that correction and
    report it); or the iteration has reached the round-off floor of double precision (below
    ``floor``, by default ROUNDING_FLOOR, and no longer halving), which for very long strips with
    coordinates of thousands of kilometres lies above the tolerance.

    The slower of two rates, not the last one alone: Gauss-Newton contracts quadratically at first
    and linearly near a solution with residuals (measured: a strip with GNSS centres and no
    control went 2.2 -> 2.8e-5 -> 1.2e-7 -> 1.4e-9 sd, where the last rate alone predicted 4e-10
    after 2.8e-5)."""
    c = history[-1].max_correction
    if c < tolerance:
        return True
    if len(history) < 2:
        return False
    previous = history[-2].max_correction
    if len(history) >= 3 and 0.0 < c < CONTRACTION_MAX * previous:
        before = history[-3].max_correction
        if 0.0 < previous < CONTRACTION_MAX * before and c * max(c / previous, previous / before) < tolerance:
            return True
    return c < floor and c > 0.5 * previous


def stop_if_diverging(history: list[Iteration], method: str, redundancy: int = 0, causes=None) -> None:
    """Raise NumericalFailure, explained (termination.diverged: the last figures of the history and
    the likely cause, ``causes()`` called only then), when the iteration diverges: non-finite
    numbers, or corrections growing for four iterations in a row far beyond a first step (in
    Iteration.element_correction where it is known, else max_correction)."""
    last = history[-1]
    c = [h.max_correction if math.isnan(h.element_correction) else h.element_correction for h in history[-5:]]
    growing = len(c) == 5 and all(b > 2 * a for a, b in zip(c, c[1:])) and c[-1] > 1e6
    if np.isfinite(last.max_correction) and np.isfinite(last.vtpv) and not growing:
        return
    raise NumericalFailure(termination.diverged(method, history, redundancy, causes or (lambda: [])))


def _final_checks(sweep: Sweep, acc: NormalAccumulator, vtpv: float, pobs, v_par: np.ndarray,
                  free_network=None, solver: solvers.NormalSolver | None = None) -> tuple[dict, float | None]:
    """Schmid's checks after convergence.

    * every condition holds for the adjusted observations and the final unknowns (his final
      check): the largest misclosure g(l^, x^), in units of its standard deviation;
    * (58) B^T k = 0: at the solution the right-hand side u of the normal equations vanishes;
      reported as max |u_i| / sqrt(N_ii);
    * (59) v^T P v equals [LL.u], the reduced sum w^T M^-1 w - u^T N^-1 u formed in the
      reduction of the normal equations; reported as the relative difference.

    Also returns the largest correction (in standard deviations, as in the history) the next
    iteration would make, a by-product of (59) (None when N is singular): whether an iteration that
    stopped at max_iterations was still converging. The solve uses the adjustment's own solver
    when it is a direct one (its analysis of the pattern is reused), else ``auto``: a direct one,
    or ``strip-pcg`` where a direct factor would not fit in memory (docs/solvers.md).
    """
    max_g = acc.max_misclosure  # formed with N in the same sweep (_assemble)
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
        if free_network is None:
            dx = direct.solve(acc.N, acc.u).dx
        else:
            dx = -_solve_free_network(acc, direct, free_network).dx
        reduced = acc.wPw - float(acc.u @ dx)
        next_correction = correction_in_sigma(dx, acc.N)
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError):
        reduced = float("nan")
    rel = abs(reduced - vtpv) / max(vtpv, 1e-300) if vtpv > 1e-20 else abs(reduced - vtpv)
    return {
        "max_condition_misclosure_sigma": max_g,
        "max_BTk_sigma": btk,
        "vtpv_reduction_relative_difference": rel,
    }, next_correction
