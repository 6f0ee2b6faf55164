"""Likely causes of a failed adjustment, in a photogrammetrist's words (docs/decisions.md, "Failures
and their diagnosis").

These checks run only after a failure (an iteration that did not converge or diverged, a singular
normal matrix, numbers that overflowed); each is vectorised over photos, points or measurements
and costs a few passes over the image points, little next to one iteration of the adjustment.
Each returns sentences naming what it found (empty when nothing):

* :func:`extreme_weights` - standard deviations so far from the others' that the weights span more
  than double precision can hold (a sigma of 1e-20 among sigmas of 0.005);
* :func:`camera_units` - a principal distance in another unit than its plate coordinates
  (c = 152000 with x, y in millimetres), judged by the field angle it implies;
* :func:`implausible_values` - centres, plate coordinates or control far outside everything else
  (a typo such as X0 = 1e300), which overflow the arithmetic;
* :func:`wrong_orientations` - photos whose approximate rotation about the camera axis (kappa) is
  a quarter, half or three quarters of a turn off, found by the coplanarity of their rays with the
  neighbouring photos' (also the whole block turned at once), and photos (or the whole block) whose
  approximate orientation does not fit for another reason;
* :func:`photo_groups` - photos in groups that share no points (a strip cut in two), and which
  group has no datum of its own.

:func:`likely_causes` runs the ones that fit a kind of failure, in that order of precedence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..geometry.camera import plate_vector
from ..equations.datum import describe
from ..equations.groups import adjusted_kind
from ..model import FULL, HEIGHT, PLAN, Project, given_axes
from ..geometry.rotations import angles_from_R, angles_jacobian

# -- weights ----------------------------------------------------------------------------------------
# A weight 1e12 times the median of its kind (sigma 1e6 times smaller or larger) leaves fewer than
# four significant digits in the solution (double precision carries 16), and pushes regular
# directions of the Jacobi-scaled normal matrix to ~1e-12, the level of the datum test
# (datum.STRICT_TOLERANCE 1e-13) and of the solvers' pivot test (pivot^2 below 1e-14): the
# failures it causes are then reported as a datum defect or a singular matrix.
SIGMA_RATIO = 1e6

# -- units of c ---------------------------------------------------------------------------------------
# A frame camera's half-field angle to the farthest measured point lies between a few degrees (long
# focal lengths) and some 60 deg (super wide angle); c/extent of about 0.5 to 10. A c more than 200
# times the extent (half-field angle below 0.3 deg) or less than 1/20 of it (above 87 deg) is no
# frame camera: the two are in different units.
C_TOO_LONG = 200.0
C_TOO_SHORT = 1.0 / 20.0
EXTENT_QUANTILE = 0.95  # the extent of a camera's plate coordinates (robust to a few wild ones)

# -- implausible values -------------------------------------------------------------------------------
FAR = 1000.0  # a value this many times farther out than the typical one is a typo or another unit
OUTSIDE_IMAGE = 2.0  # a plate coordinate this many times beyond the camera's EXTENT_QUANTILE lies off the image

# -- turned photos -------------------------------------------------------------------------------------
TURNS_DEG = (90, 180, 270)
# The misclosure of a ray pair: the angle by which one ray misses the epipolar plane of the other
# and the base (90 deg, the most there is, for a pair whose rays meet behind a camera). Approximate
# orientations good to a few degrees give a median of a few degrees; a photo turned by a quarter
# turn or more gives tens of degrees. A photo (or the block) is called turned when its median at
# the given kappa is above GROSS_DEG and a turn lowers it by at least IMPROVEMENT times.
GROSS_DEG = 10.0
IMPROVEMENT = 4.0
MIN_PAIRS = 3  # ray pairs a photo needs for a verdict
# A photo no kappa turn explains is blamed when MISFIT_SHARE of its ray pairs miss by more than
# MISFIT_DEG (its neighbours share only part of their pairs with it); approximate attitudes good to
# 5 deg (std) give such misses in fewer than one pair in a thousand. The whole block is blamed when
# the median of all pairs exceeds MISFIT_DEG and no photo in particular explains it.
MISFIT_DEG = 30.0
MISFIT_SHARE = 0.75
PAIR_CHUNK = 200_000  # ray pairs evaluated at once (bounds the memory)
LIST_MAX = 8  # photos, points or groups named in one message before "and N more"

ANGLE_UNITS = {"deg": 180.0 / np.pi, "gon": 200.0 / np.pi, "rad": 1.0}
THIRD_ANGLE = {"omega-phi-kappa": "kappa", "alpha-omega-chi": "chi", "phi-omega-kappa": "kappa"}


def likely_causes(project: Project, failure: str) -> list[str]:
    """The likely causes of a failure of kind ``failure``, most specific first:

    * ``"iteration"`` (not converged, diverged): implausible values, extreme weights, the unit of c,
      grossly wrong approximate orientations;
    * ``"singular"`` (a singular normal matrix, a datum defect): extreme weights, photo groups
      without a datum, implausible values, the unit of c;
    * ``"overflow"`` (numbers that are not finite): implausible values, the unit of c, extreme
      weights.
    """
    with np.errstate(all="ignore"):
        if failure == "iteration":
            checks = (distance_scale, implausible_values, extreme_weights, absolute_extremes, camera_units,
                      principal_points, wrong_orientations)
        elif failure == "singular":
            checks = (distance_scale, extreme_weights, absolute_extremes, lambda p: photo_groups(p).explain(),
                      implausible_values, camera_units, principal_points)
        elif failure == "overflow":
            checks = (distance_scale, implausible_values, camera_units, principal_points, extreme_weights,
                      absolute_extremes)
        else:
            raise ValueError(f"unknown failure kind {failure!r}")
        causes: list[str] = []
        for check in checks:
            causes += check(project)
        return causes


# ------------------------------------------------------------------------------------------ distances

DISTANCE_RATIO = 1e3  # an observed distance this many times longer or shorter than in the approximations


def distance_scale(project: Project) -> list[str]:
    """The rows of distances.csv whose distance is more than DISTANCE_RATIO times longer or shorter
    than the distance of its two points in the approximations (equations.triangulation.planned_points: given
    coordinates, approx_points.csv, or the intersection of their rays): a wrong value or unit, which
    the adjustment meets as a scale it cannot reach (before, a 1e9 m distance was reported as an
    undetermined datum). Approximations are never off in scale by a factor of a thousand."""
    dist = getattr(project, "distances", None)
    if dist is None or not len(dist):
        return []
    from ..equations.triangulation import planned_points

    xyz = planned_points(project)
    approx = np.linalg.norm(xyz[dist.point_from] - xyz[dist.point_to], axis=1)
    ratio = dist.distance / approx
    bad = np.flatnonzero(np.isfinite(ratio) & (approx > 0)
                         & ((ratio > DISTANCE_RATIO) | (ratio < 1.0 / DISTANCE_RATIO)))
    out = []
    for i in bad[:LIST_MAX]:
        line = "" if dist.line is None else f", line {int(dist.line[i])}"
        a, b = project.points.ids[dist.point_from[i]], project.points.ids[dist.point_to[i]]
        out.append(f"distances.csv{line}: the distance {float(dist.distance[i]):.6g} m between {a} and {b} is "
                   f"{float(ratio[i]):.3g} times their distance in the approximations ({float(approx[i]):.6g} m): "
                   "check the value and its unit")
    return out


# ------------------------------------------------------------------------------------------ weights


def extreme_weights(project: Project) -> list[str]:
    """Measurements (plate coordinates, weighted control, observed elements) whose standard
    deviation is more than SIGMA_RATIO times smaller or larger than the median of its kind."""
    out = []
    ip = project.image_points
    if len(ip):
        sig = ip.sigma_xy
        med = float(np.median(sig[np.isfinite(sig) & (sig > 0)])) if np.any(sig > 0) else np.nan
        ratio = sig / med
        bad = np.flatnonzero(((ratio > SIGMA_RATIO) | (ratio < 1.0 / SIGMA_RATIO)).any(axis=1))
        if len(bad) and np.isfinite(med):
            items = []
            for row in bad[:LIST_MAX]:
                axis = int(np.argmax(np.abs(np.log(ratio[row]))))
                items.append(f"point {project.points.ids[ip.point_index[row]]} on photo "
                             f"{project.photos.ids[ip.photo_index[row]]} (sigma_{'xy'[axis]} = {sig[row, axis]:.3g})")
            out.append(_weights_sentence("plate measurement", items, len(bad), med, "image_points.csv"))
    pts = project.points
    sg = np.where(np.isfinite(pts.xyz_given), pts.sigma_given, np.nan)
    sg = np.where(sg > 0, sg, np.nan)
    if np.isfinite(sg).any():
        med = float(np.nanmedian(sg))
        ratio = sg / med
        bad = np.flatnonzero(np.nan_to_num((ratio > SIGMA_RATIO) | (ratio < 1.0 / SIGMA_RATIO)).any(axis=1))
        items = [f"point {pts.ids[i]} (sigma {', '.join(f'{s:.3g}' for s in sg[i] if np.isfinite(s))})"
                 for i in bad[:LIST_MAX]]
        if len(bad):
            out.append(_weights_sentence("control coordinate", items, len(bad), med, "control.csv"))
    ph = project.photos
    for name, sig, elements in (("observed centre", ph.sigma_xyz0, ("X0", "Y0", "Z0")),
                                ("observed angle", ph.sigma_angles, ("omega", "phi", "kappa"))):
        s = np.where(np.isfinite(sig) & (sig > 0), sig, np.nan)
        if not np.isfinite(s).any():
            continue
        med = float(np.nanmedian(s))
        ratio = s / med
        bad = np.argwhere(np.nan_to_num((ratio > SIGMA_RATIO) | (ratio < 1.0 / SIGMA_RATIO)))
        items = [f"photo {ph.ids[i]} (sigma_{elements[a]} = {s[i, a]:.3g})" for i, a in bad[:LIST_MAX]]
        if len(bad):
            out.append(_weights_sentence(name, items, len(bad), med, "photos.csv"))
    return out


# A standard deviation this far below or above the block's extent (coordinates, m) or a radian
# (angles) cannot be a statement about a measurement: it is a typo or another unit, and its weight
# leaves double precision (a sigma_X0 of 1e-20 m makes N singular; a control sigma of 1e12 m
# overflows). Used where the median of the others says nothing (one weighted value of its kind).
ABSOLUTE_SMALL = 1e-9
ABSOLUTE_LARGE = 1e6


def absolute_extremes(project: Project) -> list[str]:
    """Weighted control coordinates and observed elements whose standard deviation is below
    ABSOLUTE_SMALL or above ABSOLUTE_LARGE times their scale (the block's extent in metres, one
    radian for angles), whatever the others have."""
    out = []
    ph, pts = project.photos, project.points
    extent = float(np.ptp(ph.xyz0, axis=0).max()) if len(ph) > 1 else 1.0
    extent = max(extent, 1.0)

    def extreme(s, scale):
        s = np.where(np.isfinite(s) & (s > 0), s, np.nan)
        return np.nan_to_num((s < ABSOLUTE_SMALL * scale) | (s > ABSOLUTE_LARGE * scale)).astype(bool)

    sg = np.where(np.isfinite(pts.xyz_given), pts.sigma_given, np.nan)
    bad = np.flatnonzero(extreme(sg, extent).any(axis=1))
    if len(bad):
        items = [f"point {pts.ids[i]} (sigma {', '.join(f'{x:.3g}' for x in sg[i] if np.isfinite(x) and x > 0)} m)"
                 for i in bad[:LIST_MAX]]
        out.append(_absolute_sentence("control coordinate", items, len(bad), f"{extent:.4g} m", "control.csv"))
    for name, sig, elements, scale, unit in (("observed centre", ph.sigma_xyz0, ("X0", "Y0", "Z0"), extent, "m"),
                                             ("observed angle", ph.sigma_angles, ("omega", "phi", "kappa"), 1.0,
                                              "rad")):
        bad = np.argwhere(extreme(sig, scale))
        if len(bad):
            items = [f"photo {ph.ids[i]} (sigma_{elements[a]} = {sig[i, a]:.3g} {unit})" for i, a in bad[:LIST_MAX]]
            out.append(_absolute_sentence(name, items, len(bad), f"{scale:.4g} {unit}", "photos.csv"))
    return out


def _absolute_sentence(kind: str, items: list[str], n: int, scale: str, file: str) -> str:
    listed = ", ".join(items) + (_more(n - len(items)) if n > len(items) else "")
    return (f"the standard deviation of {n} {kind}{'s' if n != 1 else ''} in {file} is more than "
            f"{1 / ABSOLUTE_SMALL:.0e} times smaller or {ABSOLUTE_LARGE:.0e} times larger than {scale} "
            f"(the block's extent, or a radian for angles): {listed}. No measurement is that exact or that "
            f"vague, and its weight leaves double precision: give its real standard deviation (or hold the "
            f"value fixed: {HOLD_EXACTLY[file]}; or leave it out).")


# A settled iteration with sigma0 above this (v^T P v steady to 1e-3) points at gross errors.
GROSS_SIGMA0 = 10.0
STEADY = 1e-3


def gross_residuals(project: Project, history, redundancy: int, plate_residuals: np.ndarray) -> list[str]:
    """A gross error, when the iteration has settled (v^T P v steady) far above sigma0 = 1: the
    plate measurements with the largest residuals in units of their standard deviation.
    plate_residuals (m_ip, 2): v = l^ - l of the last estimate, in the rows of image_points."""
    if redundancy <= 0 or len(history) < 2:
        return []
    vtpv, last = history[-1].vtpv, history[-2].vtpv
    if not (np.isfinite(vtpv) and np.isfinite(last)) or abs(vtpv - last) > STEADY * vtpv:
        return []
    sigma0 = float(np.sqrt(vtpv / redundancy))
    ip = project.image_points
    if sigma0 < GROSS_SIGMA0 or len(ip) != len(plate_residuals):
        return []
    with np.errstate(all="ignore"):
        w = np.abs(plate_residuals) / ip.sigma_xy
    w = np.where(np.isfinite(w), w, 0.0)
    worst = np.argsort(-w.max(axis=1))[:3]
    unit = project.settings.plate_unit
    items = []
    control = sorted({str(project.points.ids[ip.point_index[row]]) for row in worst
                      if np.isfinite(project.points.xyz_given[ip.point_index[row]]).any()})
    for row in worst:
        axis = int(np.argmax(w[row]))
        items.append(f"point {project.points.ids[ip.point_index[row]]} on photo "
                     f"{project.photos.ids[ip.photo_index[row]]} ({'xy'[axis]} {plate_residuals[row, axis]:+.4g} {unit}, "
                     f"{w[row, axis]:.3g} sigma)")
    return [f"a gross error in the measurements: the iteration has settled at sigma0 = {sigma0:.4g}, where about 1 "
            f"is expected, and a settled iteration converges slowly when its residuals are that large. The largest "
            f"residuals: {'; '.join(items)}."
            + (f" {', '.join(control)} {'is a control point' if len(control) == 1 else 'are control points'}: "
               "check the given coordinates in control.csv too." if control else "")
            + " Check these measurements (a wrong point id, a typo, another unit); "
            "correct them or set active = 0 on their rows in image_points.csv. --blunders snoop finds gross "
            "errors once the adjustment converges (raise --max-iterations for that run)."]


HOLD_EXACTLY = {
    "image_points.csv": "a plate measurement is never exact",
    "control.csv": "an empty sigma holds a control coordinate fixed",
    "photos.csv": "a sigma of 0 holds an element fixed",
}


def _weights_sentence(kind: str, items: list[str], n: int, median: float, file: str) -> str:
    more = f" and {n - len(items)} more" if n > len(items) else ""
    one = n == 1
    return (f"the standard deviation of {'this' if one else 'these'} {kind}{'' if one else 's'} is more than "
            f"{SIGMA_RATIO:.0e} times smaller or larger than the median {median:.3g} of the others: "
            f"{'; '.join(items)}{more}. {'Its weight differs' if one else 'Their weights differ'} from the others' "
            f"by more than {SIGMA_RATIO ** 2:.0e}, beyond what double precision can carry through the normal "
            "equations (16 digits), so the solution loses all meaning there. Give "
            f"{'it a realistic standard deviation' if one else 'them realistic standard deviations'} in {file} "
            f"({HOLD_EXACTLY[file]}), or remove {'it' if one else 'them'}.")


# -------------------------------------------------------------------------------------------- units


def _plate_extent(project: Project) -> tuple[np.ndarray, np.ndarray]:
    """Per camera: the EXTENT_QUANTILE of the distances of its plate coordinates from the principal
    point (nan without measurements), and the number of measurements."""
    ip, cams = project.image_points, project.cameras
    n_cam = len(cams)
    cam = project.photos.camera_index[ip.photo_index]
    d = np.max(np.abs(ip.xy - cams.interior[cam, 1:3]), axis=1)  # no overflow for wild values
    return _group_quantile(cam, d, n_cam, EXTENT_QUANTILE), np.bincount(cam, minlength=n_cam)


def camera_units(project: Project) -> list[str]:
    """Cameras whose principal distance c is not of the order of the extent of the plate
    coordinates of their photos (thresholds C_TOO_LONG, C_TOO_SHORT: a frame camera's field angle)."""
    cams = project.cameras
    extent, count = _plate_extent(project)
    c = cams.interior[:, 0]
    out = []
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(c) / extent
    for j in np.flatnonzero((count > 0) & (extent > 0) & ~((ratio >= C_TOO_SHORT) & (ratio <= C_TOO_LONG))):
        q = ratio[j]
        angle = np.degrees(np.arctan(extent[j] / abs(c[j]))) if c[j] != 0 else 90.0
        what = (f"camera {cams.ids[j]}: c = {c[j]:.6g} while the plate coordinates of its photos extend to "
                f"{extent[j]:.4g} from the principal point, a half-field angle of {angle:.3g} deg where a frame "
                "camera's lies between a few degrees and some 60 deg")
        factor = q if q > 1 else 1.0 / q
        power = 10 ** np.round(np.log10(factor))
        near = abs(np.log10(factor / power)) < 0.5 and power in (1e3, 1e6)
        if q > 1:
            unit = {1e3: "c is probably in micrometres while x, y are in millimetres (or c in millimetres and x, y "
                         "in metres)",
                    1e6: "c is probably in nanometres or x, y in kilometres"}.get(power if near else 0.0,
                                                                                 "c and x, y are not in one unit")
            out.append(f"{what}: c is about {factor:.2g} times too large for them; {unit}. Give c and the plate "
                       "coordinates in one unit (cameras.csv, image_points.csv).")
        else:
            unit = {1e3: "c is probably in metres while x, y are in millimetres (or x, y in micrometres)",
                    1e6: "c is probably in kilometres, or x, y in nanometres"}.get(power if near else 0.0,
                                                                                  "c and x, y are not in one unit "
                                                                                  "(x, y in pixels?)")
            out.append(f"{what}: c is about {factor:.2g} times too small for them; {unit}. Give c and the plate "
                       "coordinates in one unit (cameras.csv, image_points.csv).")
    return out


def principal_points(project: Project) -> list[str]:
    """Cameras whose principal point (xp, yp) lies outside the box of their photos' plate
    coordinates: a frame camera's principal point lies inside its image."""
    cams, ip = project.cameras, project.image_points
    if not len(ip):
        return []
    cam = project.photos.camera_index[ip.photo_index]
    n = len(cams)
    low = np.full((n, 2), np.inf)
    high = np.full((n, 2), -np.inf)
    np.minimum.at(low, cam, ip.xy)
    np.maximum.at(high, cam, ip.xy)
    pp = cams.interior[:, 1:3]
    out = []
    with np.errstate(invalid="ignore"):
        outside = ((pp < low) | (pp > high)).any(axis=1) & np.isfinite(low).all(axis=1)
    for j in np.flatnonzero(outside)[:LIST_MAX]:
        out.append(f"camera {cams.ids[j]}: its principal point (xp, yp) = ({pp[j, 0]:.6g}, {pp[j, 1]:.6g}) lies "
                   f"outside the area its photos' plate coordinates cover (x {low[j, 0]:.6g} to {high[j, 0]:.6g}, "
                   f"y {low[j, 1]:.6g} to {high[j, 1]:.6g}), where a frame camera's principal point lies inside its "
                   "image: check xp, yp in cameras.csv (a typo, another unit, or another origin than the plate "
                   "coordinates).")
    return out


# ------------------------------------------------------------------------------- implausible values


def implausible_values(project: Project) -> list[str]:
    """Projection centres, control coordinates and plate coordinates FAR times farther out than
    the typical one (the median distance from the median), in the max norm (no overflow)."""
    out = []
    ph, pts, ip, cams = project.photos, project.points, project.image_points, project.cameras
    O = ph.xyz0
    middle, d, typical = _centre_spread(O)
    bad = np.flatnonzero(~(d <= FAR * typical))
    if len(bad):
        items = [f"photo {ph.ids[i]} ({', '.join(f'{v:.6g}' for v in O[i])})" for i in bad[:LIST_MAX]]
        out.append(f"the approximate projection centre{'s' if len(bad) > 1 else ''} of "
                   f"{'; '.join(items)}{_more(len(bad))} lie{'s' if len(bad) == 1 else ''} more than {FAR:.0f} times "
                   f"farther from the middle of the block than the photos' typical {typical:.4g} m: check X0, Y0, "
                   "Z0 in photos.csv (a typo, or a value in another unit or coordinate system).")
    given = np.isfinite(pts.xyz_given)
    dg = np.max(np.where(given, np.abs(pts.xyz_given - middle), 0.0), axis=1)
    bad = np.flatnonzero(given.any(axis=1) & ~(dg <= FAR * max(typical, float(np.max(d[d <= FAR * typical],
                                                                                      initial=0.0)))))
    if len(bad):
        items = [f"{pts.ids[i]} ({', '.join(f'{v:.6g}' for v in pts.xyz_given[i] if np.isfinite(v))})"
                 for i in bad[:LIST_MAX]]
        out.append(f"the given coordinates of control point{'s' if len(bad) > 1 else ''} {'; '.join(items)}"
                   f"{_more(len(bad))} lie more than {FAR:.0f} times farther from the photos than the block's extent: "
                   "check control.csv (a typo, or another unit or coordinate system than photos.csv).")
    if len(ip):
        cam = ph.camera_index[ip.photo_index]
        r = np.max(np.abs(ip.xy - cams.interior[cam, 1:3]), axis=1)
        typical_r = _group_quantile(cam, r, len(cams), 0.5)[cam]
        bad = np.flatnonzero(~(r <= FAR * np.maximum(typical_r, 1e-300)))
        if len(bad):
            items = [f"point {pts.ids[ip.point_index[i]]} on photo {ph.ids[ip.photo_index[i]]} "
                     f"({ip.xy[i, 0]:.6g}, {ip.xy[i, 1]:.6g})" for i in bad[:LIST_MAX]]
            out.append(f"the plate coordinates of {'; '.join(items)}{_more(len(bad))} lie more than {FAR:.0f} times "
                       "farther from the principal point than the other measurements of the camera: check "
                       "image_points.csv (a typo, or another unit).")
        extent = _plate_extent(project)[0][cam]
        off = np.flatnonzero((r <= FAR * np.maximum(typical_r, 1e-300)) & (r > OUTSIDE_IMAGE * extent))
        if len(off):
            items = [f"point {pts.ids[ip.point_index[i]]} on photo {ph.ids[ip.photo_index[i]]} "
                     f"({ip.xy[i, 0]:.6g}, {ip.xy[i, 1]:.6g})" for i in off[:LIST_MAX]]
            out.append(f"the plate coordinates of {'; '.join(items)}{_more(len(off))} lie outside the image: more than "
                       f"{OUTSIDE_IMAGE:g} times as far from the principal point as {EXTENT_QUANTILE:.0%} of the "
                       "camera's measurements: check image_points.csv (a typo, or another unit).")
    return out


def _centre_spread(O: np.ndarray):
    """The median centre, every centre's distance from it (max norm, no overflow) and the typical
    distance (their median, at least 1 m)."""
    middle = np.median(O, axis=0) if len(O) else np.zeros(3)
    d = np.max(np.abs(O - middle), axis=1)
    return middle, d, max(float(np.median(d)) if len(d) else 0.0, 1.0)


def _more(n: int) -> str:
    return f" and {n - LIST_MAX} more" if n > LIST_MAX else ""


# ----------------------------------------------------------------------------------- turned photos


@dataclass(frozen=True)
class Turn:
    """A photo (index, -1 for the whole block) whose approximate kappa is ``degrees`` off (0: its
    approximate orientation does not fit and no turn of kappa explains it): the median misclosure of
    its ray pairs (degrees) at the given kappa and with the turn (nan for 0), over ``pairs``."""

    photo: int
    degrees: int
    given_deg: float
    turned_deg: float
    pairs: int


def find_turns(project: Project) -> list[Turn]:
    """The photos (or the whole block) whose approximate rotation about the camera axis is 90, 180
    or 270 deg off (module doc; thresholds GROSS_DEG, IMPROVEMENT, MIN_PAIRS), then the photos whose
    approximate orientation does not fit their neighbours' for another reason (_misfits).

    For every pair of rays of one point in two photos (consecutive and next-but-one photos of the
    point in photo order), at the approximate orientations: the angle by which each ray misses the
    plane of the base and the other ray (coplanarity, Schmid 20, as an angle), or 90 deg when the
    rays meet behind a camera (a coplanarity that a half turn of both photos keeps). Per photo, the
    median over its pairs with its own kappa turned by 0, 90, 180, 270 deg and the other photo's as
    given; for the block, the median over all pairs with every photo turned alike.
    """
    ph, ip = project.photos, project.image_points
    n = len(ph)
    if len(ip) < 2 or n < 2:
        return []
    p = _camera_vectors(project)
    order = np.lexsort((ip.photo_index, ip.point_index))
    a_rows, b_rows = [], []
    for s in (1, 2):
        a, b = order[:-s], order[s:]
        keep = (ip.point_index[a] == ip.point_index[b]) & (ip.photo_index[a] != ip.photo_index[b])
        a_rows.append(a[keep])
        b_rows.append(b[keep])
    a, b = np.concatenate(a_rows), np.concatenate(b_rows)
    if len(a) == 0:
        return []
    i, j = ip.photo_index[a], ip.photo_index[b]
    _, d, typical = _centre_spread(ph.xyz0)
    sound = d <= FAR * typical  # a wild centre (implausible_values) says nothing about kappa
    keep = sound[i] & sound[j]
    a, b, i, j = a[keep], b[keep], i[keep], j[keep]
    if len(a) == 0:
        return []
    turns = (0,) + TURNS_DEG
    # scores[0, t]: photo i turned by turns[t]; scores[1, t]: photo j turned; scores[2, t]: both
    scores = np.empty((3, len(turns), len(a)), dtype=np.float32)
    for start in range(0, len(a), PAIR_CHUNK):
        sl = slice(start, start + PAIR_CHUNK)
        base = ph.xyz0[j[sl]] - ph.xyz0[i[sl]]
        ri = [np.einsum("mij,mj->mi", ph.R_ground_from_cam[i[sl]], _turned(p[a[sl]], t)) for t in turns]
        rj = [np.einsum("mij,mj->mi", ph.R_ground_from_cam[j[sl]], _turned(p[b[sl]], t)) for t in turns]
        for t in range(len(turns)):
            scores[0, t, sl] = _pair_misclosure(base, ri[t], rj[0])
            scores[1, t, sl] = _pair_misclosure(base, ri[0], rj[t])
            scores[2, t, sl] = _pair_misclosure(base, ri[t], rj[t])
    photos = np.concatenate([i, j])
    med = np.stack([_group_quantile(photos, np.concatenate([scores[0, t], scores[1, t]]), n, 0.5)
                    for t in range(len(turns))], axis=1)  # (n, 4) radians
    count = np.bincount(photos[np.isfinite(np.concatenate([scores[0, 0], scores[1, 0]]))], minlength=n)
    block = np.array([np.nanmedian(scores[2, t]) for t in range(len(turns))])
    gross = np.radians(GROSS_DEG)
    best = 1 + int(np.argmin(block[1:]))
    if block[0] > gross and block[best] * IMPROVEMENT < block[0]:  # every photo turned alike
        return [Turn(-1, turns[best], float(np.degrees(block[0])), float(np.degrees(block[best])), len(a))]
    bt = 1 + np.argmin(med[:, 1:], axis=1)
    bv = med[np.arange(n), bt]
    flagged = np.flatnonzero((med[:, 0] > gross) & (bv * IMPROVEMENT < med[:, 0]) & (count >= MIN_PAIRS))
    out = [Turn(int(k), turns[bt[k]], float(np.degrees(med[k, 0])), float(np.degrees(bv[k])), int(count[k]))
           for k in flagged]
    if block[0] > np.radians(MISFIT_DEG) and not out:  # nothing in particular: the whole block does not fit
        return [Turn(-1, 0, float(np.degrees(block[0])), float("nan"), len(a))]
    return out + _misfits(np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([scores[0, 0], scores[1, 0]]),
                          n, flagged)


def _misfits(photo: np.ndarray, partner: np.ndarray, score: np.ndarray, n: int, turned: np.ndarray) -> list[Turn]:
    """Photos whose approximate orientation does not fit their neighbours' and no kappa turn
    explains: at least MISFIT_SHARE of their ray pairs (with partners not already blamed) miss by
    more than MISFIT_DEG. Blamed greedily, worst first, so that the neighbours of a wrong photo,
    whose pairs with it are bad too, are not blamed for it."""
    ok = np.isfinite(score)
    photo, partner, score = photo[ok], partner[ok], score[ok]
    bad = score > np.radians(MISFIT_DEG)
    count = np.bincount(photo, minlength=n)
    share = np.bincount(photo, weights=bad, minlength=n) / np.maximum(count, 1)
    candidates = np.flatnonzero((share >= MISFIT_SHARE) & (count >= MIN_PAIRS))
    candidates = candidates[~np.isin(candidates, turned)]
    if not len(candidates):
        return []
    order = np.argsort(photo, kind="stable")
    starts = np.searchsorted(photo[order], np.arange(n + 1))
    blamed = set(int(t) for t in turned)
    out = []
    for k in candidates[np.argsort(-share[candidates], kind="stable")]:
        rows = order[starts[k]:starts[k + 1]]
        rows = rows[~np.isin(partner[rows], list(blamed))]
        if len(rows) >= MIN_PAIRS and np.mean(bad[rows]) >= MISFIT_SHARE:
            blamed.add(int(k))
            out.append(Turn(int(k), 0, float(np.degrees(np.median(score[rows]))), float("nan"), len(rows)))
    return out


def wrong_orientations(project: Project) -> list[str]:
    """find_turns in words, with the corrected angle in the project's unit and convention."""
    turns = find_turns(project)
    if not turns:
        return []
    ph, settings = project.photos, project.settings
    unit = ANGLE_UNITS.get(settings.angle_unit, ANGLE_UNITS["deg"])
    u = {"deg": " deg", "gon": " gon", "rad": " rad"}.get(settings.angle_unit, " deg")
    name = THIRD_ANGLE.get(settings.rotation, "kappa")
    counted = "(rays that meet behind a camera count as 90 deg)"
    if turns[0].photo < 0:
        t = turns[0]
        if t.degrees:
            return [f"the approximate {name} of all photos is probably {_off(t.degrees)} deg off: their rays miss "
                    f"each other's epipolar planes by a median {t.given_deg:.3g} deg at the given angles {counted}, "
                    f"and by {t.turned_deg:.2g} deg with every {name} turned by {t.degrees} deg. Check the flight "
                    f"direction, the sign and unit of {name} in photos.csv and the angle settings in project.toml."]
        return [f"the approximate orientations of the photos as a whole do not fit the measurements: the rays of a "
                f"point in two photos miss each other's epipolar planes by a median {t.given_deg:.3g} deg {counted}. "
                "Check the conventions: Z up, the rotation convention and angle unit in project.toml, the signs of "
                "omega, phi, kappa and of the plate coordinates, and that the centres and the control are in one "
                "coordinate system."]
    out = []
    for t in turns[:LIST_MAX]:
        if not t.degrees:
            out.append(f"photo {ph.ids[t.photo]}: its approximate orientation does not fit its neighbours': its rays "
                       f"miss the epipolar planes of theirs by a median {t.given_deg:.3g} deg {counted} and no turn "
                       f"of {name} explains it. Check its angles (omega, phi) and centre in photos.csv, and that its "
                       "measurements in image_points.csv belong to it.")
            continue
        R = ph.R_ground_from_cam[t.photo] @ _rz(np.radians(t.degrees))
        given = ph.angles[t.photo, 2] * unit
        better = angles_from_R(R[None], settings.rotation)[0, 2] * unit
        out.append(f"photo {ph.ids[t.photo]}: its approximate {name} is probably {_off(t.degrees)} deg off: its rays "
                   f"miss the epipolar planes of the neighbouring photos' rays by a median {t.given_deg:.3g} deg at "
                   f"the given {name} = {given:.4f}{u} {counted}, and by {t.turned_deg:.2g} deg at "
                   f"{name} = {better:.4f}{u} ({t.pairs} ray pairs). Correct it in photos.csv.")
    if len(turns) > LIST_MAX:
        out.append(f"and {len(turns) - LIST_MAX} more photos whose approximate orientation seems grossly wrong.")
    return out


def _off(turn: int) -> int:
    """How far off the given angle is, as a positive angle up to 180 deg, for a correcting turn."""
    return min(turn, 360 - turn)


def _camera_vectors(project: Project) -> np.ndarray:
    """Camera-frame vectors p = (x - xp, y - yp, -c) of the measurements (distortion left in: a
    few micrometres do not matter to a test for turns of 90 deg)."""
    ip, cams = project.image_points, project.cameras
    cam = project.photos.camera_index[ip.photo_index]
    return plate_vector(ip.xy, cams.interior[cam, :3])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _turned(p: np.ndarray, degrees: int) -> np.ndarray:
    """Rz(degrees) p: the camera vector of a photo whose kappa is ``degrees`` larger (exact for
    quarter turns)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if degrees == 0:
        return p
    if degrees == 90:
        return np.stack([-y, x, z], 1)
    if degrees == 180:
        return np.stack([-x, -y, z], 1)
    return np.stack([y, -x, z], 1)


def _pair_misclosure(b: np.ndarray, r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """(m,) the larger angle (radians) by which a ray misses the plane of the base b = O2 - O1 and
    the other ray; pi/2 when the points of closest approach lie behind a camera (scales <= 0); nan
    for (nearly) parallel rays or a zero base."""
    n = np.cross(r1, r2)
    g = np.abs(np.einsum("mi,mi->m", b, n))
    l1, l2 = np.linalg.norm(r1, axis=1), np.linalg.norm(r2, axis=1)
    s1 = g / (np.linalg.norm(np.cross(b, r1), axis=1) * l2)
    s2 = g / (np.linalg.norm(np.cross(b, r2), axis=1) * l1)
    angle = np.arcsin(np.clip(np.maximum(s1, s2), 0.0, 1.0))
    nn = np.einsum("mi,mi->m", n, n)
    # O1 + s r1 and O2 + t r2 nearest: s = ((b x r2) . n) / n.n, t = ((b x r1) . n) / n.n
    s = np.einsum("mi,mi->m", np.cross(b, r2), n) / nn
    t = np.einsum("mi,mi->m", np.cross(b, r1), n) / nn
    angle = np.where((s <= 0) | (t <= 0), np.pi / 2, angle)
    parallel = nn <= 1e-8 * (l1 * l2) ** 2
    return np.where(parallel | ~np.isfinite(angle), np.nan, angle)


def _group_quantile(groups: np.ndarray, values: np.ndarray, n_groups: int, q: float) -> np.ndarray:
    """(n_groups,) the q-quantile (lower, by rank) of the finite values of each group; nan where none."""
    ok = np.isfinite(values)
    g, v = groups[ok], values[ok]
    order = np.lexsort((v, g))
    g, v = g[order], v[order]
    counts = np.bincount(g, minlength=n_groups)
    starts = np.cumsum(counts) - counts
    out = np.full(n_groups, np.nan)
    has = counts > 0
    if q == 0.5:
        lo = starts + (counts - 1) // 2
        hi = starts + counts // 2
        out[has] = 0.5 * (v[lo[has]] + v[hi[has]])
    else:
        idx = starts + np.floor(q * (counts - 1)).astype(int)
        out[has] = v[idx[has]]
    return out


# ------------------------------------------------------------------------------------- photo groups


@dataclass
class PhotoGroups:
    """Connected components of the photos over shared points (and enforced or observed base
    components): ``label`` (n_photos,) the group of every photo, groups numbered by their first
    photo; ``free`` per group the (7, d) coefficients of the similarity directions its own control
    and observed or fixed elements leave free (datum.describe's basis); ``project`` for the names."""

    label: np.ndarray
    free: list
    extent: float
    centroids: np.ndarray
    project: Project

    @property
    def count(self) -> int:
        return len(self.free)

    def lacking(self) -> list[int]:
        return [g for g, f in enumerate(self.free) if f.shape[1]]

    def explain(self) -> list[str]:
        """Words for groups that lack a datum (empty with one group, or when every group has one)."""
        if self.count < 2 or not self.lacking():
            return []
        ids = self.project.photos.ids
        lines = [f"the photos form {self.count} groups that share no points, and each group needs its own datum "
                 "(control, observed or fixed elements):"]
        shown = range(min(self.count, LIST_MAX))
        for g in shown:
            members = np.flatnonzero(self.label == g)
            names = ", ".join(ids[k] for k in members[:LIST_MAX]) + (
                f" and {len(members) - LIST_MAX} more" if len(members) > LIST_MAX else "")
            free = self.free[g]
            if free.shape[1] == 0:
                state = "its datum is fixed"
            elif free.shape[1] == 7:
                state = ("no datum: it has no control point and no observed or fixed element, so its position, "
                         "orientation and scale are free")
            else:
                words = describe(free, self.extent, self.centroids[g])
                state = "its control leaves free: " + "; ".join(words)
            lines.append(f"  - group {g + 1}: photo{'s' if len(members) > 1 else ''} {names} "
                         f"({len(members)} photo{'s' if len(members) > 1 else ''}): {state}")
        if self.count > LIST_MAX:
            rest = self.count - LIST_MAX
            lines.append(f"  - and {rest} more group{'s' if rest > 1 else ''}")
        lines.append("Connect the groups with tie points measured in photos of both, or give every group enough "
                     "control of its own (two full points and one height point not on a line), or adjust each group "
                     "as a project of its own.")
        return ["\n".join(lines)]


def photo_groups(project: Project) -> PhotoGroups:
    """The connected components of the photos (scipy.sparse.csgraph) over the points that link them
    (seen in two or more photos) and the base components (bases.csv), and the similarity directions
    each group's own datum leaves free: the rank of the rows that the control coordinates of its
    points and its observed or fixed elements put on the seven similarity coefficients."""
    ph, ip, pts = project.photos, project.image_points, project.points
    n, n_pt = len(ph), len(pts)
    rays = np.bincount(ip.point_index, minlength=n_pt)
    kinds = adjusted_kind(pts.kind)
    link = rays[ip.point_index] >= 2
    rows = np.concatenate([ip.photo_index[link], project.bases.photo_from])
    cols = np.concatenate([n + ip.point_index[link], project.bases.photo_to])
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + n_pt, n + n_pt))
    _, comp = connected_components(graph, directed=False)
    # renumber the groups of the photos by their first photo
    _, first, photo_label = np.unique(comp[:n], return_index=True, return_inverse=True)
    relabel = np.argsort(np.argsort(first))
    label = relabel[photo_label]
    n_groups = len(first)

    extent = max(float(np.ptp(ph.xyz0, axis=0).max()) if n else 1.0, 1.0)
    size = np.bincount(label, minlength=n_groups)
    centroids = np.stack([np.bincount(label, ph.xyz0[:, a], n_groups) for a in range(3)], 1) / size[:, None]
    H_rows, owner = _datum_rows(project, label, rays, kinds, extent, centroids)
    free = []
    for g in range(n_groups):
        M = H_rows[owner == g]
        if len(M) == 0:
            free.append(np.eye(7))
            continue
        M = M / np.linalg.norm(M, axis=1, keepdims=True)
        _, sv, Vt = np.linalg.svd(M, full_matrices=True)
        rank = int(np.sum(sv > 1e-6 * sv[0]))
        free.append(Vt[rank:].T)
    return PhotoGroups(label, free, extent, centroids, project)


def _similarity_rows(X: np.ndarray, extent: float) -> np.ndarray:
    """(m, 3, 7) the change of ground coordinates X (relative to their group's centroid) under the
    seven scaled similarity coefficients (datum.similarity_changes' basis)."""
    m = len(X)
    H = np.zeros((m, 3, 7))
    H[:, :, :3] = np.eye(3)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        H[:, :, 3 + k] = np.cross(e, X) / extent
    H[:, :, 6] = X / extent
    return H


def _datum_rows(project: Project, label, rays, kinds, extent, centroids):
    """Rows (r, 7) on the similarity coefficients of each group, and the group of each row: the given
    coordinates of control points with conditions, the observed or fixed centres and angles, the
    enforced or observed base components."""
    ph, ip, pts = project.photos, project.image_points, project.points
    rows, owner = [], []
    # control points: the group of any photo that sees them; approximate positions where not given
    given = given_axes(kinds)
    has_cond = 2 * rays - (3 - given.sum(axis=1)) > 0  # groups.condition_count
    ctrl = np.flatnonzero(has_cond & np.isin(kinds, (FULL, PLAN, HEIGHT)) & given.any(axis=1))
    if len(ctrl):
        first_row = np.full(len(pts), -1)
        first_row[ip.point_index[::-1]] = np.arange(len(ip))[::-1]
        g = label[ip.photo_index[first_row[ctrl]]]
        mean_centre = np.zeros((len(pts), 3))
        np.add.at(mean_centre, ip.point_index, ph.xyz0[ip.photo_index])
        mean_centre /= np.maximum(rays, 1)[:, None]
        X = np.where(given[ctrl] & np.isfinite(pts.xyz_given[ctrl]), pts.xyz_given[ctrl], mean_centre[ctrl])
        H = _similarity_rows(X - centroids[g], extent)
        sel = given[ctrl]
        rows.append(H[sel])
        owner.append(np.repeat(g, 3)[sel.ravel()])
    # observed or fixed centres and angles
    H_photo = _similarity_rows(ph.xyz0 - centroids[label], extent)
    held_c = np.isfinite(ph.sigma_xyz0) & (ph.sigma_xyz0 >= 0)
    rows.append(H_photo[held_c])
    owner.append(np.repeat(label, 3)[held_c.ravel()])
    held_a = np.isfinite(ph.sigma_angles) & (ph.sigma_angles >= 0)
    if held_a.any():
        k = np.flatnonzero(held_a.any(axis=1))
        # an angle changes by J R^T omega under a ground rotation omega (R <- Exp(omega) R)
        J = angles_jacobian(ph.R_ground_from_cam[k], project.settings.rotation)
        Hrot = np.zeros((len(k), 3, 7))
        Hrot[:, :, 3:6] = J @ np.swapaxes(ph.R_ground_from_cam[k], 1, 2) / extent
        rows.append(Hrot[held_a[k]])
        owner.append(np.repeat(label[k], 3)[held_a[k].ravel()])
    b = project.bases
    if len(b):
        # a base component O_to - O_from does not move under a translation
        d = _similarity_rows(ph.xyz0[b.photo_to] - ph.xyz0[b.photo_from], extent)[np.arange(len(b)), b.axis]
        d[:, :3] = 0.0
        rows.append(d)
        owner.append(label[b.photo_to])
    rows = [r for r in rows if len(r)]
    if not rows:
        return np.zeros((0, 7)), np.zeros(0, dtype=int)
    M = np.concatenate(rows)
    own = np.concatenate([o for o in owner if len(o)])
    ok = np.linalg.norm(M, axis=1) > 0
    return M[ok], own[ok]
