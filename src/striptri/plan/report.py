"""report.html of ``striptri plan``: the plan's figures, the what-if table, the control ranking and
three maps (a-priori point precision, internal reliability, external reliability). Self-contained
HTML, figures embedded as PNG (matplotlib, imported when the first map is drawn)."""

from __future__ import annotations

import base64
import html
import io

import numpy as np

from ..report.figures import KIND_STYLE
from ..model import KIND_NAMES, TIE
from ..report.page import STYLE, run_block  # the adjust report's style: one look for every striptri report


def _fmt(x, spec: str = ".4g") -> str:
    if x is None:
        return "&ndash;"
    if isinstance(x, str):
        return html.escape(x)
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return format(float(x), spec) if np.isfinite(x) else "&ndash;"


def _table(header: list[str], rows: list[list], left: int = 1) -> str:
    head = "".join(f"<th{' class=l' if j < left else ''}>{html.escape(h)}</th>" for j, h in enumerate(header))
    body = "".join("<tr>" + "".join(f"<td{' class=l' if j < left else ''}>{_fmt(c)}</td>" for j, c in enumerate(r))
                   + "</tr>" for r in rows)
    return f"<div class='scroll'><table><tr>{head}</tr>{body}</table></div>"


def _map(xy_centres, xy_points, kinds, values, unchecked, title: str, label: str, log: bool = False) -> bytes:
    """The block seen from above: photo centres (grey), points coloured by ``values`` (nan: not
    drawn; a logarithmic scale when ``log``: a few nearly unchecked coordinates have MDBs hundreds
    of times the others), each kind with its own marker (figures.KIND_STYLE: control as triangles),
    points in ``unchecked`` marked with a red cross. The legend stands right of the map, clear of
    its axis labels."""
    from matplotlib.colors import LogNorm, Normalize
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.5, 5.5))
    ax = fig.add_subplot()
    ax.plot(xy_centres[:, 0], xy_centres[:, 1], ".", color="0.6", ms=3, label="photo centres")
    ok = np.isfinite(values) & ((values > 0) if log else True)
    if ok.any():
        lo, hi = values[ok].min(), max(values[ok].max(), values[ok].min() * 1.01)
        norm = LogNorm(vmin=lo, vmax=hi) if log else Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1.0)
        sc = None
        for name, (marker, _, text) in KIND_STYLE.items():
            sel = ok & (kinds == name)
            if sel.any():
                sc = ax.scatter(xy_points[sel, 0], xy_points[sel, 1], c=values[sel], s=14 if name == "tie" else 40,
                                marker="o" if name == "tie" else marker, cmap="viridis", norm=norm,
                                edgecolors="none" if name == "tie" else "black", linewidths=0.5,
                                label=f"{text} ({int(sel.sum())})")
        if sc is not None:
            fig.colorbar(sc, ax=ax, label=label, pad=0.02)
    if unchecked.any():
        ax.plot(xy_points[unchecked, 0], xy_points[unchecked, 1], "x", color="red", ms=6,
                label="a measurement not checked (r = 0)")
    ax.set_aspect("equal")
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.25, 1.0), fontsize="small", frameon=False)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return buf.getvalue()


def _img(png: bytes, alt: str) -> str:
    return f"<figure><img alt='{html.escape(alt)}' src='data:image/png;base64,{base64.b64encode(png).decode()}'></figure>"


def html_report(analysis, summary: dict, whatifs: list[dict], ranking: list[dict] | None, plate_unit: str) -> str:
    """The report (module doc). analysis: analysis.PlanAnalysis; summary: summary.json's dict;
    whatifs: the rows of whatifs.csv; ranking: those of control_ranking.csv (None: not computed)."""
    a = analysis
    pts = a.project.points
    xyz = a.points.xyz + a.result.offset
    centres = a.project.photos.xyz0
    ip = a.project.image_points
    n = len(pts)
    max_mdb = np.zeros(n)
    np.maximum.at(max_mdb, ip.point_index, np.max(a.reliability.mdb, axis=1))
    unchecked = ~np.isfinite(max_mdb) & np.isfinite(xyz).all(axis=1)
    sxy = np.hypot(a.sigma_points[:, 0], a.sigma_points[:, 1])
    ext = np.max(a.external, axis=1)
    plan = summary["plan"]
    kinds = np.array([KIND_NAMES[int(k)] for k in pts.kind])
    parts = [f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             "<meta name='viewport' content='width=device-width, initial-scale=1'>"
             f"<title>striptri plan</title><style>{STYLE}</style></head><body><main>"
             "<h1>Pre-analysis of a planned block</h1>",
             run_block(summary),
             "<p>Mean errors a priori (sigma0 = 1): the precision the simultaneous adjustment of this design "
             "will give when the measurements have the planned sigmas. No measurement was used.</p>",
             _table(["", "value"], [
                 ["method", summary["method"]], ["photos", summary["n_photos"]], ["points", summary["n_points"]],
                 ["plate measurements", len(ip)], ["tie points from", plan.get("tie_points", "image_points.csv")],
                 ["redundancy", summary["redundancy"]],
                 ["worst sigma_XY of the new points (m)", plan["precision"]["worst_sigma_XY"]],
                 ["RMS sigma_XY (m)", plan["precision"]["rms_sigma_XY"]],
                 ["worst sigma_Z (m)", plan["precision"]["worst_sigma_Z"]],
                 ["RMS sigma_Z (m)", plan["precision"]["rms_sigma_Z"]],
                 ["smallest redundancy number", plan["reliability"]["min_redundancy"]],
                 [f"largest finite MDB ({plate_unit})", plan["reliability"]["max_finite_mdb"]],
                 ["plate coordinates not checked (r = 0)", plan["reliability"]["n_unchecked"]],
                 ["seconds", plan["seconds"]]]),
             "<h2>What-ifs</h2>",
             _table(["case", "status", "worst sigma_XY (m)", "RMS sigma_XY (m)", "worst sigma_Z (m)", "RMS sigma_Z (m)",
                     "worst sigma_P (m)"],
                    [[w["case"], w["status"], w["worst_sigma_XY"], w["rms_sigma_XY"], w["worst_sigma_Z"],
                      w["rms_sigma_Z"], w["worst_sigma_P"]] for w in whatifs], left=2)]
    if ranking is not None:
        parts += ["<h2>Which control point matters</h2><p>Each control point dropped in turn (it becomes a check "
                  "point): the worst 3D mean error of the new points and its increase over the plan.</p>",
                  _table(["rank", "point", "kind", "status", "worst sigma_P (m)", "loss (m)"],
                         [[r["rank"], r["point_id"], r["kind"], r["status"], r["worst_sigma_P"], r["loss_sigma_P"]]
                          for r in ranking], left=4)]
    parts += ["<h2>Maps</h2>",
              _img(_map(centres, xyz, kinds, sxy, np.zeros(n, bool), "A-priori planimetric precision of the points",
                        "sigma_XY (m)"), "precision map"),
              _img(_map(centres, xyz, kinds, np.where(np.isfinite(max_mdb) & (max_mdb > 0), max_mdb, np.nan), unchecked,
                        "Internal reliability: largest MDB of a point's measurements",
                        f"MDB ({plate_unit})", log=True), "internal reliability map"),
              _img(_map(centres, xyz, kinds, np.where(np.isfinite(ext), ext, np.nan), unchecked,
                        "External reliability: a point's shift by an undetected blunder",
                        f"largest |dX|, |dY|, |dZ| (m, {a.external_method})", log=True), "external reliability map"),
              "<h2>Points</h2>",
              _table(["point", "kind", "sigma_X (m)", "sigma_Y (m)", "sigma_Z (m)", f"max MDB ({plate_unit})",
                      "external (m)"],
                     [[pts.ids[i], KIND_NAMES[int(pts.kind[i])], *a.sigma_points[i], max_mdb[i], ext[i]]
                      for i in np.argsort(-np.nan_to_num(sxy, nan=-1.0))[:50]], left=2),
              "<p>The 50 points of largest sigma_XY; points.csv has all.</p>" if n > 50 else "",
              f"<p>{int(np.sum(pts.kind == TIE))} tie points.</p></main></body></html>"]
    return "\n".join(parts)
