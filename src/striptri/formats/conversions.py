"""Conversions between BAL problems, COLMAP models and striptri projects (docs/formats.md).

No file is opened here. A :class:`Scene` is a :class:`striptri.model.Project` plus approximate
ground coordinates of its object points (BAL and COLMAP carry them; a striptri project carries only
the given coordinates of control points).

Frames:

* striptri: ``R_ground_from_cam`` maps the camera vector ``p = (x - xp, y - yp, -c)`` (diapositive,
  y up, the camera looks along -z) to the ground; centre ``O``.
* BAL: ``P = R_bal X + t``, the camera looks down -z, y up, pixels from the image centre: the
  same camera frame, so ``R_ground_from_cam = R_bal^T``, ``O = -R_bal^T t``, ``c = f``,
  ``xp = yp = 0`` and plate coordinates = BAL pixels (plate unit: pixel).
* COLMAP: ``P = R_cw X + t``, x right, y down, looking along +z, pixels from the top-left corner,
  y down. With ``D = diag(1, -1, -1)``: ``R_cw = D R_ground_from_cam^T``, ``t = -R_cw O``; with s
  plate units per pixel and an image of W x H pixels: ``x = (u - W/2) s``, ``y = (H/2 - v) s``
  (geometry.pixels, the convention of cameras.csv's digital frame cameras), ``c = f s``,
  ``xp = (cx - W/2) s``, ``yp = (H/2 - cy) s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from striptri.geometry import lens, rotations
from striptri import model
from striptri.geometry.camera import ray_ground
from striptri.geometry.pixels import pixel_from_plate, plate_from_pixel
from striptri.errors import InputError
from striptri.formats.bal import BalProblem, behind_camera
from striptri.formats.colmap import ColmapModel, R_from_quaternion, quaternion_from_R
from striptri.formats.scene import Scene, photo_datum

# striptri camera frame (y up, looking along -z) from the COLMAP camera frame (y down, along +z).
D_STRIPTRI_FROM_COLMAP = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class ColmapNames:
    """striptri ids of COLMAP objects (kept in the side file striptri_ids.csv): COLMAP id -> id."""

    cameras: dict[int, str] = field(default_factory=dict)
    points: dict[int, str] = field(default_factory=dict)
    strips: dict[int, str] = field(default_factory=dict)  # image id -> strip_id


# --------------------------------------------------------------------------- BAL


def bal_distortion_pixels(bal: BalProblem) -> np.ndarray:
    """Per camera, the largest displacement (pixels) the BAL radial distortion causes at the
    camera's observed points: f |k1 r^2 + k2 r^4| |p| with p = xy / f (the undistorted radius
    approximated by the observed one). -> (ncam,)."""
    cam = bal.camera_index
    p = bal.xy_pixel / bal.f[cam, None]
    r2 = np.sum(p * p, axis=1)
    shift = np.abs(bal.k1[cam] * r2 + bal.k2[cam] * r2 * r2) * np.sqrt(r2) * np.abs(bal.f[cam])
    out = np.zeros(bal.n_cameras)
    np.maximum.at(out, cam, shift)
    return out


def bal_to_project(bal: BalProblem, drop_distortion: bool = False) -> Scene:
    """A striptri project of a BAL problem: one camera and one photo per BAL camera, one tie point
    per BAL point, plate coordinates = BAL pixels ([units] plate = "px"), sigma 1 pixel,
    free-network datum.

    The camera is BAL's: principal distance f, principal point at the image centre (held), radial
    distortion k1, k2 in the image convention (lens.IMAGE: applied to the projected point in
    normalised coordinates, BAL's ``f (1 + k1 |p|^2 + k2 |p|^4) p``). f, k1 and k2 are free, as in
    the BAL problem. Datum: the first camera and one coordinate of the camera farthest from it
    held (scene.photo_datum), a minimal datum for both methods; the cost at the minimum does not
    depend on it. drop_distortion: k1 = k2 = 0, held (a pinhole camera; said in Scene.notes with
    the largest displacement it causes). A BAL focal length must be > 0."""
    path = bal.path or Path("<BAL problem>")
    distorted = np.flatnonzero((bal.k1 != 0) | (bal.k2 != 0))
    shift = bal_distortion_pixels(bal)
    notes = []
    if len(distorted) and drop_distortion:
        notes.append(f"radial distortion k1, k2 of {len(distorted)} cameras dropped (--drop-distortion); it "
                     f"displaced observed points by up to {shift.max():.3g} px")
    bad_f = np.flatnonzero(bal.f <= 0)
    if len(bad_f):
        i = int(bad_f[0])
        raise InputError(path, int(bal.camera_lines[i]),
                         f"camera {i} (parameters from this line): focal length f = {float(bal.f[i])!r} is not > 0")
    pair = bal.camera_index * max(bal.n_points, 1) + bal.point_index
    _, first, counts = np.unique(pair, return_index=True, return_counts=True)
    if np.any(counts > 1):
        k = int(first[np.argmax(counts > 1)])
        raise InputError(path, None, f"camera {bal.camera_index[k]} observes point {bal.point_index[k]} more than once")
    R_cw = bal.R_cam_from_world()
    R_ground_from_cam = np.swapaxes(R_cw, -1, -2)
    xyz0 = -np.einsum("nij,nj->ni", R_ground_from_cam, bal.t_cam_from_world)
    ncam, npts, nobs = bal.n_cameras, bal.n_points, bal.n_observations
    cams = [str(i) for i in range(ncam)]
    photos = _photos(cams, np.arange(ncam), [""] * ncam, xyz0, R_ground_from_cam)
    if ncam >= 2:
        photos, note = photo_datum(photos, 0, "units")
        notes.append(note)
    interior = np.zeros((ncam, lens.NCP))
    sigma = np.full((ncam, lens.NCP), np.nan)
    interior[:, lens.C] = bal.f
    sigma[:, lens.C] = np.inf
    if not drop_distortion:
        interior[:, lens.K1], interior[:, lens.K2] = bal.k1, bal.k2
        sigma[:, lens.K1] = sigma[:, lens.K2] = np.inf
    project = model.Project(
        cameras=model.Cameras(ids=cams, interior=interior, sigma_interior=sigma,
                              convention=np.full(ncam, lens.IMAGE)),
        photos=photos,
        image_points=model.ImagePoints(
            photo_index=bal.camera_index.copy(), point_index=bal.point_index.copy(),
            xy=bal.xy_pixel.copy(), sigma_xy=np.ones((nobs, 2)),
        ),
        points=_tie_points([str(j) for j in range(npts)]),
        # BAL problems want the bundle method with damping and a cost tolerance (docs/formats.md)
        settings=model.ProjectSettings(sigma_image=1.0, datum="control", method="bundle", max_iterations=100,
                                       cost_tolerance=1e-10, plate_unit="px"),
        source=bal.path,
    )
    project = replace(project, points=replace(project.points, xyz_approx=bal.xyz_world.copy()))
    behind = behind_camera(bal)
    if behind.any():  # kept as inactive rows (image_points.csv active = 0), as COLMAP gives them no residual
        ip = project.image_points
        rows = np.flatnonzero(behind)
        keep = np.flatnonzero(~behind)
        pick = lambda r: model.ImagePoints(photo_index=ip.photo_index[r], point_index=ip.point_index[r],  # noqa: E731
                                           xy=ip.xy[r], sigma_xy=ip.sigma_xy[r])
        project = replace(project, image_points=pick(keep), inactive_image_points=pick(rows))
        notes.append(f"{len(rows)} observations whose point lies behind its camera at the problem's values written "
                     "inactive (image_points.csv active = 0): a camera cannot image a point behind it, and COLMAP's "
                     "cost leaves them out too; their residuals are reported after the adjustment (set active = 1 "
                     "to adjust them)")
    return Scene(project=project, xyz_ground=bal.xyz_world.copy(), plate_units_per_pixel=1.0, notes=notes)


def project_to_bal(project: model.Project, xyz_ground: np.ndarray | None = None) -> tuple[BalProblem, list[str]]:
    """A BAL problem of project: one BAL camera per photo (its camera's c, k1, k2), one BAL point per
    object point with coordinates (xyz_ground, default the approximate coordinates or
    approximate_points), observations = plate coordinates (the plate unit is BAL's pixel).

    BAL's camera has the principal point at the origin and radial distortion applied to the
    projected point: a camera with xp, yp != 0, k3, p1, p2, b1, b2 != 0, or distortion in the plate
    convention is refused (InputError naming cameras.csv). Control is not written (a note says so)."""
    from scipy.spatial.transform import Rotation

    cams, photos, ip, pts = project.cameras, project.photos, project.image_points, project.points
    where = Path(project.source or ".") / "cameras.csv"
    for j, cid in enumerate(cams.ids):
        prm = cams.interior[j]
        if prm[lens.XP] != 0 or prm[lens.YP] != 0:
            raise InputError(where, None, f"camera {cid}: BAL's principal point is the origin of the image "
                                          f"coordinates; xp, yp = {float(prm[lens.XP])!r}, {float(prm[lens.YP])!r}")
        extra = prm[[lens.K3, lens.P1, lens.P2, lens.B1, lens.B2]]
        if np.any(extra != 0):
            raise InputError(where, None, f"camera {cid}: BAL's camera has only k1, k2; k3, p1, p2, b1, b2 are not 0")
        if cams.convention[j] != lens.IMAGE and np.any(prm[[lens.K1, lens.K2]] != 0):
            raise InputError(where, None, f"camera {cid}: distortion in the plate convention (a correction of the "
                                          "measured coordinates) has no BAL equivalent")
    if xyz_ground is None:
        xyz_ground = approximate_points(project)
        if pts.xyz_approx is not None:
            xyz_ground = np.where(np.isfinite(pts.xyz_approx).all(axis=1)[:, None], pts.xyz_approx, xyz_ground)
    known = np.isfinite(xyz_ground).all(axis=1)
    new_index = -np.ones(len(pts), dtype=np.int64)
    new_index[known] = np.arange(int(known.sum()))
    keep = known[ip.point_index]
    R_cw = np.swapaxes(photos.R_ground_from_cam, -1, -2)
    cam = photos.camera_index
    problem = BalProblem(
        path=None, rotation_cam_from_world=Rotation.from_matrix(R_cw).as_rotvec(),
        t_cam_from_world=-np.einsum("nij,nj->ni", R_cw, photos.xyz0),
        f=cams.interior[cam, lens.C].copy(), k1=cams.interior[cam, lens.K1].copy(), k2=cams.interior[cam, lens.K2].copy(),
        xyz_world=xyz_ground[known], camera_index=ip.photo_index[keep].copy(), point_index=new_index[ip.point_index[keep]],
        xy_pixel=ip.xy[keep].copy(), camera_lines=np.zeros(len(photos), dtype=np.int64),
    )
    notes = []
    if (~known).any():
        notes.append(f"{int((~known).sum())} points without coordinates left out with their {int((~keep).sum())} "
                     "image points")
    if np.any(pts.kind != model.TIE):
        notes.append("BAL has no control: point kinds, given coordinates and sigmas are not written")
    return problem, notes


# --------------------------------------------------------------------------- COLMAP -> project


def colmap_to_project(colmap: ColmapModel, pixel_size: float = 1.0, names: ColmapNames | None = None,
                      source: Path | None = None) -> Scene:
    """A striptri project of a COLMAP model (frames in the module doc). pixel_size: plate units per
    pixel (1.0: plate coordinates in pixels, [units] plate = "px"; otherwise mm per pixel, "mm":
    colmap_plate_unit). Photo ids are the image names; camera and point ids
    from names, else the COLMAP ids. Every COLMAP point is a tie point; observations without a 3D
    point are left out (counted in notes). Image sigma: one pixel. Raises InputError for a PINHOLE
    camera with fx != fy (striptri has one principal distance)."""
    names = names or ColmapNames()
    where = Path(source) / "cameras.txt" if source is not None else Path("cameras.txt")
    s = _check_pixel_size(pixel_size)
    fx, fy = colmap.focal[:, 0], colmap.focal[:, 1]
    unequal = np.flatnonzero(np.abs(fx - fy) > 1e-12 * np.abs(fx))
    if len(unequal):
        k = int(unequal[0])
        raise InputError(where, None, f"camera {colmap.camera_ids[k]}: PINHOLE with fx = {float(fx[k])!r} "
                                      f"!= fy = {float(fy[k])!r}; striptri's camera has one principal distance")
    half = colmap.width_height / 2.0
    interior = np.zeros((len(colmap.camera_ids), lens.NCP))
    interior[:, :3] = np.stack([fx * s, (colmap.principal[:, 0] - half[:, 0]) * s,
                                (half[:, 1] - colmap.principal[:, 1]) * s], 1)
    interior[:, lens.K1:lens.P2 + 1] = colmap_distortion_to_lens(colmap.distortion)
    R_cw = R_from_quaternion(colmap.q_cam_from_world)
    R_ground_from_cam = np.swapaxes(R_cw, -1, -2) @ D_STRIPTRI_FROM_COLMAP
    xyz0 = -np.einsum("nji,nj->ni", R_cw, colmap.t_cam_from_world)
    keep = colmap.obs_point3d_id != -1
    point_row = {int(pid): j for j, pid in enumerate(colmap.point3d_ids)}
    obs_image = colmap.obs_image[keep]
    obs_point = np.array([point_row[int(p)] for p in colmap.obs_point3d_id[keep]], dtype=np.int64)
    cam = colmap.image_camera[obs_image]
    uv = colmap.obs_xy[keep]
    xy = plate_from_pixel(uv, colmap.width_height[cam], s)
    pair = obs_image * max(len(point_row), 1) + obs_point
    _, first, counts = np.unique(pair, return_index=True, return_counts=True)
    if np.any(counts > 1):
        k = int(first[np.argmax(counts > 1)])
        raise InputError(Path(source or ".") / "images.txt", None,
                         f"image {colmap.image_names[obs_image[k]]} observes 3D point "
                         f"{colmap.obs_point3d_id[keep][k]} more than once")
    if len(set(colmap.image_names)) != len(colmap.image_names):
        raise InputError(Path(source or ".") / "images.txt", None, "two images have the same NAME (the photo id)")
    notes = []
    if (~keep).sum():
        notes.append(f"{int((~keep).sum())} image points without a 3D point left out")
    project = model.Project(
        cameras=model.Cameras(
            ids=[names.cameras.get(int(c), str(int(c))) for c in colmap.camera_ids],
            interior=interior, sigma_interior=np.full((len(colmap.camera_ids), 3), np.nan),
            convention=np.full(len(colmap.camera_ids), lens.IMAGE),
        ),
        photos=_photos(list(colmap.image_names), colmap.image_camera.copy(),
                       [names.strips.get(int(i), "") for i in colmap.image_ids], xyz0, R_ground_from_cam),
        image_points=model.ImagePoints(photo_index=obs_image, point_index=obs_point, xy=xy,
                                       sigma_xy=np.full((len(xy), 2), s)),
        points=_tie_points([names.points.get(int(p), str(int(p))) for p in colmap.point3d_ids]),
        settings=model.ProjectSettings(sigma_image=s, datum="inner", plate_unit=colmap_plate_unit(s)),
        source=source,
    )
    project = replace(project, points=replace(project.points, xyz_approx=colmap.xyz_world.copy()))
    return Scene(project=project, xyz_ground=colmap.xyz_world.copy(), plate_units_per_pixel=s, notes=notes)


def pixel_size_note(plate_unit: str, pixel_size: float, target: str) -> list[str]:
    """Notes on writing a project whose plate unit is plate_unit ("mm" or "px") as pixels of pixel_size
    plate units (COLMAP or DBAT output, target names it): a project in mm at 1 mm per pixel, or one
    in pixels at another size, is most likely a forgotten or a wrong --pixel-size."""
    if plate_unit == "mm" and pixel_size == 1.0:
        return [f"the project's plate coordinates are in mm and the pixel size is 1: one {target} pixel is 1 mm "
                "(give the pixel pitch in mm with --pixel-size, e.g. 0.005 for 5 um pixels)"]
    if plate_unit == "px" and pixel_size != 1.0:
        return [f"the project's plate coordinates are pixels ([units] plate = \"px\") and the pixel size is "
                f"{pixel_size:g}: one {target} pixel is {pixel_size:g} of the project's pixels"]
    return []


def colmap_plate_unit(pixel_size: float) -> str:
    """The plate unit (model.PLATE_UNITS) of a project converted from COLMAP at pixel_size plate
    units per pixel: "px" at 1 (the plate coordinates are the pixels), else "mm" (pixel_size is the
    pixel pitch in mm, e.g. 0.0045 for a 4.5 um sensor: a pixel of 1 mm does not occur).
    docs/decisions.md, "Plate units"."""
    return "px" if pixel_size == 1.0 else "mm"


# --------------------------------------------------------------------------- COLMAP distortion


def colmap_distortion_to_lens(dist: np.ndarray) -> np.ndarray:
    """COLMAP's OpenCV k1, k2, p1, p2 (ncam, 4) -> striptri's k1, k2, k3, p1, p2 (ncam, 5), image
    convention. COLMAP's tangential terms are ``du = 2 p1 u v + p2 (r^2 + 2u^2)`` in a frame with v
    down; striptri's (Brown) ``dx = p1 (r^2 + 2x^2) + 2 p2 x y`` with y up (x = u, y = -v), hence
    p1 = p2_colmap, p2 = -p1_colmap."""
    dist = np.asarray(dist, dtype=float).reshape(-1, 4)
    return np.column_stack([dist[:, 0], dist[:, 1], np.zeros(len(dist)), dist[:, 3], -dist[:, 2]])


def lens_to_colmap_distortion(prm: np.ndarray) -> np.ndarray:
    """The inverse of :func:`colmap_distortion_to_lens` (k3 must be 0). (ncam, NCP) -> (ncam, 4)."""
    prm = np.asarray(prm, dtype=float).reshape(-1, lens.NCP)
    return np.column_stack([prm[:, lens.K1], prm[:, lens.K2], -prm[:, lens.P2], prm[:, lens.P1]])


def _colmap_model_of(cams: model.Cameras, j: int, where) -> str:
    """COLMAP camera model of striptri camera j (the simplest that holds it), or InputError."""
    prm = cams.interior[j]
    dist = prm[lens.DISTORTION_ELEMENTS]
    if not np.any(dist != 0):
        return "SIMPLE_PINHOLE"
    if cams.convention[j] != lens.IMAGE:
        raise InputError(where, None, f"camera {cams.ids[j]} has distortion in the plate convention (a correction "
                                            "of the measured coordinates), which COLMAP's models cannot express")
    if prm[lens.K3] != 0 or prm[lens.B1] != 0 or prm[lens.B2] != 0:
        raise InputError(where, None, f"camera {cams.ids[j]}: k3, b1, b2 have no COLMAP model here "
                                            "(SIMPLE_RADIAL, RADIAL, OPENCV)")
    if prm[lens.P1] != 0 or prm[lens.P2] != 0:
        return "OPENCV"
    return "RADIAL" if prm[lens.K2] != 0 else "SIMPLE_RADIAL"


# --------------------------------------------------------------------------- project -> COLMAP


def project_to_colmap(project: model.Project, xyz_ground: np.ndarray | None = None,
                      pixel_size: float = 1.0) -> tuple[ColmapModel, ColmapNames, list[str]]:
    """A COLMAP model of project (per camera the simplest of SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL,
    OPENCV that holds it; plate-convention distortion is refused), its striptri names, and notes.

    xyz_ground: coordinates of the object points (nan = unknown); default approximate_points(project).
    Points without coordinates are not written; their image points get POINT3D_ID -1. pixel_size:
    plate units per pixel. Image size per camera: the smallest even W, H (pixels) whose centre-origin
    frame holds every measurement and the principal point, plus one pixel of margin."""
    s = _check_pixel_size(pixel_size)
    xyz = approximate_points(project) if xyz_ground is None else np.asarray(xyz_ground, dtype=float)
    cams, photos, ip = project.cameras, project.photos, project.image_points
    ncam = len(cams)
    cam_of_obs = photos.camera_index[ip.photo_index]
    extent = np.zeros((ncam, 2))
    np.maximum.at(extent, cam_of_obs, np.abs(ip.xy))
    extent = np.maximum(extent, np.abs(cams.interior[:, 1:3]))
    wh = 2 * (np.ceil(extent / s).astype(np.int64) + 1)
    half = wh / 2.0
    focal = np.repeat(cams.interior[:, :1] / s, 2, axis=1)
    principal = np.stack([half[:, 0] + cams.interior[:, 1] / s, half[:, 1] - cams.interior[:, 2] / s], 1)
    R_cw = D_STRIPTRI_FROM_COLMAP @ np.swapaxes(photos.R_ground_from_cam, -1, -2)
    t = -np.einsum("nij,nj->ni", R_cw, photos.xyz0)
    known = np.all(np.isfinite(xyz), axis=1)
    point3d_id = np.full(len(project.points), -1, dtype=np.int64)
    point3d_id[known] = np.arange(1, known.sum() + 1)
    uv = pixel_from_plate(ip.xy, wh[cam_of_obs], s)
    colmap = ColmapModel(
        camera_ids=np.arange(1, ncam + 1), camera_models=[_colmap_model_of(cams, j, Path(project.source or '.') / 'cameras.csv') for j in range(ncam)],
        width_height=wh, focal=focal, principal=principal, distortion=lens_to_colmap_distortion(cams.interior),
        image_ids=np.arange(1, len(photos) + 1), image_names=list(photos.ids),
        image_camera=photos.camera_index.copy(), q_cam_from_world=quaternion_from_R(R_cw), t_cam_from_world=t,
        obs_image=ip.photo_index.copy(), obs_xy=uv, obs_point3d_id=point3d_id[ip.point_index],
        point3d_ids=point3d_id[known], xyz_world=xyz[known],
        rgb=np.full((int(known.sum()), 3), 128, dtype=np.int64), error=np.zeros(int(known.sum())),
    )
    names = ColmapNames(
        cameras={k + 1: cid for k, cid in enumerate(cams.ids)},
        points={int(point3d_id[j]): project.points.ids[j] for j in np.flatnonzero(known)},
        strips={k + 1: sid for k, sid in enumerate(photos.strip_ids)},
    )
    notes = []
    lost = np.flatnonzero(~known)
    if len(lost):
        notes.append(f"{len(lost)} points without ground coordinates (fewer than two rays and not given) "
                     f"written without a 3D point: {', '.join(project.points.ids[j] for j in lost[:5])}"
                     + (" ..." if len(lost) > 5 else ""))
    if np.any(project.points.kind != model.TIE):
        notes.append("COLMAP has no control: point kinds, given coordinates and sigmas are not written")
    notes += pixel_size_note(project.settings.plate_unit, s, "COLMAP")
    return colmap, names, notes


def approximate_points(project: model.Project) -> np.ndarray:
    """Ground coordinates of every object point: the given X, Y, Z when all three are given, else
    the least-squares intersection of its rays from the photos' (approximate) orientations; nan for
    a point with fewer than two rays. -> (n_points, 3)."""
    ip, ph, pts, cams = project.image_points, project.photos, project.points, project.cameras
    n = len(pts)
    cam = ph.camera_index[ip.photo_index]
    ideal = lens.ideal_xy(ip.xy, cams.interior[cam], cams.convention[cam])
    r = ray_ground(ph.R_ground_from_cam[ip.photo_index], ideal, cams.interior[cam, :3])
    rh = r / np.linalg.norm(r, axis=1, keepdims=True)
    P = np.eye(3) - rh[:, :, None] * rh[:, None, :]
    lhs = np.zeros((n, 3, 3))
    rhs = np.zeros((n, 3))
    np.add.at(lhs, ip.point_index, P)
    np.add.at(rhs, ip.point_index, np.einsum("mij,mj->mi", P, ph.xyz0[ip.photo_index]))
    rays = np.bincount(ip.point_index, minlength=n)
    ok = rays >= 2
    xyz = np.full((n, 3), np.nan)
    if ok.any():
        xyz[ok] = np.linalg.solve(lhs[ok], rhs[ok][..., None])[..., 0]
    given = np.all(np.isfinite(pts.xyz_given), axis=1)
    xyz[given] = pts.xyz_given[given]
    return xyz


# --------------------------------------------------------------------------- helpers


def _check_pixel_size(pixel_size: float) -> float:
    s = float(pixel_size)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"pixel size must be a finite number > 0, got {pixel_size!r}")
    return s


def _photos(ids, camera_index, strip_ids, xyz0, R_ground_from_cam) -> model.Photos:
    """Photos with free (approximate) orientations; angles omega-phi-kappa of R_ground_from_cam."""
    n = len(ids)
    angles = rotations.opk_from_R(R_ground_from_cam)
    return model.Photos(
        ids=list(ids), camera_index=np.asarray(camera_index, dtype=np.int64), strip_ids=list(strip_ids),
        xyz0=np.asarray(xyz0, dtype=float), R_ground_from_cam=rotations.R_from_opk(angles), angles=angles,
        sigma_xyz0=np.full((n, 3), np.nan), sigma_angles=np.full((n, 3), np.nan),
    )


def _tie_points(ids) -> model.ObjectPoints:
    n = len(ids)
    return model.ObjectPoints(ids=list(ids), kind=np.full(n, model.TIE, dtype=np.int64),
                              xyz_given=np.full((n, 3), np.nan), sigma_given=np.full((n, 3), np.nan))
