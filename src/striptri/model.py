"""The in-memory project: struct-of-arrays tables that every layer below the I/O edge works on.

Ids (strings) live here only to name things in output; the mathematics works on integer indices.
Conventions (DESIGN.md section 1):

* ground frame right-handed, metres, Z up; plate frame x, y in the units of c, named by
  ``ProjectSettings.plate_unit`` (mm by default, px for pixels);
* ``R_ground_from_cam`` maps the camera-frame vector ``p = (x - xp, y - yp, -c)`` to the ground;
* angles in the tables are radians, in the convention named by ``ProjectSettings.rotation``;
* every element (camera, photo, point, GNSS) is held, observed or free (:class:`ElementState`). The
  tables keep the files' sigma conventions, which differ by file for good reasons (an empty sigma
  leaves a photo free, holds a control coordinate or a camera element, Schmid 24's enforced
  elements are a sigma of 0); each table translates its own, in one place, into its ``*_state``
  arrays, and everything below reads those (docs/decisions.md, "One element state").
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .geometry.lens import NCP, PLATE

# Object point kinds (column `kind` of control.csv; TIE for points only measured on the plates).
TIE, HEIGHT, PLAN, FULL, CHECK = 0, 1, 2, 3, 4
KIND_NAMES = {TIE: "tie", HEIGHT: "Z", PLAN: "XY", FULL: "XYZ", CHECK: "check"}
KIND_CODES = {"XYZ": FULL, "XY": PLAN, "Z": HEIGHT, "CHECK": CHECK}
# Which of X, Y, Z a kind gives (used in the adjustment; check points are withheld). Read it
# through given_axes / needed_axes below, the one place that turns kinds into axes.
GIVEN_AXES = {
    TIE: (False, False, False),
    HEIGHT: (False, False, True),
    PLAN: (True, True, False),
    FULL: (True, True, True),
    CHECK: (False, False, False),
}
_GIVEN_AXES_TABLE = np.array([GIVEN_AXES[code] for code in range(len(GIVEN_AXES))], dtype=bool)  # (5, 3)
_NEEDED_AXES_TABLE = _GIVEN_AXES_TABLE.copy()
_NEEDED_AXES_TABLE[CHECK] = True


def given_axes(kind) -> np.ndarray:
    """Which of X, Y, Z the points of kind codes ``kind`` give as observations of the adjustment:
    (...,) int -> (..., 3) bool (a single code gives (3,)). Check points give none: their
    coordinates are reference values, withheld (needed_axes)."""
    return _GIVEN_AXES_TABLE[_kind_codes(kind)]


def needed_axes(kind) -> np.ndarray:
    """Which of X, Y, Z a control.csv row of kind codes ``kind`` must carry: the given axes, and all
    three for a check point (its reference coordinates). (...,) int -> (..., 3) bool."""
    return _NEEDED_AXES_TABLE[_kind_codes(kind)]


def _kind_codes(kind) -> np.ndarray:
    codes = np.asarray(kind, dtype=np.int64)
    if codes.size and (codes.min() < 0 or codes.max() >= len(_GIVEN_AXES_TABLE)):
        raise ValueError(f"unknown point kind code(s) {sorted(set(codes[(codes < 0) | (codes > CHECK)].tolist()))}")
    return codes

ROTATION_CONVENTIONS = ("omega-phi-kappa", "alpha-omega-chi", "phi-omega-kappa")
# Output photos.csv always has omega, phi, kappa; a project in another convention also gets that
# convention's angles, with these column prefixes (docs/file-formats.md, output folder).
ROTATION_OUTPUT_NAMES = {
    "alpha-omega-chi": ("schmid_alpha", "schmid_omega", "schmid_chi"),
    "phi-omega-kappa": ("pok_phi", "pok_omega", "pok_kappa"),
}
ANGLE_UNITS = ("deg", "gon", "rad")
# Values of [units] plate: the unit of the plate quantities (c, xp, yp, x, y and their sigmas).
PLATE_UNITS = ("mm", "px")
# Values accepted for [adjustment] solver in project.toml and --solver (DESIGN sections 5, 8;
# docs/solvers.md): here, where reading a project needs them without loading the solvers (and scipy).
SOLVERS = ("auto", "dense", "sparse", "banded", "cholmod", "cvxopt", "gauss-seidel", "pcg", "strip-pcg")


class ElementState(enum.IntEnum):
    """How an element of the model takes part in the adjustment, as COLMAP's bundle-adjustment
    Config sets parameters constant or variable: HELD, its value is kept (not an unknown);
    OBSERVED, an unknown with an observation of its value (its sigma > 0 the observation's);
    FREE, an unknown without an observation."""

    HELD = 0
    OBSERVED = 1
    FREE = 2


HELD, OBSERVED, FREE = ElementState.HELD, ElementState.OBSERVED, ElementState.FREE


def element_states(sigma: np.ndarray, missing: ElementState) -> np.ndarray:
    """The states (int8, sigma's shape) of elements with standard deviations ``sigma``: 0 held, inf
    free, finite > 0 observed, nan ``missing`` (the file's meaning of an empty sigma)."""
    sigma = np.asarray(sigma, dtype=float)
    state = np.full(sigma.shape, int(OBSERVED), dtype=np.int8)
    state[np.isnan(sigma)] = int(missing)
    state[sigma == 0] = int(HELD)
    state[np.isposinf(sigma)] = int(FREE)
    return state


@dataclass(frozen=True)
class Cameras:
    """Interior orientation and additional parameters per camera (striptri.geometry.lens).

    interior: (ncam, NCP) columns lens.CAMERA_ELEMENTS (c, xp, yp, k1, k2, k3, p1, p2, b1, b2);
    sigma_interior: (ncam, NCP), nan (or 0) = held fixed, > 0 = observed, inf = free, translated
    into interior_state (ncam, NCP) ElementState codes;
    convention: (ncam,) lens.PLATE or lens.IMAGE, where the distortion acts.
    r0: (ncam,) the zero-crossing radius of cameras given with balanced radial distortion
    (striptri.geometry.balanced; nan = none, None = no camera): ``interior`` always holds the Gaussian form,
    r0 only says how to write the camera back.
    Tables with only the first columns (c, xp, yp) are padded: distortion 0 and held fixed.
    size_px: (ncam, 2) width and height in pixels of a digital frame camera's images, and
    pixel_size: (ncam,) the size of its pixels in plate units (striptri.geometry.pixels); nan for a
    camera without them, None when no camera has them.
    """

    ids: list[str]
    interior: np.ndarray
    sigma_interior: np.ndarray
    convention: np.ndarray | None = None
    r0: np.ndarray | None = None
    size_px: np.ndarray | None = None
    pixel_size: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.ids)
        interior = np.zeros((n, NCP))
        sigma = np.full((n, NCP), np.nan)
        given = np.asarray(self.interior, dtype=float).reshape(n, -1)
        given_sigma = np.asarray(self.sigma_interior, dtype=float).reshape(n, -1)
        interior[:, : given.shape[1]] = given
        sigma[:, : given_sigma.shape[1]] = given_sigma
        conv = np.full(n, PLATE, dtype=int) if self.convention is None else np.asarray(self.convention, dtype=int)
        object.__setattr__(self, "interior", interior)
        object.__setattr__(self, "sigma_interior", sigma)
        object.__setattr__(self, "convention", conv.reshape(n).copy())

    @property
    def interior_state(self) -> np.ndarray:
        """(ncam, NCP) ElementState of each camera element (an empty sigma holds it)."""
        return element_states(self.sigma_interior, HELD)

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class Photos:
    """Exterior orientation per photo (approximate values unless observed).

    xyz0: (n, 3) projection centres, ground metres. R_ground_from_cam: (n, 3, 3).
    angles: (n, 3) the file's angles in radians (convention ProjectSettings.rotation).
    sigma_xyz0, sigma_angles: (n, 3); nan = free, 0 = held fixed, > 0 = observed (GNSS, IMU),
    translated into centre_state and angle_state (n, 3) ElementState codes.
    """

    ids: list[str]
    camera_index: np.ndarray
    strip_ids: list[str]
    xyz0: np.ndarray
    R_ground_from_cam: np.ndarray
    angles: np.ndarray
    sigma_xyz0: np.ndarray
    sigma_angles: np.ndarray
    @property
    def centre_state(self) -> np.ndarray:
        """(n, 3) ElementState of X0, Y0, Z0 (an empty sigma leaves it free)."""
        return element_states(self.sigma_xyz0, FREE)

    @property
    def angle_state(self) -> np.ndarray:
        """(n, 3) ElementState of the three angles (an empty sigma leaves it free)."""
        return element_states(self.sigma_angles, FREE)

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class ImagePoints:
    """Plate measurements, one row per (photo, point). xy, sigma_xy: (m, 2) plate units."""

    photo_index: np.ndarray
    point_index: np.ndarray
    xy: np.ndarray
    sigma_xy: np.ndarray

    def __len__(self) -> int:
        return len(self.photo_index)


@dataclass(frozen=True)
class ObjectPoints:
    """Every object point named in image_points.csv or control.csv.

    kind: (np,) codes TIE, HEIGHT, PLAN, FULL, CHECK. xyz_given: (np, 3), nan where not given
    (check points carry their reference coordinates here). sigma_given: (np, 3), nan (or 0) = held
    fixed, > 0 = weighted control (an observation of the point's group); given_state (np, 3) the
    ElementState of each coordinate: held or observed where the point gives it (given_axes, with
    a finite coordinate), free elsewhere. xyz_approx: (np, 3)
    approximate coordinates (approx_points.csv; nan or None = none): starting values for the
    bundle method, never observations.
    """

    ids: list[str]
    kind: np.ndarray
    xyz_given: np.ndarray
    sigma_given: np.ndarray
    xyz_approx: np.ndarray | None = None
    @property
    def given_state(self) -> np.ndarray:
        """(np, 3) ElementState of each coordinate: held or observed where the point gives it, free
        elsewhere (an empty sigma of a given coordinate holds it)."""
        given = self.given_axes & np.isfinite(np.asarray(self.xyz_given, dtype=float).reshape(len(self), 3))
        state = element_states(np.asarray(self.sigma_given, dtype=float).reshape(len(self), 3), HELD)
        return np.where(given, state, np.int8(FREE)).astype(np.int8)

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def given_axes(self) -> np.ndarray:
        """(np, 3) bool: which of X, Y, Z each point gives to the adjustment (model.given_axes)."""
        return given_axes(self.kind).reshape(len(self), 3)


@dataclass(frozen=True)
class BaseComponents:
    """Observed or enforced base components (Schmid 17, 24): value = O[photo_to, axis] - O[photo_from, axis].
    sigma: nan or 0 = enforced exactly, > 0 = observed (statoscope)."""

    photo_from: np.ndarray
    photo_to: np.ndarray
    axis: np.ndarray
    value: np.ndarray
    sigma: np.ndarray

    def __len__(self) -> int:
        return len(self.photo_from)

    @staticmethod
    def empty() -> "BaseComponents":
        e = np.zeros(0)
        return BaseComponents(e.astype(int), e.astype(int), e.astype(int), e, e)


HEIGHT_KINDS = ("ellipsoidal", "orthometric")


@dataclass(frozen=True)
class CoordinateSettings:
    """project.toml [coordinates] (docs/file-formats.md): the CRS of the ground coordinates (an EPSG
    code or WKT, as given; a projected CRS in metres), the kind of the heights (HEIGHT_KINDS) and,
    for orthometric heights, the geoid undulation N (h = H + N): a constant in metres or a PROJ grid
    file (absolute path). line: of the section header in project.toml, for messages."""

    crs: str
    heights: str
    geoid_undulation: float | None = None
    geoid_grid: Path | None = None
    line: int | None = None


@dataclass(frozen=True)
class Distances:
    """Observed distances between object points (distances.csv). point_from, point_to: (r,) indices into Project.points; distance (r,) m; sigma (r,) m (> 0);
    line: (r,) line numbers in distances.csv (for messages), or None."""

    point_from: np.ndarray
    point_to: np.ndarray
    distance: np.ndarray
    sigma: np.ndarray
    line: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.distance)


@dataclass(frozen=True)
class ProjectSettings:
    """What project.toml says (all optional)."""

    angle_unit: str = "deg"
    rotation: str = "omega-phi-kappa"
    sigma_image: float = 0.005
    method: str = "conditions"
    solver: str = "auto"
    max_iterations: int = 30
    datum: str = "control"
    datum_points: tuple = ()  # [datum] points: the datum points of mode "inner-points" (empty: all)
    cost_tolerance: float = 0.0  # bundle method: AdjustmentOptions.cost_tolerance (0 = off)
    plate_unit: str = "mm"  # PLATE_UNITS: mm of the plate (film, sensor) or px (pixels of the image)
    # [corrections] (striptri.equations.plate_corrections): classical corrections of the plate coordinates
    earth_curvature: bool = False
    refraction: bool = False
    earth_radius: float = 6_371_000.0  # m, the sphere of the Earth curvature correction
    coordinates: CoordinateSettings | None = None  # [coordinates]: None = a local Cartesian frame (striptri.crs)


@dataclass(frozen=True)
class Project:
    cameras: Cameras
    photos: Photos
    image_points: ImagePoints
    points: ObjectPoints
    bases: BaseComponents = field(default_factory=BaseComponents.empty)
    settings: ProjectSettings = field(default_factory=ProjectSettings)
    source: Path | None = None
    # what the reader did not use or had to interpret (striptri.errors.Note): printed as warnings,
    # listed in report.html and summary.json "warnings"; nothing in the input is ignored silently
    notes: tuple = ()
    # GNSS lever arm, boresight, shift and drift (GnssModel below); None: plain observed
    # centres and angles
    gnss: GnssModel | None = None
    # scanned film (striptri.film.data.FilmData): the fiducial fit and the calibration report,
    # for the report and output tables; None: plate coordinates given in plate units
    film: object | None = None
    # image_points.csv rows with active = 0 (striptri.report.inactive): kept, written back, given residuals
    # against the adjusted result and reported, but never adjusted; None: every row is active.
    # Their point_index refers to ``points`` like image_points' (a point may have inactive rows only).
    inactive_image_points: ImagePoints | None = None
    # distances.csv (Distances): observed distances between object
    # points (methods conditions and bundle, striptri.equations.joint_groups); None: none
    distances: object | None = None


# ------------------------------------------------------------------- GNSS and IMU
# GNSS-supported triangulation: what the project says about the GNSS antenna and the IMU
# (docs/decisions.md "GNSS-supported triangulation").
#
# Observation equations (parameter_observations, rows of the observed centres and angles):
#
# * antenna position of photo i (camera c, strip s, time t_i), the photos.csv centre with a sigma:
#   ``A_i = O_i + R_ground_from_cam_i e_c + s_s + d_s (t_i - t0_s)``: e_c the lever arm of camera c
#   (metres, camera frame: x, y on the plate axes, z along the viewing direction's opposite, the
#   frame of DESIGN section 1), s_s the shift and d_s the drift of the strip (ground frame, m and
#   m/s), t0_s the earliest time of the strip's photos;
# * IMU angles of photo i, the photos.csv angles with a sigma: ``angles(R_ground_from_cam_i Exp(b_c))``
#   with b_c the boresight rotation vector of camera c (radians, camera frame):
#   ``R_cam_from_imu = Exp(b_c)``, so ``R_ground_from_imu = R_ground_from_cam R_cam_from_imu``.
#
# Every element is held (sigma nan, the default; a lever arm and boresight of 0 held is the model
# without them), observed (sigma > 0, an observation of the element with the given value) or free
# (sigma inf), as the camera elements (model.Cameras). Shift and drift are "none" (not in the
# model), "free" or "observed" (an observation of 0 with the sigma of the project).


GNSS_MODES = ("none", "free", "observed")  # of the shift and the drift


@dataclass(frozen=True)
class GnssModel:
    """lever (ncam, 3) m, sigma_lever (ncam, 3) (nan held, > 0 observed, inf free); boresight
    (ncam, 3) rotation vector in radians, sigma_boresight (ncam, 3) radians; lever_state and
    boresight_state their ElementState codes; time (n_photos,)
    seconds (nan: not given); strip (n_photos,) index of the photo's strip (-1: empty strip_id:
    no shift or drift), strip_ids (n_strips,); shift / drift modes (GNSS_MODES) with their sigmas
    (m, m/s; used when "observed")."""

    lever: np.ndarray
    sigma_lever: np.ndarray
    boresight: np.ndarray
    sigma_boresight: np.ndarray
    time: np.ndarray
    strip: np.ndarray
    strip_ids: tuple
    shift: str = "none"
    drift: str = "none"
    sigma_shift: float = float("nan")
    sigma_drift: float = float("nan")
    @property
    def lever_state(self) -> np.ndarray:
        """(ncam, 3) ElementState of the lever arm's components."""
        return element_states(self.sigma_lever, HELD)

    @property
    def boresight_state(self) -> np.ndarray:
        """(ncam, 3) ElementState of the boresight's components."""
        return element_states(self.sigma_boresight, HELD)

    @property
    def n_strips(self) -> int:
        return len(self.strip_ids)

    @property
    def t0(self) -> np.ndarray:
        """(n_strips,) the earliest time of each strip's photos (0 where no time is given)."""
        t0 = np.full(self.n_strips, np.inf)
        ok = (self.strip >= 0) & np.isfinite(self.time)
        np.minimum.at(t0, self.strip[ok], self.time[ok])
        return np.where(np.isfinite(t0), t0, 0.0)

    @property
    def dt(self) -> np.ndarray:
        """(n_photos,) t_i - t0 of the photo's strip (0 without a strip or a time)."""
        ok = (self.strip >= 0) & np.isfinite(self.time)
        out = np.zeros(len(self.time))
        out[ok] = self.time[ok] - self.t0[self.strip[ok]]
        return out

    @property
    def in_play(self) -> bool:
        """True when the model differs from plain observed centres and angles."""
        return bool(np.any(self.lever != 0) or np.any(self.boresight != 0) or np.any(self.lever_state != HELD)
                    or np.any(self.boresight_state != HELD) or self.shift != "none" or self.drift != "none")


def default_gnss(n_cameras: int, strip_ids: list[str]) -> GnssModel:
    """The model of a project without GNSS columns: lever arm and boresight 0, held; no shift or
    drift (today's observed centres and angles)."""
    names = [s for s in dict.fromkeys(strip_ids) if s != ""]
    index = {s: k for k, s in enumerate(names)}
    strip = np.array([index.get(s, -1) for s in strip_ids], dtype=int)
    z = np.zeros((n_cameras, 3))
    nan = np.full((n_cameras, 3), np.nan)
    return GnssModel(lever=z, sigma_lever=nan, boresight=z.copy(), sigma_boresight=nan.copy(),
                     time=np.full(len(strip_ids), np.nan), strip=strip, strip_ids=tuple(names))
