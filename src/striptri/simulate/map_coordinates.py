"""A synthetic block on the curved Earth, in map coordinates (``striptri simulate --crs``).

The simulator's true block (:mod:`.truth`) is a Cartesian block; here its frame is taken as the
local topocentric frame (:mod:`striptri.crs.frame`) whose origin lies on the ellipsoid below
geodetic (lat, lon), with X along grid east there: the block's flat true geometry is a real
geometry on the ellipsoid (rays straight in space, the Earth curved below them). Everything given
(approximate and GNSS centres with their rotations, control, check points) and the truth tables are
then written in the projected CRS, heights ellipsoidal or orthometric (h = H + N with a constant N),
with project.toml's [coordinates] saying so. The same files without [coordinates] are the "naive"
adjustment in grid coordinates (docs/decisions.md, "Map coordinates").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from striptri import model
from striptri.crs.frame import LocalFrame, angle_sigmas, parse_crs
from striptri.geometry.rotations import R_from_opk, angles_from_R, opk_from_R


def central_meridian(crs_text: str) -> float | None:
    """Longitude of the natural origin of a projected CRS (degrees), or None if it has none."""
    op = parse_crs(crs_text).coordinate_operation
    for p in getattr(op, "params", []) or []:
        if p.name in ("Longitude of natural origin", "Longitude of origin"):
            return float(p.value)
    return None


def sim_frame(coordinates: model.CoordinateSettings, lat: float, lon: float) -> LocalFrame:
    """The local frame of the simulation: origin on the ellipsoid at (lat, lon) degrees."""
    import pyproj  # only with --crs: pyproj costs start-up time

    crs = parse_crs(coordinates.crs)
    e, n = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True).transform(lon, lat)
    return LocalFrame(coordinates, np.array([e, n, 0.0]))


def to_map_coordinates(project: model.Project, truth: dict, coordinates: model.CoordinateSettings,
                       lat: float, lon: float) -> tuple[model.Project, dict]:
    """The simulated project and truth tables (simulate.truth_tables) in map coordinates. The
    simulator's frame, shifted so that the centre of its photo centres lies above (lat, lon), is the
    local frame there (module doc)."""
    frame = sim_frame(coordinates, lat, lon)
    shift = np.array([*project.photos.xyz0[:, :2].mean(axis=0), 0.0])
    photos = project.photos
    xyz0 = frame.from_local(photos.xyz0 - shift)
    R = frame.rotations_to_grid(photos.xyz0 - shift, photos.R_ground_from_cam)
    convention = project.settings.rotation
    new_photos = replace(photos, xyz0=xyz0, R_ground_from_cam=R, angles=angles_from_R(R, convention),
                         sigma_xyz0=frame.sigmas_to_grid(photos.xyz0 - shift, photos.sigma_xyz0),
                         sigma_angles=angle_sigmas(photos.R_ground_from_cam, R, photos.sigma_angles, convention))
    pts = project.points
    true_xyz = np.column_stack([np.asarray(truth["points.csv"][a], dtype=float) for a in "XYZ"])
    full = np.where(np.isnan(pts.xyz_given), true_xyz, pts.xyz_given)  # partial control: the rest from the truth
    grid = frame.from_local(full - shift)
    points = replace(pts, xyz_given=np.where(np.isnan(pts.xyz_given), np.nan, grid),
                     sigma_given=frame.sigmas_to_grid(full - shift, pts.sigma_given))
    settings = replace(project.settings, coordinates=coordinates)
    out = replace(project, photos=new_photos, points=points, settings=settings)

    t_photos = dict(truth["photos.csv"])
    t_xyz0 = np.column_stack([np.asarray(t_photos[n], dtype=float) for n in ("X0", "Y0", "Z0")])
    t_R = R_from_opk(np.radians(np.column_stack([np.asarray(t_photos[n], dtype=float)
                                                 for n in ("omega", "phi", "kappa")])))
    g_xyz0 = frame.from_local(t_xyz0 - shift)
    g_opk = np.degrees(opk_from_R(frame.rotations_to_grid(t_xyz0 - shift, t_R)))
    for j, n in enumerate(("X0", "Y0", "Z0")):
        t_photos[n] = g_xyz0[:, j]
    for j, n in enumerate(("omega", "phi", "kappa")):
        t_photos[n] = g_opk[:, j]
    t_points = dict(truth["points.csv"])
    g_points = frame.from_local(true_xyz - shift)
    for j, n in enumerate("XYZ"):
        t_points[n] = g_points[:, j]
    tables = {**truth, "photos.csv": t_photos, "points.csv": t_points}
    if "strips.csv" in truth:  # a GNSS block: its per-strip shift and drift turned into grid axes
        tables["strips.csv"] = _strip_vectors_to_grid(truth["strips.csv"], frame, photos.xyz0 - shift)
    return out, tables


def _strip_vectors_to_grid(strips: dict, frame, xyz_local: np.ndarray) -> dict:
    """truth/strips.csv's shifts (m) and drifts (m/s), ground vectors of the simulator's local frame,
    in the grid's axes: turned by the rotation from the local frame to the grid at the block's centre
    (the meridian convergence and the deflection of the local vertical; the projection's scale, at
    most 1e-3, is left out: it changes a shift of a metre by a millimetre). The lever arm and the
    boresight are in the camera frame and stay as they are."""
    centre = xyz_local.mean(axis=0, keepdims=True)
    R_grid_from_local = frame.rotations_to_grid(centre, np.eye(3)[None])[0]
    out = dict(strips)
    for kind in ("shift", "drift"):
        v = np.column_stack([np.asarray(strips[f"{kind}_{a}"], dtype=float) for a in "XYZ"])
        g = v @ R_grid_from_local.T
        for j, a in enumerate("XYZ"):
            out[f"{kind}_{a}"] = g[:, j]
    return out
