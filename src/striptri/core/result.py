"""What an adjustment returns, whatever its method: AdjustmentResult with its iteration history,
the reason the iteration stopped (Termination), Schmid's checks and the timings of its phases
(STYLE: one result dataclass with everything a report needs)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
import scipy.sparse as sp

from ..equations import datum
from .. import solvers
from ..selected_inverse.covariance import Covariance
from ..errors import NumericalFailure
from ..equations.parameters import State, UnknownLayout
from ..geometry.rotations import angles_jacobian
from ..equations.observations import Observations

DENSE_QXX_LIMIT = 5000  # unknowns up to which AdjustmentResult.Qxx forms the dense N^-1

# Why an iteration stopped (summary.json "termination", docs/decisions.md "Termination"):
# "converged": the corrections fell below the tolerance (or the round-off floor); "cost_flat": the
# bundle's cost tolerance was met (also a success); "iteration_limit": max_iterations reached first;
# "diverged": non-finite numbers or corrections growing without bound; "datum_defect": the control
# does not fix the datum; "singular": an element not determined by the measurements;
# "not_finite": the equations overflow (wild values, units). Only the first two are results; an
# "iteration_limit" is kept when the user asks (--keep-unconverged); the rest are failures
# (NumericalFailure with that reason).
TERMINATIONS = ("converged", "cost_flat", "iteration_limit", "diverged", "datum_defect", "singular", "not_finite")
SUCCESSFUL_TERMINATIONS = ("converged", "cost_flat")


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
    solver_info: solvers.SolverInfo = field(default_factory=solvers.SolverInfo)  # the solve's report
    element_correction: float = float("nan")


class _Record:
    """A record of named numbers, None where a field does not apply; ``as_dict`` gives the ones
    that do, in field order (summary.json)."""

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class Checks(_Record):
    """Schmid's checks after convergence (the simultaneous methods).

    max_condition_misclosure_sigma: every condition (observation equation) holds for the adjusted
    observations and the final unknowns: the largest misclosure in units of its standard deviation
    (his final check).
    max_BTk_sigma: (58) B^T k = 0, the right-hand side of the normal equations vanishes at the
    solution: max |u_i| / sqrt(N_ii).
    vtpv_reduction_relative_difference: (59) v^T P v equals [LL.u], the reduced sum formed in the
    reduction of the normal equations: their relative difference (reduction_check).
    max_point_gradient_sigma: the bundle only, (58) for the point coordinates.
    """

    max_condition_misclosure_sigma: float
    max_BTk_sigma: float
    vtpv_reduction_relative_difference: float
    max_point_gradient_sigma: float | None = None


@dataclass(frozen=True)
class SequentialChecks(_Record):
    """The sequential method's fits in metres (docs/sequential.md): the RMS of the absolute
    orientation's residuals per axis and its redundancy, the RMS of the scale transfers, the RMS
    of the reprojection residuals (plate units), the procedure and whether it ran backward (1/0)."""

    absolute_orientation_rms_X_m: float
    absolute_orientation_rms_Y_m: float
    absolute_orientation_rms_Z_m: float
    absolute_orientation_redundancy: float
    scale_transfer_rms_m: float
    reprojection_rms_plate: float
    procedure: float
    backward: float


@dataclass
class Timings(_Record):
    """Seconds per phase of an adjustment (summary.json timings_s); None: not a phase of the method.
    The method of conditions: conditions (forming and linearising them), assembly (whitening and
    summing N), solve, back_substitution, final_checks. The bundle: initial_points (their
    intersection), linearisation_and_reduction (linearising and eliminating the points), solve,
    back_substitution, final_checks. The sequential method: total only."""

    initial_points: float | None = None
    conditions: float | None = None
    linearisation_and_reduction: float | None = None
    assembly: float | None = None
    solve: float | None = None
    back_substitution: float | None = None
    final_checks: float | None = None
    total: float = 0.0

    def add(self, phase: str, seconds: float) -> None:
        setattr(self, phase, (getattr(self, phase) or 0.0) + seconds)


def observation_count(project, obs: Observations, n_parameter_observations: int) -> int:
    """The observations of a simultaneous adjustment: two plate coordinates per image point, the
    weighted control coordinates, the observed elements and the observed distances (distances.csv)."""
    n_distances = 0 if project.distances is None else len(project.distances)
    return (2 * len(project.image_points) + int(np.count_nonzero(obs.q_control > 0)) + int(n_parameter_observations)
            + n_distances)


def sigma0_of(vtpv: float, redundancy: int) -> float:
    """sigma0 a posteriori ``sqrt(v^T P v / r)`` (Schmid 60); nan without redundancy."""
    return float(np.sqrt(vtpv / redundancy)) if redundancy > 0 else float("nan")


class SolutionSystems:
    """The method of conditions' whitened groups at the solution, from the sweep of its final
    checks (ConditionsOptions.keep_solution_systems), kept for the residual cofactors that come
    next (precision.residuals): the tests then need no linearisation of their own. Per chunk of
    groups its whitened system (conditions_method's kept chunk: chunk, Bw = L^-1 B, Gt = L^-1 A Q,
    clear (m,): M = A Q A^T clearly regular), or for a chunk of long tracks the chunk alone (its
    groups are formed from B by ray again). They hold for the project adjusted only, and are taken
    once (:meth:`take`), chunk by chunk, so that memory falls as they are used."""

    def __init__(self, project, chunks: list):
        self.project, self._chunks = project, chunks

    def take(self, project) -> list | None:
        """The chunks, once, for ``project`` (the very project adjusted), else None; either way they
        are let go here, for every copy of the result that shares them."""
        chunks, self._chunks = self._chunks, None
        return chunks if project is self.project else None


@dataclass
class AdjustmentResult:
    """Everything a report needs. Ground coordinates are in the reduced frame; add ``offset``.

    termination: why the iteration stopped (TERMINATIONS: "converged" or "cost_flat" for a result,
    "iteration_limit" for one kept with keep_unconverged); termination_message: for every reason but
    "converged", the same in words with the last figures of the history and the likely cause.
    """

    method: str
    solver: str
    state: State
    layout: UnknownLayout
    offset: np.ndarray
    sigma0: float
    redundancy: int
    vtpv: float
    iterations: int
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
    checks: Checks | SequentialChecks
    timings: Timings = field(default_factory=Timings)
    free_network: datum.FreeNetwork | None = None
    termination: str = "converged"
    termination_message: str = ""
    # (photo ids, camera ids) of the project: names the unknowns in messages (None: by column)
    ids: tuple | None = None
    _covariance: Covariance | None = None
    # the method of conditions' whitened groups at the solution for the residual cofactors, or None
    solution_systems: SolutionSystems | None = None

    def __post_init__(self):
        if self.termination not in TERMINATIONS:
            raise ValueError(f"unknown termination {self.termination!r}")

    @classmethod
    def of(cls, project, obs: Observations, *, plate_adjusted: np.ndarray, control_adjusted: np.ndarray,
           vtpv: float, redundancy: int, history: list[Iteration], layout: UnknownLayout,
           **rest) -> "AdjustmentResult":
        """The result of a method, with what every method computes alike: sigma0 (sigma0_of), the
        residuals ``l^ - l`` of the adjusted plate and control observations, the number of
        unknowns, the ids that name them, and ``iterations`` (by default one per history entry).
        ``rest``: the other fields, by name (``iterations`` among them when not one per entry)."""
        iterations = rest.pop("iterations", None)
        return cls(sigma0=sigma0_of(vtpv, redundancy), redundancy=int(redundancy), vtpv=float(vtpv),
                   history=history, iterations=len(history) if iterations is None else int(iterations),
                   layout=layout, n_unknowns=layout.n_unknowns,
                   plate_adjusted=plate_adjusted, plate_residuals=plate_adjusted - obs.plate,
                   control_adjusted=control_adjusted, control_residuals=control_adjusted - obs.control,
                   ids=(project.photos.ids, project.cameras.ids), **rest)

    @property
    def converged(self) -> bool:
        """Whether the iteration ended in a result (termination "converged" or "cost_flat")."""
        return self.termination in SUCCESSFUL_TERMINATIONS

    @property
    def covariance(self) -> Covariance:
        """Selected entries of Qxx = N^-1 (covariance.Covariance), computed once. Raises
        NumericalFailure, naming the first element that is not determined, when N is singular."""
        if self._covariance is None:
            if not np.isfinite(sp.csr_matrix(self.N).data).all():
                raise NumericalFailure(self._precision_failure(None), reason="not_finite")
            try:
                self._covariance = Covariance(self.N, self.layout, self.free_network)
            except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:
                raise NumericalFailure(self._precision_failure(exc), reason="singular") from exc
        return self._covariance

    def release_covariance(self, keep_blocks: bool = False) -> None:
        """Let the selected inverse behind ``covariance`` go, keeping its photo blocks and diagonal
        and, with ``keep_blocks``, the blocks its group forms have read (Covariance.release: what
        needs more makes it again); nothing when it was never computed."""
        if self._covariance is not None:
            self._covariance.release(keep_blocks)

    def _precision_failure(self, exc: Exception | None) -> str:
        """Why Qxx cannot be formed: a singular N (naming the first element that is not determined)
        or one with numbers that are not finite; with the adjustment's own failure when it had one."""
        status = "" if self.converged else (
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
        Q_xyz, Q_ang = self._photo_cofactors(convention)
        return (s0 * np.sqrt(np.maximum(np.einsum("nii->ni", Q_xyz), 0)),
                s0 * np.sqrt(np.maximum(np.einsum("nii->ni", Q_ang), 0)))

    def photo_covariances(self, convention: str) -> np.ndarray:
        """Covariances (sigma0^2 Q) of each photo's centre and angles in ``convention``:
        (n, 6, 6) over X0, Y0, Z0 (m) and the three angles (rad); fixed elements zero."""
        Qphoto = self.covariance.photo_blocks()  # (n, 6, 6), fixed elements zero
        F = np.zeros_like(Qphoto)
        F[:, :3, :3] = np.eye(3)
        F[:, 3:, 3:] = angles_jacobian(self.state.R_ground_from_cam, convention) @ self.layout.rotation_maps(self.state)
        return self.sigma0_for_precision**2 * (F @ Qphoto @ np.swapaxes(F, 1, 2))

    def _photo_cofactors(self, convention: str) -> tuple[np.ndarray, np.ndarray]:
        Qphoto = self.covariance.photo_blocks()  # (n, 6, 6), fixed elements zero
        T = self.layout.rotation_maps(self.state)
        J = angles_jacobian(self.state.R_ground_from_cam, convention) @ T
        return Qphoto[:, :3, :3], J @ Qphoto[:, 3:, 3:] @ np.swapaxes(J, 1, 2)

    def camera_mean_errors(self) -> np.ndarray:
        s0 = self.sigma0_for_precision
        diag = np.concatenate([self.covariance.diag(), [0.0]])
        return s0 * np.sqrt(np.maximum(diag[self.layout.camera_cols], 0))
