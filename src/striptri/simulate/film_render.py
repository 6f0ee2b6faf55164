"""Rendered film scans (issue 28): the photos of a simulated film strip (striptri.simulate.film) as
a scanner would give them, with the fiducial marks, so that finding the marks and matching scans
can be tested against the truth.

Each scan pixel centre goes through the photo's scan transformation backwards to the film (the
plate as measured: fiducial system, mm), through the lens correction to the ideal plate (the
camera's calibrated distortion, geometry.lens), and along its ray to the terrain, where the ground
texture of simulate.render gives its grey value. Outside the image area (IMAGE_HALF_MM) and in a
dark surround about each fiducial the film is unexposed base. The fiducial marks are crosses on
the film at their calibrated positions (fiducials are printed on the film by the camera's frame,
not through the lens), drawn anti-aliased in film millimetres, so they turn and shift with the
scan. As in render_photo, the mapping is followed exactly at nodes every few pixels and
interpolated between them by bicubic splines.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..film import transform
from ..geometry.camera import ray_ground
from ..geometry.lens import NCP, brown
from . import film
from .render import GroundTexture, ImageOptions, encode, ground_of_rays, in_batches, texture_for, to_image
from .terrain import Terrain
from .truth import Truth

IMAGE_HALF_MM = 110.0  # the exposed image area: |x|, |y| below this (a 230 mm format's frame)
SURROUND_MM = 7.0  # the unexposed film about each fiducial
BASE_GREY = 20.0  # unexposed film base
MARK_GREY = 235.0  # the fiducial crosses
_NODE_STEP = 8


@dataclass(frozen=True)
class Cross:
    """A fiducial cross on the film: arms of half-length ``arm_mm``, lines ``line_mm`` wide."""

    arm_mm: float = 2.5
    line_mm: float = 0.5


@dataclass(frozen=True)
class Scan:
    """One photo's scan: params (6,) of its affine scan transformation (film.transform, q =
    F(xy)); size (width, height) px; lens (NCP,) the camera's elements (c, xp, yp, distortion);
    fiducials (f, 2) their calibrated plate positions (mm)."""

    params: np.ndarray
    size: tuple
    lens: np.ndarray
    fiducials: np.ndarray


def render_scan(R: np.ndarray, xyz0: np.ndarray, scan: Scan, terrain: Terrain, texture: GroundTexture,
                mark: Cross = Cross()) -> np.ndarray:
    """The grey scan (height, width) float of the photo of rotation R and centre xyz0 (module doc)."""
    W, H = scan.size
    cols = np.arange(-2 * _NODE_STEP, W + 3 * _NODE_STEP, _NODE_STEP, dtype=float) + 0.5
    rows = np.arange(-2 * _NODE_STEP, H + 3 * _NODE_STEP, _NODE_STEP, dtype=float) + 0.5
    cc, rr = np.meshgrid(cols, rows)
    q = transform.q_from_colrow(np.stack([cc, rr], -1)).reshape(-1, 2)
    film, _, _ = transform.plate_from_scan("affine", np.broadcast_to(scan.params, (len(q), 6)), q)
    pp = scan.lens[1:3]
    ideal = brown(film - pp, np.broadcast_to(scan.lens, (len(film), NCP)))[0] + pp
    ground = ground_of_rays(xyz0, ray_ground(R, ideal, scan.lens[:3]), terrain)
    at = (np.arange(H, dtype=float) + 0.5, np.arange(W, dtype=float) + 0.5)

    def spline(values):  # nodes (rows, cols) -> every pixel centre
        return RectBivariateSpline(rows, cols, values.reshape(len(rows), len(cols)), kx=3, ky=3, s=0)(*at)

    X, Y = spline(ground[:, 0]), spline(ground[:, 1])
    fx, fy = spline(film[:, 0]), spline(film[:, 1])
    grey = texture.grey(X, Y)
    # film millimetres per scan pixel: the square root of the inverse affine part's area factor
    px_mm = float(transform.plate_per_pixel("affine", scan.params))
    exposed = np.clip((IMAGE_HALF_MM - np.maximum(np.abs(fx), np.abs(fy))) / px_mm + 0.5, 0.0, 1.0)
    for x0, y0 in scan.fiducials:  # the 4 or 8 marks
        d = np.hypot(fx - x0, fy - y0)
        exposed = np.minimum(exposed, np.clip((d - SURROUND_MM) / px_mm + 0.5, 0.0, 1.0))
    out = BASE_GREY + (grey - BASE_GREY) * exposed
    for x0, y0 in scan.fiducials:
        near = (np.abs(fx - x0) < mark.arm_mm + 2 * px_mm) & (np.abs(fy - y0) < mark.arm_mm + 2 * px_mm)
        dx, dy = np.abs(fx[near] - x0), np.abs(fy[near] - y0)

        def bar(across, along):  # coverage of one arm of the cross
            return (np.clip((mark.line_mm / 2 - across) / px_mm + 0.5, 0.0, 1.0)
                    * np.clip((mark.arm_mm - along) / px_mm + 0.5, 0.0, 1.0))

        cover = np.maximum(bar(dy, dx), bar(dx, dy))
        out[near] = out[near] * (1.0 - cover) + MARK_GREY * cover
    return out


def fiducial_truth(scan: Scan) -> np.ndarray:
    """(f, 2) the true scan pixels (col, row) of the fiducial marks' centres."""
    q, _, _ = transform.scan_from_plate("affine", scan.params[None], scan.fiducials[None])
    return transform.colrow_from_q(q[0])


SCAN_SPAN_MM = 260.0  # a rendered scan's side on the film: the 230 mm frame, the fiducials and a margin
OFFSET_MM = 3.0  # the film's plate origin lies within this of the scan's centre


def film_scan_options(n_photos: int, size_px: int, sigma_image_mm: float, n_check: int) -> film.FilmOptions:
    """The film strip of ``striptri simulate strip --film --images``: scans of size_px x size_px
    covering SCAN_SPAN_MM of film, turned by up to 2 degrees and shifted by up to OFFSET_MM; the
    control points' measurements to sigma_image_mm on the film (in scan pixels)."""
    pixel_mm = SCAN_SPAN_MM / size_px
    sigma_px = max(sigma_image_mm / pixel_mm, 1e-4)
    return film.FilmOptions(n_photos=n_photos, pixel_mm=pixel_mm, sigma_point_px=sigma_px, sigma_fiducial_px=sigma_px,
                            n_check=n_check, scan_centre_px=(size_px / 2.0, size_px / 2.0),
                            scan_offset_px=OFFSET_MM / pixel_mm, max_rotation_deg=2.0)


def render_film_images(truth: Truth, params: np.ndarray, lens: film.FilmLens, options: film.FilmOptions,
                       image: ImageOptions, rng: np.random.Generator,
                       workers: int | None = None) -> Iterator[tuple[str, bytes]]:
    """The scans of a film strip (film.film_files_and_truth's truth and scan parameters): ->
    (file name ``<photo_id>.png`` or ``.jpg``, its bytes) in photo order, rendered on ``workers``
    threads a few at a time (as simulate.render.render_images)."""
    n = image.size_px
    el = lens.elements()
    scale = float(np.median(truth.xyz0[:, 2]) - truth.terrain.mean_z) / float(el[0])  # m per film mm
    texture = texture_for(truth.terrain, options.pixel_mm * scale, 230.0 * scale, int(rng.integers(2**31)))
    noise_seeds = rng.spawn(len(truth.photo_ids))
    workers = workers or os.cpu_count() or 1

    def one(k: int) -> bytes:
        grey = render_scan(truth.R_ground_from_cam[k], truth.xyz0[k], Scan(params[k], (n, n), el, film.FIDUCIALS_MM),
                           truth.terrain, texture)
        return encode(to_image(grey, image, noise_seeds[k]), image)

    yield from in_batches([f"{pid}{image.extension}" for pid in truth.photo_ids], one, workers)
