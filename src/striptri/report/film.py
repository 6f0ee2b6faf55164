"""The film inputs in the report, summary.json and fiducial_residuals.csv (issue 16).

:func:`report_parts` gives the section's content as HTML paragraphs (str) and tables
(header, rows, left-aligned columns) for striptri.report.html to render; :func:`residual_columns` the
columns of fiducial_residuals.csv; :func:`summary_entry` summary.json's "film".
"""

from __future__ import annotations

import html

import numpy as np

from striptri.film.fiducials import W_LIMIT
from striptri.film.data import FilmData

MAX_FIDUCIAL_ROWS = 400  # fiducial residual rows listed in the report (all are in fiducial_residuals.csv)


def _f(x, spec=".2f") -> str:
    return "&ndash;" if x is None or not np.isfinite(x) else format(float(x), spec)


def report_parts(film: FilmData) -> list:
    """The report section's content (module doc)."""
    parts: list = []
    fit = film.fit
    if fit is not None:
        P, F = fit.measured.shape
        n_flag = int(fit.flagged.sum())
        parts.append(
            f"<p>Image points measured in scan pixels (col, row) were carried to the plate (mm; x right, y up) "
            f"by {'an' if film.transformation[0] in 'aeiou' else 'a'} <b>{html.escape(film.transformation)}</b> transformation per photograph, fitted by least "
            f"squares to the measured fiducial marks (a priori sigma {film.sigma_px:g} px unless "
            f"fiducial_measurements.csv gives one). Residuals v = fitted &minus; measured in pixels (col, "
            f"&minus;row); w = v / &sigma;<sub>v</sub>; a fiducial is flagged when |w| &gt; {W_LIMIT} and left out "
            f"of its photo's fit (data snooping, one at a time). {n_flag} fiducial(s) flagged. The propagated "
            f"plate sigmas of the image points enter the adjustment's weights; the correlations (x with y, and "
            f"between the points of one photo through the shared transformation) are dropped "
            f"(docs/decisions.md).</p>")
        rows = []
        for k in range(P):
            flagged = [film.fiducial_ids[k][j] for j in np.flatnonzero(fit.flagged[k])]
            vmax = np.nanmax(np.hypot(fit.v[k, :, 0], fit.v[k, :, 1]))
            rows.append([html.escape(film.photo_ids[k]), str(int(fit.measured[k].sum())), str(int(fit.redundancy[k])),
                         _f(fit.sigma0[k]), _f(vmax),
                         (html.escape(", ".join(flagged)) or "&ndash;", "bad" if flagged else "", "")])
        parts.append((["photo", "fiducials", "redundancy", "sigma0", "largest |v| px", "flagged fiducials"], rows, 1))
        rows = []
        for k in range(P):
            for j in np.flatnonzero(fit.measured[k]):
                if len(rows) >= MAX_FIDUCIAL_ROWS:
                    break
                w = np.nan_to_num(np.abs(fit.w[k, j]), nan=0.0).max()
                rows.append([html.escape(film.photo_ids[k]), html.escape(film.fiducial_ids[k][j]),
                             _f(fit.v[k, j, 0]), _f(fit.v[k, j, 1]), _f(w),
                             ("flagged" if fit.flagged[k, j] else "", "bad" if fit.flagged[k, j] else "", "")])
        parts.append("<p>Residuals of every fiducial"
                     + (f" (the first {MAX_FIDUCIAL_ROWS}; all in fiducial_residuals.csv)" if
                        int(fit.measured.sum()) > MAX_FIDUCIAL_ROWS else " (also in fiducial_residuals.csv)") + ".</p>")
        parts.append((["photo", "fiducial", "v<sub>col</sub> px", "v<sub>&minus;row</sub> px", "max |w|", ""], rows, 2))
    for cal in film.calibrations:
        fit_r = cal.fit
        el = cal.elements
        parts.append(
            f"<p>Calibration report of camera <b>{html.escape(cal.camera_id)}</b> (calibration.toml): calibrated "
            f"focal length {cal.focal_length_mm:.3f} mm; principal point of best symmetry (PBS) "
            f"({cal.pbs_mm[0]:.3f}, {cal.pbs_mm[1]:.3f}) mm, used as the principal point and centre of the "
            f"radial distortion; principal point of autocollimation (PPA) "
            + (f"({cal.ppa_mm[0]:.3f}, {cal.ppa_mm[1]:.3f}) mm, PPA &minus; PBS = "
               f"({(cal.ppa_mm[0] - cal.pbs_mm[0]) * 1000:.0f}, {(cal.ppa_mm[1] - cal.pbs_mm[1]) * 1000:.0f}) &micro;m"
               if np.all(np.isfinite(cal.ppa_mm)) else "not given")
            + ". The radial distortion table is fitted by least squares with "
            + ("k0 (folded into c), " if fit_r.k0 else "") + ", ".join(f"k{i + 1}" for i in range(fit_r.n_terms))
            + f": rms of the fit {fit_r.rms_um:.2f} &micro;m. Camera model (plate convention): c = {el[0]:.4f} mm, "
            f"k1 = {el[3]:.4e}, k2 = {el[4]:.4e}, k3 = {el[5]:.4e}, p1 = {el[6]:.4e}, p2 = {el[7]:.4e}.</p>")
        rows = [[_f(a, ".1f") if np.isfinite(a) else "&ndash;", _f(r, ".3f"), _f(d, ".1f"), _f(m, ".2f"), _f(v, ".2f")]
                for a, r, d, m, v in zip(cal.field_angle_deg, fit_r.radius_mm, fit_r.dr_um, fit_r.model_um,
                                         fit_r.residual_um)]
        parts.append((["field angle deg", "radius mm", "report &micro;m", "fitted &micro;m", "residual &micro;m"], rows, 0))
    return parts


def residual_columns(film: FilmData) -> dict:
    """fiducial_residuals.csv: photo_id, fiducial_id, v_col, v_row (px, fitted - measured), w_col,
    w_row, flag (one row per measured fiducial)."""
    fit = film.fit
    k, j = np.nonzero(fit.measured)
    return {"photo_id": [film.photo_ids[a] for a in k], "fiducial_id": [film.fiducial_ids[a][b] for a, b in zip(k, j)],
            "v_col": fit.v[k, j, 0], "v_row": -fit.v[k, j, 1], "w_col": fit.w[k, j, 0], "w_row": -fit.w[k, j, 1],
            "flag": ["flagged" if f else "" for f in fit.flagged[k, j]]}


def summary_entry(film: FilmData) -> dict:
    """summary.json "film": transformation, photos, median sigma0, flagged fiducials, calibration fit rms."""
    out: dict = {"transformation": film.transformation if film.fit is not None else None}
    if film.fit is not None:
        fit = film.fit
        k, j = np.nonzero(fit.flagged)
        out.update({"n_photos": len(film.photo_ids),
                    "sigma0_median": float(np.nanmedian(fit.sigma0)) if np.isfinite(fit.sigma0).any() else None,
                    "flagged_fiducials": [[film.photo_ids[a], film.fiducial_ids[a][b]] for a, b in zip(k, j)]})
    out["calibration_rms_um"] = {c.camera_id: c.fit.rms_um for c in film.calibrations}
    return out
