"""report.html: a human-readable account of an adjustment, readable offline.

One self-contained file: inline CSS, every figure a PNG data URI, no scripts, no links but to its
own sections. It holds the summary (with the global test of sigma0), Schmid's checks after
convergence, the convergence history, the residual vectors on the photographs, the error ellipses
of the ground points over the block, the check points, the flagged measurements, the photographs
with their mean errors and the structure of the normal matrix.

Large projects stay quick and readable (docs/benchmarks.md, "Reading, tables, report and
imports"): at most MAX_PHOTO_PANELS photos get a panel of their own (the worst ones when there are
more), tables list the first and worst rows with a note; beyond MAX_VECTORS measurements the
residuals of all photographs are drawn as a raster of their RMS per cell of the format with the
WORST_VECTORS largest on top, and beyond MAX_ELLIPSES points the error ellipses as rasters of the
RMS horizontal and vertical error per cell of the block with the WORST_ELLIPSES worst on top and a
table of the worst points. Every section is timed (html_report's ``timings``; the footer lists
them).
"""

from __future__ import annotations

import html
import time
from dataclasses import dataclass, field
import numpy as np

from . import drawing, figures as fig
from ..core.result import AdjustmentResult
from ..bundle.distances import report_parts as distance_report_parts
from ..reliability.distances import distance_table
from . import film as film_report
from .gnss import report_tables as gnss_report_tables
from ..geometry.rotations import RADIANS_PER_UNIT
from ..geometry.lens import CAMERA_ELEMENTS, CONVENTION_NAMES
from ..model import KIND_NAMES, Project
from ..precision.residuals import PHOTO_ELEMENTS, camera_correlations
from ..geometry.rotations import angles_from_R
from ..equations.triangulation import Triangulated
from ..core.runs import RunSummary
from . import page  # the page's limits, read at call time (tests set them)
from .page import (
    SECTIONS, ResidualUnit, _STYLE, _card, _cell, _flag_text, _flags_of, _fmt, _img,
    _photo_statistics, _point_covariance, _section, _table, _without_folders, chi2_quantile, length_unit,
    residual_unit, run_block,
)
from .points import (
    _check_points_section, _flagged_section, _largest_section, _points_section, _rejected_section,
    _residuals_section,
)


CHECK_TEXT = {
    "max_condition_misclosure_sigma": "Final check: largest misclosure of a condition at the adjusted observations "
                                      "and unknowns, in units of its standard deviation",
    "max_BTk_sigma": "(58) B<sup>T</sup>k = 0: largest |u<sub>i</sub>| / &radic;N<sub>ii</sub> at the solution",
    "vtpv_reduction_relative_difference": "(59) v<sup>T</sup>P v = [LL.u]: relative difference of the two sums",
    "max_point_gradient_sigma": "Largest gradient with respect to a point coordinate, in units of its "
                                "standard deviation",
}

def _summary_section(project: Project, result: AdjustmentResult, summary: RunSummary, flagged: np.ndarray) -> list[str]:
    s0, r = summary.sigma0, summary.redundancy
    cards = []
    if s0 is not None:
        cards.append(_card(f"{s0:.3f}", "&sigma;<sub>0</sub> a posteriori"))
    cards.append(_card(str(r), "redundancy"))
    conv = summary.converged
    cards.append(_card(f"{summary.iterations}", "iterations, " + ("converged" if conv else "NOT converged"),
                       "good" if conv else "bad"))
    cp = summary.check_points
    if cp["n"]:
        rms_xy = np.hypot(cp["rms_X"], cp["rms_Y"])
        cards.append(_card(f"{rms_xy:.3f} / {cp['rms_Z']:.3f} m", f"check points ({cp['n']}): RMS XY / Z"))
    nf = int(flagged.sum())
    cards.append(_card(str(nf), "flagged measurements", "bad" if nf else "good"))

    kinds = np.bincount(project.points.kind, minlength=len(KIND_NAMES))
    kind_text = ", ".join(f"{kinds[k]} {KIND_NAMES[k]}" for k in sorted(KIND_NAMES) if kinds[k])
    method = {"conditions": "conditions (Schmid's simultaneous adjustment)", "bundle": "bundle (collinearity)"}
    rows = [
        ("method", _fmt(method.get(summary.method, summary.method))),
        ("solver", _fmt(summary.solver)),
        ("factorisation of the normal equations", _fmt(summary.factorisation)),
        ("BLAS it ran on", _without_folders(summary.blas)),
        ("&sigma;<sub>0</sub> a posteriori (unit: the a-priori &sigma;)", _fmt(s0, ".4f")),
        ("v<sup>T</sup>P v", _fmt(summary.vtpv)),
        ("redundancy r", _fmt(r)),
        ("iterations", _fmt(summary.iterations)),
        ("converged", f"<span class='{'ok' if conv else 'no'}'>{_fmt(conv)}</span>"),
        ("termination (why the iteration stopped)", _termination_text(summary)),
    ]
    if summary.frame is not None:  # a project in map coordinates (striptri.crs)
        f = summary.frame
        rows.append(("coordinate frame", html.escape(
            f"files in {f['crs_name']} ({f['crs']}), {f['heights']} heights"
            + (f" (geoid: {f['geoid']})" if "geoid" in f else "")
            + f"; adjusted, and shown in this report (points, check points), in the local frame: {f['local']}")))
    if summary.datum is not None:  # a free network (datum.FreeNetwork.summary)
        d = summary.datum
        on = (f"inner constraints on {d['n_datum_points']} object points" if "n_datum_points" in d
              else "inner constraints on the photos")
        free = "; ".join(d["free_directions"])
        rows.append(("datum (free network)", html.escape(f"{d['mode']}: {on}; free: {free}")))
    if r > 0 and s0 is not None:
        lo, hi = np.sqrt(chi2_quantile(np.array([0.025, 0.975]), r) / r)
        inside = lo <= s0 <= hi
        verdict = "<span class='ok'>inside</span>" if inside else "<span class='no'>outside</span>"
        rows.append(("global test: 95 % range of &sigma;<sub>0</sub> if the a-priori &sigma; hold",
                     f"{lo:.3f} &ndash; {hi:.3f} ({verdict})"))
    sizes = [
        ("photographs", _fmt(summary.n_photos)),
        ("strips", _fmt(len(set(project.photos.strip_ids)))),
        ("cameras", _fmt(len(project.cameras))),
        ("object points", _fmt(summary.n_points)),
        ("&nbsp;&nbsp;by kind", _fmt(kind_text)),
        ("plate measurements (points on photos)", _fmt(len(project.image_points))),
        ("observations", _fmt(summary.n_observations)),
        ("condition equations", _fmt(summary.n_conditions)),
        ("unknowns", _fmt(summary.n_unknowns)),
    ]
    timings = [(html.escape(k.replace("_", " ")), _fmt(v, ".3f")) for k, v in summary.timings_s.items()]
    return [
        _section("summary"),
        "<div class='cards'>" + "".join(cards) + "</div>",
        "<div class='cols'>",
        "<div><h3>Adjustment</h3>" + _table(["quantity", "value"], rows, left=1, wrap=(0, 1)) + "</div>",
        "<div><h3>Size</h3>" + _table(["quantity", "value"], sizes, left=1, wrap=(0, 1)) + "</div>",
        "<div><h3>Timings (s)</h3>" + _table(["step", "seconds"], timings, left=1) + "</div>",
        "</div>",
    ]


TERMINATION_WORDS = {
    "converged": "converged: every correction below the tolerance in units of its standard deviation",
    "cost_flat": "cost_flat: the sum of squares no longer decreased (the bundle's cost tolerance)",
    "iteration_limit": "iteration_limit: max_iterations reached before convergence (kept on request)",
}


def _termination_text(summary: RunSummary) -> str:
    """summary.json's termination in words, with its message when it has one."""
    reason = str(summary.termination)
    text = html.escape(TERMINATION_WORDS.get(reason, reason))
    message = summary.message
    if message and reason != "iteration_limit":  # the iteration limit's message is in the warnings
        text += f"<br><small>{html.escape(message)}</small>"
    return f"<span class='{'ok' if summary.converged else 'no'}'>{text}</span>"


def _warnings_section(summary: RunSummary) -> list[str]:
    """Everything the run warned of: input it did not use (the reader's notes), a result kept
    although it did not converge, solver warnings. Nothing in the input is ignored silently."""
    warnings = summary.warnings or []
    parts = [_section("warnings")]
    if not summary.converged:
        parts.append(f"<p class='no'>The adjustment did not converge ({html.escape(str(summary.termination))})"
                     f": {html.escape(str(summary.message or ''))}</p>")
    if warnings:
        parts.append("<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>")
    else:
        parts.append("<p>None: every line of the input was used.</p>")
    return parts


CORRECTION_NAMES = {"earth_curvature": "Earth curvature", "refraction": "Atmospheric refraction"}


def _corrections_section(summary: RunSummary) -> list[str]:
    """The corrections of the plate coordinates that were applied (summary.json "plate_corrections",
    striptri.equations.plate_corrections): size, direction and the formula's source; nothing when none was."""
    applied = summary.plate_corrections
    if not applied:
        return []
    unit = html.escape(applied["plate_unit"])
    rows = [[CORRECTION_NAMES[k], _fmt(v["max"], ".3g"), _fmt(v["rms"], ".3g"), _fmt(v["at_r_max"], ".3g"),
             html.escape(v["direction"]), html.escape(v["source"])]
            for k, v in applied.items() if k in CORRECTION_NAMES]
    return [_section("corrections"),
            f"<p>Applied to the measured plate coordinates before the adjustment; residuals.csv and the residuals "
            f"below refer to the corrected coordinates. Radial corrections about the principal point, in {unit}; the "
            f"largest radius measured is {_fmt(applied['r_max'], '.4g')} {unit}. Heights used: "
            f"{html.escape(applied['heights'])}.</p>",
            _table(["correction", f"largest ({unit})", f"RMS ({unit})", f"at the largest radius ({unit})",
                    "direction", "formula and source"], rows, left=1)]


def _distances_section(project: Project, result: AdjustmentResult, summary: RunSummary, points,
                       cols: dict | None = None) -> list[str]:
    """The observed distances, their residuals and tests (bundle.distances.report_parts,
    reliability.distances); nothing without. cols: distances.csv's columns when the caller has them
    (pipeline), else they are formed here."""
    if project.distances is None or points is None:
        return []
    if cols is None:
        cols = distance_table(project, result, points.xyz,
                              critical=(summary.blunders or {}).get("critical_value"))
    return [_section("distances")] + [p if isinstance(p, str) else _table(*p) for p in
                                      distance_report_parts(project.points.ids, project.distances, points.xyz, cols)]


def _inactive_section(summary: RunSummary, unit: "ResidualUnit") -> list[str]:
    """The measurements image_points.csv marks inactive (summary.json "inactive", striptri.report.inactive):
    not adjusted; their residuals against the adjusted result. Nothing when there are none."""
    info = summary.inactive
    if not info:
        return []
    rows = [[html.escape(r["photo_id"]), html.escape(r["point_id"]), unit(r["vx"]), unit(r["vy"])]
            for r in info["largest"]]
    rms = ("" if info["rms_vx"] is None else
           f" RMS of their residuals: x {unit(info['rms_vx'])}, y {unit(info['rms_vy'])} {unit.label}.")
    return [_section("inactive"),
            f"<p>{info['n']} measurements are marked inactive in image_points.csv: they took no part in the "
            f"adjustment; their residuals (the adjusted point projected with the adjusted orientation and camera, "
            f"minus the measurement) are in residuals.csv with the flag <i>inactive</i>; {info['n_determined']} "
            f"of them have a point determined by the active measurements.{rms} The largest:</p>",
            _table(["photo", "point", f"v<sub>x</sub> ({unit.label})", f"v<sub>y</sub> ({unit.label})"], rows,
                   left=2)]


def _automatic_section(summary: RunSummary) -> list[str]:
    """The automatic tie points of striptri match (image_points.csv source auto): how many the
    gross-error procedure removed and how well the others fit, in pixels (io.sources)."""
    a = summary.automatic_tie_points
    if a is None:
        return []
    rms = "n/a" if a["rms_px"] is None else f"{a['rms_px']:.3f} px"
    cards = "".join([_card(f"{a['rays']:,}", "automatic rays"), _card(f"{a['removed']:,}", "removed as gross errors",
                                                                     "bad" if a["removed"] else ""),
                     _card(f"{a['points_left']:,} / {a['points']:,}", "tie points left (two rays or more)"),
                     _card(rms, "image residual RMS of the rays left")])
    return [_section("automatic"), f"<div class='cards'>{cards}</div>",
            "<p>The tie points found by <code>striptri match</code> (image_points.csv, source auto). False "
            "matches are expected among them; the gross-error procedure (--blunders) removes them. The "
            "residuals of every photo, the automatic rays among them, are drawn under <a href='#residuals'>"
            "Residuals on the photographs</a>.</p>"]


def _checks_section(summary: RunSummary) -> list[str]:
    rows = []
    for k, v in summary.checks.items():
        holds = v is not None and abs(v) < page.CHECKS_HOLD_BELOW
        mark = "<span class='ok'>holds</span>" if holds else "<span class='no'>fails</span>"
        rows.append((CHECK_TEXT.get(k, html.escape(k)), _fmt(v, ".2e"), mark))
    return [
        _section("checks"),
        "<p>After the last iteration the adjustment is checked as Schmid prescribes; every value should "
        f"vanish to rounding (here: below {page.CHECKS_HOLD_BELOW:g}).</p>",
        _table(["check", "value", ""], [((t, "wrap", ""), v, m) for t, v, m in rows], left=1),
    ]


def _convergence_section(result: AdjustmentResult) -> list[str]:
    hist = result.history
    inner = [h.solver_info.inner_iterations for h in hist]
    has_inner = any(i is not None for i in inner)
    png = drawing.draw(fig.convergence, [h.vtpv for h in hist], [h.max_correction for h in hist],
                       [np.nan if i is None else i for i in inner] if has_inner else None)
    header = ["iteration", "v<sup>T</sup>P v", "largest correction / its &sigma;", "seconds"]
    if has_inner:
        header += ["inner iterations", "relative residual"]
    rows = []
    for i, h in enumerate(hist):
        row = [str(i + 1), _fmt(h.vtpv, ".8g"), _fmt(h.max_correction, ".3e"), _fmt(h.seconds, ".3f")]
        if has_inner:
            row += [_fmt(h.solver_info.inner_iterations), _fmt(h.solver_info.relative_residual, ".1e")]
        rows.append(row)
    return [
        _section("convergence"),
        _img(png, "convergence history",
             "Sum of the weighted squared residuals and the correction (the largest correction of any element "
             "or function of the elements, in units of its standard deviation) per iteration, on log axes."
             + (" Right: inner iterations of the iterative solver." if has_inner else "")),
        _table(header, rows),
    ]


def _photos_section(project: Project, result: AdjustmentResult, stats: dict) -> list[str]:
    unit = project.settings.angle_unit
    plate = residual_unit(project)
    per_rad = 1.0 / RADIANS_PER_UNIT[unit]
    digits = {"deg": 5, "gon": 5, "rad": 7}[unit]
    xyz = result.state.xyz0 + result.offset
    opk = angles_from_R(result.state.R_ground_from_cam, "omega-phi-kappa") * per_rad
    sig_xyz, sig_ang = result.photo_mean_errors("omega-phi-kappa")
    sig_ang = sig_ang * per_rad
    n = len(project.photos)
    worst_key = np.nan_to_num(sig_xyz.max(axis=1), nan=np.inf)
    if n <= page.MAX_PHOTO_ROWS:
        shown, classes, note = np.arange(n), None, ""
    else:
        first = np.arange(page.PHOTO_ROWS_EACH)
        worst = np.array([p for p in np.argsort(-worst_key, kind="stable") if p >= page.PHOTO_ROWS_EACH][:page.PHOTO_ROWS_EACH])
        shown = np.concatenate([first, worst])
        classes = [""] * page.PHOTO_ROWS_EACH + ["sep"] + [""] * (len(worst) - 1)
        note = (f"<p class='note'>The first {page.PHOTO_ROWS_EACH} photographs, then (below the line) the "
                f"{len(worst)} others with the largest mean error of the projection centre, of {n}; "
                "photos.csv lists all.</p>")
    rows = []
    factor, length = length_unit(sig_xyz[shown])
    for p in shown:
        rows.append([html.escape(project.photos.ids[p]), html.escape(project.photos.strip_ids[p]),
                     str(stats["count"][p])]
                    + [_fmt(x, ".2f") for x in xyz[p]] + [_fmt(x, f".{digits - 1}f") for x in opk[p]]
                    + [_fmt(x * factor, ".3f") for x in sig_xyz[p]] + [_fmt(x, f".{digits}f") for x in sig_ang[p]]
                    + [plate(x) for x in stats["rms"][p]] + [_fmt(stats["wmax"][p], ".2f"),
                       _cell(str(stats["flagged"][p]), "flag" if stats["flagged"][p] else "")])
    header = ["photo", "strip", "pts", "X0", "Y0", "Z0", "&omega;", "&phi;", "&kappa;", "&sigma;X0", "&sigma;Y0",
              "&sigma;Z0", "&sigma;&omega;", "&sigma;&phi;", "&sigma;&kappa;", "RMS v<sub>x</sub>",
              "RMS v<sub>y</sub>", "max |w|", "flagged"]
    return [
        _section("photos"),
        f"<p>Adjusted exterior orientation (centres in m, angles &omega;, &phi;, &kappa; in {unit}) with their "
        f"mean errors &sigma;<sub>0</sub>&radic;Q<sub>ii</sub> (of the centres in {length}), and the residuals of "
        "each photograph (RMS in "
        f"{plate.label}).</p>",
        _table(header, rows, cls="photos", left=2, row_classes=classes),
        note,
    ]


def _camera_section(project: Project, result: AdjustmentResult) -> list[str]:
    """The estimated camera elements with their mean errors, their correlations and, for each, the
    exterior element it is most correlated with (precision.camera_correlations)."""
    out = [_section("camera")]
    blocks = camera_correlations(result)
    if not blocks:
        out.append("<p>No camera element was estimated (every camera is held).</p>")
        return out
    out.append(f"<p>Estimated interior orientation and additional parameters (plate units, here "
               f"{residual_unit(project).plate_words}; k, p of the "
               "plate convention per plate unit, of the image convention dimensionless) with their mean "
               "errors, the correlations among them and each one's largest correlation with an exterior "
               "element. Correlations near &plusmn;1 mean the data cannot separate the two.</p>")
    for b in blocks:
        j = b["camera"]
        names = [CAMERA_ELEMENTS[e] for e in b["elements"]]
        rows = []
        for i, e in enumerate(b["elements"]):
            photo, element, rho = b["exterior"][i]
            other = np.abs(np.nan_to_num(b["matrix"][i]))
            other[i] = -1.0
            k = int(np.argmax(other)) if len(names) > 1 else -1
            rows.append([names[i], _fmt(result.state.interior[j, e], ".8g"), _fmt(b["sigma"][i], ".3g"),
                         (f"{names[k]} {_fmt(b['matrix'][i, k], '.3f')}" if k >= 0 else "&ndash;"),
                         (f"{html.escape(project.photos.ids[photo])} {PHOTO_ELEMENTS[element]} {_fmt(rho, '.3f')}"
                          if photo >= 0 else "&ndash;")])
        out.append(f"<h3>Camera {html.escape(project.cameras.ids[j])} (distortion convention "
                   f"{CONVENTION_NAMES[int(result.state.convention[j])]})</h3>")
        out.append(_table(["element", "value", "&sigma;", "largest correlation (camera)",
                           "largest correlation (exterior)"], rows, left=1))
        matrix_rows = [[names[i]] + [_fmt(x, ".2f") for x in b["matrix"][i]] for i in range(len(names))]
        out.append("<div class='scroll'>" + _table([""] + names, matrix_rows, left=1) + "</div>")
    return out


def _gnss_section(project: Project, result: AdjustmentResult) -> list[str]:
    """The GNSS/IMU unknowns (gnss_output.report_tables)."""
    out = [_section("gnss")]
    unit = project.settings.angle_unit
    tables = gnss_report_tables(project, result, 1.0 / RADIANS_PER_UNIT[unit], unit)
    if not tables:
        out.append("<p>No GNSS or IMU element was estimated (lever arms and boresights held, no shift or "
                   "drift).</p>")
    for text, header, rows, left in tables:
        out += [f"<p>{text}</p>", _table(header, rows, left=left)]
    return out


# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReportParts:
    """What the caller of html_report made already or wants back: figures, name -> PNG bytes (or a
    report.drawing figure) made elsewhere ("structure": the normal matrix pattern); distances, distances.csv's columns
    (reliability.distances.distance_table) when the caller formed them (formed here otherwise);
    timings, a dict that receives the seconds each section took (section id -> s; "total" for
    the whole report)."""

    figures: dict = field(default_factory=dict)
    distances: dict | None = None
    timings: dict | None = None
    sections: dict | None = None  # figure_sections' sections, made before (their figures drawn meanwhile)


def _residual_inputs(project: Project, result: AdjustmentResult, w: np.ndarray, flags) -> tuple:
    """(w as floats, the largest |w| of each measurement, its flag, the flags' wording, the
    photos' statistics): what the sections of the residuals read (html_report's arguments)."""
    w = np.asarray(w, dtype=float)
    absw = np.nan_to_num(np.abs(w), nan=0.0).max(axis=1) if len(w) else np.zeros(0)
    flagged = _flags_of(flags, w)
    return w, absw, flagged, _flag_text(flags), _photo_statistics(project, result.plate_residuals, absw, flagged)


FIGURE_SECTIONS = ("convergence", "residuals", "points")  # the sections with figures


def figure_sections(project: Project, result: AdjustmentResult, w: np.ndarray | None = None,
                    points: Triangulated | None = None, flags=None,
                    keys=FIGURE_SECTIONS) -> dict[str, tuple[list[str], float]]:
    """The report's sections with figures among ``keys`` (convergence, residuals (w needed) and,
    with points, points), each with the seconds it took: ReportParts.sections of :func:`html_report`
    with the same arguments. The pipeline asks for them early, so that a drawing worker
    (report.drawing) draws their figures meanwhile."""
    out = {}
    for key in keys:
        if key == "points" and points is None:
            continue
        start = time.perf_counter()
        if key == "convergence":
            section = _convergence_section(result)
        elif key == "residuals":
            _, absw, flagged, flag_text, stats = _residual_inputs(project, result, w, flags)
            section = _residuals_section(project, result, stats, flagged, flag_text, absw)
        else:
            section = _points_section(project, result, points, _point_covariance(result, points))
        out[key] = (section, time.perf_counter() - start)
    return out


def html_report(project: Project, result: AdjustmentResult, summary: RunSummary, w: np.ndarray,
                points: Triangulated | None = None, flags=None, parts: ReportParts = ReportParts()) -> str:
    """The report as one self-contained HTML text.

    summary: the run's runs.RunSummary (summary.json's typed form); w: (m, 2) normalised
    residuals of the plate coordinates (nan where undefined); points: the triangulated points (pipeline.triangulate_result), needed for the error
    ellipses and the check-point table; flags: optional (m,) flags of the plate measurements (bool, or
    residuals.csv's "flag" strings); by default residuals.csv's rule |w| > 3.29. parts: figures,
    tables and a timing dict of the caller (ReportParts).
    """
    t0 = time.perf_counter()
    figures, distances, timings = parts.figures or {}, parts.distances, parts.timings
    w, absw, flagged, flag_text, stats = _residual_inputs(project, result, w, flags)
    src = html.escape(str(project.source or ""))
    seconds: dict[str, float] = {"preparation": time.perf_counter() - t0}
    made = parts.sections or {}

    def timed(key: str, make) -> list[str]:
        if key in made:  # made by the caller (figure_sections), with the seconds it took
            section, seconds[key] = made[key]
            return section
        start = time.perf_counter()
        parts = make()
        seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - start
        return parts

    body = [timed("summary", lambda: _summary_section(project, result, summary, flagged)),
            timed("warnings", lambda: _warnings_section(summary)),
            _corrections_section(summary),
            timed("checks", lambda: _checks_section(summary)),
            timed("convergence", lambda: _convergence_section(result)),
            timed("residuals", lambda: _residuals_section(project, result, stats, flagged, flag_text, absw))]
    if points is not None:
        cov = _point_covariance(result, points)
        sig = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
        body += [timed("points", lambda: _points_section(project, result, points, cov)),
                 timed("check-points", lambda: _check_points_section(project, result, points, sig, summary))]
    else:
        body += [[_section("points"), "<p>Not available (no triangulated points given).</p>"],
                 [_section("check-points"), "<p>Not available (no triangulated points given).</p>"]]
    body += [timed("flagged", lambda: _flagged_section(project, result, w, absw, flagged, flag_text)),
             timed("rejected", lambda: _rejected_section(summary)),
             _automatic_section(summary),
             _inactive_section(summary, residual_unit(project)),
             _distances_section(project, result, summary, points, distances),
             timed("largest", lambda: _largest_section(project, result, w, absw)),
             timed("photos", lambda: _photos_section(project, result, stats)),
             timed("camera", lambda: _camera_section(project, result))]
    if project.film is not None:
        body.append(timed("film", lambda: [_section("film")] + [
            p if isinstance(p, str) else _table(*p) for p in film_report.report_parts(project.film)]))
    if result.layout.gnss_cols is not None:
        body.append(timed("gnss", lambda: _gnss_section(project, result)))
    structure = [_section("structure")]
    if "structure" in figures:
        structure.append(_img(figures["structure"], "normal matrix structure",
                              "Nonzero 6 &times; 6 blocks of the normal matrix, one row and column per photograph "
                              "(cameras last), as in Schmid's Fig. 10: the band shows which photographs share "
                              "points; its width decides the cost of the solution."))
    else:
        structure.append("<p>Not drawn.</p>")
    body.append(structure)

    nav = " ".join(f"<a href='#{k}'>{v}</a>" for k, v in SECTIONS.items()
                   if (k != "corrections" or summary.plate_corrections is not None)
                   and (k != "gnss" or result.layout.gnss_cols is not None)
                   and (k != "film" or project.film is not None)
                   and (k != "inactive" or summary.inactive is not None)
                   and (k != "automatic" or summary.automatic_tie_points is not None)
                   and (k != "distances" or (project.distances is not None and points is not None)))
    body_text = "\n".join(p for section in body for p in section if p)
    waited = time.perf_counter()
    body_text = drawing.fill(body_text)  # the figures of a drawing worker (report.drawing), waited for here
    if drawing.drawing_elsewhere():
        seconds["waiting for the figures drawn by the second process"] = time.perf_counter() - waited
    slow = sorted(((v, k) for k, v in seconds.items() if v >= 0.005), reverse=True)
    breakdown = ", ".join(f"{html.escape(SECTIONS.get(k, k).lower())} {v:.2f}" for v, k in slow)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>striptri adjustment report</title><style>{_STYLE}</style></head><body><main>",
        "<h1>Aerial triangulation: adjustment report</h1>",
        f"<p class='sub'>Project {src or '(in memory)'} &middot; {summary.n_photos} photographs, "
        f"{summary.n_points} points &middot; method {html.escape(summary.method)}, solver "
        f"{html.escape(summary.solver)}</p>",
        f"<nav>{nav}</nav>",
        run_block(summary),
    ]
    parts.append(body_text)
    total = time.perf_counter() - t0 + sum(spent for _, spent in made.values())
    parts.append(f"<footer>Written by striptri. Report and figures built in {total:.2f} s"
                 + (f" ({breakdown})" if breakdown else "") + ". "
                 "The numbers in full are in photos.csv, points.csv, residuals.csv and summary.json beside "
                 "this file.</footer></main></body></html>")
    if timings is not None:
        timings.update(seconds)
        timings["total"] = time.perf_counter() - t0
    return "\n".join(parts)
