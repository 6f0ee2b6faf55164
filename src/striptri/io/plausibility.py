"""Plausibility limits of input numbers (docs/file-formats.md, "Limits"): values no real project
reaches, beyond which double-precision arithmetic stops meaning anything. A value outside them is
refused by the reader with the file, the line and the reason, instead of ending in an overflow,
a singular normal matrix or a traceback deep in the adjustment.

* Ground coordinates (X0, Y0, Z0, control X, Y, Z, approximate points, base components):
  ``|value| <= GROUND_LIMIT_M`` = 1e9 m. Geocentric coordinates of the Earth are below 6.4e6 m,
  projected northings below 1e7 m (false northing included), a geostationary satellite is at
  4.2e7 m and the Moon at 3.8e8 m from the geocentre; at 1e9 m a double still resolves 1e-7 m.
* Plate quantities (c, xp, yp, x, y), in plate units (mm, um, pixels, ...): ``|value| <=
  PLATE_LIMIT`` = 1e9 (no sensor or film is a million times larger than its resolution, in
  any unit in use).
* A measured point must make a ray at most MAX_OFF_AXIS_DEG = 89 deg off the camera axis:
  ``hypot(x - xp, y - yp) <= c tan(89 deg)`` (57.3 c). A frame camera cannot image a ray at 90 deg
  or more (the widest frame lenses see 60 deg off the axis).
* A camera whose measured points all lie within MIN_FIELD = 1e-5 c of its principal point (a
  field of view of 4 arc seconds) has numerically parallel rays: its photos' resections are
  singular to working precision. The narrowest frame cameras in use (long telephoto, satellite
  telescopes) see 1e-2 c and more. Typically c is wrong, or c and the plate coordinates are in
  different units.
* Angles: ``|angle| <= ANGLE_LIMIT_TURNS`` = 10 full turns (3600 deg, 4000 gon, 20 pi rad); an
  attitude is never typed as more, and a sine of a huge argument is noise.
* Standard deviations, where they are observations: finite and within
  [SIGMA_MIN, SIGMA_MAX] = [1e-100, 1e100] in the file's units. Outside that the weight
  1/sigma^2 (and the products the adjustment forms with it) is no longer a finite, normal double,
  which has no physical meaning. Tiny but representable sigmas (say 1e-20 mm) are accepted: they
  are physically absurd but not meaningless to the arithmetic, and what they do to the
  conditioning of the normal equations is explained by the adjustment, not hidden by the reader.
"""

from __future__ import annotations

import math

import numpy as np

GROUND_LIMIT_M = 1e9
PLATE_LIMIT = 1e9
MAX_OFF_AXIS_DEG = 89.0
MAX_RADIUS_PER_C = math.tan(math.radians(MAX_OFF_AXIS_DEG))
MIN_FIELD = 1e-5
ANGLE_LIMIT_TURNS = 10
SIGMA_MIN, SIGMA_MAX = 1e-100, 1e100


def first_beyond(values: np.ndarray, limit: float) -> tuple[int, int] | None:
    """(row, column) of the first |value| > limit in a (n,) or (n, k) array (nan ignored), else None."""
    a = np.abs(np.asarray(values, dtype=float))
    a = a[:, None] if a.ndim == 1 else a
    with np.errstate(invalid="ignore"):
        bad = np.argwhere(a > limit)
    return None if len(bad) == 0 else (int(bad[0][0]), int(bad[0][1]))


def first_sigma_out_of_range(values: np.ndarray) -> int | None:
    """Index of the first finite sigma > 0 outside [SIGMA_MIN, SIGMA_MAX] in a (n,) array (nan, 0 and
    inf are the callers' words for "not observed", "held", "free"), else None."""
    a = np.asarray(values, dtype=float)
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(np.isfinite(a) & (a > 0) & ((a < SIGMA_MIN) | (a > SIGMA_MAX)))
    return None if len(bad) == 0 else int(bad[0])


def angle_limit(radians_per_unit: float) -> float:
    """ANGLE_LIMIT_TURNS in the unit with radians_per_unit."""
    return ANGLE_LIMIT_TURNS * 2.0 * math.pi / radians_per_unit


def number_text(value: float) -> str:
    """A number for a message, plain (never a numpy repr): 1e9 for 1e+09, 0.005 for 0.005."""
    text = f"{float(value):g}"
    return text.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")
