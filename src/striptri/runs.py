"""What a run of ``striptri adjust`` is asked for: the typed options of pipeline.run_adjust.

The command line (cli/adjust.py) and scripts build one frozen :class:`RunOptions` and pass it to
``pipeline.run_adjust(project_dir, out_dir, RunOptions(...))``. The adjustment options in it are
``None`` where project.toml's [adjustment] value stands (DESIGN section 10: the command line wins
over project.toml, which wins over the defaults); the rest belong to the run: the blunder
procedure, the point precision, the plate corrections, the covariance export and whether an
unconverged adjustment is kept.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .precision.export import CovarianceRequest

# the fields of RunOptions that are AdjustmentOptions values over project.toml's (pipeline.options_for)
ADJUSTMENT_FIELDS = ("method", "solver", "datum", "datum_points", "max_iterations", "cost_tolerance", "init",
                     "scale_form", "procedure", "direction", "polynomial_degree")


@dataclass(frozen=True)
class RunOptions:
    """The options of one run (module doc).

    method, solver, datum, datum_points, max_iterations, cost_tolerance, init: AdjustmentOptions
    values (core.options), None for project.toml's. scale_form (conditions method), procedure,
    direction, polynomial_degree (sequential method): that method's options, None for the default.
    blunders: the gross-error procedure, "off", "snoop", "snoop-classic" or "robust". point_precision: "schmid90"
    (the orientation plus the measurement part, Schmid 87-90) or "joint92" (the rigorous joint form
    (92)). earth_curvature, refraction: the plate corrections, None for project.toml's
    [corrections]. covariance: a precision.export.CovarianceRequest (covariance.npz is written too)
    or None. keep_unconverged: write an adjustment that stopped without converging (converged:
    false) instead of failing.
    """

    method: str | None = None
    solver: str | None = None
    datum: str | None = None
    datum_points: tuple[str, ...] | None = None
    max_iterations: int | None = None
    cost_tolerance: float | None = None
    init: str | None = None
    scale_form: str | None = None
    procedure: int | None = None
    direction: str | None = None
    polynomial_degree: int | None = None
    blunders: str = "off"
    point_precision: str = "schmid90"
    earth_curvature: bool | None = None
    refraction: bool | None = None
    covariance: "CovarianceRequest | None" = None
    keep_unconverged: bool = False

    def __post_init__(self) -> None:  # the values are checked where a run starts (pipeline.run_adjust)
        if self.datum_points is not None:
            object.__setattr__(self, "datum_points", tuple(str(p) for p in self.datum_points))

    @property
    def adjustment(self) -> dict:
        """The AdjustmentOptions values given here (not None), by name (pipeline.options_for)."""
        return {k: getattr(self, k) for k in ADJUSTMENT_FIELDS if getattr(self, k) is not None}

    @property
    def corrections(self) -> dict:
        """The plate-correction switches, None where project.toml's [corrections] stands
        (equations.plate_corrections.with_switches)."""
        return {"earth_curvature": self.earth_curvature, "refraction": self.refraction}


assert set(ADJUSTMENT_FIELDS) <= {f.name for f in fields(RunOptions)}
