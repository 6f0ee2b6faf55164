"""Rendered photographs of a simulated project (issue 28; ``striptri simulate ... --images``).

The ground carries a grey texture that is a function of X, Y alone (:class:`GroundTexture`), so
every photo sees the same ground, and feature matching between rendered photos has a known truth.
Each photo is rendered by following the ray of every pixel centre to the terrain surface (the
simulated terrain of the project, :mod:`striptri.simulate.terrain`) with the true orientation and
camera (:func:`render_photo`), and reading the texture there.

The texture is a sum of octaves of cubic B-spline noise: in octave k the ground carries a square
lattice of spacing ``finest * 2**k`` with a random value at every node, drawn from a hash of the
node's integer indices and the seed (so it is the same wherever it is evaluated, and never
repeats), and the octave's grey value is the cubic B-spline through those nodes (scipy.ndimage,
without prefilter: smooth, and free of frequencies the pixels could alias). Each octave's
amplitude grows with its wavelength as ``2**(k * roughness)``; with roughness 0 (the default) every
octave has the same amplitude: features at every scale, from a few pixels (``finest`` is 1.5
ground pixels) to a tenth of the photo, which is what SIFT's scale space needs to match photos
taken from different heights and turned against each other. (Measured on rendered 1,000-pixel
photos: roughness 0.5, where the coarse octaves dominate, gives a third as many matches and three
times the matching error; 0 gives a median error of 0.03 px.)

Pixels follow striptri.geometry.pixels: the centre of the top-left pixel is (0.5, 0.5).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage
from scipy.interpolate import RectBivariateSpline

from ..geometry.camera import ray_ground
from ..geometry.pixels import plate_from_pixel
from ..model import TIE, Project
from .terrain import Terrain
from .truth import Truth

_B3_SQUARED = 151.0 / 315.0  # integral of the cubic B-spline's square: the variance factor per axis
_GREY_MEAN, _GREY_STD = 128.0, 42.0  # grey levels of the texture's mean and standard deviation
_NODE_STEP = 8  # pixels between the nodes where the rays are followed to the terrain exactly


@dataclass(frozen=True)
class ImageOptions:
    """size_px: the width of the images (pixels); noise: standard deviation of Gaussian noise
    added to the grey values (grey levels, 0 = noise-free); jpeg_quality: write JPEG of that
    quality (1..100), None = PNG (lossless); height_px: the height (None: square images).

    The simulated camera's format is square: its side spans the images' shorter side, and a
    longer width (the camera's x, along the flight) widens the format that way, so that the
    forward overlap grows and the sidelap stays (3,000 x 2,000 px with a 60 % design overlap: 73 %)."""

    size_px: int = 1000
    noise: float = 0.0
    jpeg_quality: int | None = None
    height_px: int | None = None

    def __post_init__(self):
        for side in (self.size_px, self.height):
            if not (isinstance(side, int) and 64 <= side <= 20000):
                raise ValueError(f"images: the size must be 64 .. 20000 pixels, not {side}")
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"images: the noise must be >= 0 grey levels, not {self.noise}")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"images: the JPEG quality must be 1 .. 100, not {self.jpeg_quality}")

    @property
    def height(self) -> int:
        return self.size_px if self.height_px is None else self.height_px

    @property
    def shape(self) -> tuple[int, int]:
        """(width, height) pixels."""
        return self.size_px, self.height

    def pixel_size(self, format_mm: float) -> float:
        """Plate units per pixel: the square format over the shorter side (class doc)."""
        return format_mm / min(self.shape)

    @property
    def extension(self) -> str:
        return ".png" if self.jpeg_quality is None else ".jpg"


@dataclass(frozen=True)
class GroundTexture:
    """The grey value of the ground at X, Y (module doc). finest: the lattice spacing of the finest
    octave (m); octaves: how many; roughness: log2 of the amplitude ratio of neighbouring octaves."""

    seed: int
    finest: float
    octaves: int
    roughness: float = 0.0

    def grey(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Grey values (float, mean 128, standard deviation about 42) at ground X, Y (any shape, m).
        Each octave's node values are made for the rectangle the points span: meant for compact
        batches (a photo's pixels), not for a few points far apart."""
        X, Y = np.asarray(X, dtype=float), np.asarray(Y, dtype=float)
        total = np.zeros(X.shape)
        amplitudes = 2.0 ** (self.roughness * np.arange(self.octaves))
        for k, amplitude in enumerate(amplitudes):
            spacing = self.finest * 2.0**k
            u, v = X / spacing, Y / spacing
            i0, j0 = int(np.floor(u.min())) - 2, int(np.floor(v.min())) - 2
            i1, j1 = int(np.ceil(u.max())) + 3, int(np.ceil(v.max())) + 3
            nodes = _node_values(np.arange(i0, i1), np.arange(j0, j1), k, self.seed)
            total += amplitude * ndimage.map_coordinates(nodes, [v - j0, u - i0], order=3, prefilter=False,
                                                         mode="nearest")
        std = np.sqrt(np.sum(amplitudes**2) * _B3_SQUARED**2 / 3.0)  # node values uniform on [-1, 1]
        return _GREY_MEAN + _GREY_STD * total / std


def _node_values(i: np.ndarray, j: np.ndarray, octave: int, seed: int) -> np.ndarray:
    """(len(j), len(i)) values uniform on [-1, 1] at the lattice nodes (i, j) of an octave: the
    splitmix64 hash of the node's indices, the octave and the seed."""
    with np.errstate(over="ignore"):
        z = (i.astype(np.int64).astype(np.uint64)[None, :] * np.uint64(0x9E3779B97F4A7C15)
             ^ j.astype(np.int64).astype(np.uint64)[:, None] * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ np.uint64((seed * 1000003 + octave * 7919) & 0xFFFFFFFFFFFFFFFF))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return np.ldexp((z >> np.uint64(11)).astype(float), -52) - 1.0  # 53 random bits on [0, 2), less 1


def texture_for(terrain: Terrain, ground_pixel: float, footprint: float, seed: int) -> GroundTexture:
    """The texture of a project whose pixels cover ``ground_pixel`` metres and whose photos
    ``footprint`` metres: octaves from 1.5 ground pixels up to about a tenth of the footprint."""
    finest = 1.5 * ground_pixel
    octaves = max(1, int(np.floor(np.log2(footprint / 10.0 / finest))) + 1)
    return GroundTexture(seed=seed, finest=finest, octaves=octaves)


def ground_of_rays(origin: np.ndarray, ray: np.ndarray, terrain: Terrain, tolerance: float = 1e-6) -> np.ndarray:
    """Where rays from origin (3,) along ray (..., 3) (pointing down) meet the terrain: (..., 3).
    Fixed-point iteration on the height (converges where the terrain is flatter than the rays are
    steep, as under any aerial photo); ValueError if it does not."""
    z = np.full(ray.shape[:-1], terrain.mean_z)
    for _ in range(50):
        s = (z - origin[2]) / ray[..., 2]
        xy = origin[:2] + s[..., None] * ray[..., :2]
        z_new = terrain.z(xy)
        if np.max(np.abs(z_new - z)) < tolerance:
            return np.concatenate([xy, z_new[..., None]], -1)
        z = z_new
    raise ValueError("a ray does not settle on the terrain (too steep a terrain for the view)")


@dataclass(frozen=True)
class Targets:
    """Signalised ground points: xy (t, 2) ground X, Y (m); radius of the white disc (m)."""

    xy: np.ndarray
    radius: float


def render_photo(R: np.ndarray, xyz0: np.ndarray, interior: np.ndarray, pixel_size: float, size_px,
                 terrain: Terrain, texture: GroundTexture, targets: Targets | None = None) -> np.ndarray:
    """The grey image (height, width) float, size_px = width or (width, height), of a photo of
    rotation R (ground from camera),
    centre xyz0 and interior (c, xp, yp), with square pixels of pixel_size plate units: every
    pixel centre's ray to the terrain, the texture there. The rays are followed exactly at nodes
    every _NODE_STEP pixels and interpolated between them by a bicubic interpolating spline (the
    ground position is a smooth function of the pixel: the error is far below a thousandth of a
    pixel). targets: signalised points, each painted as a white disc of targets.radius metres in
    a black ring out to 1.8 times that (anti-aliased over a ground pixel), as control points are
    signalised before a flight."""
    W, H = (size_px, size_px) if np.ndim(size_px) == 0 else (int(size_px[0]), int(size_px[1]))
    cols = np.arange(-2 * _NODE_STEP, W + 3 * _NODE_STEP, _NODE_STEP, dtype=float) + 0.5
    rows = np.arange(-2 * _NODE_STEP, H + 3 * _NODE_STEP, _NODE_STEP, dtype=float) + 0.5
    col, row = np.meshgrid(cols, rows)
    plate = plate_from_pixel(np.stack([col, row], -1), np.array([W, H]), pixel_size)
    ground = ground_of_rays(xyz0, ray_ground(R, plate, interior[:3]), terrain)
    at = (np.arange(H, dtype=float) + 0.5, np.arange(W, dtype=float) + 0.5)
    X, Y = (RectBivariateSpline(rows, cols, ground[..., a], kx=3, ky=3, s=0)(*at) for a in (0, 1))
    grey = texture.grey(X, Y)
    if targets is not None and len(targets.xy) and targets.radius > 0:
        target_radius, xy = targets.radius, np.asarray(targets.xy, dtype=float)
        ground_pixel = float(np.hypot(X[0, 1] - X[0, 0], Y[0, 1] - Y[0, 0]))
        lo, hi = np.array([X.min(), Y.min()]) - 2 * target_radius, np.array([X.max(), Y.max()]) + 2 * target_radius
        for tx, ty in xy[((xy >= lo) & (xy <= hi)).all(1)]:  # the few in this photo
            d = np.hypot(X - tx, Y - ty)
            near = d < 2.0 * target_radius + ground_pixel
            ring = np.clip((1.8 * target_radius - d[near]) / ground_pixel + 0.5, 0.0, 1.0)
            disc = np.clip((target_radius - d[near]) / ground_pixel + 0.5, 0.0, 1.0)
            grey[near] = grey[near] * (1.0 - ring) + 255.0 * disc  # black ring, white disc
    return grey


def to_image(grey: np.ndarray, options: ImageOptions, rng: np.random.Generator) -> np.ndarray:
    """Grey values with the options' noise, rounded and clipped to uint8."""
    if options.noise > 0:
        grey = grey + rng.normal(0.0, options.noise, grey.shape)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def encode(image: np.ndarray, options: ImageOptions) -> bytes:
    """The image as PNG or JPEG bytes (OpenCV: the extra ``images``)."""
    from ..match.features import cv2_module

    cv2 = cv2_module()
    if options.jpeg_quality is None:
        ok, data = cv2.imencode(".png", image)
    else:
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(options.jpeg_quality)])
    if not ok:
        raise RuntimeError("OpenCV could not encode a rendered image")
    return data.tobytes()


def digital_project(project: Project, format_mm: float, options: ImageOptions) -> Project:
    """The simulated project as one of a digital frame camera whose images are rendered: cameras.csv
    gets the images' width_px, height_px and pixel_size (ImageOptions.pixel_size), and
    image_points.csv keeps only the rows of control and check points (the measurements a user makes
    by hand); the tie points are left to ``striptri match``."""
    ncam = len(project.cameras)
    cameras = replace(project.cameras, size_px=np.tile(np.array(options.shape, dtype=float), (ncam, 1)),
                      pixel_size=np.full(ncam, options.pixel_size(format_mm)))
    ip = project.image_points
    keep = project.points.kind[ip.point_index] != TIE
    image_points = replace(ip, photo_index=ip.photo_index[keep], point_index=ip.point_index[keep],
                           xy=ip.xy[keep], sigma_xy=ip.sigma_xy[keep])
    return replace(project, cameras=cameras, image_points=image_points)


def render_images(truth: Truth, format_mm: float, options: ImageOptions, rng: np.random.Generator,
                  workers: int | None = None) -> Iterator[tuple[str, bytes]]:
    """Render every photo of the truth: -> (file name ``<photo_id>.png`` or ``.jpg``, its bytes),
    in photo order, a few photos at a time on ``workers`` threads (scipy's interpolation releases
    the GIL; default: one per core), so that memory holds only the photos in flight. Control and
    check points are signalised: a white disc of 3 ground pixels' radius in a black ring."""
    pixel_size = options.pixel_size(format_mm)
    scale = float(np.median(truth.xyz0[:, 2]) - truth.terrain.mean_z) / truth.interior[0]  # m per plate unit
    texture = texture_for(truth.terrain, pixel_size * scale, format_mm * scale, int(rng.integers(2**31)))
    noise_seeds = rng.spawn(len(truth.photo_ids))
    targets = Targets(truth.xyz_ground[truth.kind != TIE, :2], 3.0 * pixel_size * scale)  # control, check points
    workers = workers or os.cpu_count() or 1

    def one(k: int) -> bytes:
        grey = render_photo(truth.R_ground_from_cam[k], truth.xyz0[k], truth.interior, pixel_size, options.shape,
                            truth.terrain, texture, targets)
        return encode(to_image(grey, options, noise_seeds[k]), options)

    yield from in_batches([f"{pid}{options.extension}" for pid in truth.photo_ids], one, workers)


def in_batches(names: list, one, workers: int) -> Iterator[tuple[str, bytes]]:
    """(names[k], one(k)) in order, computed on ``workers`` threads 2 x workers at a time, so that
    memory holds only the images in flight."""
    with ThreadPoolExecutor(workers) as pool:
        for start in range(0, len(names), 2 * workers):
            batch = range(start, min(start + 2 * workers, len(names)))
            for k, data in zip(batch, pool.map(one, batch)):
                yield names[k], data
