"""Features of an image (SIFT, OpenCV) at a chosen pyramid level, in full-resolution pixels.

Pixel coordinates follow docs/file-formats.md: the origin is the top-left corner of the image, the
centre of the top-left pixel is (0.5, 0.5), column to the right, row down. OpenCV puts the centre
of the top-left pixel at (0, 0): a keypoint (u, v) of OpenCV is (u + 0.5, v + 0.5) here. Read at
``scale`` (0.25: a quarter of the width and height, by area averaging), a feature's coordinates
are those of the reduced image divided by ``scale``; with the corner as origin this is exact.

SIFT runs with OpenCV's precise upscaling (``enable_precise_upscale``): by default its first
octave doubles the image such that every keypoint comes out 0.25 pixel (of the level it runs on)
too far right and down, measured on rendered photographs (tests/test_match_images.py: an offset
of 0.2497, 0.2499 px at full resolution, 0.499 px at half; with the precise upscaling 0.0004 px).

A large image is worked on in tiles (:func:`detect`): SIFT's pyramid of a whole image, its first
octave doubled, takes about 220 bytes per pixel of the level it runs on (some 14 float images of 4
times the pixels, over all octaves): 6.1 GB for a 20,000 px scan at a quarter, 16 times the scan's
8-bit array (scripts/bench/bench_scan_memory.py). Tiles of TILE px with TILE_MARGIN px of context on each
side keep it near 0.5 GB; a keypoint is taken from the tile whose core holds it, and the strongest
``max_features`` of all tiles are kept, as SIFT keeps the strongest of a whole image.

OpenCV comes from the optional extra ``striptri[images]`` (opencv-python-headless, wheels): the
rest of striptri never imports it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAX_FEATURES = 8000  # per image: the strongest (SIFT's response)
TILE = 1536  # px of the level SIFT runs on: larger images are worked on in tiles (module doc)
TILE_MARGIN = 96  # px of context around a tile's core (the blur and the descriptor's window)


@dataclass(frozen=True)
class Features:
    """xy (n, 2) column, row in full-resolution pixels (module doc); descriptors (n, 128) float32;
    size (n,) the feature's scale in full-resolution pixels."""

    xy: np.ndarray
    descriptors: np.ndarray
    size: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


def cv2_module():
    """OpenCV, or an ImportError that says how to install it."""
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - the message is the point
        raise ImportError("automatic tie points need OpenCV: pip install 'striptri[images]' "
                          "(opencv-python-headless)") from exc
    return cv2


def read_grey(path, flag: str = "IMREAD_GRAYSCALE") -> np.ndarray:
    """The image at path as 8-bit grey (OpenCV's imread flag by name: IMREAD_REDUCED_GRAYSCALE_2 ..
    decode it reduced). InputError when OpenCV cannot read it. An 8-bit grey TIFF read whole is
    read by tifffile (:func:`_tiff_grey`)."""
    if flag == "IMREAD_GRAYSCALE" and Path(path).suffix.lower() in (".tif", ".tiff"):
        image = _tiff_grey(path)
        if image is not None:
            return image
    cv2 = cv2_module()
    image = cv2.imread(str(path), getattr(cv2, flag))
    if image is None:
        from ..errors import InputError

        raise InputError(path, None, "not an image OpenCV can read")
    return image


def _tiff_grey(path) -> np.ndarray | None:
    """An 8-bit single-channel TIFF read by tifffile, strip by strip (or tile by tile) straight into
    one array; None for any other TIFF, or without tifffile (OpenCV reads it then). OpenCV's TIFF
    decoder holds a second full-size copy while it reads: 813 MB for a 20,000 px scan of 381 MB,
    412 MB with tifffile (scripts/bench/bench_scan_memory.py), the issue's "full-resolution array
    in memory once". A single compressed strip still needs its compressed bytes beside it."""
    try:
        import tifffile
    except ImportError:
        return None
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            if page.dtype != np.uint8 or len(page.shape) != 2:
                return None
            return page.asarray()
    except Exception:  # noqa: BLE001 - anything tifffile cannot read goes to OpenCV, which names the problem
        return None


def reduced(image: np.ndarray, scale: float) -> np.ndarray:
    """The image at ``scale`` (<= 1) of its width and height, by area averaging (the pyramid level
    the features are found on); 8-bit grey."""
    cv2 = cv2_module()
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if grey.dtype != np.uint8:
        top = float(np.max(grey)) if grey.size else 1.0
        grey = np.clip(np.asarray(grey, dtype=float) * (255.0 / (top or 1.0)), 0, 255).astype(np.uint8)
    if scale >= 1.0:
        return grey
    h, w = grey.shape
    size = (max(1, int(round(w * scale))), max(1, int(round(h * scale))))
    return cv2.resize(grey, size, interpolation=cv2.INTER_AREA)


def detect(image: np.ndarray, scale: float = 1.0, max_features: int = MAX_FEATURES) -> Features:
    """SIFT features of ``image`` (2-D grey or 3-channel BGR array) found at ``scale`` (module doc)."""
    cv2 = cv2_module()
    small = reduced(image, scale)
    sx = small.shape[1] / image.shape[1]  # the scale actually applied (sizes are rounded)
    sy = small.shape[0] / image.shape[0]
    sift = cv2.SIFT_create(nfeatures=max_features, enable_precise_upscale=True)
    whole = max(small.shape[:2]) <= TILE + 2 * TILE_MARGIN
    uv, descriptors, sizes = _sift(sift, small) if whole else _tiled(sift, small, max_features)
    if not len(uv):
        return Features(np.zeros((0, 2)), np.zeros((0, 128), dtype=np.float32), np.zeros(0))
    xy = np.column_stack([(uv[:, 0] + 0.5) / sx, (uv[:, 1] + 0.5) / sy])
    return Features(xy, np.asarray(descriptors, dtype=np.float32), sizes / np.sqrt(sx * sy))


def _sift(sift, image: np.ndarray, with_response: bool = False):
    """SIFT on image -> (uv (n, 2) OpenCV pixels, descriptors (n, 128), sizes (n,)[, responses (n,)])."""
    keypoints, descriptors = sift.detectAndCompute(np.ascontiguousarray(image), None)
    if descriptors is None or not keypoints:
        keypoints, descriptors = (), np.zeros((0, 128), dtype=np.float32)
    uv = np.array([k.pt for k in keypoints], dtype=float).reshape(-1, 2)
    sizes = np.array([k.size for k in keypoints], dtype=float)
    if with_response:
        return uv, descriptors, sizes, np.array([k.response for k in keypoints], dtype=float)
    return uv, descriptors, sizes


def _tiled(sift, image: np.ndarray, max_features: int):
    """SIFT over tiles of ``image`` (module doc) -> as _sift, the strongest max_features of all
    tiles (rows in the order of the tiles)."""
    h, w = image.shape[:2]
    parts = []
    for r0 in range(0, h, TILE):
        for c0 in range(0, w, TILE):
            top, left = max(r0 - TILE_MARGIN, 0), max(c0 - TILE_MARGIN, 0)
            uv, d, size, response = _sift(sift, image[top:min(r0 + TILE + TILE_MARGIN, h),
                                                      left:min(c0 + TILE + TILE_MARGIN, w)], with_response=True)
            uv += [left, top]
            core = (uv[:, 0] >= c0) & (uv[:, 0] < c0 + TILE) & (uv[:, 1] >= r0) & (uv[:, 1] < r0 + TILE)
            parts.append((uv[core], d[core], size[core], response[core]))
    uv, descriptors, sizes, response = (np.concatenate(column) for column in zip(*parts))
    best = np.sort(np.argsort(-response, kind="stable")[:max_features]) if max_features else np.arange(len(uv))
    return uv[best], descriptors[best], sizes[best]
