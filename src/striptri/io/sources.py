"""image_points.csv's ``source`` column after the adjustment (issue 28; docs/matching.md): how many
of the automatic tie points (source auto, written by striptri match) the gross-error procedure
removed, and how well the others fit, in pixels. summary.json ``automatic_tie_points`` and the
report's section of the same name."""

from __future__ import annotations

import csv
import io

import numpy as np

from ..model import Project

REMOVED = ("rejected", "inseparable", "dropped")  # residuals.csv flags of a measurement taken out


def automatic_rows(project: Project) -> np.ndarray | None:
    """(m,) bool over project.image_points (the active rows of image_points.csv, in the file's
    order): True where ``source`` is auto. None without a source column or an auto row."""
    path = None if project.source is None else project.source / "image_points.csv"
    if path is None or not path.is_file():
        return None
    with path.open(encoding="utf-8-sig", newline="") as f:  # the header alone decides, for every adjust run
        header = next(csv.reader(f), [])
    if "source" not in (h.strip() for h in header):
        return None
    reader = csv.DictReader(io.StringIO(path.read_text(encoding="utf-8-sig")))
    rows = [((r.get("source") or "").strip().lower() == "auto",
             (r.get("active") or "1").strip().lower() not in ("0", "false")) for r in reader]
    auto = np.array([a for a, active in rows if active], dtype=bool)
    if len(auto) != len(project.image_points) or not auto.any():
        return None
    return auto


def _pixel_of_photo(project: Project) -> np.ndarray:
    """(n,) plate units per pixel of each photo: its digital camera's pixel_size, or for a film scan
    the scale of its fiducial transformation (the root of the linear part's determinant); nan
    where neither is known."""
    ph, cams, film = project.photos, project.cameras, project.film
    pixel = np.full(len(ph.ids), np.nan) if cams.pixel_size is None else cams.pixel_size[ph.camera_index].astype(float)
    if film is not None and film.fit is not None:
        from striptri.film import transform

        row_of = {pid: k for k, pid in enumerate(ph.ids)}
        rows = [row_of[pid] for pid in film.photo_ids]
        pixel[rows] = transform.plate_per_pixel(film.fit.kind, film.fit.params)
    return pixel


def summary_entry(project: Project, flags, residuals: np.ndarray) -> dict | None:
    """summary.json ``automatic_tie_points``: rays (automatic measurements), points, removed (rays
    the gross-error procedure took out: rejected, inseparable or dropped), points_left (those that
    still have two rays or more), rms_px (the RMS of the remaining automatic rays' residuals, x and
    y together, in pixels of their camera or scan). flags: (m,) residuals.csv's flag of each row;
    residuals: (m, 2) plate units. None for a project without automatic rows."""
    auto = automatic_rows(project)
    if auto is None:
        return None
    ip = project.image_points
    removed = np.isin(np.asarray(flags, dtype=object), REMOVED)
    left = auto & ~removed
    pixel = _pixel_of_photo(project)[ip.photo_index]
    v = np.asarray(residuals, dtype=float)[left] / pixel[left, None]
    rays_left = np.bincount(ip.point_index[left], minlength=len(project.points))
    points = np.unique(ip.point_index[auto])
    rms = float(np.sqrt(np.mean(v**2))) if len(v) and np.isfinite(v).all() else None
    return {"rays": int(auto.sum()), "points": int(len(points)), "removed": int((auto & removed).sum()),
            "points_left": int((rays_left[points] >= 2).sum()), "rms_px": rms}
