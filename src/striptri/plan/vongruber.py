"""The planned tie points of a plan without image_points.csv: von Gruber points per model, strip ties
in the sidelap, and which photo sees which point (docs/plan.md "Von Gruber points").

The rule (a photogrammetrist's standard pattern, made exact):

* strips: the photos of each strip_id in photos.csv's order; a model is two consecutive photos;
  the flight direction u of a strip is the horizontal direction from its first to its last centre
  (one photo: its camera x axis), v = z x u the left of it;
* the terrain: the mean terrain height Z_t (``--terrain-height``, project.toml ``[plan]
  terrain_height``, else the mean Z of the control.csv points that give one);
* every photo's nadir point (X0, Y0, Z_t) is a tie point (the two nadir points of each model), and
  abreast of it, at (X0, Y0, Z_t) +- d v, two more (the six von Gruber positions of each model are
  those of its two photos). d, on each side of a strip separately: half the distance to the
  neighbouring strip on that side (the middle of the sidelap, so that the point is a strip tie seen
  by both strips), at most 0.4 of the photo's ground footprint across track (the classical position
  y = +-b of a 60 % film model); without a neighbour on that side, 0.4 of the footprint;
* candidates closer than a fifth of the strip's median base merge into one point (their mean; the
  points of two strips in the middle of their sidelap coincide when the photos are abreast);
* a point is seen by every photo whose format contains its image: |x - xp| <= w/2, |y - yp| <= h/2
  (collinearity with the camera's distortion) with the point in front of the camera; a tie point
  seen by fewer than two photos is dropped; control and check points of control.csv (placed by
  their given X, Y, Z, else approx_points.csv, a missing Z at Z_t) are measured on every photo that
  sees them;
* the format w x h (plate units): ``--format W[xH]`` or project.toml ``[plan] format = W`` or
  ``[W, H]``; none is an InputError (the camera's format is not in cameras.csv).

The ground footprint of a photo in a ground direction e (horizontal unit vector): the extent of the
format along the image of e, ``1 / max(|a|/w, |b|/h)`` with (a, b) the unit plate direction of e,
times the scale (Z0 - Z_t) / c. The overlap what-if (whatif.respaced) uses it along u.

Tie point ids: ``vg_<photo>`` (nadir), ``vg_<photo>_l`` / ``vg_<photo>_r`` (left, right of the
flight direction); a merged point keeps the id of its first candidate.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..geometry.collinearity import camera_from_ground, plate_from_ground
from ..errors import InputError
from ..io import plausibility as limits
from ..geometry.lens import observed_from_ideal
from ..model import KIND_NAMES, TIE, ImagePoints, ObjectPoints, Project
from .design import planned_points

LATERAL_FRACTION = 0.4  # the lateral offset as a fraction of the footprint across track (y = +-b at 60 %)
MERGE_FRACTION = 0.2  # candidates closer than this fraction of the median base merge
PARALLEL_COS = np.cos(np.radians(30.0))  # strips within 30 degrees of parallel are neighbours


def plan_settings(project_dir: Path) -> dict:
    """project.toml's [plan] section ({} when absent)."""
    path = Path(project_dir) / "project.toml"
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_bytes().decode("utf-8-sig")).get("plan", {})
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:  # read_project has reported it already
        raise InputError(path, None, str(exc)) from exc


def format_of(option: str | None, settings: dict, project_dir: Path) -> np.ndarray:
    """The format (w, h) in plate units from ``--format W[xH]``, else project.toml [plan] format."""
    if option is not None:
        parts = str(option).lower().split("x")
        where, what = "command line", f"--format {option}"
    elif "format" in settings:
        value = settings["format"]
        parts = value if isinstance(value, list) else [value]
        where, what = Path(project_dir) / "project.toml", f"[plan] format = {value!r}"
    else:
        raise InputError("command line", None, "the plan has no image_points.csv (or --von-gruber asks for its von "
                         "Gruber points, or --overlap for a re-spaced plan): give the camera format with --format W[xH] "
                         "(plate units, e.g. --format 230 for a 23 cm film camera) or project.toml [plan] format")
    try:
        wh = [float(p) for p in parts if not isinstance(p, bool)]
    except (TypeError, ValueError):
        wh = []
    if len(wh) == 1:
        wh = wh * 2
    if len(wh) != 2 or len(parts) != len(wh) and len(parts) != 1 or not all(np.isfinite(wh)) or min(wh) <= 0:
        raise InputError(where, None, f"{what}: give the format as W or WxH, positive numbers in plate units")
    if max(wh) > limits.PLATE_LIMIT:
        raise InputError(where, None, f"{what}: beyond the plausible {limits.number_text(limits.PLATE_LIMIT)} plate "
                                      "units (docs/file-formats.md, Limits)")
    return np.array(wh)


def terrain_height(option: float | None, settings: dict, project: Project, project_dir: Path) -> float:
    """The mean terrain height Z_t (module doc), ground metres."""
    if option is not None:
        value, where = option, "command line"
    elif "terrain_height" in settings:
        value, where = settings["terrain_height"], Path(project_dir) / "project.toml"
    else:
        z = project.points.xyz_given[:, 2]
        z = z[np.isfinite(z)]
        if not len(z):
            raise InputError("command line", None, "the von Gruber points need the terrain height: give "
                             "--terrain-height Z or project.toml [plan] terrain_height (no control point gives a Z)")
        return float(np.mean(z))
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(where, None, f"terrain height {value!r}: a number (ground metres)")
    if abs(value) > limits.GROUND_LIMIT_M:
        raise InputError(where, None, f"terrain height {value!r}: beyond the plausible "
                                      f"{limits.number_text(limits.GROUND_LIMIT_M)} m (docs/file-formats.md, Limits)")
    return float(value)


def strips_of(project: Project) -> list[np.ndarray]:
    """The photo indices of each strip, in photos.csv's order (strips in order of first photo)."""
    sids = np.asarray(project.photos.strip_ids, dtype=object)
    return [np.flatnonzero(sids == s) for s in dict.fromkeys(project.photos.strip_ids)]  # a loop over strips


def flight_direction(project: Project, members: np.ndarray) -> np.ndarray:
    """Horizontal unit flight direction u of a strip (module doc): (3,)."""
    ph = project.photos
    d = ph.xyz0[members[-1]] - ph.xyz0[members[0]]
    d[2] = 0.0
    if len(members) < 2 or np.hypot(d[0], d[1]) == 0:
        d = ph.R_ground_from_cam[members[0]][:, 0].copy()
        d[2] = 0.0
    return d / np.linalg.norm(d)


def footprint(project: Project, photos: np.ndarray, direction: np.ndarray, fmt: np.ndarray, z_t: float) -> np.ndarray:
    """Ground footprint (m) of the photos along the horizontal unit direction (module doc): (n,)."""
    ph = project.photos
    cam_dir = np.einsum("nji,j->ni", ph.R_ground_from_cam[photos], direction)[:, :2]
    ab = cam_dir / np.linalg.norm(cam_dir, axis=1, keepdims=True)
    extent = 1.0 / np.max(np.abs(ab) / fmt, axis=1)
    c = project.cameras.interior[ph.camera_index[photos], 0]
    return extent * np.abs(ph.xyz0[photos, 2] - z_t) / c


def candidates(project: Project, fmt: np.ndarray, z_t: float) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The candidate tie points before merging: ids, ground xyz (n, 3), and per candidate the median
    base of its strip (m, the merge scale)."""
    ph = project.photos
    strips = strips_of(project)
    u = np.array([flight_direction(project, m) for m in strips])  # (ns, 3), a loop over strips
    v = np.cross([0.0, 0.0, 1.0], u)
    mid = np.array([ph.xyz0[m].mean(axis=0) for m in strips])
    ids, xyz, scale = [], [], []
    for s, members in enumerate(strips):
        parallel = np.abs(u @ u[s]) >= PARALLEL_COS
        offset = (mid - mid[s]) @ v[s]
        cross = footprint(project, members, v[s], fmt, z_t)
        base = np.linalg.norm(np.diff(ph.xyz0[members, :2], axis=0), axis=1)
        b = float(np.median(base)) if len(base) else float(np.median(cross))
        sides = []
        for sign, tag in ((1.0, "l"), (-1.0, "r")):
            others = parallel & (sign * offset > 0)
            half = 0.5 * np.min(sign * offset[others]) if others.any() else np.inf
            sides.append((sign * np.minimum(half, LATERAL_FRACTION * cross), tag))
        nadir = ph.xyz0[members].copy()
        nadir[:, 2] = z_t
        names = [ph.ids[i] for i in members]
        ids += [f"vg_{n}" for n in names]
        xyz.append(nadir)
        for d, tag in sides:
            ids += [f"vg_{n}_{tag}" for n in names]
            xyz.append(nadir + d[:, None] * v[s])
        scale += [b] * (3 * len(members))
    return ids, np.concatenate(xyz), np.array(scale)


def merged(ids: list[str], xyz: np.ndarray, scale: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Candidates closer than MERGE_FRACTION of their base merge (connected components): ids of
    the first candidate of each group, the group means."""
    r = MERGE_FRACTION * np.min(scale) if len(scale) else 0.0
    pairs = cKDTree(xyz[:, :2]).query_pairs(r, output_type="ndarray") if r > 0 else np.zeros((0, 2), int)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xyz), len(xyz)))
    _, label = connected_components(graph, directed=False)
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)
    order = np.argsort(first)  # groups in the order of their first candidate
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    group = rank[inverse]
    mean = np.zeros((len(first), 3))
    np.add.at(mean, group, xyz)
    mean /= np.bincount(group)[:, None]
    return [ids[i] for i in np.sort(first)], mean


def sightings(project: Project, xyz: np.ndarray, fmt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which photo sees which ground point (module doc): photo_index, point_index, observed plate xy
    (m, 2), in the order of the points, then photos."""
    ph, cams = project.photos, project.cameras
    n_ph, n_pt = len(ph), len(xyz)
    out_ph, out_pt, out_xy = [], [], []
    chunk = max(1, 250_000 // max(n_ph, 1))  # about 250,000 projections at a time
    for start in range(0, n_pt, chunk):  # chunks of points against all photos (memory), not a loop over points
        pts = xyz[start:start + chunk]
        R = ph.R_ground_from_cam[:, None]
        O = ph.xyz0[:, None]
        params = cams.interior[ph.camera_index]
        m = camera_from_ground(R, O, pts[None])
        ideal = plate_from_ground(R, O, params[:, None, :3], pts[None])
        front = m[..., 2] * (-params[:, None, 0]) > 0  # in front of the camera (m_z opposite to c)
        shape = ideal.shape
        conv = np.broadcast_to(cams.convention[ph.camera_index][:, None], shape[:2])
        obs = observed_from_ideal(ideal.reshape(-1, 2), np.broadcast_to(params[:, None], shape[:2] + params.shape[1:])
                                  .reshape(-1, params.shape[1]), conv.reshape(-1)).reshape(shape)
        inside = np.all(np.abs(obs - params[:, None, 1:3]) <= fmt / 2, axis=2) & front & np.isfinite(obs).all(axis=2)
        i_ph, i_pt = np.nonzero(inside)
        out_ph.append(i_ph)
        out_pt.append(i_pt + start)
        out_xy.append(obs[i_ph, i_pt])
    photo_index, point_index = np.concatenate(out_ph), np.concatenate(out_pt)
    xy = np.concatenate(out_xy).reshape(-1, 2)
    order = np.lexsort((photo_index, point_index))
    return photo_index[order], point_index[order], xy[order]


def control_positions(project: Project, z_t: float, measured: np.ndarray | None = None) -> np.ndarray:
    """The planned positions of the points of control.csv (given X, Y, Z, else approx_points.csv,
    else ``measured``, the intersection of their planned rays in image_points.csv (plan.design), a
    missing Z at Z_t): (np, 3); InputError for one without a planimetric position."""
    pts = project.points
    xyz = np.where(np.isfinite(pts.xyz_given), pts.xyz_given,
                   np.nan if pts.xyz_approx is None else pts.xyz_approx)
    if measured is not None:
        xyz = np.where(np.isfinite(xyz), xyz, measured)
    xyz[:, 2] = np.where(np.isfinite(xyz[:, 2]), xyz[:, 2], z_t)
    for i in np.flatnonzero(~np.isfinite(xyz[:, :2]).all(axis=1))[:1]:
        raise InputError(Path(project.source or ".") / "control.csv", None,
                         f"point '{pts.ids[i]}' ({KIND_NAMES[int(pts.kind[i])]}): the plan needs its planned X, Y; "
                         "give them in approx_points.csv, or measure the point on two photos in image_points.csv")
    return xyz


def von_gruber_project(project: Project, fmt: np.ndarray, z_t: float) -> tuple[Project, str]:
    """The plan with its von Gruber tie points and the sightings of all points (module doc), and a
    one-line note saying what was generated. The points of control.csv stay (the tie points of an
    image_points.csv, if read, are replaced); the new points' approximate coordinates are their
    planned positions; every plate sigma is project.toml's sigma_image."""
    pts = project.points
    keep = np.flatnonzero(pts.kind != TIE)
    control = ObjectPoints(ids=[pts.ids[i] for i in keep], kind=pts.kind[keep], xyz_given=pts.xyz_given[keep],
                           sigma_given=pts.sigma_given[keep],
                           xyz_approx=None if pts.xyz_approx is None else pts.xyz_approx[keep])
    measured = planned_points(project)[keep] if len(project.image_points) else None
    xyz_control = control_positions(replace(project, points=control), z_t, measured)
    ids, xyz = merged(*candidates(project, fmt, z_t))
    clash = set(ids) & set(control.ids)
    if clash:
        raise InputError(Path(project.source or ".") / "control.csv", None,
                         f"point id '{sorted(clash)[0]}' is also the id of a generated von Gruber point; rename it")
    all_xyz = np.vstack([xyz_control, xyz])
    photo_index, point_index, xy = sightings(project, all_xyz, fmt)
    n_c = len(control.ids)
    rays = np.bincount(point_index, minlength=len(all_xyz))
    used = np.concatenate([np.ones(n_c, bool), rays[n_c:] >= 2])
    new_index = np.cumsum(used) - 1
    rows = used[point_index]
    n_tie = int(used[n_c:].sum())
    points = ObjectPoints(ids=control.ids + [ids[j] for j in np.flatnonzero(used[n_c:])],
                          kind=np.concatenate([control.kind, np.full(n_tie, TIE)]),
                          xyz_given=np.vstack([control.xyz_given, np.full((n_tie, 3), np.nan)]),
                          sigma_given=np.vstack([control.sigma_given, np.full((n_tie, 3), np.nan)]),
                          xyz_approx=all_xyz[used].copy())
    s = project.settings.sigma_image
    image_points = ImagePoints(photo_index=photo_index[rows], point_index=new_index[point_index[rows]],
                               xy=xy[rows], sigma_xy=np.full((int(rows.sum()), 2), s))
    note = (f"von Gruber points: {n_tie} tie points generated ({len(xyz) - n_tie} seen by fewer than two photos "
            f"dropped), {int(rows.sum())} plate measurements; format {fmt[0]:g} x {fmt[1]:g}, terrain height "
            f"{z_t:.6g} m")
    return replace(project, points=points, image_points=image_points), note
