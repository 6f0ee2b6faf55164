"""What to simulate: the design of a synthetic flight, apart from any noise (cf. COLMAP's
``SyntheticDatasetOptions``). Frozen dataclasses, validated on construction (ValueError).

Conventions (DESIGN section 1): plate units are those of c (mm), ground units metres, angles in
these options are degrees. The flight direction ``heading_deg`` is measured in the ground XY plane
from +X towards +Y (0 = flown along +X, 90 = flown along +Y). The ideal photo looks straight down
with its plate x axis along the flight direction, i.e. ``R_ground_from_cam = Rz(heading)``
(omega = phi = 0, kappa = heading): Schmid's normal case for a strip flown along X.

A block is ``n_strips`` parallel strips of ``n_photos`` photos each, laid side by side to the left
of the first strip (towards +Y when it is flown along +X) at a spacing of
``(1 - sidelap) * format * flying_height / c``; with ``alternate`` every other strip is flown the
other way (as a survey aircraft flies a block). A strip is a block of one strip.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from striptri.model import FULL, HEIGHT, PLAN

# Control layouts (ControlDesign.layout). A pair layout needs exactly two photos; a block layout
# serves strips and blocks; Schmid's Fig. 8 strip is one fixed strip of five photos.
PAIR_LAYOUTS = ("corners", "mixed", "schmid-minimal")
BLOCK_LAYOUTS = ("ends", "every-k", "perimeter", "sparse-height")
SCHMID_FIG8 = "schmid-fig8"
STRIP_LAYOUTS = BLOCK_LAYOUTS + (SCHMID_FIG8,)
LAYOUTS = PAIR_LAYOUTS + STRIP_LAYOUTS + ("none",)
EVERY_K_KINDS = {"XYZ": FULL, "XY": PLAN, "Z": HEIGHT}


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _triple(value, name: str) -> tuple[float, float, float]:
    t = tuple(float(v) for v in value)
    _require(len(t) == 3 and all(v >= 0 for v in t), f"{name} must be three non-negative numbers")
    return t


MAX_PHOTOS_PER_STRIP = 1_000_000  # photo ids get wider than 3 digits from 1,000 photos per strip on


@dataclass(frozen=True)
class CameraDesign:
    """Metric camera: principal distance c, square format of side ``format`` centred on the fiducial
    origin, principal point (xp, yp); plate units (mm). A point is measurable when its plate
    coordinates lie within ``format / 2 - margin`` of the fiducial origin (the margin keeps points
    off the edge and the fiducial marks)."""

    c: float = 152.0
    format: float = 230.0
    xp: float = 0.0
    yp: float = 0.0
    margin: float = 5.0
    camera_id: str = "C1"

    def __post_init__(self):
        _require(self.c > 0, "camera: c must be positive")
        _require(self.format > 0, "camera: format must be positive")
        _require(0 <= self.margin < self.format / 2, "camera: margin must be in [0, format/2)")

    @property
    def half_usable(self) -> float:
        """Half side of the usable square of the plate (plate units)."""
        return self.format / 2 - self.margin


@dataclass(frozen=True)
class FlightDesign:
    """The flight: ``n_strips`` parallel strips of ``n_photos`` photos each (one strip of two photos =
    a pair).

    flying_height: metres above the mean terrain. overlap: forward overlap as a fraction of the
    format (0.6 classical, 2/3 for Schmid's Fig. 8 strip); the air base is
    ``(1 - overlap) * format * flying_height / c``. sidelap: overlap of neighbouring strips as a
    fraction of the format (0.2 .. 0.6; 0.3 classical); the strip spacing is
    ``(1 - sidelap) * format * flying_height / c``. alternate: fly every other strip the other way
    (its first photo is then at the end where the previous strip ended). start_xy: ground XY of the
    first nominal nadir of the first strip. heading_deg: flight direction of the first strip.
    attitude_std_deg: standard deviations (omega, phi, kappa) of the true attitudes about the ideal
    one. position_std_m: standard deviations (along track, across track, height) of the true
    projection centres about the ideal flight line.
    """

    n_photos: int = 2
    overlap: float = 0.6
    flying_height: float = 1500.0
    heading_deg: float = 0.0
    start_xy: tuple[float, float] = (5000.0, 5000.0)
    attitude_std_deg: tuple[float, float, float] = (1.0, 1.0, 1.0)
    position_std_m: tuple[float, float, float] = (5.0, 5.0, 5.0)
    n_strips: int = 1
    sidelap: float = 0.3
    alternate: bool = True

    def __post_init__(self):
        _require(int(self.n_photos) == self.n_photos and 2 <= self.n_photos <= MAX_PHOTOS_PER_STRIP,
                 f"flight: 2 to {MAX_PHOTOS_PER_STRIP} photos per strip")
        _require(int(self.n_strips) == self.n_strips and self.n_strips >= 1, "flight: at least 1 strip")
        _require(0.5 < self.overlap < 0.95, "flight: forward overlap must be in (0.5, 0.95)")
        _require(0.1 <= self.sidelap <= 0.7, "flight: sidelap must be in [0.1, 0.7]")
        _require(self.flying_height > 0, "flight: flying height must be positive")
        _require(len(self.start_xy) == 2, "flight: start_xy must be (X, Y)")
        object.__setattr__(self, "start_xy", tuple(float(v) for v in self.start_xy))
        object.__setattr__(self, "attitude_std_deg", _triple(self.attitude_std_deg, "flight: attitude_std_deg"))
        object.__setattr__(self, "position_std_m", _triple(self.position_std_m, "flight: position_std_m"))


@dataclass(frozen=True)
class TerrainDesign:
    """Smooth random terrain: ``Z = mean_z + sum of n_waves plane sine waves`` whose amplitudes add up
    to ``relief`` (so |Z - mean_z| <= relief), wavelengths between ``wavelength_range`` times the
    ground footprint of a photo."""

    mean_z: float = 100.0
    relief: float = 50.0
    n_waves: int = 6
    wavelength_range: tuple[float, float] = (0.5, 3.0)

    def __post_init__(self):
        _require(self.relief >= 0, "terrain: relief must be non-negative")
        _require(self.n_waves >= 1, "terrain: at least one wave")
        lo, hi = self.wavelength_range
        _require(0 < lo <= hi, "terrain: wavelength_range must be 0 < low <= high")


@dataclass(frozen=True)
class PointDesign:
    """Pass points in the classical (von Gruber) positions: at every nominal nadir and at
    +/- ``lateral_offset`` (plate units at the mean terrain, across track) from it; with a forward
    overlap above 50 % the points at an inner nadir are seen by three photos. Plus
    ``extra_ties_per_model`` random tie points in the overlap of each pair of consecutive photos."""

    lateral_offset: float = 90.0
    extra_ties_per_model: int = 0

    def __post_init__(self):
        _require(self.lateral_offset > 0, "points: lateral offset must be positive")
        _require(self.extra_ties_per_model >= 0, "points: extra tie points must be >= 0")


@dataclass(frozen=True)
class ControlDesign:
    """Which pass points are control, which are check points.

    layout (the pass point at a nadir is L, C or R: left of the flight direction, on it, right):

    * ``corners`` (pair): the four lateral points are full (XYZ) points;
    * ``mixed`` (pair): first-left XYZ, second-right XYZ, first-right XY, second-left Z;
    * ``schmid-minimal`` (pair): Schmid's minimal configuration (BRL 961, end of section on the two
      cameras): two full points in the overlap (first-left, second-right), one height point
      (second-left) and two relative points (the two nadir points), nothing else:
      8 + 2 + 2 = 12 conditions for 12 unknowns;
    Strips and blocks. The pass points of a block lie in rows across the strips: the outer row of the
    first strip (its right side), the nadir row of every strip, one row in the middle of every
    sidelap (shared by the two strips) and the outer row of the last strip; the *lateral* rows are
    all rows but the nadir rows. A *column* is a nadir position along the strips (photo k of a strip
    flown forwards, photo n-1-k of one flown backwards). For one strip the lateral rows are its L
    and R points.

    * ``ends``: the lateral points of the first two and of the last two columns (the corners of the
      first and of the last model of every strip) are XYZ;
    * ``every-k``: ``ends`` plus the lateral points at every k-th column in between, of kind
      ``every_k_kind`` (Z by default: height points);
    * ``perimeter`` (the classical block layout): XYZ points around the block perimeter every k
      models (the two outer rows at columns 0, k, 2k, ... and the last column; every lateral point
      of the first and of the last column), height points inside (the sidelap rows at the same
      columns);
    * ``sparse-height``: XYZ at the four corners of the block only, Z at the lateral points of
      every k-th column (and of the last column);
    * ``schmid-fig8``: Schmid's worked strip (BRL 961, Fig. 8 and its table; see
      :mod:`striptri.simulate.schmid_fig8`): 5 photos, 2/3 overlap, 30 points of which 12 are in two
      and 18 in three photos; XYZ points 1 (two photos), 16 (three), 30 (two); Z points 3 (two)
      and 14 (three); the rest relative (tie) points;
    * ``none``: no control (tie points only; for free-network datums).

    n_check: tie points turned into check points (evenly spread along the flight; in a block,
    shared out over the strips). n_single_photo: 0, 1 or 2 full control points outside the common
    area, each seen by one photo only (Schmid allows such points): behind the first nadir of the
    first strip, then beyond its last one (in a block, on the outer side of the first strip, so
    that no neighbouring strip sees them).
    """

    layout: str = "corners"
    every_k: int = 2
    every_k_kind: str = "Z"
    n_check: int = 0
    n_single_photo: int = 0

    def __post_init__(self):
        _require(self.layout in LAYOUTS, f"control: unknown layout {self.layout!r} (one of {', '.join(LAYOUTS)})")
        _require(self.every_k >= 1, "control: every_k must be >= 1")
        _require(self.every_k_kind in EVERY_K_KINDS, "control: every_k_kind must be XYZ, XY or Z")
        _require(self.n_check >= 0, "control: number of check points must be >= 0")
        _require(self.n_single_photo in (0, 1, 2), "control: single-photo control points must be 0, 1 or 2")


@dataclass(frozen=True)
class SyntheticDesign:
    """The whole design (truth apart from noise)."""

    camera: CameraDesign = field(default_factory=CameraDesign)
    flight: FlightDesign = field(default_factory=FlightDesign)
    terrain: TerrainDesign = field(default_factory=TerrainDesign)
    points: PointDesign = field(default_factory=PointDesign)
    control: ControlDesign = field(default_factory=ControlDesign)

    def __post_init__(self):
        layout, flight = self.control.layout, self.flight
        if layout in PAIR_LAYOUTS:
            _require(flight.n_photos == 2 and flight.n_strips == 1, f"control layout {layout!r} is for a pair (2 photos)")
        if layout == SCHMID_FIG8:
            _require(
                flight.n_photos == 5 and abs(flight.overlap - 2 / 3) < 1e-9 and flight.n_strips == 1,
                "control layout 'schmid-fig8' is Schmid's strip: 5 photos, 2/3 overlap, one strip",
            )
            _require(
                self.points.extra_ties_per_model == 0 and self.control.n_check == 0 and self.control.n_single_photo == 0,
                "control layout 'schmid-fig8' is exactly Schmid's 30 points: no extra tie, check or single-photo points",
            )
        if layout == "schmid-minimal":
            _require(
                self.points.extra_ties_per_model == 0 and self.control.n_check == 0 and self.control.n_single_photo == 0,
                "control layout 'schmid-minimal' is exactly five points: no extra tie, check or single-photo points",
            )
        _require(
            self.points.lateral_offset < self.camera.half_usable,
            "points: lateral offset must lie inside the usable format",
        )
        _require(self.terrain.relief < 0.5 * self.flight.flying_height, "terrain: relief must be below half the flying height")
        if flight.n_strips > 1:
            _require(
                (1.0 - flight.sidelap) * self.camera.format / 2 < self.camera.half_usable,
                "flight: the sidelap is too small for points in the middle of it to lie inside the usable format",
            )

    @property
    def scale(self) -> float:
        """Ground metres per plate unit at the mean terrain (the photo scale number / 1000 for mm)."""
        return self.flight.flying_height / self.camera.c

    @property
    def base(self) -> float:
        """Nominal air base (m)."""
        return (1.0 - self.flight.overlap) * self.camera.format * self.scale

    @property
    def strip_spacing(self) -> float:
        """Nominal distance between the axes of neighbouring strips (m)."""
        return (1.0 - self.flight.sidelap) * self.camera.format * self.scale
