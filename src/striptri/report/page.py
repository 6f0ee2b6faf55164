"""The pieces every page of striptri is made of: the limits of a page, the style, cells and
tables, sections, images, the units that show small values, the flags of a measurement and the
run's metadata block (report.html, the plan and the compare reports)."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path
from dataclasses import dataclass
import numpy as np

from . import drawing, figures as fig
from ..core.result import AdjustmentResult
from ..model import KIND_NAMES, Project
from ..precision.residuals import W_CRITICAL
from ..equations.triangulation import Triangulated



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
    "automatic": "Automatic tie points",  # only for a project of striptri match (io.sources)
    "inactive": "Inactive measurements",  # only when image_points.csv has inactive rows
    "distances": "Distances between points",  # only with distances.csv (striptri.bundle.distances)
    "largest": "Largest normalised residuals",
    "photos": "Photographs",
    "camera": "Camera calibration",
    "film": "Fiducial marks and calibration report",  # only with scanned film (striptri.film)
    "gnss": "GNSS and IMU (lever arm, boresight, shift, drift)",
    "structure": "Structure of the normal matrix",
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


def _img(png, alt: str, caption: str = "") -> str:
    """The figure's HTML; png: its PNG bytes, or a figure still being drawn (report.drawing: a
    placeholder until drawing.fill)."""
    def markup(data: bytes) -> str:
        encoded = base64.b64encode(data).decode("ascii")
        cap = f"<figcaption>{caption}</figcaption>" if caption else ""
        return f"<figure><img alt='{html.escape(alt)}' src='data:image/png;base64,{encoded}'>{cap}</figure>"

    return drawing.html_of(png, markup)


# the page's building blocks for the other striptri reports (match.report)
html_table, figure_html = _table, _img


def _section(key: str) -> str:
    return f"<h2 id='{key}'>{SECTIONS[key]}</h2>"


def _card(value: str, label: str, cls: str = "") -> str:
    return f"<div class='card {cls}'><div class='v'>{value}</div><div class='k'>{label}</div></div>"


card = _card


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
