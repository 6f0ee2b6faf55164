"""The classical corrections of plate coordinates: Earth curvature and atmospheric refraction.

For users who adjust in map coordinates (a national grid or UTM with heights above sea level,
treated as Cartesian) or who check old results computed that way. Both are radial displacements
about the principal point of a near-vertical photograph (the principal point stands for the nadir
point, as in the classical programs; for a tilt t the nadir lies c tan t away from it). Both are off by default
(project.toml ``[corrections]``, docs/file-formats.md; the choices are in docs/decisions.md,
"Earth curvature and refraction of the plate coordinates").

Notation: r the radial distance of a plate point from the principal point (plate units, those of
c), c the principal distance, Z0 the height of the projection centre and h the height of the ground
point, both above sea level in metres, H' = Z0 - h the flying height above the point, R the radius
of the Earth.

Earth curvature (Kraus, *Photogrammetry*, vol. 1, Duemmler 1993, on the Earth curvature correction
of image coordinates; the same formula in Wolf & Dewitt, *Elements of Photogrammetry*, 3rd ed.,
McGraw-Hill 2000, chapter "Image Measurements and Refinements"): a ground point at distance D from the nadir lies
``D^2 / (2 R)`` below the tangent plane at the nadir; seen from H' above the point, a point that much
lower appears nearer the centre by ``r D^2 / (2 R H')``; with ``D = r H' / c``::

    dr_curvature = r^3 H' / (2 R c^2)          (displacement towards the principal point)

Map coordinates place every point on a plane at its height above the curved datum, so the plane
the adjustment assumes has the point higher (by D^2 / 2R) than it is on the photograph: the
measured image lies *inward* of the map frame's image, and the correction moves it *outward* by
dr_curvature.

Atmospheric refraction (the ARDC 1959 model atmosphere in the closed form going back to Bertram,
Photogrammetric Engineering, 1966 and 1969, as printed in Wolf & Dewitt 2000, same chapter, with
heights in km above sea level): a ray that reaches the camera
at the angle alpha from the vertical (tan alpha = r / c) is bent by ``d_alpha = K tan alpha`` away from
the vertical, with, for Z0 and h in kilometres above sea level::

    K = (2410 Z0 / (Z0^2 - 6 Z0 + 250) - 2410 h^2 / ((h^2 - 6 h + 250) Z0)) 1e-6    (radians)

and the image moves ``c d(tan alpha) = c (1 + tan^2 alpha) d_alpha``::

    dr_refraction = K (r + r^3 / c^2)          (displacement away from the principal point)

The rays arrive steeper than the straight line from the point: the measured image lies *outward*,
and the correction moves it *inward* by dr_refraction.

Both displacements are functions of the ideal (map-frame, straight-ray) radius r. ``displace`` adds
them to ideal plate coordinates (what the camera records; the simulator's side); ``correct`` inverts
that exactly (Newton on the cubic ``r_measured = r + dr(r)``), so ``correct(displace(xy)) = xy`` to
rounding. The classical practice evaluates the correction at the measured radius instead; the
difference is ``dr * d(dr)/dr``, below 1e-6 of the correction for aerial photographs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..model import CHECK, Project

EARTH_RADIUS_M = 6_371_000.0  # mean radius of the Earth (IUGG R1, rounded), m
EARTH_RADIUS_RANGE_M = (6_300_000.0, 6_450_000.0)  # accepted for [corrections] earth_radius

CURVATURE_SOURCE = ("Kraus, Photogrammetry vol. 1 (1993); Wolf & Dewitt, Elements of "
                    "Photogrammetry (2000): dr = r^3 H' / (2 R c^2), towards the principal point")
REFRACTION_SOURCE = ("ARDC 1959 model atmosphere after Bertram (Photogrammetric Engineering 1966, 1969), as printed "
                     "in Wolf & Dewitt, Elements of Photogrammetry (2000): "
                     "K = (2410 H/(H^2 - 6H + 250) - 2410 h^2/((h^2 - 6h + 250) H)) 1e-6, dr = K (r + r^3/c^2), "
                     "away from the principal point")
HEIGHTS_USED = ("h: the point's height from control.csv (not check points) or approx_points.csv, else the mean of "
                "those heights on its photograph, else of the block; Z0 from photos.csv; heights above sea level")

NEWTON_STEPS = 4  # quadratic convergence from r_measured: |dr/r| < 1e-3 gives machine precision in 3


def curvature_displacement(r, c, height_above_ground_m, earth_radius_m: float = EARTH_RADIUS_M) -> np.ndarray:
    """Radial image displacement of Earth curvature (module doc; Kraus 1993).

    r: (...) radial distance from the principal point, c: (...) principal distance, both plate
    units; height_above_ground_m: (...) H' = Z0 - h, m; earth_radius_m: R, m. -> (...) plate units,
    >= 0, the displacement *towards* the principal point (correction: outward)."""
    r = np.asarray(r, dtype=float)
    c = np.asarray(c, dtype=float)
    return r**3 * np.asarray(height_above_ground_m, dtype=float) / (2.0 * earth_radius_m * c**2)


def refraction_constant(Z0_m, h_m) -> np.ndarray:
    """K of the ARDC / Bertram model (module doc), radians. Z0_m: (...) height of the projection
    centre, h_m: (...) height of the ground point, both m above sea level (converted to km here)."""
    H = np.asarray(Z0_m, dtype=float) / 1000.0
    h = np.asarray(h_m, dtype=float) / 1000.0
    return (2410.0 * H / (H**2 - 6.0 * H + 250.0) - 2410.0 * h**2 / ((h**2 - 6.0 * h + 250.0) * H)) * 1e-6


def refraction_displacement(r, c, K) -> np.ndarray:
    """Radial image displacement of atmospheric refraction ``K (r + r^3 / c^2)`` (module doc).

    r, c: (...) plate units; K: (...) radians (refraction_constant). -> (...) plate units, the
    displacement *away from* the principal point (correction: inward)."""
    r = np.asarray(r, dtype=float)
    return np.asarray(K, dtype=float) * (r + r**3 / np.asarray(c, dtype=float) ** 2)


@dataclass(frozen=True)
class RadialModel:
    """The radial displacement ``dr(r) = a r + b r^3`` (plate units, positive outward) of each
    observation, as the sum of the chosen effects. a, b: (m,); a from refraction (K), b from
    refraction (K / c^2) minus curvature (H' / (2 R c^2))."""

    a: np.ndarray
    b: np.ndarray

    @staticmethod
    def of(c, Z0_m, h_m, curvature: bool, refraction: bool, earth_radius_m: float = EARTH_RADIUS_M) -> "RadialModel":
        """c, Z0_m, h_m: (m,) principal distance (plate units), projection-centre and ground heights
        (m above sea level) of each observation."""
        c = np.asarray(c, dtype=float)
        a = np.zeros(np.broadcast(c, Z0_m, h_m).shape)
        b = np.zeros_like(a)
        if refraction:
            K = refraction_constant(Z0_m, h_m)
            a = a + K
            b = b + K / c**2
        if curvature:
            b = b - (np.asarray(Z0_m, dtype=float) - np.asarray(h_m, dtype=float)) / (2.0 * earth_radius_m * c**2)
        return RadialModel(a, b)

    def dr(self, r) -> np.ndarray:
        """(m,) ideal radius -> (m,) signed displacement, outward positive."""
        return self.a * r + self.b * r**3

    def ideal_radius(self, r_measured) -> np.ndarray:
        """Solve ``r + dr(r) = r_measured`` (Newton from r_measured). (m,) -> (m,)."""
        r = np.array(r_measured, dtype=float)
        for _ in range(NEWTON_STEPS):
            f = (1.0 + self.a) * r + self.b * r**3 - r_measured
            r = r - f / (1.0 + self.a + 3.0 * self.b * r**2)
        return r


def _scaled(xy_plate, xy_pp, new_r_of_r) -> np.ndarray:
    """Move each point radially about the principal point: (m, 2), (m, 2) -> (m, 2)."""
    d = np.asarray(xy_plate, dtype=float) - xy_pp
    r = np.hypot(d[:, 0], d[:, 1])
    new_r = new_r_of_r(r)
    scale = np.divide(new_r, r, out=np.ones_like(r), where=r > 0)
    return xy_pp + d * scale[:, None]


def displace(xy_plate, xy_pp, radial: RadialModel) -> np.ndarray:
    """Ideal plate coordinates (map frame, straight rays) -> what the camera records.
    xy_plate, xy_pp: (m, 2) plate units (point, principal point of its camera)."""
    return _scaled(xy_plate, xy_pp, lambda r: r + radial.dr(r))


def correct(xy_measured, xy_pp, radial: RadialModel) -> np.ndarray:
    """Measured plate coordinates -> corrected (ideal) ones; the exact inverse of displace.
    xy_measured, xy_pp: (m, 2) plate units."""
    return _scaled(xy_measured, xy_pp, radial.ideal_radius)


# ---------------------------------------------------------------------------------------------
# the project


def observation_heights(project: Project) -> tuple[np.ndarray, np.ndarray]:
    """Heights of each plate measurement (module doc, HEIGHTS_USED): -> Z0 (m,) of its photo and h
    (m,) of its ground point, m. The point's height is its control height (not a check point's: those
    stay independent) or its approximate height; a point with neither takes the mean of the known
    heights on its photograph, else of the whole block. InputError when no height is known."""
    ip, pts = project.image_points, project.points
    z_given = np.where(pts.kind == CHECK, np.nan, pts.xyz_given[:, 2])
    z_approx = pts.xyz_approx[:, 2] if pts.xyz_approx is not None else np.full(len(pts), np.nan)
    z_point = np.where(np.isfinite(z_given), z_given, z_approx)
    h = z_point[ip.point_index]
    known = np.isfinite(h)
    if not known.any():
        raise InputError(_toml(project), None, "[corrections]: Earth curvature and refraction need the heights of the "
                                               "ground points, but no point has a control height (control.csv) or an "
                                               "approximate height (approx_points.csv)")
    n_photos = len(project.photos)
    total = np.bincount(ip.photo_index[known], weights=h[known], minlength=n_photos)
    count = np.bincount(ip.photo_index[known], minlength=n_photos)
    block_mean = float(h[known].mean())
    photo_mean = np.divide(total, count, out=np.full(n_photos, block_mean), where=count > 0)
    h = np.where(known, h, photo_mean[ip.photo_index])
    return project.photos.xyz0[ip.photo_index, 2], h


def _toml(project: Project):
    return project.source / "project.toml" if project.source is not None else "project.toml"


@dataclass(frozen=True)
class CorrectionSizes:
    """What was applied and how large it was (summary.json "plate_corrections", the report)."""

    summary: dict


def with_switches(project: Project, earth_curvature: bool | None = None, refraction: bool | None = None) -> Project:
    """project with [corrections] earth_curvature / refraction set where given (not None): the
    command line's --earth-curvature, --refraction over project.toml."""
    given = {k: v for k, v in (("earth_curvature", earth_curvature), ("refraction", refraction)) if v is not None}
    if not given:
        return project
    return replace(project, settings=replace(project.settings, **given))


def correct_project(project: Project) -> tuple[Project, CorrectionSizes | None]:
    """The project with its plate coordinates corrected as ``project.settings`` asks
    ([corrections] earth_curvature, refraction, earth_radius), and the sizes of the corrections;
    (project, None) unchanged when no correction is asked for. InputError when a photo's Z0 is not
    above the ground it sees."""
    s = project.settings
    if not (s.earth_curvature or s.refraction):
        return project, None
    ip = project.image_points
    cam = project.photos.camera_index[ip.photo_index]
    c = project.cameras.interior[cam, 0]
    xy_pp = project.cameras.interior[cam, 1:3]
    Z0, h = observation_heights(project)
    low = np.flatnonzero(~(Z0 - h > 0))
    if len(low):
        i = int(low[0])
        photo = project.photos.ids[ip.photo_index[i]]
        point = project.points.ids[ip.point_index[i]]
        raise InputError(_toml(project), None,
                         f"[corrections]: photo '{photo}' has Z0 = {Z0[i]:.6g} m, not above the height {h[i]:.6g} m "
                         f"of the ground at point '{point}' it sees: Earth curvature and refraction need the flying "
                         "height above the ground (heights above sea level in photos.csv, control.csv)")
    radial = RadialModel.of(c, Z0, h, s.earth_curvature, s.refraction, s.earth_radius)
    xy = correct(ip.xy, xy_pp, radial)
    r_measured = np.hypot(*(ip.xy - xy_pp).T)
    r = radial.ideal_radius(r_measured)
    summary = {"plate_unit": s.plate_unit, "r_max": float(r.max()), "heights": HEIGHTS_USED}
    at = int(np.argmax(r))
    if s.earth_curvature:
        size = curvature_displacement(r, c, Z0 - h, s.earth_radius)
        summary["earth_curvature"] = {**_sizes(size, at), "earth_radius_m": float(s.earth_radius),
                                      "direction": "outward", "source": CURVATURE_SOURCE}
    if s.refraction:
        size = refraction_displacement(r, c, refraction_constant(Z0, h))
        summary["refraction"] = {**_sizes(size, at), "direction": "inward", "source": REFRACTION_SOURCE}
    corrected = replace(project, image_points=replace(ip, xy=xy))
    return corrected, CorrectionSizes(summary)


def _sizes(size: np.ndarray, at: int) -> dict:
    """Largest and RMS correction, and the one at the largest radius measured (plate units)."""
    return {"max": float(np.max(size)), "rms": float(np.sqrt(np.mean(size**2))), "at_r_max": float(size[at])}
