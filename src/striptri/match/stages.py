"""The matcher's work per photo and per pair as tasks (striptri.parallel: local processes by
default, or a Dask cluster with ``--scheduler``), the features streamed through a work folder.

:func:`find_features` reads one image (at its pyramid level, or a film scan once at full
resolution for its fiducial marks too), finds its SIFT features and writes them to the work
folder (``features_<k>.npz``: xy, size and the descriptors as uint8, which OpenCV's SIFT
descriptors are, whole numbers 0..255 stored as float32), returning only the feature positions
and the marks. :func:`match_pairs` matches and verifies a chunk of candidate pairs, reading each
photo's descriptors from the folder once. So the descriptors of the whole block are never in
memory at once: only those of the pairs in flight. On a Dask cluster, the workers must see the
images and the work folder (beside OUT) at the same paths.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .features import Features, detect, read_grey
from .film_scans import FiducialOptions, find_in_scan
from .frames import ImageFrames
from .pair_matching import match_pair

REDUCED = {0.5: "IMREAD_REDUCED_GRAYSCALE_2", 0.25: "IMREAD_REDUCED_GRAYSCALE_4", 0.125: "IMREAD_REDUCED_GRAYSCALE_8"}
PAIRS_PER_TASK = 16  # candidate pairs matched per task (sorted by photo: their descriptors read once)


@dataclass(frozen=True)
class FeatureTask:
    """One photo: k its number; path its image; folder the work folder; scale, max_features;
    size_px (W, H) the image size cameras.csv gives (None: a scan, any size); fiducials: for a scan
    whose marks are to be found, {fiducial_id: (x, y) mm} of its camera (else None), with
    fiducial_options."""

    k: int
    path: str
    folder: str
    scale: float
    max_features: int
    size_px: tuple | None = None
    fiducials: dict | None = None
    fiducial_options: FiducialOptions | None = None


def find_features(task: FeatureTask) -> tuple[np.ndarray, list | None]:
    """The photo's features written to the work folder -> (xy (n, 2) full-resolution pixels, the
    fiducial marks found or None). InputError for an image OpenCV cannot read or of the wrong size."""
    path = Path(task.path)
    marks = None
    if task.size_px is None:  # a film scan: once at full resolution, for the marks and the features
        image = read_grey(path)
        if task.fiducials is not None:
            marks = find_in_scan(image, task.fiducials, task.fiducial_options)
        found = detect(image, task.scale, task.max_features)
    else:
        found = _digital_features(path, task)
    np.savez(Path(task.folder) / f"features_{task.k}.npz", xy=found.xy, size=found.size.astype(np.float32),
             descriptors=np.rint(found.descriptors).astype(np.uint8))
    return found.xy, marks


def _digital_features(path: Path, task: FeatureTask) -> Features:
    """At 1/2, 1/4, 1/8 the image is decoded at that size (a JPEG never at full resolution);
    otherwise read whole and reduced (match.features). The features in full-resolution pixels."""
    W, H = task.size_px
    flag = REDUCED.get(task.scale)
    image = read_grey(path, flag or "IMREAD_GRAYSCALE")
    factor = task.scale if flag else 1.0
    h, w = image.shape[:2]
    if abs(w - W * factor) > 1 or abs(h - H * factor) > 1:
        raise InputError(path, None, f"the image is {int(round(w / factor))} x {int(round(h / factor))} pixels; "
                                     f"cameras.csv says {int(W)} x {int(H)}")
    found = detect(image, 1.0 if flag else task.scale, task.max_features)
    # decoded reduced: the features are in the reduced image's corner-origin pixels
    sx, sy = W / w if flag else 1.0, H / h if flag else 1.0
    return Features(found.xy * [sx, sy], found.descriptors, found.size * np.sqrt(sx * sy))


def load_features(folder, k: int) -> Features:
    """The features of photo k from the work folder (descriptors as float32, as found)."""
    with np.load(Path(folder) / f"features_{k}.npz") as f:
        return Features(f["xy"], f["descriptors"].astype(np.float32), f["size"].astype(float))


@dataclass(frozen=True)
class PairTask:
    """Candidate pairs to match: pairs ((n, p, q), ...) with n the pair's number; folder the work
    folder; frames: for scans, the photos' frames, whose image areas alone are matched (None: every
    feature)."""

    pairs: tuple
    folder: str
    frames: ImageFrames | None = None


def match_pairs(task: PairTask) -> list[tuple]:
    """-> [(n, i, j, distance, planar, epipolar)] of every pair (match.pair_matching; i, j number
    the photos' features as found)."""
    cache: dict[int, tuple[Features, np.ndarray]] = {}

    def usable(k: int) -> tuple[Features, np.ndarray]:
        if k not in cache:
            if len(cache) > 8:
                cache.pop(next(iter(cache)))
            f = load_features(task.folder, k)
            keep = np.arange(len(f))
            if task.frames is not None and len(f):
                keep = np.flatnonzero(task.frames.in_image(np.full(len(f), k), f.xy))
            cache[k] = (Features(f.xy[keep], f.descriptors[keep], f.size[keep]), keep)
        return cache[k]

    out = []
    for n, p, q in task.pairs:
        (fp, kp), (fq, kq) = usable(p), usable(q)
        m = match_pair(fp, fq)
        out.append((n, kp[m.i], kq[m.j], m.distance, m.planar, m.epipolar))
    return out


def pair_tasks(pairs: np.ndarray, folder, frames: ImageFrames | None) -> list[PairTask]:
    """The candidate pairs in tasks of PAIRS_PER_TASK, in the order of their first photo."""
    order = np.lexsort((pairs[:, 1], pairs[:, 0])) if len(pairs) else np.zeros(0, dtype=np.int64)
    rows = [(int(n), int(pairs[n, 0]), int(pairs[n, 1])) for n in order]
    return [PairTask(tuple(rows[s:s + PAIRS_PER_TASK]), str(folder), frames)
            for s in range(0, len(rows), PAIRS_PER_TASK)]
