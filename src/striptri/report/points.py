"""report.html's sections on the points and measurements: the ground points with their error
ellipses (or their rasters), the check points and those left out, the plate residuals with their
figures, the flagged, rejected and largest measurements."""

from __future__ import annotations

import html
from typing import NamedTuple
import numpy as np

from . import figures as fig
from . import drawing, plan_views
from ..core.result import AdjustmentResult
from ..model import CHECK, KIND_NAMES, Project
from ..equations.triangulation import Triangulated
from ..core.adjusted_points import undetermined_points
from ..core.runs import RunSummary
from . import page  # the page's limits, read at call time (tests set them)
from .page import (
    ResidualUnit, _cell, _fmt, _half_format, _img, _kind_names, _section, _table, length_unit, residual_unit,
)



def _cell_statistics(xy: np.ndarray, values: np.ndarray, h: float, cells: int):
    """Means of values (m, k) per cell of a cells x cells grid over [-h, h]^2 (row-major from the
    lower left; points outside go to the border cells) -> (centres (cells^2, 2), means (cells^2, k),
    counts (cells^2,))."""
    edges = np.linspace(-h, h, cells + 1)
    ix = np.clip(np.searchsorted(edges, xy[:, 0]) - 1, 0, cells - 1)
    iy = np.clip(np.searchsorted(edges, xy[:, 1]) - 1, 0, cells - 1)
    cell = iy * cells + ix
    counts = np.bincount(cell, minlength=cells * cells)
    sums = np.stack([np.bincount(cell, values[:, a], cells * cells) for a in range(values.shape[1])], axis=1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    cx, cy = np.meshgrid(centres, centres)
    return np.column_stack([cx.ravel(), cy.ravel()]), sums / np.maximum(counts, 1)[:, None], counts


def _points_section(project: Project, result: AdjustmentResult, points: Triangulated, cov: np.ndarray) -> list[str]:
    pts = project.points
    xyz = points.xyz + result.offset
    kind_names = _kind_names(pts.kind)
    centres = result.state.xyz0 + result.offset
    sig = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
    a = np.sqrt(np.maximum(np.linalg.eigvalsh(np.nan_to_num(cov[:, :2, :2]))[:, 1], 0.0))
    a = np.where(points.determined, a, np.nan)
    pos = np.isfinite(a) & (a > 0)
    every = np.concatenate([xyz[points.determined, :2], centres[:, :2]])
    span = np.ptp(every, axis=0)
    extent = float(span.max())
    n_determined = int(points.determined.sum())
    spacing = float(np.sqrt(max(span[0] * span[1], extent**2 / 100) / max(n_determined, 1)))
    typical = float(np.median(a[pos])) if pos.any() else 1.0
    # a typical ellipse 1.5 % of the block across, or a third of the mean point spacing in dense blocks
    mag = fig.nice_number(min(0.015 * extent, 0.35 * spacing) / typical)
    bar = fig.nice_number(0.12 * extent / mag)
    bar_label = f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm"
    worst_table = ""
    if n_determined <= page.MAX_ELLIPSES:
        strips = plan_views.flies_strips(result.state.R_ground_from_cam)
        plan = plan_views.BlockPlan(centres[:, :2], project.photos.strip_ids, xyz[:, :2], kind_names, strips)
        png = drawing.draw(plan_views.error_ellipses, plan, cov[:, :2, :2], fig.ScaleBar(mag, bar, bar_label),
                           labels=pts.ids)
        stations = ("projection centres (+) along their flight lines (arrow: direction of flight)" if strips else
                    "camera stations (+; convergent photographs, no flight lines)")
        figure = _img(png, "error ellipses of the ground points",
                      f"Plan view of the block: {stations}, ground points coloured by kind, control as triangles. "
                      f"Around every point its "
                      f"horizontal standard error ellipse (1 &sigma;, from the X, Y part of its covariance), "
                      f"magnified <b>{mag:g} times</b>; the bar is {bar_label} of error. Fixed control has no "
                      f"ellipse.")
    else:
        spread = _Spread(xyz, centres, kind_names, cov, sig, a, pos, every, extent, spacing)
        figure, worst_table = _precision_map(project, points, spread)
    rows = []
    factor, unit = length_unit(sig[points.determined])
    for k in sorted(KIND_NAMES):
        sel = (pts.kind == k) & points.determined
        if not sel.any():
            continue
        s = sig[sel] * factor
        rows.append([KIND_NAMES[k], str(int(sel.sum()))] + [_fmt(x, ".3f") for x in np.nanmean(s, axis=0)]
                    + [_fmt(x, ".3f") for x in np.nanmax(s, axis=0)])
    n_undet = int((~points.determined).sum())
    return [
        _section("points"),
        figure,
        f"<h3>Mean errors by kind ({unit})</h3>",
        _table(["kind", "points", "mean &sigma;X", "mean &sigma;Y", "mean &sigma;Z", "max &sigma;X", "max &sigma;Y",
                "max &sigma;Z"], rows, left=1),
        f"<p class='note'>{n_undet} points could not be determined.</p>" if n_undet else "",
        worst_table,
    ]


class _Spread(NamedTuple):
    """The points over the block, as _points_section computes them for its plan views: xyz (n_pt,
    3) and centres (n_ph, 3) ground coordinates (m); kind_names (n_pt,); cov (n_pt, 3, 3) m^2 and
    sig (n_pt, 3) m; a (n_pt,) the semi-major axis of the horizontal error ellipse (nan where
    undetermined), pos where it is finite and > 0; every (k, 2) X, Y of the determined points and
    the centres; extent (m) the block's larger side; spacing (m) the mean spacing of the points."""

    xyz: np.ndarray
    centres: np.ndarray
    kind_names: np.ndarray
    cov: np.ndarray
    sig: np.ndarray
    a: np.ndarray
    pos: np.ndarray
    every: np.ndarray
    extent: float
    spacing: float


def _precision_map(project, points, spread: _Spread):
    """The error ellipses of a large block summarised: rasters of the RMS horizontal (semi-major
    axis) and vertical error per cell of a grid over the block, the page.WORST_ELLIPSES worst drawn on
    top, and a table of the page.WORST_POINT_ROWS points with the largest error. -> (figure, table) HTML."""
    xyz, centres, kind_names, cov, sig, a, pos, every, extent, spacing = spread
    pts = project.points
    lo, hi = every.min(axis=0), every.max(axis=0)
    cell = max(extent / page.MAP_CELLS, 4.0 * spacing, 1e-9)  # about 16 points per cell at least
    nx, ny = (int(v) for v in np.maximum(np.ceil((hi - lo) / cell), 1))
    grid_extent = (lo[0], lo[0] + nx * cell, lo[1], lo[1] + ny * cell)
    sz = np.where(points.determined, sig[:, 2], np.nan)
    pos_z = np.isfinite(sz) & (sz > 0)

    def rms_grid(values, sel):
        ix = np.clip(((xyz[sel, 0] - lo[0]) / cell).astype(int), 0, nx - 1)
        iy = np.clip(((xyz[sel, 1] - lo[1]) / cell).astype(int), 0, ny - 1)
        k = iy * nx + ix
        count = np.bincount(k, minlength=nx * ny)
        ms = np.bincount(k, values[sel] ** 2, nx * ny) / np.maximum(count, 1)
        return np.where(count > 0, np.sqrt(ms), np.nan).reshape(ny, nx)

    grid_h, grid_z = rms_grid(a, pos), rms_grid(sz, pos_z)
    worst_h = np.flatnonzero(pos)[np.argsort(-a[pos], kind="stable")[:page.WORST_ELLIPSES]]
    worst_z = np.flatnonzero(pos_z)[np.argsort(-sz[pos_z], kind="stable")[:page.WORST_ELLIPSES]]
    largest = float(a[worst_h[0]]) if len(worst_h) else 1.0
    mag = fig.nice_number(0.03 * extent / largest)  # the largest ellipse 6 % of the block across
    bar = fig.nice_number(0.12 * extent / mag)
    bar_label = f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm"
    finite = np.concatenate([grid_h[np.isfinite(grid_h)], grid_z[np.isfinite(grid_z)]])
    unit, scale = ("cm", 100.0) if len(finite) == 0 or np.percentile(finite, 99) < 1.0 else ("m", 1.0)
    strips = plan_views.flies_strips(project.photos.R_ground_from_cam)
    plan = plan_views.BlockPlan(centres[:, :2], project.photos.strip_ids, xyz[:, :2], kind_names, strips)
    png = drawing.draw(plan_views.precision_map, plan, grid_extent, (grid_h, grid_z, unit, scale), (worst_h, worst_z),
                       cov[:, :2, :2], fig.ScaleBar(mag, bar, bar_label))
    n_shown = int(pos.sum())
    n_strips = len(set(project.photos.strip_ids))
    lines = " with its flight lines" if strips and n_strips <= plan_views.MAP_FLIGHT_LINES else ""
    figure = _img(png, "precision of the ground points over the block",
                  f"Plan view of the block{lines} and control (full control: red triangles, plan: orange, height: "
                  f"green, check points: purple diamonds). With {n_shown} error ellipses too many to draw one by "
                  f"one, each cell of a {nx} &times; {ny} grid ({cell:.4g} m a side) is coloured by the quadratic "
                  f"mean over its points of, left, the semi-major axis of the horizontal standard error ellipse "
                  f"(1 &sigma;) and, right, &sigma;Z ({unit}; white: no point; the colour scale runs from the 1st "
                  f"to the 99th percentile of the cells). On top, left: the error ellipses of the {len(worst_h)} "
                  f"points with the largest, magnified <b>{mag:g} times</b> (the bar is {bar_label} of error); "
                  f"right: the {len(worst_z)} points with the largest &sigma;Z, circled. Fixed control has no "
                  f"error.")
    total = np.where(points.determined, np.sqrt(np.sum(sig**2, axis=1)), np.nan)
    finite_total = np.flatnonzero(np.isfinite(total))
    worst = finite_total[np.argsort(-total[finite_total], kind="stable")[:page.WORST_POINT_ROWS]]
    rays = np.bincount(project.image_points.point_index, minlength=len(pts))
    factor, unit = length_unit(sig[worst])
    rows = [[html.escape(pts.ids[i]), kind_names[i], str(rays[i])] + [_fmt(x, ".2f") for x in xyz[i]]
            + [_fmt(x * factor, ".3f") for x in sig[i]] + [_fmt(a[i] * factor, ".3f")] for i in worst]
    table = (f"<h3>The {len(worst)} points with the largest mean error</h3>"
             f"<p class='note'>Sorted by &radic;(&sigma;X&sup2; + &sigma;Y&sup2; + &sigma;Z&sup2;), of "
             f"{len(finite_total)} determined points (coordinates in m, mean errors in {unit}); points.csv lists "
             "all.</p>"
             + _table(["point", "kind", "rays", "X", "Y", "Z", "&sigma;X", "&sigma;Y", "&sigma;Z",
                       "semi-major axis"], rows, left=2))
    return figure, table


def _check_points_section(project: Project, result: AdjustmentResult, points: Triangulated, sig: np.ndarray,
                          summary: RunSummary) -> list[str]:
    pts = project.points
    flagged = undetermined_points(project, points)
    sel = np.flatnonzero((pts.kind == CHECK) & points.determined & ~flagged)
    out = np.flatnonzero((pts.kind == CHECK) & flagged)
    parts = [_section("check-points")]
    left_out = _left_out_check_points(project, result, points, sig, out)
    if len(sel) == 0:
        return parts + ["<p>The project has no check points.</p>" if not len(out) else
                        "<p>No check point is determined by its rays.</p>"] + left_out
    d = points.xyz[sel] + result.offset - pts.xyz_given[sel]
    f, unit = length_unit(np.concatenate([d.ravel(), sig[sel].ravel()]))
    rows = [[html.escape(pts.ids[i])] + [_fmt(x * f, ".3f") for x in d[j]] + [_fmt(x * f, ".3f") for x in sig[i]]
            for j, i in enumerate(sel[:page.MAX_TABLE_ROWS])]
    classes = [""] * len(rows)
    mean = d.mean(axis=0)
    rows.append(["mean"] + [_fmt(x * f, ".3f") for x in mean] + ["", "", ""])
    cp = summary.check_points
    rms = [cp["rms_X"], cp["rms_Y"], cp["rms_Z"]]  # summary.json's values (m), in full in the cell's title
    rows.append(["RMS"] + [_cell(_fmt(x * f, ".3f"), "", repr(float(x))) for x in rms]
                + [_fmt(x * f, ".3f") for x in np.sqrt(np.nanmean(sig[sel] ** 2, axis=0))])
    classes += ["sep", "total"]
    note = (f"<p class='note'>The first {page.MAX_TABLE_ROWS} of {len(sel)} check points; points.csv lists all.</p>"
            if len(sel) > page.MAX_TABLE_ROWS else "")
    return parts + [
        f"<p>{len(sel)} check points were adjusted as tie points and compared with their given coordinates "
        f"afterwards: d = adjusted &minus; given ({unit}), beside the mean error of the adjusted point. The RMS row of "
        "&sigma; is the quadratic mean of the mean errors, to compare with the RMS of d.</p>",
        _table(["point", "dX", "dY", "dZ", "&sigma;X", "&sigma;Y", "&sigma;Z"], rows, left=1, row_classes=classes),
        note,
    ] + left_out


def _left_out_check_points(project: Project, result: AdjustmentResult, points: Triangulated, sig: np.ndarray,
                           idx: np.ndarray) -> list[str]:
    """The check points left out of the statistics because their rays do not determine them."""
    if not len(idx):
        return []
    pts = project.points
    d = points.xyz[idx] + result.offset - pts.xyz_given[idx]
    rows = [[html.escape(pts.ids[i])] + [_fmt(x, ".3f") for x in d[j]] + [_fmt(x, ".3f") for x in sig[i]]
            for j, i in enumerate(idx[:page.MAX_TABLE_ROWS])]
    return [
        f"<p class='warn'>{len(idx)} check point{'s were' if len(idx) > 1 else ' was'} left out of the statistics: "
        f"the measurements left to {'them' if len(idx) > 1 else 'it'} do not determine "
        f"{'them' if len(idx) > 1 else 'it'} (rays nearly parallel, one ray left, or coordinates lost to rejected "
        "measurements; flag <i>undetermined</i> in points.csv). Their differences say nothing of the block's "
        "accuracy:</p>",
        _table(["point", "dX", "dY", "dZ", "&sigma;X", "&sigma;Y", "&sigma;Z"], rows, left=1),
    ]


def _measurement_rows(project: Project, result: AdjustmentResult, w: np.ndarray, rows_idx) -> list:
    ip = project.image_points
    unit = residual_unit(project)
    out = []
    for i in rows_idx:
        wi = w[i]
        out.append([html.escape(project.photos.ids[ip.photo_index[i]]),
                    html.escape(project.points.ids[ip.point_index[i]]),
                    KIND_NAMES[int(project.points.kind[ip.point_index[i]])],
                    _fmt(ip.xy[i, 0], ".3f"), _fmt(ip.xy[i, 1], ".3f"),
                    unit(result.plate_residuals[i, 0]), unit(result.plate_residuals[i, 1]),
                    _fmt(wi[0], ".2f"), _fmt(wi[1], ".2f")])
    return out


def _measurement_header(unit: ResidualUnit) -> list[str]:
    """Column names of a table of _measurement_rows: plate coordinates and residuals in their units."""
    return ["photo", "point", "kind", f"x ({unit.plate})", f"y ({unit.plate})", f"v<sub>x</sub> ({unit.label})",
            f"v<sub>y</sub> ({unit.label})", "w<sub>x</sub>", "w<sub>y</sub>"]


def _flagged_section(project, result, w, absw, flagged, flag_text) -> list[str]:
    idx = np.flatnonzero(flagged)
    idx = idx[np.argsort(-absw[idx], kind="stable")]
    parts = [_section("flagged")]
    if len(idx) == 0:
        return parts + [f"<p>No measurement is flagged ({flag_text}).</p>"]
    note = (f"<p class='note'>The {page.MAX_TABLE_ROWS} with the largest |w| of {len(idx)}; residuals.csv lists all.</p>"
            if len(idx) > page.MAX_TABLE_ROWS else "")
    return parts + [
        f"<p>{len(idx)} measurement{'s' if len(idx) != 1 else ''} flagged ({flag_text}), largest |w| first. "
        "w is the normalised residual "
        "v / (&sigma; &radic;q<sub>vv</sub>) of Baarda's data snooping.</p>",
        _table(_measurement_header(residual_unit(project)), _measurement_rows(project, result, w, idx[:page.MAX_TABLE_ROWS]),
               left=3),
        note,
    ]


def _rejected_section(summary: RunSummary) -> list[str]:
    """summary.blunders["groups"] (reliability.rejections): per rejected group its members, w, MDB
    and effect on the ground."""
    groups = (summary.blunders or {}).get("groups") or []
    parts = [_section("rejected")]
    if not groups:
        return parts + ["<p>No measurement was rejected.</p>"]

    def num(v, fmt):
        return "&ndash;" if v is None else format(v, fmt)

    rows = []
    for g in groups[:page.MAX_TABLE_ROWS]:
        effect = g["ground_effect"]
        rows.append([
            html.escape(g["point_id"]), html.escape(", ".join(g["photo_ids"])),
            "found" if g["localised"] else "<span class='flag'>detected, not localisable</span>",
            g["coordinate"], f"{g['w']:.1f}", num(g["mdb"], ".4g"), num(g["bias_to_noise"], ".1f"),
            "point drops out" if effect is None else " ".join(f"{v:+.3f}" for v in effect),
        ])
    note = (f"<p class='note'>The first {page.MAX_TABLE_ROWS} of {len(groups)}; summary.json lists all.</p>"
            if len(groups) > page.MAX_TABLE_ROWS else "")
    return parts + [
        f"<p>{len(groups)} group{'s' if len(groups) != 1 else ''} rejected, in the order of rejection. A group of "
        "several photographs: their w-tests cannot be told apart (correlated beyond separability), the gross error "
        "is detected but not localised and all were rejected. w, MDB (plate units) and the bias-to-noise ratio "
        "(external reliability) of the tested coordinate when it was rejected; effect on the ground: what the "
        "group's measurements would have moved their point (X Y Z, m) had they been kept.</p>",
        _table(["point", "photos", "outcome", "coordinate", "w", "MDB", "bias / noise", "effect on the ground (m)"],
               rows, left=3),
        note,
    ]


def _largest_section(project, result, w, absw, n: int = 15) -> list[str]:
    worst = np.argsort(-absw, kind="stable")[:n]
    return [_section("largest"),
            f"<p>The {len(worst)} measurements with the largest normalised residual, flagged or not.</p>",
            _table(_measurement_header(residual_unit(project)), _measurement_rows(project, result, w, worst), left=3)]


def _residuals_section(project: Project, result: AdjustmentResult, stats: dict, flagged: np.ndarray,
                       flag_text: str, absw: np.ndarray) -> list[str]:
    ip = project.image_points
    xy, v = ip.xy, result.plate_residuals
    if len(xy) == 0:
        return [_section("residuals"), "<p>No plate measurements.</p>"]
    unit = residual_unit(project)
    h = _half_format(xy)
    length = np.hypot(v[:, 0], v[:, 1])
    sig = ip.sigma_xy[np.isfinite(ip.sigma_xy) & (ip.sigma_xy > 0)]
    sigma_prior = float(np.median(sig)) if len(sig) else 1e-3 * h
    resolvable = 0.01 * sigma_prior  # smaller residuals are zero to the eye (no redundancy, exact plates)
    typical = float(np.percentile(length, 95))
    vanish = not typical > resolvable
    if vanish:
        typical = sigma_prior  # scale as for residuals of the a-priori size
    # a typical (95 %) residual drawn as about 15 % of the format side in the small panels, half that over all
    mag = fig.nice_number(0.3 * h / max(typical, 1e-300))
    mag_all = fig.nice_number(0.5 * mag)
    bar = fig.nice_number(0.3 * h / mag)
    bar_all = fig.nice_number(0.3 * h / mag_all)
    bar_label = unit.length(bar)
    n_ph = len(project.photos)
    ids = project.photos.ids
    rms_all = np.sqrt(np.mean(v**2, axis=0))
    parts = [
        _section("residuals"),
        f"<p>RMS of the plate residuals: v<sub>x</sub> {unit(rms_all[0])} {unit.label}, v<sub>y</sub> "
        f"{unit(rms_all[1])} {unit.label} over {len(xy)} measurements (plate coordinates in {unit.plate_words}). "
        f"Vectors are drawn magnified <b>{mag:g} times</b> per photograph (<b>{mag_all:g} times</b> over "
        f"all photographs); the bar is the length of a residual of {bar_label}. "
        f"Dark blue: residuals; <span class='flag'>red</span>: {flag_text}.</p>",
        "<p class='note'>All residuals vanish (below 1 % of the a-priori &sigma;): there is no redundancy or the "
        "plates are exact.</p>" if vanish else "",
    ]
    order = np.argsort(-(stats["flagged"] * 1e6 + np.nan_to_num(np.hypot(*stats["rms"].T))), kind="stable")
    if n_ph <= page.MAX_PHOTO_PANELS:
        shown, what = np.arange(n_ph), "every photograph"
    else:
        shown = order[:page.WORST_PANELS]
        what = (f"the {page.WORST_PANELS} photographs with the most flagged measurements and the largest RMS residual "
                f"(of {n_ph}; residuals.csv lists all)")
    rows_of = np.argsort(ip.photo_index, kind="stable")
    bounds = np.searchsorted(ip.photo_index[rows_of], np.arange(n_ph + 1))
    groups = [rows_of[bounds[p]:bounds[p + 1]] for p in shown]
    rms_photo = unit.factor * np.hypot(*stats["rms"].T) / np.sqrt(2)  # RMS per coordinate, in unit.label
    titles = [f"{ids[p]}  ({stats['count'][p]} pts, {rms_photo[p]:{unit.spec}} {unit.label})" for p in shown]
    png = drawing.draw(fig.plate_residuals_per_photo, xy, v, flagged, groups, titles, h,
                       fig.ScaleBar(mag, bar, bar_label))
    parts.append("<h3>Per photograph</h3>")
    parts.append(_img(png, "residual vectors per photograph",
                      f"Residual vectors on the format of {what}; panel title: photo, measurements, RMS residual "
                      f"per coordinate. Frame: &plusmn;{h:g} {unit.plate} about the principal point."))
    # all photographs stacked, and the mean residual per cell of a 5 x 5 grid
    cells = 5
    centres_5, means, counts = _cell_statistics(xy, v, h, cells)
    biggest = float(np.max(np.hypot(means[:, 0], means[:, 1]), initial=0.0))
    cell_means = None
    right = ""
    if biggest > resolvable:
        mag2 = fig.nice_number(0.3 * h / biggest)
        bar2 = fig.nice_number(0.3 * h / mag2)
        cell_means = (centres_5, means, counts, fig.ScaleBar(mag2, bar2, unit.length(bar2)))
        right = (f" Right: the mean residual in each cell of a {cells} &times; {cells} grid (x{mag2:g}); a regular "
                 "pattern there points to a systematic image error (lens distortion, film deformation) rather than "
                 "noise.")
    if len(xy) <= page.MAX_VECTORS:
        png = drawing.draw(fig.plate_residuals_stacked, xy, v, flagged, h,
                           fig.ScaleBar(mag_all, bar_all, unit.length(bar_all)), cell_means, plate_unit=unit.plate)
        left = f"the residuals of all photographs drawn over one format (x{mag_all:g})."
    else:  # a raster of the RMS residual per cell, and the worst vectors on top
        _, ms, count = _cell_statistics(xy, length[:, None] ** 2, h, page.FIELD_CELLS)
        rms = np.where(count > 0, np.sqrt(ms[:, 0]), np.nan).reshape(page.FIELD_CELLS, page.FIELD_CELLS)
        worst = np.argsort(-(flagged * (1.0 + absw.max(initial=0.0)) + absw), kind="stable")[:page.WORST_VECTORS]
        mag_w = min(mag_all, fig.nice_number(0.3 * h / max(float(length[worst].max()), 1e-300)))
        bar_w = fig.nice_number(0.3 * h / mag_w)
        png = drawing.draw(fig.plate_residuals_stacked, xy[worst], v[worst], flagged[worst], h,
                           fig.ScaleBar(mag_w, bar_w, unit.length(bar_w)), cell_means,
                           field=(rms * unit.factor, unit.label, len(xy)), plate_unit=unit.plate)
        left = (f"the RMS length of the residuals of all {len(xy)} measurements in each cell of a {page.FIELD_CELLS} "
                f"&times; {page.FIELD_CELLS} grid over the format ({unit.label}; white: no measurement), and on top the "
                f"{len(worst)} with the largest normalised residual |w| (<span class='flag'>red</span>: flagged), "
                f"drawn x{mag_w:g}.")
    caption = ("Left: " + left + right) if right else left[:1].upper() + left[1:]
    parts.append("<h3>All photographs over one format</h3>")
    parts.append(_img(png, "residual vectors of all photographs", caption))
    return parts
