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

import base64
import html
import re
import time
from pathlib import Path
from dataclasses import dataclass
import numpy as np

from . import figures as fig
from ..core.result import AdjustmentResult
from ..bundle.distances import report_parts as distance_report_parts
from ..reliability.distances import distance_table
from . import film as film_report
from .gnss import report_tables as gnss_report_tables
from ..geometry.rotations import RADIANS_PER_UNIT
from ..geometry.lens import CAMERA_ELEMENTS, CONVENTION_NAMES
from ..model import CHECK, KIND_NAMES, Project
from ..precision.residuals import PHOTO_ELEMENTS, W_CRITICAL, camera_correlations
from ..geometry.rotations import angles_from_R
from ..equations.triangulation import Triangulated
from ..core.adjusted_points import undetermined_points

MAX_PHOTO_PANELS = 24  # all photos get a residual panel up to this many; beyond, the worst WORST_PANELS
WORST_PANELS = 12
MAX_PHOTO_ROWS = 40  # all photos in the table up to this many; beyond, the first and the worst PHOTO_ROWS_EACH
PHOTO_ROWS_EACH = 10
MAX_TABLE_ROWS = 100  # flagged measurements and check points listed at most
MAX_VECTORS = 10_000  # residual vectors of all photographs drawn up to this many; beyond, a raster and the worst
WORST_VECTORS = 300
FIELD_CELLS = 24  # the raster of the residuals over the format: FIELD_CELLS x FIELD_CELLS cells
MAX_ELLIPSES = 3_000  # error ellipses drawn for every point up to this many points; beyond, rasters and the worst
WORST_ELLIPSES = 50
MAP_CELLS = 40  # the rasters over the block: at most this many cells along its longer side
WORST_POINT_ROWS = 10
CHECKS_HOLD_BELOW = 1e-6

SECTIONS = {  # id -> heading, in the order of the report
    "summary": "Summary",
    "warnings": "Warnings and input not used",
    "corrections": "Earth curvature and refraction",  # only when [corrections] applied one
    "checks": "Checks after convergence",
    "convergence": "Convergence",
    "residuals": "Residuals on the photographs",
    "points": "Precision of the ground points",
    "check-points": "Check points",
    "flagged": "Flagged measurements",
    "rejected": "Rejected measurements (gross errors)",
    "inactive": "Inactive measurements",  # only when image_points.csv has inactive rows
    "distances": "Distances between points",  # only with distances.csv (striptri.bundle.distances)
    "largest": "Largest normalised residuals",
    "photos": "Photographs",
    "camera": "Camera calibration",
    "film": "Fiducial marks and calibration report",  # only with scanned film (striptri.film)
    "gnss": "GNSS and IMU (lever arm, boresight, shift, drift)",
    "structure": "Structure of the normal matrix",
}

CHECK_TEXT = {
    "max_condition_misclosure_sigma": "Final check: largest misclosure of a condition at the adjusted observations "
                                      "and unknowns, in units of its standard deviation",
    "max_BTk_sigma": "(58) B<sup>T</sup>k = 0: largest |u<sub>i</sub>| / &radic;N<sub>ii</sub> at the solution",
    "vtpv_reduction_relative_difference": "(59) v<sup>T</sup>P v = [LL.u]: relative difference of the two sums",
    "max_point_gradient_sigma": "Largest gradient with respect to a point coordinate, in units of its "
                                "standard deviation",
}

_STYLE = """
:root { --ink: #1d2733; --muted: #5d6d7e; --rule: #d5dbe1; --head: #eef2f6; --accent: #1f4e79; --bad: #c0392b;
        --good: #1e8449 }
* { box-sizing: border-box }
body { font: 15px/1.45 "DejaVu Sans", "Liberation Sans", Helvetica, Arial, sans-serif; color: var(--ink);
       margin: 0; background: #fafbfc }
main { max-width: 76em; margin: 0 auto; padding: 1.5em 2em 3em; background: #fff; min-height: 100vh }
h1 { font-size: 1.6em; margin: 0.2em 0 0.1em; color: var(--accent) }
h2 { font-size: 1.25em; margin: 2em 0 0.5em; padding-bottom: 0.2em; border-bottom: 2px solid var(--accent) }
h3 { font-size: 1.02em; margin: 1.2em 0 0.4em }
p, li { max-width: 62em }
.sub { color: var(--muted); margin: 0 0 1em; word-break: break-all }
nav { margin: 1em 0 0.5em; font-size: 0.9em; line-height: 1.9 }
nav a { color: var(--accent); text-decoration: none; margin-right: 0.4em; padding: 0.1em 0.5em;
        border: 1px solid var(--rule); border-radius: 3px; white-space: nowrap }
.cards { display: flex; flex-wrap: wrap; gap: 0.8em; margin: 1em 0 }
.card { border: 1px solid var(--rule); border-left: 4px solid var(--accent); border-radius: 3px;
        padding: 0.45em 0.9em; min-width: 10em; background: #fdfefe }
.card .v { font-size: 1.35em; font-weight: bold }
.card .k { font-size: 0.8em; color: var(--muted) }
.card.bad { border-left-color: var(--bad) } .card.good { border-left-color: var(--good) }
.cols { display: flex; flex-wrap: wrap; gap: 0 2.5em; align-items: flex-start }
.scroll { overflow-x: auto; max-width: 100% }
table { border-collapse: collapse; margin: 0.4em 0 1.2em; font-size: 0.88em; font-variant-numeric: tabular-nums }
td, th { border-bottom: 1px solid var(--rule); padding: 0.22em 0.7em; text-align: right; white-space: nowrap }
th { background: var(--head); font-weight: 600; border-bottom: 1px solid #aab7c4 }
td.l, th.l { text-align: left } td.wrap { white-space: normal; text-align: left; max-width: 34em;
                                         overflow-wrap: anywhere }
tr.sep td { border-top: 2px solid #aab7c4 } tr.total td { font-weight: bold; background: #f6f8fa }
table.photos td, table.photos th { padding: 0.15em 0.32em; font-size: 0.86em }
@media (max-width: 1100px) { main { padding: 1em 1em 2em } }
.ok { color: var(--good); font-weight: 600 } .no { color: var(--bad); font-weight: 600 }
.flag { color: var(--bad) } .warn { color: var(--bad) }
figure { margin: 0.6em 0 1.4em } figure img { max-width: 100%; height: auto; display: block }
figcaption { color: var(--muted); font-size: 0.88em; margin-top: 0.3em; max-width: 62em }
.note { color: var(--muted); font-size: 0.88em }
footer { margin-top: 3em; color: var(--muted); font-size: 0.8em; border-top: 1px solid var(--rule); padding-top: 0.5em }
@media print { main { max-width: none; padding: 0 } nav { display: none } h2 { break-after: avoid }
               figure { break-inside: avoid } }
"""


STYLE = _STYLE  # the look of every striptri report (plan, compare)


# ---------------------------------------------------------------------------------------------------------------
# small HTML helpers


def _fmt(x, spec: str = ".6g") -> str:
    if x is None:
        return "&ndash;"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, str):
        return html.escape(x)
    if not np.isfinite(x):
        return "&ndash;"
    x = float(x)
    if spec.endswith("f"):  # no "-0.000": round first, then drop the sign of a zero
        x = round(x, int(spec[1:-1] or 6)) + 0.0
    return format(x, spec)


def _cell(text, cls: str = "", title: str = "") -> tuple:
    return (text, cls, title)


def _table(header, rows, cls: str = "", left: int = 0, row_classes=None, wrap: tuple = ()) -> str:
    """header: list of column names (HTML); rows: cells as HTML text or (text, class, title);
    the first ``left`` columns are left-aligned; the columns in ``wrap`` wrap their text (long
    values: a table must fit the page)."""
    head = "".join(f"<th{' class=l' if j < left or j in wrap else ''}>{h}</th>" for j, h in enumerate(header))
    body = []
    for i, row in enumerate(rows):
        cells = []
        for j, c in enumerate(row):
            text, ccls, title = c if isinstance(c, tuple) else (c, "", "")
            classes = " ".join(x for x in (("l" if j < left else ""), ("wrap" if j in wrap else ""), ccls) if x)
            attrs = (f" class='{classes}'" if classes else "") + (f" title='{html.escape(title)}'" if title else "")
            cells.append(f"<td{attrs}>{text}</td>")
        rc = row_classes[i] if row_classes else ""
        body.append(f"<tr{f' class={rc}' if rc else ''}>" + "".join(cells) + "</tr>")
    return (f"<div class='scroll'><table{f' class={cls}' if cls else ''}><tr>{head}</tr>"
            + "".join(body) + "</table></div>")


def _img(png: bytes, alt: str, caption: str = "") -> str:
    data = base64.b64encode(png).decode("ascii")
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f"<figure><img alt='{html.escape(alt)}' src='data:image/png;base64,{data}'>{cap}</figure>"


def _section(key: str) -> str:
    return f"<h2 id='{key}'>{SECTIONS[key]}</h2>"


def _card(value: str, label: str, cls: str = "") -> str:
    return f"<div class='card {cls}'><div class='v'>{value}</div><div class='k'>{label}</div></div>"


@dataclass(frozen=True)
class ResidualUnit:
    """How the report shows plate residuals, from the project's plate unit ([units] plate): a
    residual of v plate units is shown as ``v * factor`` ``label``, with ``spec`` digits.

    plate: "mm" or "px" (model.PLATE_UNITS), the unit of the plate coordinates and of c;
    plate_words: that unit in a sentence. A plate in mm has its residuals in micrometres of the
    plate (factor 1000), one in pixels keeps pixels (factor 1)."""

    plate: str
    plate_words: str
    factor: float
    label: str
    spec: str

    def __call__(self, v) -> str:
        """A residual (plate units; None or nan: a dash) as text in this unit."""
        return _fmt(None if v is None else self.factor * v, self.spec)

    def length(self, v: float) -> str:
        """A length v (plate units) for a scale bar: "5 µm", "0.5 px"."""
        return f"{v * self.factor:g} {self.label}"


RESIDUAL_UNITS = {
    "mm": ResidualUnit(plate="mm", plate_words="mm", factor=1000.0, label="µm", spec=".1f"),
    "px": ResidualUnit(plate="px", plate_words="pixels", factor=1.0, label="px", spec=".2f"),
}


def residual_unit(project: Project) -> ResidualUnit:
    """The ResidualUnit of project's plate unit (ProjectSettings.plate_unit)."""
    return RESIDUAL_UNITS[project.settings.plate_unit]


# ---------------------------------------------------------------------------------------------------------------
# quantities the report shows (computed here from the result; nothing is read back from files)


def _flags_of(flags, w: np.ndarray) -> np.ndarray:
    """Boolean (m,) flags: the given array (bool, or residuals.csv's "flag" strings, non-empty =
    flagged), else residuals.csv's rule |w| > W_CRITICAL for the larger normalised residual."""
    if flags is None:
        return np.nan_to_num(np.abs(w), nan=0.0).max(axis=1) > W_CRITICAL
    flags = np.asarray(flags)
    if flags.dtype.kind in "USO":
        return np.char.str_len(np.char.strip(flags.astype(str))) > 0 if len(flags) else np.zeros(0, dtype=bool)
    return flags.astype(bool)


def _flag_text(flags) -> str:
    rule = f"suspect, |w| &gt; {W_CRITICAL} (Baarda, &alpha;<sub>0</sub> = 0.001)"
    if flags is None:
        return rule
    flags = np.asarray(flags)
    if flags.dtype.kind in "USO":
        values = sorted(set(np.char.strip(np.unique(flags.astype(str))).tolist()) - {""})
        if set(values) <= {"suspect"}:
            return rule + " as in residuals.csv"
        return "flagged " + ", ".join(html.escape(v) for v in values)
    return "flagged"


def _photo_statistics(project: Project, v: np.ndarray, absw: np.ndarray, flagged: np.ndarray) -> dict:
    """Per photo: number of measurements, RMS of vx and vy, largest |w|, number flagged."""
    n = len(project.photos)
    ph = project.image_points.photo_index
    count = np.bincount(ph, minlength=n)
    safe = np.maximum(count, 1)
    rms = np.sqrt(np.stack([np.bincount(ph, v[:, a] ** 2, n) for a in range(2)], axis=1) / safe[:, None])
    wmax = np.zeros(n)
    np.maximum.at(wmax, ph, absw)
    return {"count": count, "rms": np.where(count[:, None] > 0, rms, np.nan), "wmax": wmax,
            "flagged": np.bincount(ph, flagged.astype(float), n).astype(int)}


def _kind_names(kind: np.ndarray) -> np.ndarray:
    """(n,) names of KIND_NAMES for the (n,) kind codes."""
    codes = np.array(sorted(KIND_NAMES))
    names = np.array([KIND_NAMES[c] for c in codes])
    return names[np.searchsorted(codes, np.asarray(kind, dtype=int))] if len(kind) else np.zeros(0, dtype=names.dtype)


def _point_covariance(result: AdjustmentResult, points: Triangulated) -> np.ndarray:
    """(n_pt, 3, 3) covariance of the triangulated points in m^2, as in points.csv (Schmid 90)."""
    cov = (points.cov_measurement + points.cov_orientation) * result.sigma0_for_precision**2
    return np.where(points.determined[:, None, None], cov, np.nan)


def _half_format(xy: np.ndarray) -> float:
    """Half the side of a square about the principal point that holds every measurement, rounded up."""
    r = float(np.nanmax(np.abs(xy))) if len(xy) else 1.0
    step = fig.nice_number(r / 10)
    return float(np.ceil(r * 1.02 / step) * step)


# ---------------------------------------------------------------------------------------------------------------
# sections


def chi2_quantile(p: np.ndarray, dof: float) -> np.ndarray:
    """Quantiles of the chi-square distribution with dof degrees of freedom: 2 P^-1(dof/2, p), the
    inverse regularised lower incomplete gamma function (what scipy.stats.chi2.ppf computes),
    without importing scipy.stats (half a second)."""
    from scipy.special import gammaincinv

    return 2.0 * gammaincinv(dof / 2.0, p)


def _summary_section(project: Project, result: AdjustmentResult, summary: dict, flagged: np.ndarray) -> list[str]:
    s0, r = summary["sigma0"], summary["redundancy"]
    cards = []
    if s0 is not None:
        cards.append(_card(f"{s0:.3f}", "&sigma;<sub>0</sub> a posteriori"))
    cards.append(_card(str(r), "redundancy"))
    conv = summary["converged"]
    cards.append(_card(f"{summary['iterations']}", "iterations, " + ("converged" if conv else "NOT converged"),
                       "good" if conv else "bad"))
    cp = summary["check_points"]
    if cp["n"]:
        rms_xy = np.hypot(cp["rms_X"], cp["rms_Y"])
        cards.append(_card(f"{rms_xy:.3f} / {cp['rms_Z']:.3f} m", f"check points ({cp['n']}): RMS XY / Z"))
    nf = int(flagged.sum())
    cards.append(_card(str(nf), "flagged measurements", "bad" if nf else "good"))

    kinds = np.bincount(project.points.kind, minlength=len(KIND_NAMES))
    kind_text = ", ".join(f"{kinds[k]} {KIND_NAMES[k]}" for k in sorted(KIND_NAMES) if kinds[k])
    method = {"conditions": "conditions (Schmid's simultaneous adjustment)", "bundle": "bundle (collinearity)"}
    rows = [
        ("method", _fmt(method.get(summary["method"], summary["method"]))),
        ("solver", _fmt(summary["solver"])),
        ("factorisation of the normal equations", _fmt(summary.get("factorisation"))),
        ("BLAS it ran on", _without_folders(summary.get("blas"))),
        ("&sigma;<sub>0</sub> a posteriori (unit: the a-priori &sigma;)", _fmt(s0, ".4f")),
        ("v<sup>T</sup>P v", _fmt(summary["vtpv"])),
        ("redundancy r", _fmt(r)),
        ("iterations", _fmt(summary["iterations"])),
        ("converged", f"<span class='{'ok' if conv else 'no'}'>{_fmt(conv)}</span>"),
        ("termination (why the iteration stopped)", _termination_text(summary)),
    ]
    if "frame" in summary:  # a project in map coordinates (striptri.crs)
        f = summary["frame"]
        rows.append(("coordinate frame", html.escape(
            f"files in {f['crs_name']} ({f['crs']}), {f['heights']} heights"
            + (f" (geoid: {f['geoid']})" if "geoid" in f else "")
            + f"; adjusted, and shown in this report (points, check points), in the local frame: {f['local']}")))
    if "datum" in summary:  # a free network (datum.FreeNetwork.summary)
        d = summary["datum"]
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
        ("photographs", _fmt(summary["n_photos"])),
        ("strips", _fmt(len(set(project.photos.strip_ids)))),
        ("cameras", _fmt(len(project.cameras))),
        ("object points", _fmt(summary["n_points"])),
        ("&nbsp;&nbsp;by kind", _fmt(kind_text)),
        ("plate measurements (points on photos)", _fmt(len(project.image_points))),
        ("observations", _fmt(summary["n_observations"])),
        ("condition equations", _fmt(summary["n_conditions"])),
        ("unknowns", _fmt(summary["n_unknowns"])),
    ]
    timings = [(html.escape(k.replace("_", " ")), _fmt(v, ".3f")) for k, v in summary["timings_s"].items()]
    return [
        _section("summary"),
        "<div class='cards'>" + "".join(cards) + "</div>",
        "<div class='cols'>",
        "<div><h3>Adjustment</h3>" + _table(["quantity", "value"], rows, left=1, wrap=(0, 1)) + "</div>",
        "<div><h3>Size</h3>" + _table(["quantity", "value"], sizes, left=1, wrap=(0, 1)) + "</div>",
        "<div><h3>Timings (s)</h3>" + _table(["step", "seconds"], timings, left=1) + "</div>",
        "</div>",
    ]


def length_unit(values) -> tuple[float, str]:
    """The unit that shows mean errors and differences ``values`` (metres) with three decimals:
    (factor, name), mm where metres would print 0.000 for most of them (close range), else m."""
    a = np.abs(np.asarray(values, dtype=float)).ravel()
    a = a[np.isfinite(a) & (a > 0)]
    if len(a) and np.median(a) < 0.01:
        return 1000.0, "mm"
    return 1.0, "m"


def run_block(summary: dict) -> str:
    """The run's metadata (summary.json ``version``, ``started``, ``project``, ``options``): which
    striptri made the result, when, from what, with which options. Empty without them."""
    if "version" not in summary:
        return ""
    options = summary.get("options") or {}
    chosen = "; ".join(f"{html.escape(str(k).replace('_', ' '))} {html.escape(_option_text(v))}"
                       for k, v in options.items())
    project = summary.get("project")
    cells = [f"striptri {html.escape(str(summary['version']))}",
             f"started {html.escape(str(summary.get('started')))}"]
    if project:
        name = html.escape(Path(project).name or project)
        cells.append(f"project <span title='{html.escape(project)}'>{name}</span>")
    return (f"<p class='sub run'>{' &middot; '.join(cells)}</p>"
            + (f"<p class='note run'>Options: {chosen}</p>" if chosen else ""))


def _option_text(value) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (list, tuple)):
        return ", ".join(map(str, value))
    return str(value)


_PATH = re.compile(r"(/[^\s,;()]+)+/([^\s,;()/]+)")


def _without_folders(text) -> tuple | str:
    """A value that names files (the BLAS library) by their names alone, the full text as the cell's
    title: folders (a user's venv) make a line too long for the page and say nothing to the reader."""
    if text is None:
        return _fmt(None)
    full = str(text)
    short = _PATH.sub(lambda m: m.group(2), full)
    return (html.escape(short), "", full) if short != full else html.escape(full)


TERMINATION_WORDS = {
    "converged": "converged: every correction below the tolerance in units of its standard deviation",
    "cost_flat": "cost_flat: the sum of squares no longer decreased (the bundle's cost tolerance)",
    "iteration_limit": "iteration_limit: max_iterations reached before convergence (kept on request)",
}


def _termination_text(summary: dict) -> str:
    """summary.json's termination in words, with its message when it has one."""
    reason = str(summary.get("termination"))
    text = html.escape(TERMINATION_WORDS.get(reason, reason))
    message = summary.get("message")
    if message and reason != "iteration_limit":  # the iteration limit's message is in the warnings
        text += f"<br><small>{html.escape(message)}</small>"
    return f"<span class='{'ok' if summary['converged'] else 'no'}'>{text}</span>"


def _warnings_section(summary: dict) -> list[str]:
    """Everything the run warned of: input it did not use (the reader's notes), a result kept
    although it did not converge, solver warnings. Nothing in the input is ignored silently."""
    warnings = summary.get("warnings") or []
    parts = [_section("warnings")]
    if not summary["converged"]:
        parts.append(f"<p class='no'>The adjustment did not converge ({html.escape(str(summary.get('termination')))})"
                     f": {html.escape(str(summary.get('message') or ''))}</p>")
    if warnings:
        parts.append("<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>")
    else:
        parts.append("<p>None: every line of the input was used.</p>")
    return parts


CORRECTION_NAMES = {"earth_curvature": "Earth curvature", "refraction": "Atmospheric refraction"}


def _corrections_section(summary: dict) -> list[str]:
    """The corrections of the plate coordinates that were applied (summary.json "plate_corrections",
    striptri.equations.plate_corrections): size, direction and the formula's source; nothing when none was."""
    applied = summary.get("plate_corrections")
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


def _distances_section(project: Project, result: AdjustmentResult, summary: dict, points,
                       cols: dict | None = None) -> list[str]:
    """The observed distances, their residuals and tests (bundle.distances.report_parts,
    reliability.distances); nothing without. cols: distances.csv's columns when the caller has them
    (pipeline), else they are formed here."""
    if project.distances is None or points is None:
        return []
    if cols is None:
        cols = distance_table(project, result, points.xyz,
                              critical=(summary.get("blunders") or {}).get("critical_value"))
    return [_section("distances")] + [p if isinstance(p, str) else _table(*p) for p in
                                      distance_report_parts(project.points.ids, project.distances, points.xyz, cols)]


def _inactive_section(summary: dict, unit: "ResidualUnit") -> list[str]:
    """The measurements image_points.csv marks inactive (summary.json "inactive", striptri.report.inactive):
    not adjusted; their residuals against the adjusted result. Nothing when there are none."""
    info = summary.get("inactive")
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


def _checks_section(summary: dict) -> list[str]:
    rows = []
    for k, v in summary["checks"].items():
        holds = v is not None and abs(v) < CHECKS_HOLD_BELOW
        mark = "<span class='ok'>holds</span>" if holds else "<span class='no'>fails</span>"
        rows.append((CHECK_TEXT.get(k, html.escape(k)), _fmt(v, ".2e"), mark))
    return [
        _section("checks"),
        "<p>After the last iteration the adjustment is checked as Schmid prescribes; every value should "
        f"vanish to rounding (here: below {CHECKS_HOLD_BELOW:g}).</p>",
        _table(["check", "value", ""], [((t, "wrap", ""), v, m) for t, v, m in rows], left=1),
    ]


def _convergence_section(result: AdjustmentResult) -> list[str]:
    hist = result.history
    inner = [h.solver_info.inner_iterations for h in hist]
    has_inner = any(i is not None for i in inner)
    png = fig.convergence([h.vtpv for h in hist], [h.max_correction for h in hist],
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
    if n_ph <= MAX_PHOTO_PANELS:
        shown, what = np.arange(n_ph), "every photograph"
    else:
        shown = order[:WORST_PANELS]
        what = (f"the {WORST_PANELS} photographs with the most flagged measurements and the largest RMS residual "
                f"(of {n_ph}; residuals.csv lists all)")
    rows_of = np.argsort(ip.photo_index, kind="stable")
    bounds = np.searchsorted(ip.photo_index[rows_of], np.arange(n_ph + 1))
    groups = [rows_of[bounds[p]:bounds[p + 1]] for p in shown]
    rms_photo = unit.factor * np.hypot(*stats["rms"].T) / np.sqrt(2)  # RMS per coordinate, in unit.label
    titles = [f"{ids[p]}  ({stats['count'][p]} pts, {rms_photo[p]:{unit.spec}} {unit.label})" for p in shown]
    png = fig.plate_residuals_per_photo(xy, v, flagged, groups, titles, h, mag, bar, bar_label)
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
        cell_means = (centres_5, means, counts, mag2, bar2, unit.length(bar2))
        right = (f" Right: the mean residual in each cell of a {cells} &times; {cells} grid (x{mag2:g}); a regular "
                 "pattern there points to a systematic image error (lens distortion, film deformation) rather than "
                 "noise.")
    if len(xy) <= MAX_VECTORS:
        png = fig.plate_residuals_stacked(xy, v, flagged, h, mag_all, bar_all, unit.length(bar_all), cell_means,
                                          plate_unit=unit.plate)
        left = f"the residuals of all photographs drawn over one format (x{mag_all:g})."
    else:  # a raster of the RMS residual per cell, and the worst vectors on top
        _, ms, count = _cell_statistics(xy, length[:, None] ** 2, h, FIELD_CELLS)
        rms = np.where(count > 0, np.sqrt(ms[:, 0]), np.nan).reshape(FIELD_CELLS, FIELD_CELLS)
        worst = np.argsort(-(flagged * (1.0 + absw.max(initial=0.0)) + absw), kind="stable")[:WORST_VECTORS]
        mag_w = min(mag_all, fig.nice_number(0.3 * h / max(float(length[worst].max()), 1e-300)))
        bar_w = fig.nice_number(0.3 * h / mag_w)
        png = fig.plate_residuals_stacked(xy[worst], v[worst], flagged[worst], h, mag_w, bar_w, unit.length(bar_w),
                                          cell_means, field=(rms * unit.factor, unit.label, len(xy)),
                                          plate_unit=unit.plate)
        left = (f"the RMS length of the residuals of all {len(xy)} measurements in each cell of a {FIELD_CELLS} "
                f"&times; {FIELD_CELLS} grid over the format ({unit.label}; white: no measurement), and on top the "
                f"{len(worst)} with the largest normalised residual |w| (<span class='flag'>red</span>: flagged), "
                f"drawn x{mag_w:g}.")
    caption = ("Left: " + left + right) if right else left[:1].upper() + left[1:]
    parts.append("<h3>All photographs over one format</h3>")
    parts.append(_img(png, "residual vectors of all photographs", caption))
    return parts


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
    if n_determined <= MAX_ELLIPSES:
        strips = fig.flies_strips(result.state.R_ground_from_cam)
        png = fig.error_ellipses(centres[:, :2], project.photos.strip_ids, xyz[:, :2], kind_names, cov[:, :2, :2],
                                 mag, bar, bar_label, labels=pts.ids, flight_lines=strips)
        stations = ("projection centres (+) along their flight lines (arrow: direction of flight)" if strips else
                    "camera stations (+; convergent photographs, no flight lines)")
        figure = _img(png, "error ellipses of the ground points",
                      f"Plan view of the block: {stations}, ground points coloured by kind, control as triangles. "
                      f"Around every point its "
                      f"horizontal standard error ellipse (1 &sigma;, from the X, Y part of its covariance), "
                      f"magnified <b>{mag:g} times</b>; the bar is {bar_label} of error. Fixed control has no "
                      f"ellipse.")
    else:
        figure, worst_table = _precision_map(project, points, xyz, centres, kind_names, cov, sig, a, pos, every,
                                             extent, spacing)
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


def _precision_map(project, points, xyz, centres, kind_names, cov, sig, a, pos, every, extent, spacing):
    """The error ellipses of a large block summarised: rasters of the RMS horizontal (semi-major
    axis) and vertical error per cell of a grid over the block, the WORST_ELLIPSES worst drawn on
    top, and a table of the WORST_POINT_ROWS points with the largest error. -> (figure, table) HTML."""
    pts = project.points
    lo, hi = every.min(axis=0), every.max(axis=0)
    cell = max(extent / MAP_CELLS, 4.0 * spacing, 1e-9)  # about 16 points per cell at least
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
    worst_h = np.flatnonzero(pos)[np.argsort(-a[pos], kind="stable")[:WORST_ELLIPSES]]
    worst_z = np.flatnonzero(pos_z)[np.argsort(-sz[pos_z], kind="stable")[:WORST_ELLIPSES]]
    largest = float(a[worst_h[0]]) if len(worst_h) else 1.0
    mag = fig.nice_number(0.03 * extent / largest)  # the largest ellipse 6 % of the block across
    bar = fig.nice_number(0.12 * extent / mag)
    bar_label = f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm"
    finite = np.concatenate([grid_h[np.isfinite(grid_h)], grid_z[np.isfinite(grid_z)]])
    unit, scale = ("cm", 100.0) if len(finite) == 0 or np.percentile(finite, 99) < 1.0 else ("m", 1.0)
    strips = fig.flies_strips(project.photos.R_ground_from_cam)
    png = fig.precision_map(centres[:, :2], project.photos.strip_ids, xyz[:, :2], kind_names,
                            grid_extent, (grid_h, grid_z, unit, scale), (worst_h, worst_z), cov[:, :2, :2],
                            mag, bar, bar_label, flight_lines=strips)
    n_shown = int(pos.sum())
    n_strips = len(set(project.photos.strip_ids))
    lines = " with its flight lines" if strips and n_strips <= fig.MAP_FLIGHT_LINES else ""
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
    worst = finite_total[np.argsort(-total[finite_total], kind="stable")[:WORST_POINT_ROWS]]
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
                          summary: dict) -> list[str]:
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
            for j, i in enumerate(sel[:MAX_TABLE_ROWS])]
    classes = [""] * len(rows)
    mean = d.mean(axis=0)
    rows.append(["mean"] + [_fmt(x * f, ".3f") for x in mean] + ["", "", ""])
    cp = summary["check_points"]
    rms = [cp["rms_X"], cp["rms_Y"], cp["rms_Z"]]  # summary.json's values (m), in full in the cell's title
    rows.append(["RMS"] + [_cell(_fmt(x * f, ".3f"), "", repr(float(x))) for x in rms]
                + [_fmt(x * f, ".3f") for x in np.sqrt(np.nanmean(sig[sel] ** 2, axis=0))])
    classes += ["sep", "total"]
    note = (f"<p class='note'>The first {MAX_TABLE_ROWS} of {len(sel)} check points; points.csv lists all.</p>"
            if len(sel) > MAX_TABLE_ROWS else "")
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
            for j, i in enumerate(idx[:MAX_TABLE_ROWS])]
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
    note = (f"<p class='note'>The {MAX_TABLE_ROWS} with the largest |w| of {len(idx)}; residuals.csv lists all.</p>"
            if len(idx) > MAX_TABLE_ROWS else "")
    return parts + [
        f"<p>{len(idx)} measurement{'s' if len(idx) != 1 else ''} flagged ({flag_text}), largest |w| first. "
        "w is the normalised residual "
        "v / (&sigma; &radic;q<sub>vv</sub>) of Baarda's data snooping.</p>",
        _table(_measurement_header(residual_unit(project)), _measurement_rows(project, result, w, idx[:MAX_TABLE_ROWS]),
               left=3),
        note,
    ]


def _rejected_section(summary: dict) -> list[str]:
    """summary["blunders"]["groups"] (reliability.rejections): per rejected group its members, w, MDB
    and effect on the ground."""
    groups = (summary.get("blunders") or {}).get("groups") or []
    parts = [_section("rejected")]
    if not groups:
        return parts + ["<p>No measurement was rejected.</p>"]

    def num(v, fmt):
        return "&ndash;" if v is None else format(v, fmt)

    rows = []
    for g in groups[:MAX_TABLE_ROWS]:
        effect = g["ground_effect"]
        rows.append([
            html.escape(g["point_id"]), html.escape(", ".join(g["photo_ids"])),
            "found" if g["localised"] else "<span class='flag'>detected, not localisable</span>",
            g["coordinate"], f"{g['w']:.1f}", num(g["mdb"], ".4g"), num(g["bias_to_noise"], ".1f"),
            "point drops out" if effect is None else " ".join(f"{v:+.3f}" for v in effect),
        ])
    note = (f"<p class='note'>The first {MAX_TABLE_ROWS} of {len(groups)}; summary.json lists all.</p>"
            if len(groups) > MAX_TABLE_ROWS else "")
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
    if n <= MAX_PHOTO_ROWS:
        shown, classes, note = np.arange(n), None, ""
    else:
        first = np.arange(PHOTO_ROWS_EACH)
        worst = np.array([p for p in np.argsort(-worst_key, kind="stable") if p >= PHOTO_ROWS_EACH][:PHOTO_ROWS_EACH])
        shown = np.concatenate([first, worst])
        classes = [""] * PHOTO_ROWS_EACH + ["sep"] + [""] * (len(worst) - 1)
        note = (f"<p class='note'>The first {PHOTO_ROWS_EACH} photographs, then (below the line) the "
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


def html_report(project: Project, result: AdjustmentResult, summary: dict, w: np.ndarray,
                points: Triangulated | None = None, flags=None, figures=None, timings: dict | None = None,
                distances: dict | None = None) -> str:
    """The report as one self-contained HTML text.

    summary: summary.json's dict; w: (m, 2) normalised residuals of the plate coordinates (nan where
    undefined); points: the triangulated points (pipeline.triangulate_result), needed for the error
    ellipses and the check-point table; flags: optional (m,) flags of the plate measurements (bool, or
    residuals.csv's "flag" strings); by default residuals.csv's rule |w| > 3.29. figures: optional
    name -> PNG bytes made elsewhere ("structure": the normal matrix pattern). timings: optional dict
    that receives the seconds each section took (section id -> s; "total" for the whole report).
    distances: distances.csv's columns (reliability.distances.distance_table) when the caller formed
    them; formed here otherwise.
    """
    t0 = time.perf_counter()
    figures = figures or {}
    w = np.asarray(w, dtype=float)
    absw = np.nan_to_num(np.abs(w), nan=0.0).max(axis=1) if len(w) else np.zeros(0)
    flagged = _flags_of(flags, w)
    flag_text = _flag_text(flags)
    stats = _photo_statistics(project, result.plate_residuals, absw, flagged)
    src = html.escape(str(project.source or ""))
    seconds: dict[str, float] = {"preparation": time.perf_counter() - t0}

    def timed(key: str, make) -> list[str]:
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
                   if (k != "corrections" or "plate_corrections" in summary)
                   and (k != "gnss" or result.layout.gnss_cols is not None)
                   and (k != "film" or project.film is not None)
                   and (k != "inactive" or "inactive" in summary)
                   and (k != "distances" or (project.distances is not None and points is not None)))
    total = time.perf_counter() - t0
    slow = sorted(((v, k) for k, v in seconds.items() if v >= 0.005), reverse=True)
    breakdown = ", ".join(f"{html.escape(SECTIONS.get(k, k).lower())} {v:.2f}" for v, k in slow)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>striptri adjustment report</title><style>{_STYLE}</style></head><body><main>",
        "<h1>Aerial triangulation: adjustment report</h1>",
        f"<p class='sub'>Project {src or '(in memory)'} &middot; {summary['n_photos']} photographs, "
        f"{summary['n_points']} points &middot; method {html.escape(summary['method'])}, solver "
        f"{html.escape(summary['solver'])}</p>",
        f"<nav>{nav}</nav>",
        run_block(summary),
    ]
    for section in body:
        parts += [p for p in section if p]
    parts.append(f"<footer>Written by striptri. Report and figures built in {total:.2f} s"
                 + (f" ({breakdown})" if breakdown else "") + ". "
                 "The numbers in full are in photos.csv, points.csv, residuals.csv and summary.json beside "
                 "this file.</footer></main></body></html>")
    if timings is not None:
        timings.update(seconds)
        timings["total"] = time.perf_counter() - t0
    return "\n".join(parts)
