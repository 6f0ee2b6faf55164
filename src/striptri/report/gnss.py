"""The GNSS/IMU unknowns in the outputs (docs/file-formats.md, "Output folder"):

* cameras.csv, after its other columns: ``lever_x, lever_y, lever_z`` (m),
  ``boresight_x, boresight_y, boresight_z`` (the project's angle unit) and their sigmas (empty
  where held);
* strips.csv: ``strip_id, shift_X, shift_Y, shift_Z`` (m), ``drift_X, drift_Y, drift_Z`` (m/s)
  and their sigmas, when shift or drift are in the model;
* report.html: the tables of :func:`report_tables` (values, mean errors, correlations among the
  GNSS unknowns and each one's largest correlation with a projection-centre coordinate).
"""

from __future__ import annotations

import html

import numpy as np

from ..precision.gnss import CENTRE_NAMES, GnssPrecision, gnss_precision

LEVER = ("lever_x", "lever_y", "lever_z")
BORESIGHT = ("boresight_x", "boresight_y", "boresight_z")


def precision_of(project, result) -> GnssPrecision | None:
    if project.gnss is None or result.layout.gnss_cols is None:
        return None
    return gnss_precision(result, project.cameras.ids, project.gnss.strip_ids)


def camera_columns(prec: GnssPrecision, angle_scale: float) -> dict:
    """cameras.csv's GNSS columns; angle_scale: project angle unit per radian."""
    cols = {}
    for a, name in enumerate(LEVER):
        cols[name] = prec.values["lever"][:, a]
    for a, name in enumerate(BORESIGHT):
        cols[name] = prec.values["boresight"][:, a] * angle_scale
    for a, name in enumerate(LEVER):
        cols[f"sigma_{name}"] = prec.sigma["lever"][:, a]
    for a, name in enumerate(BORESIGHT):
        cols[f"sigma_{name}"] = prec.sigma["boresight"][:, a] * angle_scale
    return cols


def strip_table(project, prec: GnssPrecision) -> dict | None:
    """strips.csv, or None when neither shift nor drift is in the model."""
    g = project.gnss
    if g.shift == "none" and g.drift == "none":
        return None
    cols = {"strip_id": list(g.strip_ids)}
    for group in ("shift", "drift"):
        for a, axis in enumerate("XYZ"):
            cols[f"{group}_{axis}"] = prec.values[group][:, a] if getattr(g, group) != "none" \
                else np.full(g.n_strips, np.nan)
    for group in ("shift", "drift"):
        for a, axis in enumerate("XYZ"):
            cols[f"sigma_{group}_{axis}"] = prec.sigma[group][:, a]
    return cols


GROUP_TEXT = {"lever": ("Lever arm (camera frame)", "m", 1.0), "boresight": ("Boresight (rotation vector, camera frame)",
                                                                             "angle", None),
              "shift": ("GNSS shift per strip", "m", 1.0), "drift": ("GNSS drift per strip", "m/s", 1.0)}


def report_tables(project, result, angle_scale: float, angle_unit: str):
    """(text, header, rows, left) tuples for report.html: the estimates with mean errors (one table
    per estimated group), then the correlation matrix of all GNSS unknowns. Cells are HTML text."""
    prec = precision_of(project, result)
    if prec is None:
        return []
    out = []
    where = {"lever": project.cameras.ids, "boresight": project.cameras.ids,
             "shift": project.gnss.strip_ids, "drift": project.gnss.strip_ids}
    labels = list(prec.labels)
    for group, (title, unit, scale) in GROUP_TEXT.items():
        if not prec.estimated(group):
            continue
        scale = angle_scale if scale is None else scale
        unit = angle_unit if unit == "angle" else unit
        axes = "xyz" if group in ("lever", "boresight") else "XYZ"
        rows = []
        for k, name in enumerate(where[group]):
            row = [html.escape(str(name))]
            for a in range(3):
                v, s = prec.values[group][k, a] * scale, prec.sigma[group][k, a] * scale
                row.append(f"{v:.6g}" if np.isfinite(s) else f"{v:.6g} (held)")
                row.append(f"{s:.3g}" if np.isfinite(s) else "&ndash;")
            for a in range(3):
                label = f"{group} {name} {axes[a]}"
                if label in labels:
                    i = labels.index(label)
                    photo, axis, rho = prec.centre[i]
                    row.append(f"{html.escape(project.photos.ids[photo])} {CENTRE_NAMES[axis]} {rho:.3f}"
                               if photo >= 0 else "&ndash;")
                else:
                    row.append("&ndash;")
            rows.append(row)
        header = ["camera" if group in ("lever", "boresight") else "strip"]
        for a in axes:
            header += [f"{a} ({html.escape(unit)})", f"&sigma;<sub>{a}</sub>"]
        header += [f"largest correlation with a centre ({a})" for a in axes]
        out.append((f"{title}: estimates, mean errors and each component's largest correlation with a "
                    "projection-centre coordinate.", header, rows, 1))
    if len(labels):
        rows = [[html.escape(labels[i])] + [f"{x:.2f}" for x in prec.correlation[i]] for i in range(len(labels))]
        out.append(("Correlations among the estimated GNSS/IMU unknowns (near &plusmn;1: the data cannot separate "
                    "them, e.g. a lever arm and the shifts of strips flown with one heading).",
                    [""] + [html.escape(x) for x in labels], rows, 1))
    return out


def summary_entry(project, result) -> dict:
    """summary.json's "gnss" (only with a GNSS model): per group the estimates and mean errors
    (lists of rows of 3; lever m, boresight radians, shift m, drift m/s; null where held or not in
    the model) and the shift / drift modes."""
    prec = precision_of(project, result)
    if prec is None:
        return {}
    out = {"shift": project.gnss.shift, "drift": project.gnss.drift, "strip_ids": list(project.gnss.strip_ids),
           "camera_ids": list(project.cameras.ids)}
    for group in ("lever", "boresight", "shift", "drift"):
        out[f"{group}_values"] = _json_rows(prec.values[group])
        out[f"{group}_sigma"] = _json_rows(prec.sigma[group])
    return {"gnss": out}


def _json_rows(a: np.ndarray) -> list:
    return [[float(x) if np.isfinite(x) else None for x in row] for row in np.asarray(a, dtype=float)]
