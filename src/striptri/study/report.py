"""Figures (PNG bytes, matplotlib Agg via striptri.report.figures) and the self-contained report.html of a
study (figures as PNG data URIs)."""

from __future__ import annotations

import base64
import html
import math

import numpy as np

from striptri import __version__
from striptri.report.figures import png_of, plt
from striptri.report.page import STYLE as REPORT_STYLE
from striptri.study.growth import GROWTH_COLUMNS, PRECISION_COLUMNS, end_errors
from striptri.study.options import METHOD_LABELS, METHOD_SPECS

_STYLE = {label: (f"C{i}", marker) for i, (label, marker) in enumerate(zip(METHOD_LABELS, "os^vDx"))}


def _layouts(keys):
    return list(dict.fromkeys(k[1] for k in keys))


def error_along_strip(along: dict) -> bytes:
    """RMS over trials of the centre error against the photo number, one line per method; one panel
    per layout, at the longest strip (and the first noise level) of the study."""
    layouts = _layouts(along)
    fig, axes = plt.subplots(1, len(layouts), figsize=(5.2 * len(layouts), 3.8), squeeze=False)
    for ax, layout in zip(axes[0], layouts):
        keys = [k for k in along if k[1] == layout]
        n_max = max(k[2] for k in keys)
        sigma = min(k[3] for k in keys)
        for label in METHOD_LABELS:
            e = along.get((label, layout, n_max, sigma))
            if e is not None:
                colour, marker = _STYLE[label]
                ax.plot(np.arange(1, len(e) + 1), e, color=colour, marker=marker, ms=3, label=label)
        ax.set_title(f"{layout}: {n_max} photos, sigma {sigma:g}")
        ax.set_xlabel("photo")
        ax.set_ylabel("RMS centre error (m)")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    return png_of(fig)


def error_against_length(rows, growth: dict) -> bytes:
    """RMS over trials of the last centre's error against the strip length, log-log, with the fitted
    lines a n^b; one panel per layout (first noise level)."""
    ends = end_errors(rows)
    layouts = _layouts(ends)
    fig, axes = plt.subplots(1, max(len(layouts), 1), figsize=(5.2 * max(len(layouts), 1), 3.8), squeeze=False)
    fits = {}
    for i in range(len(growth["method"])):
        spec = (growth["method"][i], growth["procedure"][i], growth["direction"][i])
        label = next(k for k, v in METHOD_SPECS.items() if v == spec)
        fits[(label, growth["layout"][i], growth["sigma_image"][i])] = (growth["a"][i], growth["b"][i])
    for ax, layout in zip(axes[0], layouts):
        sigma = min(k[2] for k in ends if k[1] == layout)
        for label in METHOD_LABELS:
            by_n = ends.get((label, layout, sigma))
            if not by_n:
                continue
            colour, marker = _STYLE[label]
            n = np.array(list(by_n), dtype=float)
            e = np.array(list(by_n.values()))
            a, b = fits.get((label, layout, sigma), (math.nan, math.nan))
            ax.loglog(n, np.where(e > 0, e, np.nan), marker, color=colour)
            if math.isfinite(a) and math.isfinite(b):
                nn = np.geomspace(n.min(), n.max(), 20)
                ax.loglog(nn, a * nn**b, "-", color=colour, lw=1, label=f"{label}: {a:.3g} n^{b:.2f}")
        ax.set_title(f"{layout}, sigma {sigma:g}")
        ax.set_xlabel("photos in the strip n")
        ax.set_ylabel("RMS error of the last centre (m)")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    return png_of(fig)


def forward_against_backward(rows) -> bytes:
    """RMS centre error of each trial: forward (x) against backward (y), per sequential procedure."""
    by_key = {}
    for r in rows:
        if r["method"] == "sequential" and r["status"] == "ok":
            by_key[(r["procedure"], r["layout"], r["n_photos"], r["sigma_image"], r["trial"], r["direction"])] = r["centre_rms"]
    fig, ax = plt.subplots(figsize=(4.6, 4.4))
    top = 0.0
    for procedure, colour in ((1, "C0"), (2, "C2")):
        pairs = [(v, by_key[k[:-1] + ("backward",)]) for k, v in by_key.items()
                 if k[0] == procedure and k[-1] == "forward" and k[:-1] + ("backward",) in by_key]
        if pairs:
            x, y = np.array(pairs).T
            ax.loglog(x, y, "o", ms=3, color=colour, alpha=0.7, label=f"procedure {procedure}")
            top = max(top, x.max(), y.max())
    if top > 0:
        lo = min(v for v in by_key.values() if v > 0)
        ax.loglog([lo, top], [lo, top], "k-", lw=0.8)
        ax.legend(fontsize=8)
    ax.set_xlabel("forward: RMS centre error (m)")
    ax.set_ylabel("backward: RMS centre error (m)")
    ax.set_title("sequential: forward against backward")
    ax.grid(alpha=0.3, which="both")
    return png_of(fig)


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def _table(cols: dict, names) -> str:
    def cell(v):
        if isinstance(v, float):
            return "" if math.isnan(v) else f"{v:.4g}"
        return "" if v is None else html.escape(str(v))

    n = len(cols[names[0]]) if names else 0
    head = "".join(f"<th>{html.escape(c)}</th>" for c in names)
    body = "".join("<tr>" + "".join(f"<td>{cell(cols[c][i])}</td>" for c in names) + "</tr>" for i in range(n))
    return f"<div class='scroll'><table><tr>{head}</tr>{body}</table></div>"


def report_html(options, rows, growth: dict, precision: dict, along: dict) -> str:
    failed = sum(r["status"] != "ok" for r in rows)
    figs = [
        ("Error along the strip", error_along_strip(along) if along else None),
        ("Error at the strip end against strip length (log-log, fitted a n^b)", error_against_length(rows, growth)),
        ("Forward against backward", forward_against_backward(rows)),
    ]
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>striptri method comparison</title><style>{REPORT_STYLE}</style>",  # the adjust report's look
        "</head><body><main><h1>Method comparison</h1>",
        f"<p class='sub run'>striptri {html.escape(__version__)}</p>",
        f"<p>methods {', '.join(options.methods)}; photos {', '.join(map(str, options.photos))}; layouts "
        f"{', '.join(options.layouts)}; sigma_image {', '.join(f'{s:g}' for s in options.sigma_images)}; "
        f"{options.trials} trials; seed {options.seed}; {len(rows)} adjustments, {failed} failed.</p>",
    ]
    for title, png in figs:
        if png is not None:
            parts.append(f"<h2>{html.escape(title)}</h2>{_img(png, title)}")
    parts.append("<h2>Growth law: RMS error of the last centre = a n<sup>b</sup></h2>")
    parts.append(_table(growth, GROWTH_COLUMNS))
    parts.append("<h2>Predicted (N<sup>-1</sup>, a priori) against empirical error of the last centre</h2>")
    parts.append(_table(precision, PRECISION_COLUMNS))
    parts.append("</main></body></html>")
    return "\n".join(parts)
