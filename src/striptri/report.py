"""report.html: a human-readable account of an adjustment, readable offline (no scripts, no
external files). This first version holds the summary, Schmid's checks, the convergence history,
the check points and the largest normalised residuals; figures come with the precision issue.
"""

from __future__ import annotations

import base64
import html

import numpy as np

from .adjustment import AdjustmentResult
from .model import Project

_STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 60em; color: #222 }
table { border-collapse: collapse; margin: 0.5em 0 1.5em }
td, th { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right }
th { background: #eee } td.l, th.l { text-align: left }
"""


def _fmt(x) -> str:
    if x is None:
        return "&ndash;"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, str):
        return html.escape(x)
    if isinstance(x, float) and not np.isfinite(x):
        return "&ndash;"
    return f"{x:.6g}"


def _table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _img(png: bytes, alt: str) -> str:
    return f"<img alt='{html.escape(alt)}' src='data:image/png;base64,{base64.b64encode(png).decode()}'>"


def html_report(project: Project, result: AdjustmentResult, summary: dict, w: np.ndarray, figures=None) -> str:
    """figures: optional name -> PNG bytes, embedded (the file stays readable offline)."""
    figures = figures or {}
    src = html.escape(str(project.source or ""))
    keys = ["method", "solver", "sigma0", "redundancy", "vtpv", "iterations", "converged", "n_photos",
            "n_points", "n_observations", "n_conditions", "n_unknowns"]
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>striptri adjustment</title>"
             f"<style>{_STYLE}</style></head><body>",
             f"<h1>striptri adjustment</h1><p>Project: {src}</p>",
             "<h2>Summary</h2>", _table(["quantity", "value"], [(k, _fmt(summary[k])) for k in keys])]
    checks = summary["checks"]
    parts += ["<h2>Checks after convergence (Schmid 58, 59 and the final check)</h2>",
              _table(["check", "value"], [(html.escape(k), _fmt(v)) for k, v in checks.items()])]
    parts += ["<h2>Convergence</h2>",
              _table(["iteration", "v^T P v", "largest correction / its sigma"],
                     [(i + 1, _fmt(h.vtpv), _fmt(h.max_correction)) for i, h in enumerate(result.history)])]
    cp = summary["check_points"]
    parts += ["<h2>Check points</h2>",
              _table(["n", "RMS X (m)", "RMS Y (m)", "RMS Z (m)"],
                     [(cp["n"], _fmt(cp["rms_X"]), _fmt(cp["rms_Y"]), _fmt(cp["rms_Z"]))])]
    absw = np.nan_to_num(np.abs(w), nan=0.0).max(axis=1)
    worst = np.argsort(-absw)[:20]
    ip = project.image_points
    rows = [(html.escape(project.photos.ids[ip.photo_index[i]]), html.escape(project.points.ids[ip.point_index[i]]),
             _fmt(result.plate_residuals[i, 0]), _fmt(result.plate_residuals[i, 1]), _fmt(absw[i]))
            for i in worst]
    if "structure" in figures:
        parts += ["<h2>Structure of the normal matrix (Schmid Fig. 10)</h2>",
                  _img(figures["structure"], "normal matrix structure")]
    parts += ["<h2>Largest normalised residuals</h2>",
              _table(["photo", "point", "vx", "vy", "|w|"], rows), "</body></html>"]
    return "\n".join(parts)
