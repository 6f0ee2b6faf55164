"""COLMAP binary models: cameras.bin, images.bin, points3D.bin (issue 28; docs/formats.md).

The layout of COLMAP's ``read_write_model.py`` (all little-endian):

* cameras.bin: uint64 number of cameras; per camera int32 CAMERA_ID, int32 MODEL_ID, uint64 WIDTH,
  uint64 HEIGHT, then the model's parameters as doubles;
* images.bin: uint64 number of images; per image int32 IMAGE_ID, 4 doubles QW QX QY QZ, 3 doubles
  TX TY TZ, int32 CAMERA_ID, the NAME as bytes ending in a zero byte, uint64 number of 2D points,
  then per 2D point doubles X, Y and int64 POINT3D_ID (-1: none);
* points3D.bin: uint64 number of points; per point uint64 POINT3D_ID, 3 doubles X Y Z, 3 uint8
  R G B, double ERROR, uint64 track length, then per track entry int32 IMAGE_ID, int32 POINT2D_IDX.

The records are read into the same tables the text reader makes (formats.colmap), so both models
of one reconstruction give the same ColmapModel and the same project, and every check of the text
model holds here too; a message names the file and the record (0-based, in file order). The 2D
points and track entries are read as numpy record arrays; only the per-image and per-point headers
(whose lengths vary) are walked one by one.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from striptri.errors import InputError
from striptri.formats.colmap_models import LAYOUT, MODELS
from striptri.io.csvtable import read_input_bytes

# COLMAP's camera model ids and their numbers of parameters (src/colmap/sensor/models.h)
MODEL_IDS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
             4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
             8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12)}
_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
_TRACK = np.dtype([("image", "<i4"), ("idx", "<i4")])


class _Reader:
    """Sequential little-endian reads of one file; InputError at its end."""

    def __init__(self, path: Path):
        self.path, self.data, self.at = path, read_input_bytes(path), 0
        self.record = None

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.at + size > len(self.data):
            self.fail("the file ends inside it: is it complete?")
        values = struct.unpack_from(fmt, self.data, self.at)
        self.at += size
        return values

    def array(self, dtype: np.dtype, n: int) -> np.ndarray:
        if n < 0 or self.at + n * dtype.itemsize > len(self.data):
            self.fail("the file ends inside it: is it complete?")
        out = np.frombuffer(self.data, dtype=dtype, count=n, offset=self.at)
        self.at += n * dtype.itemsize
        return out

    def name(self) -> str:
        end = self.data.find(b"\x00", self.at)
        if end < 0:
            self.fail("the image NAME has no terminating zero byte")
        raw = self.data[self.at:end]
        self.at = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self.fail("the image NAME is not UTF-8")

    def fail(self, reason: str):
        where = "" if self.record is None else f"record {self.record}: "
        raise InputError(self.path, None, f"{where}{reason}")

    def done(self) -> None:
        if self.at != len(self.data):
            self.record = None
            self.fail(f"{len(self.data) - self.at} bytes after the last record")


def read_binary(folder: Path) -> tuple[dict, dict, dict]:
    """The tables of cameras.bin, images.bin and points3D.bin (as formats.colmap's text readers
    make them, record numbers in place of line numbers)."""
    cams = _cameras(folder / "cameras.bin")
    imgs = _images(folder / "images.bin", cams["index"])
    pts = _points(folder / "points3D.bin", imgs["index"])
    return cams, imgs, pts


def _cameras(path: Path) -> dict:
    out = {"ids": [], "models": [], "wh": [], "focal": [], "principal": [], "distortion": [], "index": {}}
    r = _Reader(path)
    (n,) = r.take("<Q")
    for k in range(n):  # one record per camera
        r.record = k
        cid, model_id, width, height = r.take("<iiQQ")
        if model_id not in MODEL_IDS:
            r.fail(f"MODEL_ID {model_id} is not a COLMAP camera model")
        model, n_params = MODEL_IDS[model_id]
        params = r.take(f"<{n_params}d")
        if model not in MODELS:
            r.fail(f"camera model {model} is not supported (one of {', '.join(MODELS)})")
        if cid in out["index"]:
            r.fail(f"CAMERA_ID {cid} occurs twice")
        ifx, ify, icx, icy, idist = LAYOUT[model]
        f = (params[ifx], params[ifx if ify is None else ify])
        if not min(f) > 0:
            r.fail(f"focal length must be > 0, found {' '.join(map(repr, params))} ({model} parameters)")
        if width <= 0 or height <= 0:
            r.fail(f"image size WIDTH HEIGHT must be positive pixels, found {width} {height}")
        out["index"][cid] = len(out["ids"])
        out["ids"].append(cid)
        out["models"].append(model)
        out["wh"].append((width, height))
        out["focal"].append(f)
        out["principal"].append((params[icx], params[icy]))
        out["distortion"].append(tuple(0.0 if i is None else params[i] for i in idist))
    r.done()
    return out


def _images(path: Path, camera_index: dict) -> dict:
    out = {"ids": [], "names": [], "camera": [], "q": [], "t": [], "index": {}, "lines": [],
           "obs_image": [], "obs_xy": [], "obs_point3d_id": [], "obs_lines": []}
    r = _Reader(path)
    (n,) = r.take("<Q")
    names: dict[str, int] = {}
    points = []
    for k in range(n):  # one record per image (its 2D points read as one array)
        r.record = k
        iid, qw, qx, qy, qz, tx, ty, tz, cid = r.take("<i7di")
        name = r.name()
        (n2d,) = r.take("<Q")
        p2d = r.array(_POINT2D, n2d)
        if iid in out["index"]:
            r.fail(f"IMAGE_ID {iid} occurs twice")
        if not abs(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz) - 1.0) <= 1e-6:
            r.fail("the quaternion QW QX QY QZ is not of unit length")
        if not np.isfinite([tx, ty, tz]).all() or not np.isfinite(p2d["x"]).all() or not np.isfinite(p2d["y"]).all():
            r.fail("a translation or 2D point is not a finite number")
        if cid not in camera_index:
            r.fail(f"CAMERA_ID {cid} is not in cameras.bin")
        if name in names:
            r.fail(f"image NAME '{name}' occurs twice (also IMAGE_ID {names[name]}): two images would become one photo")
        ids = p2d["id"][p2d["id"] != -1]
        if len(np.unique(ids)) != len(ids):
            unique, inverse = np.unique(ids, return_inverse=True)
            twice = int(unique[np.flatnonzero(np.bincount(inverse) > 1)[0]])
            r.fail(f"POINT3D_ID {twice} is observed twice in image {iid}: one image measures a point once")
        names[name] = iid
        out["index"][iid] = k
        out["ids"].append(iid)
        out["q"].append([qw, qx, qy, qz])
        out["t"].append([tx, ty, tz])
        out["camera"].append(camera_index[cid])
        out["names"].append(name)
        out["lines"].append(k)
        points.append(p2d)
    r.done()
    counts = [len(p) for p in points]
    every = np.concatenate(points) if points else np.zeros(0, dtype=_POINT2D)
    out["obs_image"] = np.repeat(np.arange(len(points)), counts)
    out["obs_xy"] = np.column_stack([every["x"], every["y"]]).reshape(-1, 2)
    out["obs_point3d_id"] = every["id"].astype(np.int64)
    out["obs_lines"] = out["obs_image"]  # the record of the image
    return out


def _points(path: Path, image_index: dict) -> dict:
    out = {"ids": [], "xyz": [], "rgb": [], "error": [], "track_image": [], "track_idx": [], "track_pid": [],
           "track_line": []}
    r = _Reader(path)
    (n,) = r.take("<Q")
    tracks = []
    seen: set[int] = set()
    known = np.array(sorted(image_index), dtype=np.int64)
    position = np.array([image_index[i] for i in known], dtype=np.int64)
    for k in range(n):  # one record per point (its track read as one array)
        r.record = k
        pid, x, y, z, red, green, blue, error, length = r.take("<Q3d3BdQ")
        track = r.array(_TRACK, length)
        if pid in seen:
            r.fail(f"POINT3D_ID {pid} occurs twice")
        seen.add(pid)
        where = np.searchsorted(known, track["image"])
        bad = (where >= len(known)) | (known[np.minimum(where, len(known) - 1)] != track["image"]) if len(known) else \
            np.ones(len(track), dtype=bool)
        if bad.any():
            r.fail(f"track names IMAGE_ID {int(track['image'][np.flatnonzero(bad)[0]])}, which is not in images.bin")
        out["ids"].append(pid)
        out["xyz"].append([x, y, z])
        out["rgb"].append([red, green, blue])
        out["error"].append(error)
        tracks.append((position[where], track["idx"].astype(np.int64), pid, k))
    r.done()
    if tracks:
        out["track_image"] = np.concatenate([t[0] for t in tracks])
        out["track_idx"] = np.concatenate([t[1] for t in tracks])
        out["track_pid"] = np.repeat([t[2] for t in tracks], [len(t[1]) for t in tracks]).astype(np.int64)
        out["track_line"] = np.repeat([t[3] for t in tracks], [len(t[1]) for t in tracks])
    return out
