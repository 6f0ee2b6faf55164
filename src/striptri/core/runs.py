"""What a run of ``striptri adjust`` is asked for (:class:`RunOptions`) and what it found
(:class:`RunSummary`, summary.json's typed form).

The command line (cli/adjust.py) and scripts build one frozen :class:`RunOptions` and pass it to
``pipeline.run_adjust(project_dir, out_dir, RunOptions(...))``. The adjustment options in it are
``None`` where project.toml's [adjustment] value stands (DESIGN section 10: the command line wins
over project.toml, which wins over the defaults); the rest belong to the run: the blunder
procedure, the point precision, the plate corrections, the covariance export and whether an
unconverged adjustment is kept.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, fields

GROUPS = ("photos", "camera", "points")  # the groups of covariance.npz (precision.export)
# the fields of RunOptions that are AdjustmentOptions values over project.toml's (pipeline.options_for)
ADJUSTMENT_FIELDS = ("method", "solver", "datum", "datum_points", "max_iterations", "cost_tolerance", "init",
                     "scale_form", "procedure", "direction", "polynomial_degree")


@dataclass(frozen=True)
class CovarianceRequest:
    """What ``striptri adjust --covariance`` asks for: groups (GROUPS), the datum points of an
    S-transformation (empty: the adjustment's datum) and whether it is a similarity (scale) or a
    rigid motion."""

    groups: tuple[str, ...]
    datum_points: tuple[str, ...] = ()
    scale: bool = True

    def __post_init__(self):
        unknown = [g for g in self.groups if g not in GROUPS]
        if unknown or not self.groups:
            raise ValueError(f"--covariance: unknown group(s) {', '.join(unknown) or '(none)'}; choose from "
                             f"{', '.join(GROUPS)}, separated by commas")
        if self.datum_points and "points" not in self.groups:
            raise ValueError("--covariance-datum needs the group points in --covariance")


@dataclass(frozen=True)
class RunOptions:
    """The options of one run (module doc).

    method, solver, datum, datum_points, max_iterations, cost_tolerance, init: AdjustmentOptions
    values (core.options), None for project.toml's. scale_form (conditions method), procedure,
    direction, polynomial_degree (sequential method): that method's options, None for the default.
    blunders: the gross-error procedure, "off", "snoop", "snoop-classic", "robust" or "robust-snoop". point_precision: "schmid90"
    (the orientation plus the measurement part, Schmid 87-90) or "joint92" (the rigorous joint form
    (92)). earth_curvature, refraction: the plate corrections, None for project.toml's
    [corrections]. covariance: a :class:`CovarianceRequest` (covariance.npz is written too)
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
    covariance: CovarianceRequest | None = None
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


@dataclass(kw_only=True)
class RunSummary(Mapping):
    """What a run found: the typed form of summary.json (DESIGN section 10), which summary.json
    and report.html both render (:meth:`as_dict` is summary.json's object, its keys in the
    contract's order). Also a read-only mapping of that object (``summary["sigma0"]``), for the
    scripts and tests that read summary.json's keys.

    The result (pipeline.summary_of): method, solver, sigma0 (None without redundancy),
    redundancy, vtpv, iterations, converged, n_photos, n_points, n_observations, n_conditions,
    n_unknowns, check_points (RMS and largest differences, m), timings_s (seconds per phase),
    factorisation and blas (what solved the normal equations), termination and message (why the
    iteration stopped, in words), plate_unit, datum (a free network only), checks (Schmid's final
    checks), history (per iteration). The run (pipeline.run_metadata): version, started, project,
    options. Then blunders (the gross-error procedure's counts and groups), warnings, and the
    sections that only some projects have, in this order: plate_corrections, inactive, gnss,
    distances, film, frame, automatic_tie_points (a project of striptri match: io.sources).
    """

    method: str
    solver: str
    sigma0: float | None
    redundancy: int
    vtpv: float | None
    iterations: int
    converged: bool
    n_photos: int
    n_points: int
    n_observations: int
    n_conditions: int
    n_unknowns: int
    check_points: dict
    timings_s: dict
    factorisation: str
    blas: str
    termination: str
    message: str
    plate_unit: str
    datum: dict | None = None
    checks: dict
    history: list
    version: str
    started: str
    project: str | None
    options: dict
    blunders: dict
    warnings: list
    plate_corrections: dict | None = None
    inactive: dict | None = None
    gnss: dict | None = None
    distances: dict | None = None
    film: dict | None = None
    frame: dict | None = None
    automatic_tie_points: dict | None = None

    def as_dict(self) -> dict:
        """summary.json's object: every field in order, the optional sections only when present."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name not in OPTIONAL_SECTIONS or getattr(self, f.name) is not None}

    def json(self) -> str:
        """summary.json's text (strict JSON: a value that is not finite is an error, not NaN)."""
        return json.dumps(self.as_dict(), indent=2, allow_nan=False) + "\n"

    def __getitem__(self, key: str):
        if key in OPTIONAL_SECTIONS and getattr(self, key) is None or key not in FIELD_NAMES:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self):
        return iter(self.as_dict())

    def __len__(self) -> int:
        return len(self.as_dict())


OPTIONAL_SECTIONS = ("datum", "plate_corrections", "inactive", "gnss", "distances", "film", "frame",
                     "automatic_tie_points")
FIELD_NAMES = frozenset(f.name for f in fields(RunSummary))
