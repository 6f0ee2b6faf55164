"""COLMAP's binary model (issue 28; formats.colmap_binary): the binary and the text model of the
same reconstruction give the same model and the same project, and broken files are named.

The binary files are written here record by record after COLMAP's read_write_model.py
(write_cameras_binary, write_images_binary, write_points3D_binary), independently of the reader."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from striptri.errors import InputError
from striptri.formats import approximate_points, colmap_files, colmap_to_project, project_to_colmap, read_colmap
from striptri.io import read_project
from striptri.io.project_writer import project_files

STRIP8 = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "strip8"
MODEL_ID = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4}


def _binary_files(m) -> dict[str, bytes]:
    cams = [struct.pack("<Q", len(m.camera_ids))]
    for k, cid in enumerate(m.camera_ids):
        model = m.camera_models[k]
        fx, fy = m.focal[k]
        cx, cy = m.principal[k]
        params = {"SIMPLE_PINHOLE": (fx, cx, cy), "PINHOLE": (fx, fy, cx, cy)}[model]
        cams.append(struct.pack("<iiQQ", int(cid), MODEL_ID[model], *map(int, m.width_height[k]))
                    + struct.pack(f"<{len(params)}d", *params))
    images = [struct.pack("<Q", len(m.image_ids))]
    for k, iid in enumerate(m.image_ids):
        rows = np.flatnonzero(m.obs_image == k)
        images.append(struct.pack("<i4d3di", int(iid), *m.q_cam_from_world[k], *m.t_cam_from_world[k],
                                  int(m.camera_ids[m.image_camera[k]]))
                      + m.image_names[k].encode() + b"\x00" + struct.pack("<Q", len(rows))
                      + b"".join(struct.pack("<ddq", *m.obs_xy[r], int(m.obs_point3d_id[r])) for r in rows))
    points = [struct.pack("<Q", len(m.point3d_ids))]
    start = np.r_[0, np.cumsum(np.bincount(m.obs_image, minlength=len(m.image_ids)))]
    for k, pid in enumerate(m.point3d_ids):
        rows = np.flatnonzero(m.obs_point3d_id == pid)
        track = b"".join(struct.pack("<ii", int(m.image_ids[m.obs_image[r]]), int(r - start[m.obs_image[r]]))
                         for r in rows)
        points.append(struct.pack("<Q3d3BdQ", int(pid), *m.xyz_world[k], *map(int, m.rgb[k]), float(m.error[k]),
                                  len(rows)) + track)
    return {"cameras.bin": b"".join(cams), "images.bin": b"".join(images), "points3D.bin": b"".join(points)}


def _model():
    original = read_project(STRIP8)
    return project_to_colmap(original, approximate_points(original), 0.012)


def test_binary_and_text_models_give_the_same_project(tmp_path):
    colmap, names, _ = _model()
    text, binary = tmp_path / "text", tmp_path / "binary"
    text.mkdir(), binary.mkdir()
    for name, content in colmap_files(colmap).items():
        (text / name).write_text(content)
    for name, content in _binary_files(colmap).items():
        (binary / name).write_bytes(content)
    a, b = read_colmap(text), read_colmap(binary)
    for field in a.__dataclass_fields__:
        x, y = getattr(a, field), getattr(b, field)
        if isinstance(x, np.ndarray):
            # the text model prints 17 significant digits: the same doubles
            np.testing.assert_array_equal(x, y, err_msg=field)
        else:
            assert x == y, field
    pa = colmap_to_project(a, 0.012, names, text).project
    pb = colmap_to_project(b, 0.012, names, binary).project
    fa, fb = project_files(pa), project_files(pb)
    assert fa == fb


def test_a_truncated_or_inconsistent_binary_model_is_named(tmp_path):
    colmap, _, _ = _model()
    files = _binary_files(colmap)
    folder = tmp_path / "m"
    folder.mkdir()
    for name, content in files.items():
        (folder / name).write_bytes(content)
    (folder / "images.bin").write_bytes(files["images.bin"][:-10])
    with pytest.raises(InputError, match=r"images\.bin.*record 7: the file ends inside it"):
        read_colmap(folder)
    (folder / "images.bin").write_bytes(files["images.bin"])
    (folder / "points3D.bin").write_bytes(files["points3D.bin"] + b"\x00")
    with pytest.raises(InputError, match=r"points3D\.bin.*1 bytes after the last record"):
        read_colmap(folder)
    # a track that names another 2D point than the one that names it
    m = struct.unpack_from("<Q", files["points3D.bin"])[0]
    assert m > 2
    body = bytearray(files["points3D.bin"])
    first_track = 8 + struct.calcsize("<Q3d3BdQ")  # the first point's first track entry
    image_id, idx = struct.unpack_from("<ii", body, first_track)
    struct.pack_into("<ii", body, first_track, image_id, idx + 1)
    (folder / "points3D.bin").write_bytes(bytes(body))
    with pytest.raises(InputError, match=r"points3D\.bin.*record 0: track of POINT3D_ID"):
        read_colmap(folder)


def test_convert_takes_a_binary_model(tmp_path):
    from click.testing import CliRunner

    from striptri.cli import main

    colmap, _, _ = _model()
    folder = tmp_path / "sparse"
    folder.mkdir()
    for name, content in _binary_files(colmap).items():
        (folder / name).write_bytes(content)
    run = CliRunner().invoke(main, ["convert", str(folder), "--to", "project", "--out", str(tmp_path / "p"),
                                    "--pixel-size", "0.012"])
    assert run.exit_code == 0, run.output
    assert len(read_project(tmp_path / "p").photos) == len(colmap.image_ids)
