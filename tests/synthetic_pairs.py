"""Small synthetic photo pairs (and short strips) with known truth, for the tests.

Not a test file: a helper the tests import. Deliberately explicit and independent of
``striptri.simulate`` (which is itself under test elsewhere); it uses only the data model, the
collinearity projection ``striptri.geometry.camera.project`` and ``striptri.geometry.rotations.R_from_opk``.

Truth apart from noise (STYLE.md):

* :func:`make_truth` builds the true photos and object points from :class:`PairOptions` and a
  ``numpy.random.Generator``: camera c = 152 mm, 230 mm format, flying height 1500 m, 60 % overlap
  (base = 0.4 * 230 mm * H / c = 908 m), attitudes of a few degrees, a terrain with relief. Every
  point is placed so that exactly the photos named in its :class:`PointSpec` see it (inside the
  format with a margin, in front of the camera).
* :func:`observe` turns the truth into a ``model.Project``: exact plate coordinates by
  ``camera.project`` plus optional plate noise, control held fixed (exact, ``sigma_given`` nan) or
  weighted (noisy, ``sigma_given`` > 0), optional GNSS-observed centres, and approximate
  orientations perturbed by tens of metres and about a degree.

Options for the hard cases: a common nominal attitude (e.g. omega = 40 deg, kappa = 120 deg), and a
rigid rotation of the whole scene (which puts the cameras in any orientation, e.g. looking
horizontally, phi = 90 deg, the gimbal lock of omega-phi-kappa) while the plate coordinates and
the geometry stay those of a good aerial pair. ``grid_offset`` adds national-grid coordinates
(X ~ 500 000 m, Y ~ 5 000 000 m).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from striptri import model
from striptri.geometry.camera import project
from striptri.geometry.rotations import R_from_opk, opk_from_R

FORMAT_MM = 230.0
NATIONAL_GRID = (500_000.0, 5_000_000.0, 0.0)


@dataclass(frozen=True)
class PointSpec:
    """One object point. kind: model.TIE, HEIGHT, PLAN or FULL. seen_by: the photos that see it
    (exactly these; chain order = photo order). weighted: control given with noise and a standard
    deviation instead of held fixed. xy_plate: plate position (mm) in photo seen_by[0]; drawn at
    random in the format when None."""

    kind: int = model.TIE
    seen_by: tuple[int, ...] = (0, 1)
    weighted: bool = False
    xy_plate: tuple[float, float] | None = None


@dataclass(frozen=True)
class PairOptions:
    """The true geometry. Lengths in metres, plate in mm, angles in degrees.

    n_photos: 2 for a pair, 3 for a short strip (points then seen by up to three photos).
    attitude_deg: standard deviation of each random angle about the nominal omega, phi, kappa
    (nominal_opk_deg; e.g. omega = 40 deg for oblique cameras looking sideways, tilted about the
    flight axis X). position_jitter: standard
    deviation of the centres about the ideal flight line. relief: terrain amplitude.
    max_off_nadir_deg: points whose ray is steeper than this from the vertical are not placed
    (keeps oblique views on near ground). usable_half_format: half-size of the plate area in which
    points are placed and counted as seen (mm). scene_rotvec: rotation vector (radians) of a rigid
    rotation of the whole scene about the middle of the centres; grid_offset added last.
    """

    n_photos: int = 2
    c: float = 152.0
    xp: float = 0.01
    yp: float = -0.02
    flying_height: float = 1500.0
    overlap: float = 0.6
    attitude_deg: float = 2.0
    nominal_opk_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_jitter: float = 10.0
    relief: float = 80.0
    usable_half_format: float = 105.0
    max_off_nadir_deg: float = 65.0
    scene_rotvec: tuple[float, float, float] = (0.0, 0.0, 0.0)
    grid_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    points: tuple[PointSpec, ...] = field(default_factory=lambda: mixed_points())

    @property
    def base(self) -> float:
        return (1.0 - self.overlap) * FORMAT_MM * self.flying_height / self.c


@dataclass(frozen=True)
class NoiseOptions:
    """How the truth is observed. noisy: add normal noise of the stated standard deviations to
    the plate coordinates, the weighted control and the observed centres (False: exact
    observations, with the same weights). sigma_plate: a-priori standard deviation of plate
    coordinates (mm). sigma_control: of weighted control (m). sigma_gnss: of observed centres (m),
    None = centres not observed.
    approx_position: standard deviation of the approximate centres (m, per axis; not used for
    GNSS-observed centres, whose observed value is the approximation). approx_angle_deg: standard
    deviation of each component of the rotation vector of the approximate attitude."""

    sigma_plate: float = 0.005
    noisy: bool = True
    sigma_control: float = 0.05
    sigma_gnss: float | None = None
    approx_position: float = 30.0
    approx_angle_deg: float = 1.0


@dataclass(frozen=True)
class PairTruth:
    """True photos and points (ground frame including grid_offset). xyz0 (n, 3);
    R_ground_from_cam (n, 3, 3); interior (3,) c, xp, yp; xyz_points (np, 3); specs per point."""

    options: PairOptions
    xyz0: np.ndarray
    R_ground_from_cam: np.ndarray
    interior: np.ndarray
    xyz_points: np.ndarray
    specs: tuple[PointSpec, ...]


# ---------------------------------------------------------------------------------------------
# point sets


def mixed_points(n_tie: int = 12, weighted: bool | str = False) -> tuple[PointSpec, ...]:
    """Tie points, every control kind in the overlap, and control outside it.

    In the overlap: n_tie tie points, 2 FULL, 2 HEIGHT, 2 PLAN. Seen by one photo only: a FULL
    point on each photo (Schmid: control outside the common area), a PLAN point on photo 0 and a
    HEIGHT point on photo 1 (the latter gives no condition: 2 - 2 = 0). weighted: False (all
    control fixed), True (all weighted) or "alternate" (every second control point weighted).
    """
    control = [
        (model.FULL, (0, 1)), (model.FULL, (0, 1)), (model.HEIGHT, (0, 1)), (model.HEIGHT, (0, 1)),
        (model.PLAN, (0, 1)), (model.PLAN, (0, 1)), (model.FULL, (0,)), (model.FULL, (1,)),
        (model.PLAN, (0,)), (model.HEIGHT, (1,)),
    ]
    specs = []
    for i, (kind, seen) in enumerate(control):
        w = bool(weighted) if weighted != "alternate" else (i % 2 == 1)
        specs.append(PointSpec(kind, seen, w))
    specs += [PointSpec(model.TIE, (0, 1)) for _ in range(n_tie)]
    return tuple(specs)


def schmid_minimal_points() -> tuple[PointSpec, ...]:
    """Schmid's minimal pair: two full control points and one height point in the overlap, two
    tie points; 4 + 4 + 2 + 1 + 1 = 12 conditions for the 12 orientation elements. Plate positions
    in photo 0 (mm) at von Gruber's places (near the two principal points, top and bottom; the
    plate base is 0.4 * 230 = 92 mm)."""
    return (
        PointSpec(model.FULL, (0, 1), xy_plate=(5.0, 90.0)),
        PointSpec(model.FULL, (0, 1), xy_plate=(87.0, -90.0)),
        PointSpec(model.HEIGHT, (0, 1), xy_plate=(5.0, -90.0)),
        PointSpec(model.TIE, (0, 1), xy_plate=(87.0, 90.0)),
        PointSpec(model.TIE, (0, 1), xy_plate=(46.0, 0.0)),
    )


def strip_points(n_tie_pair: int = 6, n_tie_triple: int = 6) -> tuple[PointSpec, ...]:
    """For n_photos = 3: control in the triple overlap and at the ends, tie points in both pairs
    and in the triple overlap (scale transfer, Schmid 93)."""
    specs = [
        PointSpec(model.FULL, (0, 1)), PointSpec(model.HEIGHT, (0, 1, 2)), PointSpec(model.PLAN, (0, 1, 2), True),
        PointSpec(model.FULL, (1, 2), True), PointSpec(model.HEIGHT, (1, 2)), PointSpec(model.FULL, (2,)),
    ]
    specs += [PointSpec(model.TIE, (0, 1)) for _ in range(n_tie_pair)]
    specs += [PointSpec(model.TIE, (1, 2)) for _ in range(n_tie_pair)]
    specs += [PointSpec(model.TIE, (0, 1, 2)) for _ in range(n_tie_triple)]
    return tuple(specs)


# ---------------------------------------------------------------------------------------------
# truth


def _terrain(rng: np.random.Generator, relief: float):
    """Z(X, Y) in the local frame: a sum of three random waves of wavelength 2-5 km."""
    k = rng.uniform(2 * np.pi / 5000.0, 2 * np.pi / 2000.0, size=(3, 2)) * rng.choice([-1, 1], size=(3, 2))
    phase = rng.uniform(0, 2 * np.pi, size=3)
    amp = relief * np.array([0.6, 0.3, 0.1])

    def z(X, Y):
        return sum(amp[i] * np.sin(k[i, 0] * X + k[i, 1] * Y + phase[i]) for i in range(3))

    return z


def _ray_meets_terrain(O, r, terrain):
    """Point O + t r on the terrain (fixed-point iteration on Z; contracting for the slopes here)."""
    Z = 0.0
    for _ in range(200):
        t = (Z - O[2]) / r[2]
        P = O + t * r
        Z_new = terrain(P[0], P[1])
        if abs(Z_new - Z) < 1e-10:
            break
        Z = Z_new
    else:
        raise RuntimeError("ray-terrain intersection did not converge")
    t = (Z - O[2]) / r[2]
    return O + t * r


def _seen_by(R, O, interior, X, options: PairOptions) -> tuple[int, ...]:
    """Photos whose usable format contains the ground point X and which see it in front."""
    seen = []
    for i in range(len(O)):
        m = R[i].T @ (X - O[i])
        if m[2] >= 0:
            continue
        xy = project(R[i], O[i], interior, X)
        d = X - O[i]
        off_nadir = np.degrees(np.arccos(-d[2] / np.linalg.norm(d)))
        if np.all(np.abs(xy) <= options.usable_half_format) and off_nadir <= options.max_off_nadir_deg:
            seen.append(i)
    return tuple(seen)


def make_truth(options: PairOptions, rng: np.random.Generator) -> PairTruth:
    """True photos (along X at height H over a terrain of mean height 0) and points."""
    n, H, B = options.n_photos, options.flying_height, options.base
    interior = np.array([options.c, options.xp, options.yp])
    xyz0 = np.zeros((n, 3))
    xyz0[:, 0] = (np.arange(n) - (n - 1) / 2.0) * B
    xyz0[:, 2] = H
    xyz0 += rng.normal(0.0, options.position_jitter, size=(n, 3))
    nominal = np.radians(options.nominal_opk_deg)
    angles = nominal + np.radians(rng.normal(0.0, options.attitude_deg, size=(n, 3)))
    R = R_from_opk(angles)
    terrain = _terrain(rng, options.relief)

    points = np.zeros((len(options.points), 3))
    for j, spec in enumerate(options.points):
        first = spec.seen_by[0]
        for _attempt in range(5000):
            if spec.xy_plate is None:
                xy = rng.uniform(-options.usable_half_format, options.usable_half_format, size=2)
            else:
                xy = np.asarray(spec.xy_plate, dtype=float)
            p = np.array([xy[0] - interior[1], xy[1] - interior[2], -interior[0]])
            r = R[first] @ p
            if r[2] >= 0:
                if spec.xy_plate is not None:
                    raise ValueError(f"point {j}: the ray at {spec.xy_plate} does not reach the ground")
                continue
            X = _ray_meets_terrain(xyz0[first], r, terrain)
            if _seen_by(R, xyz0, interior, X, options) == tuple(spec.seen_by):
                points[j] = X
                break
            if spec.xy_plate is not None:
                raise ValueError(f"point {j} at {spec.xy_plate} is seen by {_seen_by(R, xyz0, interior, X, options)}")
        else:
            raise RuntimeError(f"could not place point {j} seen by exactly {spec.seen_by}")

    # rigid rotation of the whole scene (plate coordinates unchanged), then the grid offset
    Q = Rotation.from_rotvec(np.asarray(options.scene_rotvec, dtype=float)).as_matrix()
    centre = xyz0.mean(axis=0)
    xyz0 = (xyz0 - centre) @ Q.T + centre
    points = (points - centre) @ Q.T + centre
    R = Q @ R
    offset = np.asarray(options.grid_offset, dtype=float)
    return PairTruth(options, xyz0 + offset, R, interior, points + offset, tuple(options.points))


def true_plate_coordinates(truth: PairTruth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact plate coordinates (Schmid 14) of every (photo, point) sighting, by camera.project.
    Returns photo_index (m,), point_index (m,), xy (m, 2), point-major, photos in chain order."""
    photo_index, point_index = [], []
    for j, spec in enumerate(truth.specs):
        for i in spec.seen_by:
            photo_index.append(i)
            point_index.append(j)
    photo_index, point_index = np.array(photo_index), np.array(point_index)
    # project in the reduced frame: the difference X - O is exact there even with grid offsets
    ref = truth.xyz0.mean(axis=0)
    xy = project(
        truth.R_ground_from_cam[photo_index], truth.xyz0[photo_index] - ref,
        np.broadcast_to(truth.interior, (len(photo_index), 3)), truth.xyz_points[point_index] - ref,
    )
    return photo_index, point_index, xy


# ---------------------------------------------------------------------------------------------
# observation


def observe(truth: PairTruth, noise: NoiseOptions, rng: np.random.Generator) -> model.Project:
    """The project a user would have: noisy measurements and approximate orientations."""
    n = len(truth.xyz0)
    photo_index, point_index, xy_true = true_plate_coordinates(truth)
    on = 1.0 if noise.noisy else 0.0  # the draws are made either way: same stream, same approximations
    xy = xy_true + on * rng.normal(0.0, noise.sigma_plate, size=xy_true.shape)

    kinds = np.array([s.kind for s in truth.specs], dtype=int)
    given = np.array([model.GIVEN_AXES[int(k)] for k in kinds], dtype=bool).reshape(-1, 3)
    weighted = np.array([s.weighted for s in truth.specs], dtype=bool)
    control_noise = on * rng.normal(0.0, noise.sigma_control, size=truth.xyz_points.shape)
    xyz_given = np.where(given, truth.xyz_points + np.where(weighted[:, None], control_noise, 0.0), np.nan)
    sigma_given = np.where(given & weighted[:, None], noise.sigma_control, np.nan)

    # approximate orientations (or the GNSS observations, which then serve as approximations)
    position_noise = rng.normal(0.0, 1.0, size=(n, 3))
    rotvec_noise = rng.normal(0.0, np.radians(noise.approx_angle_deg), size=(n, 3))
    if noise.sigma_gnss is not None:
        xyz0 = truth.xyz0 + on * noise.sigma_gnss * position_noise
        sigma_xyz0 = np.full((n, 3), noise.sigma_gnss)
    else:
        xyz0 = truth.xyz0 + noise.approx_position * position_noise
        sigma_xyz0 = np.full((n, 3), np.nan)
    R = truth.R_ground_from_cam @ Rotation.from_rotvec(rotvec_noise).as_matrix()
    angles = opk_from_R(R)
    return model.Project(
        cameras=model.Cameras(["C1"], truth.interior[None, :].copy(), np.full((1, 3), np.nan)),
        photos=model.Photos(
            ids=[f"P{i + 1}" for i in range(n)],
            camera_index=np.zeros(n, dtype=int),
            strip_ids=["S1"] * n,
            xyz0=xyz0,
            R_ground_from_cam=R_from_opk(angles),
            angles=angles,
            sigma_xyz0=sigma_xyz0,
            sigma_angles=np.full((n, 3), np.nan),
        ),
        image_points=model.ImagePoints(
            photo_index=photo_index,
            point_index=point_index,
            xy=xy,
            sigma_xy=np.full(xy.shape, noise.sigma_plate),
        ),
        points=model.ObjectPoints(
            ids=[f"{model.KIND_NAMES[int(k)]}{j}" for j, k in enumerate(kinds)],
            kind=kinds,
            xyz_given=xyz_given,
            sigma_given=sigma_given,
        ),
    )


def make_pair(options: PairOptions, noise: NoiseOptions, seed: int) -> tuple[PairTruth, model.Project]:
    """Truth and project from one seed (truth and noise drawn from separate child generators)."""
    truth_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    truth = make_truth(options, truth_rng)
    return truth, observe(truth, noise, noise_rng)
