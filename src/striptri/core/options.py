"""The options of an adjustment: one frozen, validated object with the options every method reads
and one object per method for the options only that method reads (STYLE: options in, summary out).

``AdjustmentOptions(method="bundle", bundle=BundleOptions(cost_tolerance=1e-9))``; the flat form
``AdjustmentOptions.of(method="bundle", cost_tolerance=1e-9)`` routes each keyword to the object it
belongs to (the command line and project.toml use it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Callable

METHODS = ("conditions", "bundle", "sequential")
# approximate values: as given in photos.csv, or from the sequential method (rough values suffice)
INITS = ("given", "sequential")
# "control": the datum comes from control and observed elements (a defect is an error);
# "inner": a free network, the directions the control leaves free fixed by inner constraints on the
# photos; "inner-points": by inner constraints on object points (striptri.equations.point_datum).
DATUMS = ("control", "inner", "inner-points")
SCALE_FORMS = ("3d", "xz")
PROCEDURES = (1, 2)
DIRECTIONS = ("forward", "backward")
# the per-photo steps of the sequential method may take at least this many iterations: a few each,
# but some of the relative orientation's starts need more
SEQUENTIAL_STEP_ITERATIONS = 30


@dataclass(frozen=True)
class ConditionsOptions:
    """Options of Schmid's method of conditions only.

    scale_form: "3d" (direction-free closest-approach scales) or "xz" (Schmid 94, strips flown along X).
    condition_transform: optional callable(GroupBatch) -> (m, nc, nc) invertible matrices that
    rescale or recombine each group's conditions (a test of invariance: the result must not depend
    on it).
    keep_solution_systems: keep the whitened groups of the final checks on the result
    (AdjustmentResult.solution_systems) for the residual cofactors of the tests that follow, which
    then linearise nothing again; the command sets it (memory of the order of the iterations'
    kept chunks, held until the cofactors are formed).
    """

    scale_form: str = "3d"
    condition_transform: Callable | None = None
    keep_solution_systems: bool = False

    def __post_init__(self):
        if self.scale_form not in SCALE_FORMS:
            raise ValueError(f"unknown scale form {self.scale_form!r}; choose one of {', '.join(SCALE_FORMS)}")
        if self.condition_transform is not None and not callable(self.condition_transform):
            raise ValueError("condition_transform must be a callable(GroupBatch) -> (m, nc, nc) matrices")


@dataclass(frozen=True)
class BundleOptions:
    """Options of the collinearity bundle adjustment only.

    cost_tolerance: 0 = off; else also converged when a step lowers the sum of squares by less than
    this fraction (Ceres' function tolerance; for problems with directions so weak that corrections
    stay large while the cost no longer changes, e.g. BAL problems). The termination is then
    "cost_flat", a success that says so.
    """

    cost_tolerance: float = 0.0

    def __post_init__(self):
        if not self.cost_tolerance >= 0.0:
            raise ValueError("cost_tolerance must be 0 (off) or positive")


@dataclass(frozen=True)
class SequentialOptions:
    """Options of the sequential method (Schut's procedures, DESIGN section 8).

    procedure: 1 (relative orientation + scale transfer) or 2 (Schmid's (20) & (14));
    direction: "forward" or "backward"; polynomial_degree: None (similarity only) or 1..3, the
    degree of the strip correction in the along-strip coordinate; tolerance, max_iterations: of
    every per-photo adjustment (criterion as adjust()).
    """

    procedure: int = 1
    direction: str = "forward"
    polynomial_degree: int | None = None
    tolerance: float = 1e-10
    max_iterations: int = SEQUENTIAL_STEP_ITERATIONS

    def __post_init__(self):
        if self.procedure not in PROCEDURES:
            raise ValueError(f"unknown procedure {self.procedure!r}; choose 1 or 2")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"unknown direction {self.direction!r}; choose forward or backward")
        if self.polynomial_degree is not None and not 1 <= self.polynomial_degree <= 3:
            raise ValueError("polynomial_degree must be None or 1, 2 or 3")
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be at least 1")

    @staticmethod
    def from_adjustment_options(options: "AdjustmentOptions") -> "SequentialOptions":
        """The sequential options of an AdjustmentOptions, with the larger of its max_iterations and
        the sequential options' own (by default SEQUENTIAL_STEP_ITERATIONS) as the limit of every
        per-photo step: [adjustment] max_iterations can raise the steps' limit, not lower it below
        what some relative orientations need."""
        return replace(options.sequential,
                       max_iterations=max(options.max_iterations, options.sequential.max_iterations))


@dataclass(frozen=True)
class AdjustmentOptions:
    """Options of an adjustment (every method), with one object per method inside.

    method: "conditions" (Schmid), "bundle" (collinearity) or "sequential" (Schut).
    solver: the normal-equation solver (docs/solvers.md; not used by the sequential method).
    max_iterations, tolerance: converged when every correction is below ``tolerance`` times its
    standard deviation (core.convergence), within max_iterations.
    chunk_size: points linearised at once (memory, not results).
    datum: "control", "inner" (a free network, inner constraints on the photos) or "inner-points"
    (on object points; the conditions and the bundle method).
    datum_points: the ids of the datum points of "inner-points" (empty: every point of the
    adjustment; else at least three).
    init: approximate values "given" (photos.csv) or "sequential" (from the sequential method).
    keep_unconverged: return an adjustment that stopped at its iteration limit as a result, with
    termination "iteration_limit"; by default it is a NumericalFailure (an unconverged adjustment
    is not a result).
    conditions, bundle, sequential: the options only that method reads.
    """

    method: str = "conditions"
    solver: str = "auto"
    max_iterations: int = 30
    tolerance: float = 1e-8
    chunk_size: int = 1024
    datum: str = "control"
    datum_points: tuple = ()
    init: str = "given"
    keep_unconverged: bool = False
    conditions: ConditionsOptions = field(default_factory=ConditionsOptions)
    bundle: BundleOptions = field(default_factory=BundleOptions)
    sequential: SequentialOptions = field(default_factory=SequentialOptions)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        if self.init not in INITS:
            raise ValueError(f"unknown init {self.init!r}; choose one of {', '.join(INITS)}")
        if self.datum not in DATUMS:
            raise ValueError(f"unknown datum {self.datum!r}; choose one of {', '.join(DATUMS)}")
        if self.method == "sequential" and self.datum != "control":
            raise ValueError(f"the sequential method takes its datum from control, not from a free network "
                             f"(datum {self.datum!r})")
        if self.datum_points and self.datum != "inner-points":
            raise ValueError("datum points are for the point datum: give it as well (--datum inner-points, or "
                             "[datum] mode = \"inner-points\")")
        if self.datum_points and len(self.datum_points) < 3:
            raise ValueError(f"the point datum needs at least three datum points, not {len(self.datum_points)}")
        if len(set(self.datum_points)) != len(self.datum_points):
            raise ValueError("a datum point is given twice")
        from .. import solvers  # here: reading a project imports these options, not the solvers (and scipy)

        solvers.resolve_solver(self.solver, 0)
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be at least 1")
        if self.chunk_size < 1:
            raise ValueError("chunk_size must be at least 1")

    @classmethod
    def of(cls, **flat) -> "AdjustmentOptions":
        """The options from flat keywords: each one goes to the object it belongs to
        (``cost_tolerance`` to ``bundle``, ``procedure`` to ``sequential``, ...). Unknown
        keywords are a TypeError."""
        own, nested = {}, {"conditions": {}, "bundle": {}, "sequential": {}}
        owners = {f.name: part for part, kind in (("conditions", ConditionsOptions), ("bundle", BundleOptions),
                                                  ("sequential", SequentialOptions)) for f in fields(kind)}
        top = {f.name for f in fields(cls)}
        for key, value in flat.items():
            if key in top and key not in nested:
                own[key] = value
            elif key in owners and key not in top:
                nested[owners[key]][key] = value
            else:
                raise TypeError(f"AdjustmentOptions has no option {key!r}")
        kinds = {"conditions": ConditionsOptions, "bundle": BundleOptions, "sequential": SequentialOptions}
        for part, values in nested.items():
            if values:
                own[part] = replace(own.get(part, kinds[part]()), **values)
        return cls(**own)
