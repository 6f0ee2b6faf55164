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

OpenCV comes from the optional extra ``striptri[images]`` (opencv-python-headless, wheels): the
rest of striptri never imports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_FEATURES = 8000  # per image: the strongest (SIFT's response)


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
    decode it reduced). InputError when OpenCV cannot read it."""
    cv2 = cv2_module()
    image = cv2.imread(str(path), getattr(cv2, flag))
    if image is None:
        from ..errors import InputError

        raise InputError(path, None, "not an image OpenCV can read")
    return image


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
    keypoints, descriptors = sift.detectAndCompute(small, None)
    if descriptors is None or not keypoints:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), dtype=np.float32), np.zeros(0))
    uv = np.array([k.pt for k in keypoints], dtype=float)
    xy = np.column_stack([(uv[:, 0] + 0.5) / sx, (uv[:, 1] + 0.5) / sy])
    size = np.array([k.size for k in keypoints], dtype=float) / np.sqrt(sx * sy)
    return Features(xy, np.asarray(descriptors, dtype=np.float32), size)
