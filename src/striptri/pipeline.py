"""Pipelines: load, compute, save. The CLI and the scripts call these; the mathematics below them
never opens a file or prints.

``run_adjust(project_dir, out_dir, RunOptions(...))`` reads a project folder, adjusts it, computes the
products of DESIGN section 10 (photos, cameras, points, residuals, summary, report) and writes the
output folder whole or not at all.
"""

from __future__ import annotations

import contextlib
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .precision import export as covariance_export
from .core import diagnosis, termination
from .report import gnss as gnss_output, inactive, html as report
from .equations import plate_corrections
from .equations.groups import rays_per_point
from . import progress, solvers
from .core.adjusted_points import triangulate_adjusted, undetermined_points
from .precision import collinearity_form
from .bundle.distances import summary_entry as distances_summary
from .crs import project as map_coordinates
from .adjustment import AdjustmentOptions, AdjustmentResult, adjust, failure_message
from .errors import InputError
from .report import figures as figure_imports
from .report import drawing
from .report.tables import (camera_table, check_point_statistics, finite_or_none, gnss_tables, photo_table,  # noqa: F401
                            point_covariances, point_table, residual_table)
from .report import film as film_report
from .io import early_read, sources
from .io.csvtable import format_csv
from .io.output import OutputReservation, check_output_location
from .solvers.memory import (WARM_BYTES_PER_INPUT_BYTE, WARM_MAX_BYTES, give_back_free_memory,
                             keep_freed_memory, warm_heap)
from .solvers.threads import single_threaded
from .io.project_reader import FILE_NAMES, read_project
from .model import CHECK, Project
from .precision.residuals import joint_point_covariance
from .reliability import blunder_options, detect_blunders
from .reliability.distances import distance_table
from .reliability.rejections import rejection_groups
from .reliability.outcome import without_tests
from .core.runs import RunOptions, RunSummary
from .solvers import SolverUnavailable
from .equations.triangulation import Triangulated


@dataclass
class AdjustmentProducts:
    """What an adjustment run produces: the result and the tables of the output folder."""

    project: Project
    result: AdjustmentResult
    points: Triangulated
    summary: RunSummary
    files: dict
    blunders: object = None
    warnings: list = field(default_factory=list)  # summary.json "warnings", also printed on stderr


def options_for(project: Project, **overrides) -> AdjustmentOptions:
    """AdjustmentOptions from project.toml's [adjustment], with command-line values on top.

    An impossible combination is an InputError blamed where it comes from: project.toml when its
    own values clash, the command line when the values given there cause the clash."""
    s = project.settings
    base = dict(method=s.method, solver=s.solver, max_iterations=s.max_iterations, datum=s.datum,
                cost_tolerance=s.cost_tolerance, datum_points=s.datum_points)
    toml = project.source / "project.toml" if project.source is not None else "project.toml"
    try:
        AdjustmentOptions.of(**base)
    except ValueError as exc:
        raise InputError(toml, None, str(exc)) from None
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = [p for p in given.get("datum_points", ()) if p not in set(map(str, project.points.ids))]
    if unknown:
        raise InputError("command line", None, f"--datum-points: {', '.join(unknown)} not among the object points "
                                               "of the project")
    try:
        return AdjustmentOptions.of(**{**base, **given})
    except ValueError as exc:
        flags = " ".join(f"--{k.replace('_', '-')} {','.join(v) if isinstance(v, (tuple, list)) else v}"
                         for k, v in given.items())
        raise InputError("command line", None, f"{exc} (given: {flags or 'no options'})") from None


POINT_PRECISION = ("schmid90", "joint92")


def input_paths(project_dir: Path) -> list[Path]:
    """Everything a project run reads: the folder and each of its input files (links included,
    so that an output folder can never swallow the target of a linked input file)."""
    return [project_dir, *(project_dir / name for name in FILE_NAMES)]


def run_adjust(project_dir, out_dir, run: RunOptions = RunOptions(),
               on_warning: Callable[[str], None] | None = None) -> AdjustmentProducts:
    """Read, adjust and write (DESIGN section 10) as ``run`` asks (runs.RunOptions). Raises
    InputError / NumericalFailure; warnings go to ``on_warning`` as they arise.

    The output location is checked before the project is read and reserved before the adjustment
    starts (io.output); nothing is written unless the whole run succeeds. An adjustment that has not
    converged is a NumericalFailure unless ``run.keep_unconverged`` (then written with converged:
    false). For the point precision "joint92" against "schmid90" see docs/decisions.md: for points
    in the adjustment the two agree to rounding. With ``run.covariance`` covariance.npz is written
    too."""
    project_dir = Path(project_dir)
    inputs = input_paths(project_dir)
    check_output_location(out_dir, inputs)
    t0 = time.perf_counter()
    if early_read.waiting_for(project_dir) and run.method != "sequential":
        # the heap's first pages faulted in while the child reads (docs/decisions.md "The heap
        # warmed while the project is read")
        keep_freed_memory()
        with contextlib.suppress(OSError):  # gone meanwhile: the read says so
            size = (project_dir / "image_points.csv").stat().st_size
            warm_heap(min(WARM_BYTES_PER_INPUT_BYTE * size, WARM_MAX_BYTES), stop=early_read.ready)
    project = early_read.take(project_dir)  # read by the console script's child meanwhile, if it could
    if project is None:
        project = read_project(project_dir)
    project = plate_corrections.with_switches(project, **run.corrections)
    if project.settings.coordinates is not None and project.settings.earth_curvature:
        raise InputError(project_dir / "project.toml", None,
                         "[corrections] earth_curvature with [coordinates] crs: the project is adjusted in a local "
                         "Cartesian frame, where the Earth's curvature is in the coordinates themselves; the "
                         "correction would count it twice (docs/decisions.md)")
    framed = map_coordinates.in_local_frame(project) if project.settings.coordinates is not None else None
    seconds_reading = time.perf_counter() - t0
    keep_freed_memory()  # its sweeps reuse the pages they free (docs/decisions.md "Freed pages kept at every size")
    options = options_for(project, **run.adjustment)
    try:
        check_products_options(options, run.point_precision, run.blunders)
    except ValueError as exc:
        raise InputError("command line", None, str(exc)) from None
    with OutputReservation(out_dir, inputs) as reservation:
        try:
            if framed is None:
                products = adjust_products(project, options, run, on_warning, seconds_reading=seconds_reading)
            else:
                products = _adjust_in_local_frame(framed, options, run, on_warning, seconds_reading)
        except SolverUnavailable as exc:
            raise InputError(solver_source(project_dir, run.adjustment), None, str(exc)) from exc
        if run.covariance is not None:
            try:
                products.files["covariance.npz"] = covariance_export.covariance_file(
                    products.project, products.result, run.covariance, None if framed is None else framed.frame)
            except ValueError as exc:
                raise InputError("command line", None, str(exc)) from None
        reservation.commit(products.files)
    return products


def solver_source(project_dir: Path, overrides: dict) -> str | Path:
    """Where the solver that could not be had was chosen: the command line (--solver) or project.toml."""
    return "command line (--solver)" if overrides.get("solver") is not None else Path(project_dir) / "project.toml"


MAX_REFINEMENTS = 4


def _adjust_in_local_frame(framed, options, run, on_warning, seconds_reading):
    """adjust_products for a project in map coordinates (striptri.crs.project): adjusted in its local
    frame, the tables written back in its CRS; partial control (XY, Z) converted again at its adjusted
    position and the block re-adjusted until that changes it by less than REFINE_TOLERANCE_M (each
    warning said once)."""
    said: set[str] = set()

    def warn_once(text: str) -> None:
        if text not in said and on_warning is not None:
            said.add(text)
            on_warning(text)

    for _ in range(MAX_REFINEMENTS):
        products = adjust_products(framed.local, options, run, warn_once, seconds_reading=seconds_reading,
                                   frame=framed.frame)
        if not map_coordinates.has_partial_control(framed.grid):
            break
        framed, change = map_coordinates.refine_partial_control(framed, products.points.xyz + products.result.offset)
        if change < map_coordinates.REFINE_TOLERANCE_M:
            break
    return products


def structure_labels(project: Project, layout) -> list[str] | None:
    """The ids of the normal matrix's blocks: photo ids, then the ids of the cameras with unknowns
    (None where the blocks are not those)."""
    n_blocks = len(layout.block_starts())
    ids = list(project.photos.ids)
    cameras = [cid for cid, cols in zip(project.cameras.ids, np.asarray(layout.camera_cols)) if (cols >= 0).any()]
    labels = ids + cameras
    return labels if len(labels) == n_blocks else None


def adjust_products(project: Project, options: AdjustmentOptions, run: RunOptions = RunOptions(),
                    on_warning: Callable[[str], None] | None = None,
                    seconds_reading: float | None = None, frame=None) -> AdjustmentProducts:
    """Adjust with ``options`` (the adjustment options of ``run`` already in them: options_for),
    then run the gross-error procedure ``run.blunders`` ("off", "snoop", "snoop-classic", "robust" or
    "robust-snoop") and build the output files with the point precision ``run.point_precision``.
    Photos, points and the summary describe the adjustment of the measurements kept;
    residuals.csv lists every original measurement with its flag.

    Warnings (the project's notes, then what the computation warns of) go to ``on_warning`` as they
    arise, even when the run then fails, and into summary.json "warnings" and the report. An
    adjustment that does not converge raises NumericalFailure unless ``run.keep_unconverged``.
    seconds_reading: the time the caller took to read the project (summary.json timings_s "read").
    frame: the crs.frame.LocalFrame of a project in map coordinates (``project`` is then in that
    frame): photos.csv and points.csv are written back in the project's CRS, summary.json and the
    report name the frame; check-point differences stay those of the local frame (metres)."""
    started = run_started()
    # BLAS threads set by striptri (solvers.threads), also for API callers; the report's figures
    # drawn by a second process (report.drawing), which _adjust_products starts and this ends
    with single_threaded(), contextlib.ExitStack() as workers:
        products = _adjust_products(project, options, run, on_warning, seconds_reading, frame, started, workers)
    return products


def run_started() -> str:
    """The time a run started, ISO 8601 with the local offset, to the second (summary.json ``started``)."""
    from datetime import datetime

    return datetime.now().astimezone().isoformat(timespec="seconds")


def run_metadata(project: Project, options: AdjustmentOptions, started: str, **more) -> dict:
    """summary.json's ``version``, ``started``, ``project`` (the folder read, when known) and ``options``
    (what decided the result besides the input: method, solver, datum, iteration limit, gross errors,
    point precision), in the report's "Run" block."""
    from . import __version__

    chosen = {"method": options.method, "solver": options.solver, "datum": options.datum,
              "max_iterations": options.max_iterations, "tolerance": options.tolerance, **more}
    if options.datum_points:
        chosen["datum_points"] = list(options.datum_points)
    return {"version": __version__, "started": started,
            "project": None if project.source is None else str(project.source), "options": chosen}


def _adjust_products(project, options, run, on_warning, seconds_reading, frame, started,
                     workers: contextlib.ExitStack) -> AdjustmentProducts:
    """adjust_products' work, with the BLAS threads already set; started: run_started()'s time;
    workers: where the drawing worker is entered (it ends with adjust_products)."""
    from dataclasses import replace as _replace

    point_precision, blunders, keep_unconverged = run.point_precision, run.blunders, run.keep_unconverged

    check_products_options(options, point_precision, blunders)
    # the tests' residual cofactors from the final checks' whitened groups (core.result.SolutionSystems)
    options = _replace(options, keep_unconverged=keep_unconverged,
                       conditions=_replace(options.conditions, keep_solution_systems=True))
    given = project  # as read: inactive.inactive_residuals corrects its inactive rows itself
    # [corrections]: Earth curvature and refraction of the plate coordinates, before everything else
    project, corrections = plate_corrections.correct_project(project)
    said: list[str] = []

    def warn(text: str) -> None:
        if text not in said:
            said.append(text)
            if on_warning is not None:
                on_warning(text)

    for note in project.notes:
        warn(str(note))
    # the pipeline's phases beyond the adjustment (summary.json timings_s, docs/file-formats.md)
    phases: dict[str, float] = {} if seconds_reading is None else {"read": seconds_reading}
    # the report's figures drawn by a second process when the run uses both cores (report.drawing):
    # "now" it imports matplotlib while the adjustment computes; "later" (large runs) once the
    # gross-error tests are done, beside the point precision and the tables: not on top of the
    # run's peaks of memory (the iterations, the tests). Without one, matplotlib is imported by a
    # thread of this process while the adjustment computes.
    worker = drawing.when_to_start(rays_per_point(project))
    if worker == "now":
        workers.enter_context(drawing.worker_for(True, drawing.DRAWERS_NOW))
    else:
        drawing.discard_early_worker()  # one started before the project was read (drawing.early_worker)
        if worker == "later" and options.method == "bundle":  # only the tables hide its start
            drawing.park_worker()
            workers.callback(drawing.discard_early_worker)  # not taken: the run ended before its tests
    if worker is None:
        figure_imports.preload()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            t0 = time.perf_counter()
            first = adjust(project, options)  # step 1: the adjustment of all rows
            t_first = time.perf_counter()
            # a worker running: the adjustment's own figures drawn during the tests, for the report
            # when the tests keep its result
            of_first = _figures_of_adjustment(project, first) if drawing.drawing_elsewhere() else {}
            drawn_for = first  # the result whose figures of_first are
            seconds_early = time.perf_counter() - t_first
            if options.method == "sequential":  # step 2: the blunder procedure on it
                det = without_tests(project, first, "not tested (sequential method)")
            else:
                det = detect_blunders(project, options, blunder_options(blunders), first)
            adjusted, result = det.project, det.result
            phases["gross_errors"] = max(time.perf_counter() - t0 - result.timings.total - seconds_early, 0.0)
            if lean_covariance(run, result, adjusted):
                # the point precision reads the blocks the tests have read (Covariance.release): the
                # inverse let go before the drawing worker starts beside it
                result.release_covariance(keep_blocks=True)
                give_back_free_memory()
            if worker == "later":  # the run's peaks of memory are behind
                workers.enter_context(drawing.worker_for(True))
                if drawing.drawing_elsewhere():  # what needs no points, drawn beside the point precision
                    t_asked = time.perf_counter()
                    of_first, drawn_for = _figures_of_adjustment(adjusted, result, det), result
                    seconds_early += time.perf_counter() - t_asked
            progress.phase("reliability measures (gross errors)", phases["gross_errors"])
            if not result.converged:
                warn("kept although the adjustment did not converge (--keep-unconverged): "
                     + failure_message(result))
            elif result.termination_message:  # e.g. converged by the cost tolerance: say so
                warn(result.termination_message)
            _warn_if_implausible(adjusted, result, warn)
            t0 = time.perf_counter()
            give_back_free_memory()
            points = triangulate_result(adjusted, result)
            if point_precision == "joint92":
                joint = joint_point_covariance(adjusted, result, points, options)
                points = _replace(points, cov_measurement=joint, cov_orientation=np.zeros_like(joint))
            phases["point_precision"] = time.perf_counter() - t0
            progress.phase("point precision", phases["point_precision"])
            weak = undetermined_warning(adjusted, points)
            if weak is not None:
                warn(weak)
        finally:
            for w in caught:
                if not figure_imports.from_figure_packages(w):
                    warn(str(w.message))
    if run.covariance is None and not _reads_covariance_entries(adjusted, result):
        # the tables and the report read only the photo blocks and the diagonal of Qxx: without
        # the rest of the inverse, the report phase is no longer the run's peak of memory
        result.release_covariance()
        give_back_free_memory()
    early: dict = {}  # with a drawing worker: the figures asked for now, drawn while the tables are written
    t0 = time.perf_counter()
    if drawing.drawing_elsewhere():
        if result is not drawn_for:  # the tests adjusted again: drawn anew (a subset with every row is
            of_first = {}            # the same photos and cameras: the first figures hold)
        early["structure"] = of_first["structure"] if of_first else _structure(adjusted, result)
        made = of_first.get("sections", {})
        early["sections"] = {**made, **report.figure_sections(
            adjusted, result, det.w[det.rows], points=points, flags=det.flag[det.rows],
            keys=[k for k in report.FIGURE_SECTIONS if k not in made])}
    seconds_early += time.perf_counter() - t0  # the report's, asked for early
    t0 = time.perf_counter()
    photo_cols, point_cols = photo_table(adjusted, result), point_table(adjusted, result, points)
    if frame is not None:
        # standard deviations in the CRS's axes with the local frame's correlations (docs/decisions.md)
        photo_cols = map_coordinates.photo_columns_to_grid(photo_cols, adjusted, frame, result.photo_covariances)
        point_cols = map_coordinates.point_columns_to_grid(
            point_cols, frame, point_covariances(result, points))
    tables = {
        "photos.csv": format_csv(photo_cols),
        "cameras.csv": format_csv(camera_table(adjusted, result)),
        "points.csv": format_csv(point_cols),
        "residuals.csv": format_csv(residual_table(project, det)),
    }
    off = None if inactive.none(given) else inactive.inactive_residuals(given, adjusted, result)
    if off is not None:  # the inactive rows after the active ones (docs/file-formats.md)
        table = residual_table(project, det)
        more = inactive.residual_columns(adjusted, off)
        tables["residuals.csv"] = format_csv({k: list(table[k]) + list(more[k]) for k in table})
    tables.update(gnss_tables(adjusted, result))
    distance_cols = None
    if adjusted.distances is not None:  # distances.csv (bundle.distances): from the adjusted points, with tests
        distance_cols = distance_table(adjusted, result, points.xyz, options, det.critical)
        tables["distances.csv"] = format_csv(distance_cols)
    if adjusted.film is not None and adjusted.film.fit is not None:  # scanned film (striptri.film)
        tables["fiducial_residuals.csv"] = format_csv(film_report.residual_columns(adjusted.film))
    phases["tables"] = time.perf_counter() - t0
    progress.phase("tables (CSV)", phases["tables"])
    found = summary_of(adjusted, result, points)  # the contract's keys first, in DESIGN's order
    found["timings_s"].update({k: round(v, 6) for k, v in phases.items()})
    blunder_counts = {**blunder_summary(det), "groups": rejection_groups(project, det)}
    summary = RunSummary(
        **found, **run_metadata(given, options, started, blunders=blunders, point_precision=point_precision,
                                keep_unconverged=keep_unconverged),
        blunders=blunder_counts, warnings=list(said),
        plate_corrections=None if corrections is None else corrections.summary,
        inactive=None if off is None else inactive.summary_entry(adjusted, off),
        **gnss_output.summary_entry(adjusted, result),
        distances=None if adjusted.distances is None else distances_summary(adjusted.distances, points.xyz,
                                                                            distance_cols),
        film=None if adjusted.film is None else film_report.summary_entry(adjusted.film),
        frame=None if frame is None else frame.summary(),
        automatic_tie_points=sources.summary_entry(project, det.flag, det.v))

    t0 = time.perf_counter()
    give_back_free_memory()
    structure = early["structure"] if "structure" in early else _structure(adjusted, result)
    html = report.html_report(adjusted, result, summary, det.w[det.rows], points=points,
                              flags=det.flag[det.rows],
                              parts=report.ReportParts(figures={"structure": structure}, distances=distance_cols,
                                                       sections=early.get("sections")))
    summary.timings_s["report"] = round(time.perf_counter() - t0 + seconds_early, 6)
    progress.phase("report", summary.timings_s["report"])
    files = {**tables, "summary.json": summary.json(), "report.html": html}
    products = AdjustmentProducts(adjusted, result, points, summary, files, det, list(said))
    return products


def _figures_of_adjustment(project: Project, result: AdjustmentResult, det=None) -> dict:
    """The report's figures that need only the adjustment (the structure of N, the convergence
    section) and, with the outcome ``det`` of its tests, the residuals section, asked for from the
    drawing worker (_adjust_products' "early")."""
    sections = report.figure_sections(project, result, keys=("convergence",))
    if det is not None:
        sections.update(report.figure_sections(project, result, det.w[det.rows], flags=det.flag[det.rows],
                                               keys=("residuals",)))
    return {"structure": _structure(project, result), "sections": sections}


def _structure(project: Project, result: AdjustmentResult):
    """The report's figure of the normal matrix's structure (report.drawing.draw: bytes, or a
    figure a worker draws), from the pattern of its blocks."""
    return drawing.draw(figure_imports.structure_figure,
                        *figure_imports.structure_parts(result.N, result.layout.block_starts()),
                        len(project.photos), labels=structure_labels(project, result.layout))


def lean_covariance(run: RunOptions, result: AdjustmentResult, project: Project) -> bool:
    """Whether the run reads nothing of Qxx beyond the blocks of its point groups, the photo blocks
    and the diagonal (no covariance.npz, the point precision schmid90, no other entries)."""
    return (run.covariance is None and run.point_precision == "schmid90"
            and not _reads_covariance_entries(project, result))


def _reads_covariance_entries(project: Project, result: AdjustmentResult) -> bool:
    """Whether the tables or the report read entries of Qxx beyond the photo blocks and the
    diagonal: the estimated camera elements' correlations with the exterior elements (the report's
    camera section, precision.camera_correlations), cameras.csv's balanced elements
    (report.tables.camera_table), the GNSS unknowns' tables and report section (precision.gnss)
    and distances.csv's tests (reliability.distances)."""
    cams = project.cameras
    balanced = cams.r0 is not None and bool(np.isfinite(cams.r0).any())
    estimated = bool((result.layout.camera_cols >= 0).any())
    return estimated or balanced or result.layout.gnss_cols is not None or project.distances is not None


SIGMA0_IMPLAUSIBLE = 10.0  # sigma0 a posteriori beyond which a converged result is suspect


def _warn_if_implausible(project: Project, result: AdjustmentResult, warn) -> None:
    """A converged adjustment with sigma0 far above 1 has usually settled in a false minimum (a photo
    turned by 180 degrees, c in another unit) or holds gross errors: say so, with the likely cause."""
    if result.redundancy <= 0 or not np.isfinite(result.sigma0) or result.sigma0 <= SIGMA0_IMPLAUSIBLE:
        return
    with np.errstate(all="ignore"):
        causes = diagnosis.likely_causes(project, "iteration")
    warn(f"sigma0 = {result.sigma0:.4g} is far above 1 (more than {SIGMA0_IMPLAUSIBLE:g} times the a-priori "
         "standard deviations): the adjustment may have settled in a false minimum or the data hold gross errors "
         "(try --blunders snoop). " + termination.causes_text(causes, "Check the approximate orientations and the "
                                                              "units of c and of the plate coordinates."))


def check_products_options(options: AdjustmentOptions, point_precision: str, blunders: str) -> None:
    """ValueError for option combinations the products cannot honour."""
    if point_precision not in POINT_PRECISION:
        raise ValueError(f"unknown point precision {point_precision!r}; choose one of {', '.join(POINT_PRECISION)}")
    if options.method == "sequential" and (blunders != "off" or point_precision != "schmid90"):
        raise ValueError("gross-error detection and the joint point precision (92) need a simultaneous "
                         "adjustment; with --method sequential use --blunders off")
    if options.datum == "inner-points" and point_precision == "joint92":
        raise ValueError("the joint point precision (92) is not available in the point datum (--datum inner-points): "
                         "there the orientation depends on the datum points' own measurements, which (92) does not "
                         "carry; use --point-precision schmid90, which includes that term (docs/decisions.md)")


def blunder_summary(det) -> dict:
    """summary.json's "blunders": the method, the test's critical value and delta0, the counts of
    rejected / suspect / dropped measurements and the adjustments it took."""
    flags = np.asarray(det.flag)
    return {
        "method": det.method,
        "critical_value": finite_or_none(float(det.critical)),
        "delta0": finite_or_none(float(det.delta0)),
        "rejected": int(np.sum(flags == "rejected")),
        "suspect": int(np.sum(flags == "suspect")),
        "dropped": int(np.sum(flags == "dropped")),
        "inseparable": int(np.sum(flags == "inseparable")),
        "adjustments": max(len(det.rounds), 1),
        "stopped": det.stopped,
    }


def triangulate_result(project: Project, result: AdjustmentResult) -> Triangulated:
    """Ground points from the adjusted rays, with Schmid's (90) precision split
    (adjusted_points.triangulate_adjusted with the orientation part; of a bundle result by the
    collinearity form, bundle.precision.points_of, kept from the reliability measures' pass)."""
    if collinearity_form.applies(project, result):
        return collinearity_form.points_of(project, result)
    # the points joined by distances.csv are intersected together there (joint_groups.joint_point_precision)
    return triangulate_adjusted(project, result, orientation_part=True)


def undetermined_warning(project: Project, tri: Triangulated) -> str | None:
    """The summary.json warning that names the undetermined points (None without any)."""
    idx = np.flatnonzero(undetermined_points(project, tri))
    if not len(idx):
        return None
    names = ", ".join(project.points.ids[i] for i in idx[:10]) + (" ..." if len(idx) > 10 else "")
    n_check = int(np.sum(project.points.kind[idx] == CHECK))
    checks = (f"; {n_check} check point{'s are' if n_check > 1 else ' is'} left out of the check-point statistics"
              if n_check else "")
    return (f"{len(idx)} point{'s are' if len(idx) > 1 else ' is'} not determined by {'their' if len(idx) > 1 else 'its'} "
            f"rays at the adjusted values ({names}): rays nearly parallel, one ray left, or a coordinate lost to "
            "rejected measurements. They are flagged 'undetermined' in points.csv, with their mean errors where "
            f"defined{checks}.")


SEQUENTIAL_FACTORISATION = ("none of the whole strip: relative orientation and model joining model after model "
                            "(small dense least squares), then the strip polynomials")


def solver_description(result: AdjustmentResult) -> dict:
    """summary.json's ``factorisation`` and ``blas``: what solved the normal equations, in words,
    and the BLAS library it ran on, found at run time (striptri.solvers.describe)."""
    if result.solver == "sequential":
        return {"factorisation": SEQUENTIAL_FACTORISATION, "blas": solvers.blas("dense")}
    info = result.history[-1].solver_info if result.history else None
    return solvers.describe(result.solver, info)


def summary_of(project: Project, result: AdjustmentResult, tri: Triangulated) -> dict:
    return {
        "method": result.method,
        "solver": result.solver,
        "sigma0": finite_or_none(result.sigma0),
        "redundancy": result.redundancy,
        "vtpv": finite_or_none(result.vtpv),
        "iterations": result.iterations,
        "converged": result.converged,
        "n_photos": len(project.photos),
        "n_points": len(project.points),
        "n_observations": result.n_observations,
        "n_conditions": result.n_conditions,
        "n_unknowns": result.n_unknowns,
        "check_points": check_point_statistics(project, result, tri),
        "timings_s": {k: round(v, 6) for k, v in result.timings.as_dict().items()},
        # DESIGN's second-wave additions: which factorisation and BLAS solved the normal equations
        **solver_description(result),
        # why the iteration stopped, in words
        "termination": result.termination,
        "message": result.termination_message if result.converged else failure_message(result),
        "plate_unit": project.settings.plate_unit,  # of c, the plate coordinates and residuals.csv's vx, vy
        # a free network: its datum (mode, the free directions in words, the number of datum points)
        **({"datum": result.free_network.summary(result.state, result.offset)} if result.free_network else {}),
        "checks": {k: finite_or_none(v) for k, v in result.checks.as_dict().items()},
        "history": [
            {"vtpv": finite_or_none(h.vtpv), "max_correction": finite_or_none(h.max_correction),
             **_solver_report(h.solver_info)}
            for h in result.history
        ],
    }


def _solver_report(info: solvers.SolverInfo) -> dict:
    """The inner iterations of an iterative solver in an outer iteration (empty for direct ones):
    summary.json's ``solver_inner_iterations``, ``solver_relative_residual``, ``solver_converged``
    and ``solver_slow``, those the solver reported."""
    reported = {"inner_iterations": info.inner_iterations, "relative_residual": info.relative_residual,
                "converged": info.converged, "slow": info.slow}
    out = {}
    for k, v in reported.items():
        if v is not None:
            out[f"solver_{k}"] = bool(v) if isinstance(v, (bool, np.bool_)) else (
                int(v) if isinstance(v, (int, np.integer)) else finite_or_none(float(v)))
    return out

