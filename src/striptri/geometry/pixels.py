"""Pixels of a digital frame camera and plate coordinates (docs/file-formats.md, cameras.csv).

An image of W x H pixels of size s (plate units, mm) has its pixel coordinates (col, row) with the
origin at the top-left corner of the image, the centre of the top-left pixel at (0.5, 0.5),
column to the right and row down (COLMAP's convention). Plate coordinates have their origin at the
image centre, x to the right and y up:

    x = (col - W/2) s,    y = (H/2 - row) s

and xp, yp, the principal point, are in that frame. The COLMAP converter, the matching and the
chips for control points use these two functions.
"""

from __future__ import annotations

import numpy as np


def plate_from_pixel(colrow: np.ndarray, size_px: np.ndarray, pixel_size) -> np.ndarray:
    """Plate coordinates (..., 2) of pixel coordinates colrow (..., 2) in images of size_px (..., 2)
    W, H pixels of pixel_size (...) plate units (module doc)."""
    colrow = np.asarray(colrow, dtype=float)
    half = np.asarray(size_px, dtype=float) / 2.0
    s = np.asarray(pixel_size, dtype=float)
    return np.stack([(colrow[..., 0] - half[..., 0]) * s, (half[..., 1] - colrow[..., 1]) * s], -1)


def pixel_from_plate(xy: np.ndarray, size_px: np.ndarray, pixel_size) -> np.ndarray:
    """Pixel coordinates (..., 2) of plate coordinates xy (..., 2): the inverse of plate_from_pixel."""
    xy = np.asarray(xy, dtype=float)
    half = np.asarray(size_px, dtype=float) / 2.0
    s = np.asarray(pixel_size, dtype=float)
    return np.stack([xy[..., 0] / s + half[..., 0], half[..., 1] - xy[..., 1] / s], -1)
