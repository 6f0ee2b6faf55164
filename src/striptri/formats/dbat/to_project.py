"""DBAT -> striptri: a :class:`~striptri.formats.dbat.reader.DbatProject` as a striptri project
(:func:`dbat_to_project`), with the pixel-to-plate and camera conventions that take DBAT's to
striptri's (:func:`pixels_to_plate`, :func:`striptri_camera`). No file is opened here.

Pixel centre convention: DBAT scales pixel coordinates to the sensor without a half-pixel shift;
its default principal point, half the sensor, is pixel coordinate (W/2, H/2), so the image corner
is (0, 0) and the centre of the top-left pixel is (0.5, 0.5). Plate coordinates (mm, x right, y
up, origin at the principal point): ``x = (col * ph - px) / aspect``, ``y = py - row * ph``
(``x = col * pw - px`` for square pixels). Checked on camcal: DBAT's result camera and camera
stations reproject the control points with mean residual 0.005 px; a half-pixel shift gives 0.5 px.
DBAT's omega, phi, kappa give R_ground_from_cam = Rx(omega) Ry(phi) Rz(kappa), striptri's
``rotations.R_from_opk`` (same check).
"""

from __future__ import annotations

import math

import numpy as np

from striptri.geometry import lens, rotations
from striptri import model
from striptri.errors import InputError, NumericalFailure
from striptri.formats.dbat.reader import DbatCamera, DbatProject
from striptri.formats.scene import Scene, photo_datum
from striptri.geometry.lens import NCP
from striptri.equations.resection import resect_missing


def plate_origin(camera: DbatCamera) -> tuple[float, float]:
    """Where the plate origin lies in DBAT's scaled sensor coordinates (col * ph, row * ph): chosen
    so that DBAT's principal point is xp = yp = 0 (module doc)."""
    return camera.pp[0], camera.pp[1]


def pixels_to_plate(camera: DbatCamera, xy_pixel: np.ndarray) -> np.ndarray:
    """Pixel coordinates (column, row; corner origin, y down) -> plate mm (x right, y up, origin at
    the camera's principal point): ``x = col * ph - px``, ``y = py - row * ph``, ph = sensor H /
    image H, no half-pixel shift. The aspect acts in the camera model (b1 = 1/aspect - 1, about
    the principal point: ``(1 + b1)(x - xp)``). Checked against DBAT's own result on camcal
    (tests/test_dbat.py)."""
    xy_pixel = np.asarray(xy_pixel, dtype=float)
    ph = camera.pixel_size[1]
    x0, y0 = plate_origin(camera)
    return np.stack([xy_pixel[..., 0] * ph - x0, y0 - xy_pixel[..., 1] * ph], axis=-1)


# DBAT's interior names -> striptri's camera elements (lens.CAMERA_ELEMENTS)
ELEMENT_OF = {"cc": "c", "px": "xp", "py": "yp", "K1": "k1", "K2": "k2", "K3": "k3", "P1": "p1", "P2": "p2",
               "as": "b1", "sk": "b2"}


def striptri_camera(camera: DbatCamera, reference: DbatCamera | None = None) -> np.ndarray:
    """striptri's camera elements (NCP,) of a DBAT camera, plate convention, plate frame of
    ``reference`` (default: the camera itself; pixels_to_plate of the reference camera).

    K, P and the skew carry over unchanged (DBAT's reprojection of camcal's control through its own
    result decides it: a sign change of P2 leaves a 0.32 px bias in y), b1 = 1/aspect - 1 (DBAT's
    'as', scaling x about the principal point); the principal point: ``xp = px - x0``,
    ``yp = y0 - py`` with (x0, y0) the reference's plate origin."""
    ref = reference or camera
    x0, y0 = plate_origin(ref)
    b1 = 1.0 / camera.aspect - 1.0
    prm = np.zeros(NCP)
    prm[lens.C] = camera.cc
    prm[lens.XP] = camera.pp[0] - x0
    prm[lens.YP] = y0 - camera.pp[1]
    prm[lens.K1:lens.K3 + 1] = camera.K
    prm[lens.P1], prm[lens.P2] = camera.P
    prm[lens.B1], prm[lens.B2] = b1, camera.skew
    return prm


def _plate_unit(dbat_unit: str) -> str:
    """The project's plate unit (model.PLATE_UNITS) for a DBAT camera's <unit>: "px" for pixels (as
    the DBAT writer labels a pixel project), else "mm", DBAT's usual unit."""
    return "px" if dbat_unit.strip().lower() in ("px", "pixel", "pixels") else "mm"


def dbat_to_project(dbat: DbatProject, drop_distortion: bool = False) -> Scene:
    """A striptri project of a DBAT project; Scene.project is the model.Project.

    Plate coordinates in mm (pixels_to_plate), the camera in the plate convention with DBAT's
    model 3 (striptri_camera; its estimated elements free, the others held), image sigmas scaled
    by the pixel height, control fixed (nan) or weighted as read. drop_distortion: hold K, P at 0
    (a pinhole camera; said in Scene.notes). Approximate orientations come from prior_eo when
    present (DBAT's omega-phi-kappa is striptri's); the images without one are resected from the
    control (resection.resect_missing, as the script's spatial_resection). DBAT's datum
    ``depend`` (the first camera and one coordinate of the longest base held) becomes held
    elements of photos.csv (:func:`_depend_datum`)."""
    cam = dbat.camera
    notes: list[str] = []
    if cam.model not in (None, 3):
        notes.append(f"DBAT lens model {cam.model} read as model 3 (backward Brown, aspect before and skew after "
                     "the distortion); the other models differ in the order of aspect and skew")
    prm = striptri_camera(cam)
    sigma = np.full(NCP, np.nan)
    for name, element in ELEMENT_OF.items():
        if cam.estimated.get(name):
            sigma[lens.CAMERA_ELEMENTS.index(element)] = math.inf
    if drop_distortion:
        dist = cam.distortion()
        nonzero = ", ".join(f"{k} = {v!r}" for k, v in dist.items() if v != 0) or "all zero"
        prm[lens.K1:lens.P2 + 1] = 0.0
        sigma[lens.K1:lens.P2 + 1] = np.nan
        notes.append(f"DBAT distortion dropped (drop_distortion): {nonzero}")
    est = [n for n in ELEMENT_OF if cam.estimated.get(n)]
    if est:
        notes.append("camera elements estimated as in the script: " + ", ".join(ELEMENT_OF[n] for n in est))

    photo_of = {iid: i for i, iid in enumerate(dbat.image_ids)}
    point_ids = list(dict.fromkeys(list(dbat.ctrl_ids) + list(dbat.ip_point)))
    point_of = {pid: j for j, pid in enumerate(point_ids)}
    n = len(point_ids)
    kind = np.full(n, model.TIE, dtype=np.int64)
    xyz_given = np.full((n, 3), np.nan)
    sigma_given = np.full((n, 3), np.nan)
    for k, cid in enumerate(dbat.ctrl_ids):
        j = point_of[cid]
        kind[j] = model.FULL
        xyz_given[j] = dbat.ctrl_xyz[k]
        sigma_given[j] = dbat.ctrl_sigma[k]

    nim = dbat.n_images
    xyz0 = np.full((nim, 3), np.nan)
    angles = np.zeros((nim, 3))
    prior = {pid: k for k, pid in enumerate(dbat.prior_ids)}
    have = [i for i, iid in enumerate(dbat.image_ids) if iid in prior]
    for i in have:
        k = prior[dbat.image_ids[i]]
        xyz0[i] = dbat.prior_xyz[k]
        angles[i] = dbat.prior_angles[k]
    if have:
        notes.append(f"approximate orientations of {len(have)} of {nim} images from prior_eo (DBAT's "
                     "omega-phi-kappa is striptri's omega-phi-kappa)")
    if len(have) < nim:
        notes.append(f"{nim - len(have)} images have no approximate orientation in the script: resected from the "
                     "control (DBAT's spatial_resection)")
    R = rotations.R_from_opk(angles)
    pw, ph = cam.pixel_size
    photos = model.Photos(
        ids=list(dbat.image_names), camera_index=np.zeros(nim, dtype=np.int64), strip_ids=[""] * nim,
        xyz0=xyz0, R_ground_from_cam=R, angles=angles,
        sigma_xyz0=np.full((nim, 3), np.nan), sigma_angles=np.full((nim, 3), np.nan),
    )
    datum = "control" if dbat.n_control else "inner"
    if dbat.datum and dbat.datum.get("type") == "depend":
        photos, note = _depend_datum(dbat, photos)
        notes.append(note)
        datum = "control"
    elif dbat.datum:
        notes.append(f"DBAT datum {dbat.datum} is not reproduced; striptri's datum is '{datum}'")
    project = model.Project(
        cameras=model.Cameras(ids=[cam.id], interior=prm[None, :], sigma_interior=sigma[None, :],
                              convention=np.array([lens.PLATE])),
        photos=photos,
        image_points=model.ImagePoints(
            photo_index=np.array([photo_of[i] for i in dbat.ip_image], dtype=np.int64),
            point_index=np.array([point_of[p] for p in dbat.ip_point], dtype=np.int64),
            xy=pixels_to_plate(cam, dbat.ip_xy),
            sigma_xy=dbat.ip_sigma * ph,
        ),
        points=model.ObjectPoints(ids=point_ids, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given),
        settings=model.ProjectSettings(angle_unit="deg", plate_unit=_plate_unit(dbat.camera.unit), sigma_image=float(np.median(dbat.ip_sigma) * ph)
                                       if dbat.n_image_points else 0.005,
                                       datum=datum),
        source=dbat.path,
    )
    if len(have) < nim:
        try:
            project, more = resect_missing(project)
            notes += more
        except NumericalFailure as exc:
            notes.append(f"{exc}; approximations must come from elsewhere")
    return Scene(project=project, xyz_ground=xyz_given.copy(), plate_units_per_pixel=float(ph), notes=notes)


def _depend_datum(dbat: DbatProject, photos: model.Photos):
    """DBAT's ``set_datum depend`` (ref_cam, ref_base="longest"): :func:`photo_datum` of the
    reference camera. -> (photos, note)."""
    ref_id = str(dbat.datum.get("ref_cam", dbat.image_ids[0]))
    if ref_id not in dbat.image_ids:
        raise InputError(dbat.path, None, f"set_datum names ref_cam '{ref_id}', which is not an image id")
    if not np.isfinite(photos.xyz0).all():
        raise InputError(dbat.path, None, "set_datum depend needs approximate positions of every camera (prior_eo)")
    return photo_datum(photos, dbat.image_ids.index(ref_id), dbat.project_unit)
