"""``striptri plan DIR --out OUT``: read a plan, analyse it, write the folder whole or not at all.

Output folder (docs/plan.md, docs/file-formats.md): photos.csv, cameras.csv and points.csv in the
columns ``striptri adjust`` writes (the mean errors a priori, sigma0 = 1), points.csv with the
reliability columns after the contract's; reliability.csv (one row per plate measurement);
whatifs.csv (the plan and each what-if, one row each); control_ranking.csv (unless switched off);
summary.json (adjust's keys, sigma0 = 1, and "plan"); report.html.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.csvtable import format_csv
from ..io.output import OutputReservation, check_output_location
from ..io.project_reader import read_project
from ..model import CHECK, Project
from ..pipeline import (camera_table, input_paths, options_for, photo_table, point_table, run_metadata, run_started,
                        solver_source, summary_of)
from ..solvers import SolverUnavailable
from . import ranking as fast_ranking
from . import report, vongruber, whatif
from .analysis import PlanAnalysis, analyse
from .design import planned_points

WHATIF_COLUMNS = ("case", "status", "n_points", "worst_sigma_XY", "rms_sigma_XY", "worst_sigma_Z", "rms_sigma_Z",
                  "worst_sigma_P", "message")
RANKING_COLUMNS = ("rank", "point_id", "kind", "status", "worst_sigma_P", "loss_sigma_P")


@dataclass
class PlanProducts:
    analysis: PlanAnalysis
    summary: dict
    whatifs: list
    ranking: list | None
    files: dict


AUTO_RANK_LIMIT = 40  # control points up to which the ranking is computed unless asked (one analysis each)


@dataclass(frozen=True)
class PlanOptions:
    """What ``striptri plan`` is asked for (docs/plan.md).

    drop_control, add_control, sigma_image, keep_every, overlap: the what-ifs (whatif: control
    points dropped or added, plate sigmas, every k-th photo kept, forward overlaps of re-spaced
    photos); rank_control: True, False, or None: rank when the rank-3 update applies
    (plan.ranking) or the plan has at most AUTO_RANK_LIMIT control points (the brute force
    re-analyses the plan once per control point; otherwise a warning says so). von_gruber (or no
    image_points.csv): the tie points are the plan's von Gruber points (plan.vongruber), with
    plate_format ("W" or "WxH", plate units) and terrain_height (m) or their project.toml [plan]
    keys. method, solver: over project.toml's [adjustment] (None: project.toml's)."""

    drop_control: tuple = ()
    add_control: tuple = ()
    sigma_image: tuple = ()
    keep_every: tuple = ()
    overlap: tuple = ()
    rank_control: bool | None = None
    von_gruber: bool = False
    plate_format: str | None = None
    terrain_height: float | None = None
    method: str | None = None
    solver: str | None = None

    def __post_init__(self):
        for name in ("drop_control", "add_control", "sigma_image", "keep_every", "overlap"):
            object.__setattr__(self, name, tuple(getattr(self, name) or ()))

    @property
    def adjustment(self) -> dict:
        """The AdjustmentOptions values given here (pipeline.options_for)."""
        return {k: v for k, v in (("method", self.method), ("solver", self.solver)) if v is not None}


def run_plan(project_dir, out_dir, plan: PlanOptions = PlanOptions(), on_warning=None) -> PlanProducts:
    """Read the plan in ``project_dir``, analyse it with the what-ifs of ``plan`` (PlanOptions),
    write ``out_dir`` (module doc). The output location is checked before anything is read;
    InputError for bad input or bad what-ifs, NumericalFailure when the plan itself cannot be
    adjusted (e.g. a datum defect)."""
    project_dir = Path(project_dir)
    inputs = input_paths(project_dir)
    check_output_location(out_dir, inputs)
    project = read_project(project_dir, plate_measurements_optional=True)
    said = [str(note) for note in project.notes]
    generate = plan.von_gruber or not len(project.image_points)
    geometry = None
    if generate or plan.overlap:
        toml = vongruber.plan_settings(project_dir)
        geometry = (vongruber.format_of(plan.plate_format, toml, project_dir),
                    vongruber.terrain_height(plan.terrain_height, toml, project, project_dir))
    tie_points = "image_points.csv"
    if generate:
        project, tie_points = vongruber.von_gruber_project(project, *geometry)
    for text in said:
        if on_warning is not None:
            on_warning(text)
    options = options_for(project, **plan.adjustment)
    if options.method == "sequential":
        raise InputError("command line", None, "a plan is analysed for a simultaneous adjustment (conditions or "
                         "bundle); the sequential method has no normal matrix of the whole block")
    xyz = planned_points(project)
    cases = ([whatif.drop_control(project, s) for s in plan.drop_control]
             + [whatif.add_control(project, s, xyz) for s in plan.add_control]
             + [whatif.sigma_image(project, float(s)) for s in plan.sigma_image]
             + [whatif.every_kth_photo(project, k) for k in plan.keep_every]
             + [whatif.respaced(project, float(p), *geometry) for p in plan.overlap])
    with OutputReservation(out_dir, inputs) as reservation:
        try:
            products = plan_products(project, options, xyz, cases, plan.rank_control, said, on_warning, tie_points)
        except SolverUnavailable as exc:
            raise InputError(solver_source(project_dir, plan.adjustment), None, str(exc)) from exc
        reservation.commit(products.files)
    return products


def plan_products(project: Project, options, xyz: np.ndarray, cases: list, rank_control: bool | None,
                  said: list[str] = (), on_warning=None, tie_points: str = "image_points.csv") -> PlanProducts:
    """Analyse, evaluate the what-ifs and the ranking, and build the files (module doc). said: the
    warnings so far (the project's notes), summary.json "warnings"; rank_control as run_plan's;
    tie_points: where the sightings come from (summary.json plan.tie_points)."""
    said = list(said)
    started = run_started()
    t0 = time.perf_counter()
    a = analyse(project, options, xyz)
    seconds_analysis = time.perf_counter() - t0
    base = {"case": "plan", "status": "ok", "message": "", "worst_sigma_P": whatif.worst_sigma_p(a.project, a.sigma_points),
            **a.precision_figures()}
    rows = [base] + [{"case": c.name, **whatif.evaluate(c.project, options, xyz if c.xyz is None else c.xyz)}
                     for c in cases]
    t1 = time.perf_counter()
    ranking, how = None, None
    fast = fast_ranking.applicable(a.result, options)
    n_control = len(whatif.control_indices(project))
    if rank_control is None:
        rank_control = fast or n_control <= AUTO_RANK_LIMIT
        if not rank_control:
            said.append(f"the control ranking was not computed: without the rank-3 update (self-calibration, "
                        f"distortion or a free network) it analyses the plan once more for each of the {n_control} "
                        f"control points (more than {AUTO_RANK_LIMIT}); ask for it with --rank-control")
            if on_warning is not None:
                on_warning(said[-1])
    if rank_control and fast:
        ranking, how = whatif.ranked(project, fast_ranking.rank_control_fast(a.project, a.result, a.sigma_points),
                                     base), "rank-3 update"
    elif rank_control:
        ranking, how = whatif.rank_control(project, options, xyz, base), "brute force"
    seconds_ranking = time.perf_counter() - t1
    summary = plan_summary(a, rows, ranking, seconds_analysis, seconds_ranking)
    summary["plan"]["ranking_method"] = how
    summary["plan"]["external_method"] = a.external_method
    summary["plan"]["tie_points"] = tie_points
    summary["warnings"] = list(said)
    summary.update(run_metadata(project, options, started, rank_control=bool(rank_control)))
    plate_unit = project.settings.plate_unit
    files = {
        "photos.csv": format_csv(photo_table(a.project, a.result)),
        "cameras.csv": format_csv(camera_table(a.project, a.result)),
        "points.csv": format_csv(plan_point_table(a)),
        "reliability.csv": format_csv(reliability_table(a)),
        "whatifs.csv": format_csv({k: [r[k] for r in rows] for k in WHATIF_COLUMNS}),
    }
    if ranking is not None:
        files["control_ranking.csv"] = format_csv({k: [r[k] for r in ranking] for k in RANKING_COLUMNS})
    files["summary.json"] = json.dumps(summary, indent=2, allow_nan=False) + "\n"
    files["report.html"] = report.html_report(a, summary, rows, ranking, plate_unit)
    return PlanProducts(a, summary, rows, ranking, files)


def _finite(x):
    return None if x is None or not np.isfinite(x) else float(x)


def plan_point_table(a: PlanAnalysis) -> dict:
    """points.csv: adjust's columns (the planned coordinates, their a-priori mean errors, rays), then
    min_redundancy (smallest r of the point's plate coordinates), max_mdb (their largest MDB, plate
    units; inf: one is not checked), ext_X, ext_Y, ext_Z (PlanAnalysis.external, m) and
    ext_photos_X, ext_photos_Y, ext_photos_Z (PlanAnalysis.external_photos, m)."""
    cols = point_table(a.project, a.result, a.points)
    ip, n = a.project.image_points, len(a.project.points)
    rmin = np.full(n, np.inf)
    np.minimum.at(rmin, ip.point_index, np.min(a.reliability.redundancy, axis=1))
    mdb = np.zeros(n)
    np.maximum.at(mdb, ip.point_index, np.max(a.reliability.mdb, axis=1))
    cols["min_redundancy"] = np.where(np.isfinite(rmin), rmin, np.nan)
    cols["max_mdb"] = mdb
    for k, name in enumerate("XYZ"):
        cols[f"ext_{name}"] = a.external[:, k]
    for k, name in enumerate("XYZ"):
        cols[f"ext_photos_{name}"] = a.external_photos[:, k]
    return cols


def reliability_table(a: PlanAnalysis) -> dict:
    """reliability.csv, one row per plate measurement: photo_id, point_id, r_x, r_y (redundancy
    numbers), mdb_x, mdb_y (minimal detectable biases, plate units; inf: not checked), bnr_x, bnr_y
    (bias-to-noise ratios, external reliability)."""
    ip, rel = a.project.image_points, a.reliability
    return {"photo_id": [a.project.photos.ids[i] for i in ip.photo_index],
            "point_id": [a.project.points.ids[i] for i in ip.point_index],
            "r_x": rel.redundancy[:, 0], "r_y": rel.redundancy[:, 1],
            "mdb_x": rel.mdb[:, 0], "mdb_y": rel.mdb[:, 1], "bnr_x": rel.bnr[:, 0], "bnr_y": rel.bnr[:, 1]}


def plan_summary(a: PlanAnalysis, rows: list, ranking, seconds_analysis: float, seconds_ranking: float) -> dict:
    """summary.json: adjust's keys (pipeline.summary_of; not "blunders": nothing is measured, nothing
    tested) with sigma0 = 1 and vtpv 0; check_points
    with the predicted RMS (the root mean square of the check points' a-priori mean errors per axis,
    what the RMS of their differences will be on average); "plan" with the precision figures, the
    reliability figures, the what-ifs and the ranking."""
    s = summary_of(a.project, a.result, a.points)
    s["sigma0"], s["vtpv"] = 1.0, 0.0
    chk = (a.project.points.kind == CHECK) & np.isfinite(a.sigma_points).all(axis=1)
    s["check_points"] = {"n": int(chk.sum()), **{f"rms_{ax}": _finite(np.sqrt(np.mean(a.sigma_points[chk, k] ** 2)))
                                                if chk.any() else None for k, ax in enumerate("XYZ")}}
    rel = a.reliability
    finite = rel.mdb[np.isfinite(rel.mdb)]
    s["plan"] = {
        "sigma0": "a priori (1)",
        "precision": a.precision_figures(),
        "reliability": {"min_redundancy": _finite(rel.redundancy.min()) if rel.redundancy.size else None,
                        "max_finite_mdb": _finite(finite.max()) if finite.size else None,
                        "n_unchecked": int(np.sum(~np.isfinite(rel.mdb))),
                        "delta0": rel.delta0, "critical_value": rel.critical},
        "what_ifs": [{k: r[k] for k in WHATIF_COLUMNS} for r in rows],
        "control_ranking": ranking,
        "seconds": round(seconds_analysis, 6),
        "seconds_ranking": round(seconds_ranking, 6),
    }
    return s
