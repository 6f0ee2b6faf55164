"""COLMAP text models: cameras.txt, images.txt, points3D.txt (docs/formats.md).

COLMAP conventions (https://colmap.github.io/format.html):

* ``images.txt``: per image a line ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` (the
  Hamilton quaternion and translation of ``cam_from_world``: ``P_cam = R X_world + t``) and a line of
  ``X Y POINT3D_ID`` triples (pixel coordinates, POINT3D_ID -1 when the point has none; the line
  may be empty);
* ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...``; only ``SIMPLE_PINHOLE`` (f, cx, cy)
  and ``PINHOLE`` (fx, fy, cx, cy) are read here; any other model is an error that names it;
* ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)...``; every track entry
  must name a 2D point of that image (0 <= POINT2D_IDX < its number of POINTS2D) whose POINT3D_ID
  is this point, and every 2D point with a POINT3D_ID must be in that point's track exactly once
  (:func:`_check_tracks`): a truncated images.txt fails instead of losing measurements;
* camera frame x right, y down, looking along +z; pixel coordinates with the origin at the
  top-left corner of the image (the centre of the first pixel is (0.5, 0.5)), y down.

Lines starting with ``#`` are comments. Everything is kept as struct of arrays; the conversion to
a striptri project is :mod:`striptri.formats.conversions`. Errors are InputError(file, line, reason).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from striptri.errors import InputError
from striptri.formats.bal import parse_number
from striptri.formats.colmap_models import LAYOUT, MODELS  # noqa: F401  (MODELS: this module's API too)
from striptri.io.csvtable import read_input_bytes

FILES = ("cameras.txt", "images.txt", "points3D.txt")


@dataclass(frozen=True)
class ColmapModel:
    """A COLMAP reconstruction (text model) as struct of arrays.

    Cameras: camera_ids (ncam,) int; camera_models list[str]; width_height (ncam, 2) int;
    focal (ncam, 2) fx, fy pixels; principal (ncam, 2) cx, cy pixels (top-left origin);
    distortion (ncam, 4) k1, k2, p1, p2 of COLMAP's OpenCV model (0 where the model has none).
    Images: image_ids (nimg,) int; image_names list[str]; image_camera (nimg,) index into cameras;
    q_cam_from_world (nimg, 4) qw, qx, qy, qz (unit); t_cam_from_world (nimg, 3).
    Observations (the POINTS2D of images.txt, in file order): obs_image (nobs,) index into images;
    obs_xy (nobs, 2) pixels; obs_point3d_id (nobs,) int, -1 = no 3D point.
    Points: point3d_ids (npts,) int; xyz_world (npts, 3); rgb (npts, 3) int; error (npts,).
    """

    camera_ids: np.ndarray
    camera_models: list[str]
    width_height: np.ndarray
    focal: np.ndarray
    principal: np.ndarray
    image_ids: np.ndarray
    image_names: list[str]
    image_camera: np.ndarray
    q_cam_from_world: np.ndarray
    t_cam_from_world: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray
    obs_point3d_id: np.ndarray
    point3d_ids: np.ndarray
    xyz_world: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    distortion: np.ndarray | None = None

    def __post_init__(self):
        if self.distortion is None:
            object.__setattr__(self, "distortion", np.zeros((len(self.camera_ids), 4)))


# --------------------------------------------------------------------------- quaternions


def R_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of Hamilton quaternions (qw, qx, qy, qz), normalised first. (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = (q[..., i] for i in range(4))
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quaternion_from_R(R: np.ndarray) -> np.ndarray:
    """Unit Hamilton quaternion (qw >= 0) of rotation matrices (Shepperd's method). (..., 3, 3) -> (..., 4)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.stack([tr, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], -1)
    k = np.argmax(d, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    r = lambda i, j: R[..., i, j]
    cand = [
        np.stack([1 + tr, r(2, 1) - r(1, 2), r(0, 2) - r(2, 0), r(1, 0) - r(0, 1)], -1),
        np.stack([r(2, 1) - r(1, 2), 1 + 2 * r(0, 0) - tr, r(0, 1) + r(1, 0), r(0, 2) + r(2, 0)], -1),
        np.stack([r(0, 2) - r(2, 0), r(0, 1) + r(1, 0), 1 + 2 * r(1, 1) - tr, r(1, 2) + r(2, 1)], -1),
        np.stack([r(1, 0) - r(0, 1), r(0, 2) + r(2, 0), r(1, 2) + r(2, 1), 1 + 2 * r(2, 2) - tr], -1),
    ]
    for i in range(4):
        q = np.where((k == i)[..., None], cand[i], q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


# --------------------------------------------------------------------------- reading


def read_colmap(folder: str | Path) -> ColmapModel:
    """Read the COLMAP model in folder: the binary model (cameras.bin, images.bin, points3D.bin,
    formats.colmap_binary) where all three are there, as COLMAP itself prefers it, else the text
    model (cameras.txt, images.txt, points3D.txt). Raises InputError; writes nothing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, None, "COLMAP model folder not found" if not folder.exists() else "is not a folder")
    if all((folder / f"{name}.bin").is_file() for name in ("cameras", "images", "points3D")):
        from striptri.formats.colmap_binary import read_binary

        cams, imgs, pts = read_binary(folder)
        binary = True
    else:
        cams = _read_cameras(folder / "cameras.txt")
        imgs = _read_images(folder / "images.txt", cams["index"])
        pts = _read_points(folder / "points3D.txt", imgs["index"])
        binary = False
    known = np.asarray(sorted(set(pts["ids"])), dtype=np.int64)
    obs_pid = np.asarray(imgs["obs_point3d_id"], dtype=np.int64)
    unknown = np.flatnonzero((obs_pid != -1) & ~np.isin(obs_pid, known))
    if len(unknown):
        i = int(unknown[0])
        name = "images.bin" if binary else "images.txt"
        reason = f"POINT3D_ID {obs_pid[i]} is not in points3D.{'bin' if binary else 'txt'}"
        raise (InputError(folder / name, None, f"record {imgs['obs_lines'][i]}: {reason}") if binary
               else InputError(folder / name, imgs["obs_lines"][i], reason))
    _check_tracks(folder, imgs, pts, binary)
    return ColmapModel(
        camera_ids=np.array(cams["ids"], dtype=np.int64),
        camera_models=cams["models"],
        width_height=np.array(cams["wh"], dtype=np.int64).reshape(-1, 2),
        focal=np.array(cams["focal"], dtype=float).reshape(-1, 2),
        principal=np.array(cams["principal"], dtype=float).reshape(-1, 2),
        distortion=np.array(cams["distortion"], dtype=float).reshape(-1, 4),
        image_ids=np.array(imgs["ids"], dtype=np.int64),
        image_names=imgs["names"],
        image_camera=np.array(imgs["camera"], dtype=np.int64),
        q_cam_from_world=np.array(imgs["q"], dtype=float).reshape(-1, 4),
        t_cam_from_world=np.array(imgs["t"], dtype=float).reshape(-1, 3),
        obs_image=np.array(imgs["obs_image"], dtype=np.int64),
        obs_xy=np.array(imgs["obs_xy"], dtype=float).reshape(-1, 2),
        obs_point3d_id=np.array(imgs["obs_point3d_id"], dtype=np.int64),
        point3d_ids=np.array(pts["ids"], dtype=np.int64),
        xyz_world=np.array(pts["xyz"], dtype=float).reshape(-1, 3),
        rgb=np.array(pts["rgb"], dtype=np.int64).reshape(-1, 3),
        error=np.array(pts["error"], dtype=float),
    )


def _check_tracks(folder: Path, imgs: dict, pts: dict, binary: bool = False) -> None:
    """Tracks of points3D against the POINTS2D of images (module doc). InputError naming the file
    and line (the text model) or record (the binary one: the lines below are record numbers) of
    the first disagreement."""
    suffix = ".bin" if binary else ".txt"
    images_txt, points_txt = folder / f"images{suffix}", folder / f"points3D{suffix}"
    unit = "record" if binary else "line"

    def error(path, where, reason):  # noqa: ANN001
        return InputError(path, None, f"record {where}: {reason}") if binary else InputError(path, where, reason)

    n_img = len(imgs["ids"])
    obs_image = np.asarray(imgs["obs_image"], dtype=np.int64)
    obs_pid = np.asarray(imgs["obs_point3d_id"], dtype=np.int64)
    count = np.bincount(obs_image, minlength=n_img)
    start = np.concatenate([[0], np.cumsum(count)])[:n_img]  # observations are stored image by image
    t_image = np.asarray(pts["track_image"], dtype=np.int64)
    t_idx = np.asarray(pts["track_idx"], dtype=np.int64)
    t_pid = np.asarray(pts["track_pid"], dtype=np.int64)
    t_line = np.asarray(pts["track_line"], dtype=np.int64)
    outside = np.flatnonzero((t_idx < 0) | (t_idx >= count[t_image]))
    if len(outside):
        k = int(outside[0])
        img = int(t_image[k])
        raise error(points_txt, int(t_line[k]),
                         f"track entry (IMAGE_ID {imgs['ids'][img]}, POINT2D_IDX {int(t_idx[k])}): image "
                         f"{imgs['ids'][img]} has {int(count[img])} 2D points in {images_txt.name} ({unit} "
                         f"{imgs['lines'][img]}); is {images_txt.name} complete?")
    obs = start[t_image] + t_idx
    wrong = np.flatnonzero(obs_pid[obs] != t_pid)
    if len(wrong):
        k = int(wrong[0])
        raise error(points_txt, int(t_line[k]),
                         f"track of POINT3D_ID {int(t_pid[k])} names 2D point {int(t_idx[k])} of IMAGE_ID "
                         f"{imgs['ids'][int(t_image[k])]}, whose POINT3D_ID in {images_txt.name} ({unit} "
                         f"{imgs['obs_lines'][int(obs[k])]}) is {int(obs_pid[obs[k]])}")
    uses = np.bincount(obs, minlength=len(obs_pid))
    twice = np.flatnonzero(uses > 1)
    if len(twice):
        o = int(twice[0])
        k = int(np.flatnonzero(obs == o)[1])
        raise error(points_txt, int(t_line[k]),
                         f"2D point {int(t_idx[k])} of IMAGE_ID {imgs['ids'][int(t_image[k])]} is in a track twice")
    missing = np.flatnonzero((obs_pid != -1) & (uses == 0))
    if len(missing):
        o = int(missing[0])
        img = int(obs_image[o])
        raise error(images_txt, imgs["obs_lines"][o],
                         f"2D point {o - int(start[img])} of IMAGE_ID {imgs['ids'][img]} has POINT3D_ID "
                         f"{int(obs_pid[o])}, but the track of that point in {points_txt.name} does not name it")


def _lines(path: Path) -> list[tuple[int, str]]:
    """Physical (1-based number, stripped text) of every line of path."""
    raw = read_input_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, raw[: exc.start].count(b"\n") + 1, "not valid UTF-8 text") from None
    return [(n, line.strip()) for n, line in enumerate(text.splitlines(), start=1)]


def _data(lines):
    return [(n, s) for n, s in lines if s and not s.startswith("#")]


def _int(path, line, name, token) -> int:
    try:
        return int(token)
    except ValueError:
        raise InputError(path, line, f"{name} '{token}' is not an integer") from None


_float = parse_number  # one parser of numbers for the text formats (formats.bal)


def _read_cameras(path: Path) -> dict:
    out = {"ids": [], "models": [], "wh": [], "focal": [], "principal": [], "distortion": [], "index": {}}
    for n, text in _data(_lines(path)):
        tokens = text.split()
        if len(tokens) < 4:
            raise InputError(path, n, "camera line must be 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
        cid = _int(path, n, "CAMERA_ID", tokens[0])
        model = tokens[1]
        if model not in MODELS:
            raise InputError(path, n, f"camera model {model} is not supported (one of {', '.join(MODELS)})")
        params = [_float(path, n, f"{model} parameter", t) for t in tokens[4:]]
        if len(params) != MODELS[model]:
            raise InputError(path, n, f"{model} has {MODELS[model]} parameters, found {len(params)}")
        if cid in out["index"]:
            raise InputError(path, n, f"CAMERA_ID {cid} occurs twice")
        ifx, ify, icx, icy, idist = LAYOUT[model]
        f = (params[ifx], params[ifx if ify is None else ify])
        if min(f) <= 0:
            raise InputError(path, n, f"focal length must be > 0, found {' '.join(tokens[4:])} ({model} parameters)")
        out["index"][cid] = len(out["ids"])
        out["ids"].append(cid)
        out["models"].append(model)
        width, height = _int(path, n, "WIDTH", tokens[2]), _int(path, n, "HEIGHT", tokens[3])
        if width <= 0 or height <= 0:
            raise InputError(path, n, f"image size WIDTH HEIGHT must be positive pixels, found {tokens[2]} {tokens[3]}")
        out["wh"].append((width, height))
        out["focal"].append(f)
        out["principal"].append((params[icx], params[icy]))
        out["distortion"].append(tuple(0.0 if i is None else params[i] for i in idist))
    return out


def _read_images(path: Path, camera_index: dict) -> dict:
    out = {"ids": [], "names": [], "camera": [], "q": [], "t": [], "index": {}, "lines": [],
           "obs_image": [], "obs_xy": [], "obs_point3d_id": [], "obs_lines": []}
    lines = _lines(path)
    names: dict[str, int] = {}  # image NAME -> its IMAGE_ID
    i = 0
    while i < len(lines):
        n, text = lines[i]
        i += 1
        if not text or text.startswith("#"):
            continue
        tokens = text.split(maxsplit=9)
        if len(tokens) != 10:
            raise InputError(path, n, "image line must be 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        iid = _int(path, n, "IMAGE_ID", tokens[0])
        if iid in out["index"]:
            raise InputError(path, n, f"IMAGE_ID {iid} occurs twice")
        q = [_float(path, n, name, t) for name, t in zip(("QW", "QX", "QY", "QZ"), tokens[1:5])]
        if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-6:
            raise InputError(path, n, "the quaternion QW QX QY QZ is not of unit length")
        t = [_float(path, n, name, tok) for name, tok in zip(("TX", "TY", "TZ"), tokens[5:8])]
        cid = _int(path, n, "CAMERA_ID", tokens[8])
        if cid not in camera_index:
            raise InputError(path, n, f"CAMERA_ID {cid} is not in cameras.txt")
        if tokens[9] in names:
            raise InputError(path, n, f"image NAME '{tokens[9]}' occurs twice (also IMAGE_ID {names[tokens[9]]}): "
                                      "two images would become one photo")
        names[tokens[9]] = iid
        k = len(out["ids"])
        out["index"][iid] = k
        out["ids"].append(iid)
        out["q"].append(q)
        out["t"].append(t)
        out["camera"].append(camera_index[cid])
        out["names"].append(tokens[9])
        out["lines"].append(n)
        # the POINTS2D line follows directly (it may be empty)
        if i >= len(lines):
            break
        n2, text2 = lines[i]
        i += 1
        values = text2.split()
        if len(values) % 3:
            raise InputError(path, n2, "POINTS2D line must hold triples 'X Y POINT3D_ID'")
        here: set[int] = set()
        for j in range(0, len(values), 3):
            pid = _int(path, n2, "POINT3D_ID", values[j + 2])
            if pid != -1 and pid in here:
                raise InputError(path, n2, f"POINT3D_ID {pid} is observed twice in image {iid}: one image measures "
                                           "a point once")
            here.add(pid)
            out["obs_image"].append(k)
            out["obs_xy"].append((_float(path, n2, "X", values[j]), _float(path, n2, "Y", values[j + 1])))
            out["obs_point3d_id"].append(pid)
            out["obs_lines"].append(n2)
    return out


def _read_points(path: Path, image_index: dict) -> dict:
    out = {"ids": [], "xyz": [], "rgb": [], "error": [], "track_image": [], "track_idx": [], "track_pid": [],
           "track_line": []}
    seen: set[int] = set()
    for n, text in _data(_lines(path)):
        tokens = text.split()
        if len(tokens) < 8 or (len(tokens) - 8) % 2:
            raise InputError(path, n, "point line must be 'POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)...'")
        pid = _int(path, n, "POINT3D_ID", tokens[0])
        if pid in seen:
            raise InputError(path, n, f"POINT3D_ID {pid} occurs twice")
        seen.add(pid)
        for j in range(8, len(tokens), 2):
            image_id = _int(path, n, "IMAGE_ID", tokens[j])
            if image_id not in image_index:
                raise InputError(path, n, f"track names IMAGE_ID {tokens[j]}, which is not in images.txt")
            out["track_image"].append(image_index[image_id])
            out["track_idx"].append(_int(path, n, "POINT2D_IDX", tokens[j + 1]))
            out["track_pid"].append(pid)
            out["track_line"].append(n)
        out["ids"].append(pid)
        out["xyz"].append([_float(path, n, name, t) for name, t in zip("XYZ", tokens[1:4])])
        out["rgb"].append([_int(path, n, name, t) for name, t in zip("RGB", tokens[4:7])])
        out["error"].append(_float(path, n, "ERROR", tokens[7]))
    return out


# --------------------------------------------------------------------------- writing


def colmap_files(m: ColmapModel) -> dict[str, str]:
    """Text of cameras.txt, images.txt and points3D.txt of m (floats by repr; tracks from the
    observations with a 3D point)."""
    cams = ["# Camera list with one line of data per camera:",
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"# Number of cameras: {len(m.camera_ids)}"]
    for k, cid in enumerate(m.camera_ids):
        model = m.camera_models[k]
        ifx, ify, icx, icy, idist = LAYOUT[model]
        params = [0.0] * MODELS[model]
        params[ifx], params[icx], params[icy] = m.focal[k, 0], m.principal[k, 0], m.principal[k, 1]
        if ify is not None:
            params[ify] = m.focal[k, 1]
        for value, i in zip(m.distortion[k], idist):
            if i is not None:
                params[i] = value
        cams.append(" ".join([str(int(cid)), m.camera_models[k], str(int(m.width_height[k, 0])),
                              str(int(m.width_height[k, 1]))] + [repr(float(v)) for v in params]))
    point2d_idx = np.zeros(len(m.obs_image), dtype=np.int64)
    imgs = ["# Image list with two lines of data per image:",
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
            "#   POINTS2D[] as (X, Y, POINT3D_ID)",
            (f"# Number of images: {len(m.image_ids)}, mean observations per image: "
             f"{len(m.obs_image) / max(len(m.image_ids), 1):.6g}")]
    order = np.argsort(m.obs_image, kind="stable")
    starts = np.searchsorted(m.obs_image[order], np.arange(len(m.image_ids) + 1))
    for k, iid in enumerate(m.image_ids):
        values = list(m.q_cam_from_world[k]) + list(m.t_cam_from_world[k])
        imgs.append(" ".join([str(int(iid))] + [repr(float(v)) for v in values]
                             + [str(int(m.camera_ids[m.image_camera[k]])), m.image_names[k]]))
        rows = order[starts[k] : starts[k + 1]]
        point2d_idx[rows] = np.arange(len(rows))
        imgs.append(" ".join(f"{float(m.obs_xy[r, 0])!r} {float(m.obs_xy[r, 1])!r} {int(m.obs_point3d_id[r])}"
                             for r in rows))
    has3d = np.flatnonzero(m.obs_point3d_id != -1)
    by_point = {}
    for r in has3d[np.argsort(m.obs_point3d_id[has3d], kind="stable")]:
        by_point.setdefault(int(m.obs_point3d_id[r]), []).append(r)
    n_obs = len(has3d)
    pts = ["# 3D point list with one line of data per point:",
           "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
           f"# Number of points: {len(m.point3d_ids)}, mean track length: {n_obs / max(len(m.point3d_ids), 1):.6g}"]
    for k, pid in enumerate(m.point3d_ids):
        track = " ".join(f"{int(m.image_ids[m.obs_image[r]])} {int(point2d_idx[r])}" for r in by_point.get(int(pid), []))
        fields = [str(int(pid))] + [repr(float(v)) for v in m.xyz_world[k]] + [str(int(v)) for v in m.rgb[k]]
        fields.append(repr(float(m.error[k])))
        pts.append(" ".join(fields) + (" " + track if track else ""))
    return {"cameras.txt": "\n".join(cams) + "\n", "images.txt": "\n".join(imgs) + "\n",
            "points3D.txt": "\n".join(pts) + "\n"}
