"""Options and results of blunder detection, and what both procedures share: removing rows,
knowing which rows take part, the residuals of rows left out, the per-row results."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..core.adjusted_points import triangulate_adjusted  # re-exported: the ground points of an adjustment
from ..core.result import SUCCESSFUL_TERMINATIONS, AdjustmentResult
from ..equations.groups import points_with_conditions
from ..model import Project
from ..equations.parameters import with_state
from ..equations.triangulation import ray_terms
from .measures import ALPHA0, BETA0, PlateReliability, critical_value, noncentrality, row_abs, row_statistic

FLAG_OK, FLAG_SUSPECT, FLAG_REJECTED, FLAG_DROPPED = "", "suspect", "rejected", "dropped"
FLAG_INSEPARABLE = "inseparable"  # rejected with others as one group: detected, not localisable
FLAGS = (FLAG_OK, FLAG_SUSPECT, FLAG_REJECTED, FLAG_DROPPED, FLAG_INSEPARABLE)
BLUNDER_METHODS = ("snoop", "robust", "robust-snoop", "off")
PROCEDURES = ("separable", "classic")
PER_ROUND = ("separated", "single")


@dataclass(frozen=True)
class BlunderOptions:
    """Options of gross-error detection (striptri.reliability).

    method: "snoop" (data snooping), "robust" (reweighting), "robust-snoop" (reweighting to find the
    first rejections, then data snooping from the survivors) or "off" (flag only).
    alpha0, beta0: size and power of the w-test (critical value, MDB).
    per_round (snoop): "separated" rejects several well separated rows per round
    (snooping.select_rejections); "single" one row per round (textbook data snooping).
    procedure (snoop): "separable" (inseparable groups rejected together, rejected groups re-tested
    and re-admitted, snooping.snoop) or "classic" (the procedure before issue 18).
    max_rejections: at most this many rows are rejected (None: 10 % of the rows, at least 1); rows
    still above the critical value are then flagged "suspect".
    max_rounds: adjustments at most (snoop: testing rounds; robust: reweighting iterations).
    robust_c: the constant c of the weight function (robust.robust_weight), in units of the
    studentised gross error. robust_tolerance: reweighting has converged when no weight changes
    by more than this. min_weight: the smallest weight (keeps the normal equations finite).
    """

    method: str = "snoop"
    alpha0: float = ALPHA0
    beta0: float = BETA0
    per_round: str = "separated"
    procedure: str = "separable"
    max_rejections: int | None = None
    max_rounds: int = 100
    robust_c: float = 3.0
    robust_tolerance: float = 0.01
    min_weight: float = 1e-6

    def __post_init__(self):
        if self.method not in BLUNDER_METHODS:
            raise ValueError(f"unknown blunder method {self.method!r}; choose one of {', '.join(BLUNDER_METHODS)}")
        if self.procedure not in PROCEDURES:
            raise ValueError(f"procedure must be one of {', '.join(PROCEDURES)}")
        if self.per_round not in PER_ROUND:
            raise ValueError(f"per_round must be one of {', '.join(PER_ROUND)}")
        if not (0 < self.alpha0 < 1 and 0 < self.beta0 < 1):
            raise ValueError("alpha0 and beta0 must lie in (0, 1)")
        if self.max_rejections is not None and self.max_rejections < 0:
            raise ValueError("max_rejections must be non-negative")
        if self.max_rounds < 1:
            raise ValueError("max_rounds must be at least 1")
        if not (self.robust_c > 0 and self.robust_tolerance > 0 and 0 < self.min_weight < 1):
            raise ValueError("robust_c and robust_tolerance must be positive, min_weight in (0, 1)")

    def rejection_limit(self, m: int) -> int:
        """The most rows that may be rejected out of m."""
        return self.max_rejections if self.max_rejections is not None else max(1, int(np.ceil(0.1 * m)))


def blunder_options(name: str) -> BlunderOptions:
    """The options of a ``--blunders`` choice: "off", "snoop", "robust", "robust-snoop", or "snoop-classic" (data
    snooping with procedure "classic")."""
    if name == "snoop-classic":
        return BlunderOptions(method="snoop", procedure="classic")
    return BlunderOptions(method=name)


@dataclass
class Rejection:
    """One rejected image point: its row in the original ImagePoints, its photo and point index,
    the round (1-based adjustment) after which it was rejected, and its w (x, y) and MDB (x, y) in
    that adjustment. Robust method: w holds the studentised estimated gross errors u
    (robust.studentised_gross_errors) of the last reweighting; MDB is nan."""

    row: int
    photo_index: int
    point_index: int
    round: int
    w: np.ndarray
    mdb: np.ndarray
    group: int = -1  # rows rejected together as one inseparable group share this number


@dataclass
class Round:
    """One adjustment of the procedure: rows rejected after it (snoop) or rows with a weight below
    1/2 (robust), the largest row |w| (robust: u), its Gauss-Newton iterations and seconds."""

    rejected: int
    max_abs_w: float
    iterations: int
    seconds: float


@dataclass
class BlunderResult:
    """The outcome of blunder detection.

    result: the final adjustment, of ``project`` (the rows kept; approximate orientations from the
    previous round); rows: (m_kept,) the original row of each row of ``project.image_points``.
    Per row of the *original* ImagePoints, (m, 2) for x and y unless said:

    * w: normalised residual in the final adjustment; nan for rejected and dropped rows and where
      the coordinate has no redundancy;
    * redundancy: r_i in the final adjustment (nan for rejected rows);
    * mdb: minimal detectable bias (plate units) in the final adjustment; inf where r_i = 0, nan
      for rejected rows (their MDB at rejection is in ``rejected``);
    * bnr: bias-to-noise ratio, likewise;
    * v: residual in the final adjustment; for a rejected row the residual it would have there,
      ``f(x^) - l`` with its point triangulated from the remaining rays (about minus the gross
      error; nan when the point is no longer determined);
    * flag: (m,) "" | "suspect" (|w| > critical value, not rejected) | "rejected" | "dropped" (the
      row's point lost its conditions when other rows of it were rejected);
    * weights: robust method: the final reweighting weights (1 = full weight); otherwise None.

    rejected: in the order of rejection. rounds: one per adjustment. stopped: why the procedure
    ended: "clean" (no |w| above the critical value), "limit" (max_rejections), "rounds"
    (max_rounds; robust: the re-weighting did not converge), "off", "failure: <message>" (a
    re-adjustment failed or did not converge: the rows of that round were taken back and are flagged
    "suspect"), or "not tested: ..." (the adjustment of all rows did not converge: no w-test, see
    :func:`untested`).
    """

    method: str
    result: AdjustmentResult
    project: Project
    rows: np.ndarray
    w: np.ndarray
    redundancy: np.ndarray
    mdb: np.ndarray
    bnr: np.ndarray
    v: np.ndarray
    flag: np.ndarray
    rejected: list[Rejection]
    rounds: list[Round]
    stopped: str
    critical: float
    delta0: float
    weights: np.ndarray | None = None
    seconds: float = 0.0

    @property
    def row_w(self) -> np.ndarray:
        """(m,) the signed w of the larger magnitude of x and y (residuals.csv's w column)."""
        return row_statistic(self.w)

    @property
    def groups(self) -> list[np.ndarray]:
        """The original rows of every rejected group (rows rejected together because their
        w-tests cannot be told apart share one), in the order of rejection."""
        out: dict[int, list[int]] = {}
        for k, rej in enumerate(self.rejected):
            out.setdefault(rej.group if rej.group >= 0 else -1 - k, []).append(rej.row)
        return [np.array(rows, dtype=int) for rows in out.values()]

    @property
    def rejected_rows(self) -> np.ndarray:
        return np.array([rej.row for rej in self.rejected], dtype=int)


def succeeded(result: AdjustmentResult) -> bool:
    """The adjustment ended with a result ("converged" or "cost_flat"): only then do its residuals
    and normal matrix describe a solution that w-tests can judge."""
    return result.termination in SUCCESSFUL_TERMINATIONS


def untested(method: str, project: Project, result: AdjustmentResult, blunders: "BlunderOptions",
             seconds: float = 0.0) -> BlunderResult:
    """The outcome when the adjustment of all rows did not converge (termination "iteration_limit"):
    no w-test, no rejection, every flag empty, w and MDB nan; ``stopped`` names the termination.
    The caller ends with the adjustment's termination_message (or keeps the result when asked)."""
    m = len(project.image_points)
    nan = np.full((m, 2), np.nan)
    return BlunderResult(
        method=method, result=result, project=project, rows=np.arange(m), w=nan, redundancy=nan.copy(),
        mdb=nan.copy(), bnr=nan.copy(), v=result.plate_residuals.copy(), flag=np.full(m, FLAG_OK, dtype=object),
        rejected=[], rounds=[Round(0, float("nan"), result.iterations, seconds)],
        stopped=f"not tested: the adjustment ended with \"{result.termination}\"",
        critical=critical_value(blunders.alpha0), delta0=noncentrality(blunders.alpha0, blunders.beta0),
        seconds=seconds,
    )


def without_tests(project: Project, result: AdjustmentResult, stopped: str) -> BlunderResult:
    """The outcome of an adjustment whose residuals are not tested (method "off", ``stopped`` says
    why: e.g. the sequential method, whose normal matrix is not that of a simultaneous adjustment,
    so that normalised residuals and MDBs would mean nothing, docs/sequential.md): every row kept,
    its residual, w, redundancy and MDB nan, no flag."""
    m = len(project.image_points)
    nan = np.full((m, 2), np.nan)
    return BlunderResult(
        method="off", result=result, project=project, rows=np.arange(m), w=nan, redundancy=nan.copy(),
        mdb=nan.copy(), bnr=nan.copy(), v=result.plate_residuals, flag=np.full(m, FLAG_OK, dtype=object),
        rejected=[], rounds=[], stopped=stopped, critical=float("nan"), delta0=float("nan"),
    )


def subset(project: Project, keep: np.ndarray) -> Project:
    """The project with only the ImagePoints rows where keep is True: the project itself when keep is
    true everywhere (the first round of the tests), so that what is kept for that project object (its
    condition groups: groups.build_batches) serves the tests too."""
    ip = project.image_points
    if keep.dtype == bool and len(keep) == len(ip.point_index) and keep.all():
        return project
    return replace(project, image_points=replace(
        ip, photo_index=ip.photo_index[keep], point_index=ip.point_index[keep], xy=ip.xy[keep],
        sigma_xy=ip.sigma_xy[keep],
    ))


warm_start = with_state  # re-adjustments start from the previous adjusted orientations


def participating_rows(project: Project) -> np.ndarray:
    """(m,) True for the rows of points that have conditions (take part in the adjustment)."""
    return points_with_conditions(project)[project.image_points.point_index]


def predicted_residuals(project: Project, adjusted: Project, result: AdjustmentResult, rows: np.ndarray) -> np.ndarray:
    """``f(x^) - l`` of rows of ``project`` left out of the adjustment of ``adjusted``: the point
    triangulated from its adjusted rays (and control), projected into the row's photo with the
    adjusted orientation. -> (len(rows), 2); nan where the point is not determined."""
    s = result.state
    tri = triangulate_adjusted(adjusted, result)
    ip = project.image_points
    ph, pt = ip.photo_index[rows], ip.point_index[rows]
    X = np.where(tri.determined[pt, None], tri.xyz[pt], np.nan)
    params, conv = s.camera_terms(ph)
    with np.errstate(invalid="ignore", divide="ignore"):
        res, *_ = ray_terms(s.R_ground_from_cam[ph][:, None], s.xyz0[ph][:, None], params[:, None], conv[:, None], X,
                            ip.xy[rows][:, None], with_lens=result.layout.lens_in_play(s))
    return -res[:, 0]


class FinalAdjustment(NamedTuple):
    """The last adjustment of a blunder procedure: ``adjusted`` the project of the rows it kept,
    its ``result`` and reliability ``rel``, ``rows`` the indices of those rows in the original."""

    adjusted: Project
    result: AdjustmentResult
    rel: PlateReliability
    rows: np.ndarray


def blunder_result(method: str, project: Project, final: FinalAdjustment, rejected: list[Rejection],
                   rounds: list[Round], stopped: str, seconds: float,
                   weights: np.ndarray | None = None) -> BlunderResult:
    """The per-row results over the original rows of ``project`` (BlunderResult) from the final
    adjustment of the rows it kept (``final``)."""
    adjusted, result, rel, rows = final
    m = len(project.image_points)
    keep = np.zeros(m, dtype=bool)
    keep[rows] = True

    def spread(values):
        out = np.full((m, 2), np.nan)
        out[rows] = values
        return out

    v = spread(result.plate_residuals)
    gone = np.flatnonzero(~keep)
    if len(gone):
        v[gone] = predicted_residuals(project, adjusted, result, gone)
    w = spread(rel.w)
    flag = np.full(m, FLAG_OK, dtype=object)
    now_part = np.zeros(m, dtype=bool)
    now_part[rows] = participating_rows(adjusted)
    flag[keep & participating_rows(project) & ~now_part] = FLAG_DROPPED
    flag[keep & (row_abs(w) > rel.critical)] = FLAG_SUSPECT
    flag[~keep] = FLAG_REJECTED
    sizes: dict[int, int] = {}
    for rej in rejected:
        sizes[rej.group] = sizes.get(rej.group, 0) + 1
    flag[[rej.row for rej in rejected if rej.group >= 0 and sizes[rej.group] > 1]] = FLAG_INSEPARABLE
    return BlunderResult(
        method=method, result=result, project=adjusted, rows=rows, w=w, redundancy=spread(rel.redundancy),
        mdb=spread(rel.mdb), bnr=spread(rel.bnr), v=v, flag=flag, rejected=rejected, rounds=rounds,
        stopped=stopped, critical=rel.critical, delta0=rel.delta0, weights=weights, seconds=seconds,
    )
