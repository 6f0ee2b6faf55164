"""Image pixels and plate coordinates of every photo, for the matcher (issue 28).

Two kinds of image, one interface (:class:`ImageFrames`):

* a digital frame camera (cameras.csv width_px, height_px, pixel_size): the fixed relation of
  striptri.geometry.pixels; the image area is the whole image;
* a film scan (project.toml ``[film] image_points = "scan_px"``): each photo's fiducial
  transformation, fitted to its fiducial marks as the reader fits it (striptri.film.fiducials),
  carries scan pixels to the plate (the measured plate: the lens correction is the adjustment's;
  what the matcher does with plate coordinates - pairing, the ground check, thinning - does not
  need it). The image area is the rectangle of the camera's fiducials shrunk by IMAGE_MARGIN, less
  a disc of FIDUCIAL_CLEARANCE_MM about every fiducial: the frame, the film base about it and the
  marks are the same in every scan and would "match" between all of them.

Pixels as everywhere in striptri: the origin at the top-left corner, the centre of the top-left
pixel at (0.5, 0.5), col right, row down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..film import fiducials as fid
from ..film import transform
from ..geometry.pixels import pixel_from_plate, plate_from_pixel
from ..model import Project

IMAGE_MARGIN = 0.05  # the image area of a scan: the fiducials' rectangle shrunk by this share
FIDUCIAL_CLEARANCE_MM = 10.0  # ... and no closer to a fiducial than this (the mark and its unexposed surround)


@dataclass(frozen=True)
class ImageFrames:
    """Pixels <-> plate of every photo (module doc).

    half: (n, 2) the half width and height of each photo's image area (plate units), centred on the
    plate origin; mm_per_px: (n,) plate units per pixel; size_px: (n, 2) each image's expected
    width and height (nan: not known, a scan); film: for scans, (kind, params (n, k) of the fiducial
    transformation q = F(xy), the fiducials (n, F, 2) plate mm, nan-padded), else None."""

    half: np.ndarray
    mm_per_px: np.ndarray
    size_px: np.ndarray
    film: tuple | None = None

    @property
    def units(self) -> str:
        """How image_points.csv gives a photo's measurements: 'plate' or 'scan_px'."""
        return "plate" if self.film is None else "scan_px"

    def plate(self, photo: np.ndarray, colrow: np.ndarray) -> np.ndarray:
        """(m, 2) plate coordinates of pixels colrow (m, 2) of photos photo (m,)."""
        if self.film is None:
            return plate_from_pixel(colrow, self.size_px[photo], self.mm_per_px[photo])
        kind, params, _ = self.film
        xy, _, _ = transform.plate_from_scan(kind, params[photo], transform.q_from_colrow(colrow))
        return xy

    def pixel(self, photo: np.ndarray, plate: np.ndarray) -> np.ndarray:
        """(m, 2) pixels of plate coordinates plate (m, 2) of photos photo (m,)."""
        if self.film is None:
            return pixel_from_plate(plate, self.size_px[photo], self.mm_per_px[photo])
        kind, params, _ = self.film
        q, _, _ = transform.scan_from_plate(kind, params[photo], np.asarray(plate, dtype=float)[:, None])
        return transform.colrow_from_q(q[:, 0])

    def in_image(self, photo: np.ndarray, colrow: np.ndarray) -> np.ndarray:
        """(m,) bool: the pixel lies in the photo's image area (module doc)."""
        colrow = np.asarray(colrow, dtype=float)
        if self.film is None:
            return (colrow >= 0).all(1) & (colrow <= self.size_px[photo]).all(1)
        xy = self.plate(photo, colrow)
        inside = (np.abs(xy) <= self.half[photo]).all(1)
        marks = self.film[2][photo]  # (m, F, 2)
        with np.errstate(invalid="ignore"):
            near = (np.linalg.norm(xy[:, None, :] - marks, axis=2) < FIDUCIAL_CLEARANCE_MM).any(1)
        return inside & ~near


def digital_frames(project: Project) -> ImageFrames:
    """The frames of a project of digital frame cameras (cameras.csv width_px, height_px, pixel_size)."""
    cams = project.cameras
    cam = project.photos.camera_index
    size = cams.size_px[cam]
    return ImageFrames(half=0.5 * size * cams.pixel_size[cam][:, None], mm_per_px=cams.pixel_size[cam].copy(),
                       size_px=size.copy())


@dataclass(frozen=True)
class FiducialMeasurements:
    """The fiducial marks of every photo (in photos.csv order): kind of the transformation;
    xy_plate (n, F, 2) the calibrated positions (mm; padded); q (n, F, 2) the measured scan
    positions in q = (col, -row); sigma (n, F) px; measured (n, F) bool; names (n, F) the ids."""

    kind: str
    xy_plate: np.ndarray
    q: np.ndarray
    sigma: np.ndarray
    measured: np.ndarray
    names: list


def film_frames(marks: FiducialMeasurements) -> tuple[ImageFrames, fid.FiducialFit]:
    """The frames of scanned film photos from their fiducial marks: each photo's transformation
    fitted as the project reader fits it (striptri.film.fiducials.fit_fiducials, with its data
    snooping), and the image area of its camera's fiducials (module doc)."""
    fit = fid.fit_fiducials(marks.kind, marks.xy_plate, marks.q, marks.sigma, marks.measured)
    n = len(marks.q)
    known = np.array([[bool(name) for name in row] for row in marks.names]).reshape(n, -1)
    fiducials = np.where(known[..., None], marks.xy_plate, np.nan)
    extent = np.nanmax(np.abs(fiducials), axis=1)  # (n, 2)
    mm_per_px = transform.plate_per_pixel(marks.kind, fit.params)
    return ImageFrames(half=(1.0 - IMAGE_MARGIN) * extent, mm_per_px=mm_per_px, size_px=np.full((n, 2), np.nan),
                       film=(marks.kind, fit.params, fiducials)), fit
