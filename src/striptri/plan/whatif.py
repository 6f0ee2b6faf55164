"""What-ifs of a plan and the ranking of its control points: the same design with one change,
analysed for precision only (analysis.precision_only), one row each.

A what-if (WhatIf) changes the plan's project before the analysis; the planned ground points stay
those of the original plan (a what-if changes what is observed, not where the points are):

* ``drop_control(project, spec)``: the control points named by ``spec`` (a point id, a kind XYZ,
  XY or Z, or several of them separated by commas) become check points: still measured on the
  photos, no longer given, their precision reported;
* ``add_control(project, spec)``: ``ID=KIND[:SIGMA]`` (KIND XYZ, XY or Z), a tie or check point
  becomes a control point of that kind at its planned coordinates, held fixed or with the mean
  error SIGMA (m) on each given axis;
* ``sigma_image(project, s)``: every plate coordinate with the sigma s (plate units);
* ``every_kth_photo(project, k)``: the overlap what-if: only every k-th photo of each strip is
  flown (the first, the (k+1)-th, ...; photos.csv's order within a strip), so that a forward
  overlap p becomes ``1 - k (1 - p)``; the measurements of the other photos are dropped;
* ``respaced(project, p, format, Z_t)``: the overlap what-if for any overlap p: every strip
  re-spaced along its flight line, the von Gruber points regenerated (plan.vongruber).

The control ranking (rank_control) drops each control point in turn and re-analyses: the loss of
precision ``worst_sigma_P(dropped) - worst_sigma_P(plan)`` (worst 3D mean error of the new points,
tie and check points) orders them, the one that matters most first. A drop that leaves a datum
defect is ranked first with status "datum defect". This is the brute force; plan.ranking computes the
same by rank-3 updates of N where it applies.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..adjustment import AdjustmentOptions
from ..errors import InputError, NumericalFailure
from ..model import CHECK, KIND_CODES, KIND_NAMES, TIE, Project
from .analysis import precision_figures, precision_only
from .design import CONTROL_KINDS, planned_points
from .vongruber import flight_direction, footprint, strips_of, von_gruber_project

CONTROL_AXES = {"XYZ": np.array([True, True, True]), "XY": np.array([True, True, False]),
                "Z": np.array([False, False, True])}


@dataclass(frozen=True)
class WhatIf:
    """One changed plan: a name (the option as given), the changed project, and its planned ground
    points (np, 3) where they are not the plan's (None: the plan's)."""

    name: str
    project: Project
    xyz: np.ndarray | None = None


def _ids_of(project: Project, spec: str, option: str) -> np.ndarray:
    """Indices of the control points named by spec (ids or kinds, comma-separated)."""
    pts = project.points
    index = {pid: i for i, pid in enumerate(pts.ids)}
    control = np.isin(pts.kind, list(CONTROL_KINDS.values()))
    chosen = np.zeros(len(pts), dtype=bool)
    for part in (s.strip() for s in spec.split(",")):
        if part.upper() in CONTROL_KINDS:
            chosen |= pts.kind == CONTROL_KINDS[part.upper()]
        elif part in index and control[index[part]]:
            chosen[index[part]] = True
        else:
            what = "not a point of the project" if part not in index else \
                f"a {KIND_NAMES[int(pts.kind[index[part]])]} point, not control"
            raise InputError("command line", None, f"{option} {spec}: {part!r} is {what} "
                             "(give control point ids or a kind XYZ, XY, Z)")
    return np.flatnonzero(chosen)


def drop_control(project: Project, spec: str) -> WhatIf:
    """The control points of spec become check points (module doc)."""
    drop = _ids_of(project, spec, "--drop-control")
    kind = project.points.kind.copy()
    kind[drop] = CHECK
    given = project.points.xyz_given.copy()
    return WhatIf(f"drop control {spec}", replace(project, points=replace(project.points, kind=kind, xyz_given=given)))


def add_control(project: Project, spec: str, xyz_plan: np.ndarray) -> WhatIf:
    """``ID=KIND[:SIGMA]``: a tie or check point becomes control of KIND at its planned point, held
    fixed, or with SIGMA (ground metres, > 0) on each of its given axes."""
    pid, _, rest = spec.partition("=")
    kind_name, colon, sigma_text = rest.partition(":")
    pts = project.points
    index = {p: i for i, p in enumerate(pts.ids)}
    if kind_name.upper() not in CONTROL_KINDS or pid not in index:
        raise InputError("command line", None, f"--add-control {spec}: give ID=KIND[:SIGMA] with the id of a point "
                         "the photos see, KIND one of XYZ, XY, Z and SIGMA its mean error in metres")
    try:
        weight = float(sigma_text) if colon else np.nan
    except ValueError:
        weight = -1.0
    if colon and not (np.isfinite(weight) and weight > 0):
        raise InputError("command line", None, f"--add-control {spec}: SIGMA must be a positive number "
                         "(ground metres; leave out ':SIGMA' for a point held fixed)")
    i = index[pid]
    if pts.kind[i] not in (TIE, CHECK):
        raise InputError("command line", None, f"--add-control {spec}: {pid} is already a control point")
    code = KIND_CODES[kind_name.upper()]
    kind, given, sigma = pts.kind.copy(), pts.xyz_given.copy(), pts.sigma_given.copy()
    kind[i] = code
    given[i] = xyz_plan[i]
    sigma[i] = np.where(CONTROL_AXES[kind_name.upper()], weight, np.nan)
    return WhatIf(f"add control {spec}", replace(project, points=replace(pts, kind=kind, xyz_given=given,
                                                                          sigma_given=sigma)))


def sigma_image(project: Project, s: float) -> WhatIf:
    """Every plate coordinate with sigma s (plate units)."""
    if not (np.isfinite(s) and s > 0):
        raise InputError("command line", None, f"--sigma-image {s}: must be a positive number (plate units)")
    ip = project.image_points
    return WhatIf(f"sigma image {s:g}", replace(project, image_points=replace(
        ip, sigma_xy=np.full_like(ip.sigma_xy, s))))


def every_kth_photo(project: Project, k: int) -> WhatIf:
    """Every k-th photo of each strip (module doc)."""
    if not (int(k) == k and k >= 2):
        raise InputError("command line", None, f"--keep-every {k}: a whole number of 2 or more")
    if len(project.bases):
        raise InputError("command line", None, f"--keep-every {k}: the project has observed base components "
                         "(bases.csv) between photos; thin the photos by hand instead")
    ph, ip = project.photos, project.image_points
    strips = np.asarray(ph.strip_ids, dtype=object)
    position = np.zeros(len(ph), dtype=int)
    for sid in dict.fromkeys(ph.strip_ids):  # a loop over strips, not photos
        members = np.flatnonzero(strips == sid)
        position[members] = np.arange(len(members))
    keep = position % int(k) == 0
    new_index = np.cumsum(keep) - 1
    rows = keep[ip.photo_index]
    photos = replace(ph, ids=[i for i, kept in zip(ph.ids, keep) if kept], camera_index=ph.camera_index[keep],
                     strip_ids=[s for s, kept in zip(ph.strip_ids, keep) if kept], xyz0=ph.xyz0[keep],
                     R_ground_from_cam=ph.R_ground_from_cam[keep], angles=ph.angles[keep],
                     sigma_xyz0=ph.sigma_xyz0[keep], sigma_angles=ph.sigma_angles[keep])
    image_points = replace(ip, photo_index=new_index[ip.photo_index[rows]], point_index=ip.point_index[rows],
                           xy=ip.xy[rows], sigma_xy=ip.sigma_xy[rows])
    return WhatIf(f"every {int(k)}-th photo", replace(project, photos=photos, image_points=image_points))


RESPACED_PHOTO_FACTOR = 20  # a re-spaced plan may have at most this many times the plan's photos
RESPACED_MIN_LIMIT = 1000  # (or this many, for small plans)


def respaced(project: Project, overlap: float, fmt: np.ndarray, z_t: float) -> WhatIf:
    """The overlap what-if for any overlap (module doc): each strip re-spaced along its flight line
    with base (1 - overlap) x its first photo's ground footprint along the line, from the same first
    photo over at least the same length; each new photo takes the attitude, camera and sigmas of the
    original photo nearest along the line; the von Gruber points are regenerated (plan.vongruber)."""
    if not (np.isfinite(overlap) and 0 < overlap < 1):
        raise InputError("command line", None, f"--overlap {overlap}: a forward overlap between 0 and 1 (0.6 for 60 %)")
    if len(project.bases) or project.gnss is not None:
        raise InputError("command line", None, f"--overlap {overlap:g}: the project has observed base components "
                         "(bases.csv) or a GNSS model tied to its photos; re-space the photos by hand instead")
    ph = project.photos
    take, xyz0, sids, ids = [], [], [], []
    planned = []
    for members in strips_of(project):  # a loop over strips, not photos: the sizes first
        u = flight_direction(project, members)
        along = (ph.xyz0[members] - ph.xyz0[members[0]]) @ u
        base = (1.0 - overlap) * float(footprint(project, members[:1], u, fmt, z_t)[0])
        planned.append(max(2, int(min(np.ceil(float(along[-1]) / base - 1e-9), 1e12)) + 1) if base > 0 else None)
    if any(n is None for n in planned) or sum(planned) > max(RESPACED_PHOTO_FACTOR * len(ph), RESPACED_MIN_LIMIT):
        total = "too many" if any(n is None for n in planned) else f"{sum(planned):,}"
        raise InputError("command line", None, f"--overlap {overlap:g}: the re-spaced plan would have {total} "
                         f"photographs, more than {RESPACED_PHOTO_FACTOR} times the plan's {len(ph)}; give a "
                         "forward overlap a camera can fly (0.6 to 0.9)")
    for members in strips_of(project):
        u = flight_direction(project, members)
        first, last = ph.xyz0[members[0]], ph.xyz0[members[-1]]
        along = (ph.xyz0[members] - first) @ u
        length = float(along[-1])
        base = (1.0 - overlap) * float(footprint(project, members[:1], u, fmt, z_t)[0])
        n = max(2, int(np.ceil(length / base - 1e-9)) + 1)
        s = np.arange(n) * base
        slope = (last - first) / length if length > 0 else u
        xyz0.append(first + s[:, None] * slope)
        take.append(members[np.argmin(np.abs(along[None, :] - s[:, None]), axis=1)])
        sid = ph.strip_ids[members[0]]
        sids += [sid] * n
        ids += [f"{sid}_{k + 1:03d}" for k in range(n)]
    take = np.concatenate(take)
    photos = replace(ph, ids=ids, camera_index=ph.camera_index[take], strip_ids=sids, xyz0=np.concatenate(xyz0),
                     R_ground_from_cam=ph.R_ground_from_cam[take], angles=ph.angles[take],
                     sigma_xyz0=ph.sigma_xyz0[take], sigma_angles=ph.sigma_angles[take])
    new, _ = von_gruber_project(replace(project, photos=photos), fmt, z_t)
    return WhatIf(f"overlap {overlap:g} ({len(photos)} photos)", new, planned_points(new))


def worst_sigma_p(project: Project, sigma_points: np.ndarray) -> float | None:
    """Worst 3D a-priori mean error sqrt(sX^2 + sY^2 + sZ^2) of the new points (tie, check), m."""
    kind = project.points.kind
    sel = ((kind == TIE) | (kind == CHECK)) & np.isfinite(sigma_points).all(axis=1)
    return float(np.sqrt(np.sum(sigma_points[sel] ** 2, axis=1)).max()) if sel.any() else None


def evaluate(project: Project, options: AdjustmentOptions, xyz_plan: np.ndarray) -> dict:
    """The precision figures of a (changed) plan: analysis.precision_figures plus worst_sigma_P and
    the status ("ok" or why the design fails, e.g. its datum defect)."""
    try:
        plan, _, _, sigma = precision_only(project, options, xyz_plan)
    except NumericalFailure as exc:
        status = "datum defect" if exc.reason == "datum_defect" else exc.reason
        return {"status": status, "message": str(exc).splitlines()[0], "worst_sigma_P": None,
                **precision_figures(project, np.full((len(project.points), 3), np.nan))}
    kind = plan.points.kind
    rays = np.bincount(plan.image_points.point_index, minlength=len(kind))
    lost = int(np.sum(((kind == TIE) | (kind == CHECK)) & (rays > 0) & ~np.isfinite(sigma).all(axis=1)))
    message = f"{lost} new points not determined (on one photo), not counted" if lost else ""
    return {"status": "ok", "message": message, "worst_sigma_P": worst_sigma_p(plan, sigma),
            **precision_figures(plan, sigma)}


def rank_control(project: Project, options: AdjustmentOptions, xyz_plan: np.ndarray, base: dict) -> list[dict]:
    """Each control point dropped in turn and the plan re-analysed (module doc; brute force, one
    adjustment each): ranked rows as ``ranked`` makes them."""
    figures = []
    for i in control_indices(project):
        fig = evaluate(drop_control(project, project.points.ids[i]).project, options, xyz_plan)
        figures.append({"worst_sigma_P": fig["worst_sigma_P"], "status": fig["status"]})
    return ranked(project, figures, base)


def control_indices(project: Project) -> np.ndarray:
    """The control points (kinds XYZ, XY, Z), in the order of the points: the ranking's order."""
    return np.flatnonzero(np.isin(project.points.kind, list(CONTROL_KINDS.values())))


def ranked(project: Project, figures: list[dict], base: dict) -> list[dict]:
    """Rows point_id, kind, worst_sigma_P, loss_sigma_P (m; None with a datum defect), status, rank
    of the control points (control_indices) from their ``figures`` (worst_sigma_P, status) when
    dropped, the one that matters most first."""
    rows = []
    for i, fig in zip(control_indices(project), figures):
        loss = None if fig["worst_sigma_P"] is None or base["worst_sigma_P"] is None else \
            fig["worst_sigma_P"] - base["worst_sigma_P"]
        rows.append({"point_id": project.points.ids[i], "kind": KIND_NAMES[int(project.points.kind[i])],
                     "worst_sigma_P": fig["worst_sigma_P"], "loss_sigma_P": loss, "status": fig["status"]})
    rows.sort(key=lambda r: (r["loss_sigma_P"] is not None, -(r["loss_sigma_P"] or 0.0)))
    for rank, row in enumerate(rows, 1):
        row["rank"] = rank
    return rows
