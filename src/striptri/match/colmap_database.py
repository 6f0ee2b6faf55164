"""Tie points a user matched with COLMAP: its database (issue 28; ``striptri match PROJECT
--colmap-database DB``; docs/matching.md).

COLMAP keeps its features and matches in an SQLite database (src/colmap/scene/database.cc):
``images`` (image_id, name, camera_id), ``keypoints`` (image_id, rows, cols, data: float32 rows x
cols, the first two columns x, y in pixels with the centre of the top-left pixel at (0.5, 0.5), as
striptri's), and ``two_view_geometries`` (pair_id, rows, cols, data: uint32 rows x 2, the verified
matches of the pair as keypoint numbers in its two images; config, the kind of geometry). A pair
id is ``image_id1 * 2147483647 + image_id2`` with image_id1 < image_id2.

The verified matches of every pair whose geometry is defined (config not UNDEFINED, DEGENERATE or
WATERMARK) between two photos of the project are taken as they are, and striptri joins them into
tracks, checks them against the approximate orientations and thins them as it does its own
(match.pipeline). A database image is a photo's when its name, without folders and extension, is
the photo_id, or when it equals photos.csv's ``image``. The database carries no descriptor distances:
the tracks are joined in the database's order (pairs by pair id, matches as stored).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from ..errors import InputError
from ..model import Project
from .image_names import image_column

PAIR_BASE = 2147483647  # COLMAP's kMaxNumImages: pair_id = id1 * PAIR_BASE + id2
UNUSABLE_CONFIGS = (0, 1, 7)  # UNDEFINED, DEGENERATE, WATERMARK (TwoViewGeometry::ConfigurationType)


@dataclass(frozen=True)
class DatabaseMatches:
    """xy: per photo (in project order) its keypoints (n_k, 2) px; a, b: (k,) matched keypoints as
    numbers into the photos' keypoints concatenated; score: (k,) zeros (no distances: the order
    decides); pairs: (p, 2) photo numbers of the pairs with matches; pair_matches: (p,)."""

    xy: list
    a: np.ndarray
    b: np.ndarray
    score: np.ndarray
    pairs: np.ndarray
    pair_matches: np.ndarray


def _blob(data, rows: int, cols: int, dtype, path: Path, what: str) -> np.ndarray:
    values = np.frombuffer(data or b"", dtype=dtype)
    if values.size != rows * cols:
        raise InputError(path, None, f"{what}: {values.size} values where rows x cols = {rows} x {cols}")
    return values.reshape(rows, cols)


def read_database(path: Path) -> tuple[dict, dict, dict]:
    """-> (image_id -> name, image_id -> keypoints (n, 2) px, (id1, id2) -> matches (k, 2)).
    InputError for a file that is not a COLMAP database."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "COLMAP database not found")
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
            names = dict(db.execute("SELECT image_id, name FROM images"))
            keypoints = {int(i): _blob(data, r, c, np.float32, path, f"keypoints of image {i}")[:, :2].astype(float)
                         for i, r, c, data in db.execute("SELECT image_id, rows, cols, data FROM keypoints")}
            matches = {}
            query = "SELECT pair_id, rows, cols, data, config FROM two_view_geometries ORDER BY pair_id"
            for pair_id, r, c, data, config in db.execute(query):
                if not r or config in UNUSABLE_CONFIGS:
                    continue
                id2 = int(pair_id) % PAIR_BASE
                id1 = (int(pair_id) - id2) // PAIR_BASE
                matches[(id1, id2)] = _blob(data, r, c, np.uint32, path, f"matches of images {id1}, {id2}")
    except sqlite3.DatabaseError as exc:
        raise InputError(path, None, f"not a COLMAP database ({exc})") from None
    return names, keypoints, matches


def matches_for_project(path: Path, project: Project, project_dir: Path) -> DatabaseMatches:
    """The database's keypoints and verified matches for the photos of project (module doc).
    InputError naming a photo without an image in the database, or a match outside its keypoints."""
    names, keypoints, matches = read_database(path)
    named = {text: pid for pid, (_, text) in image_column(project_dir / "photos.csv").items()}
    photo_of = {pid: k for k, pid in enumerate(project.photos.ids)}
    image_photo = {}
    for image_id, name in names.items():
        pid = named.get(name, PurePosixPath(name.replace("\\", "/")).stem)
        if pid in photo_of:
            image_photo[int(image_id)] = photo_of[pid]
    missing = sorted(set(range(len(project.photos))) - set(image_photo.values()))
    if missing:
        raise InputError(path, None, f"no image of photo '{project.photos.ids[missing[0]]}' in the database (an "
                                     "image named <photo_id>.<ext>, or photos.csv's image)")
    image_of = {k: i for i, k in image_photo.items()}
    xy = [keypoints.get(image_of[k], np.zeros((0, 2))) for k in range(len(project.photos))]
    offsets = np.cumsum([0] + [len(x) for x in xy])
    a, b, pairs, counts = [], [], [], []
    for (id1, id2), m in matches.items():  # one entry per pair
        if id1 not in image_photo or id2 not in image_photo:
            continue
        p, q = image_photo[id1], image_photo[id2]
        if (m[:, 0] >= len(xy[p])).any() or (m[:, 1] >= len(xy[q])).any():
            raise InputError(path, None, f"matches of images {id1} and {id2} name keypoints that are not there")
        a.append(offsets[p] + m[:, 0].astype(np.int64))
        b.append(offsets[q] + m[:, 1].astype(np.int64))
        pairs.append((p, q))
        counts.append(len(m))
    cat = (lambda x: np.concatenate(x) if x else np.zeros(0, dtype=np.int64))  # noqa: E731
    a, b = cat(a), cat(b)
    return DatabaseMatches(xy, a, b, np.zeros(len(a)), np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
                           np.asarray(counts, dtype=np.int64))
