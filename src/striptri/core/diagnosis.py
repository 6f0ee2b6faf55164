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
  group has no datum of its own;
* :func:`control_off_its_rays` - control points whose rays miss their given coordinates at the
  approximate orientations far more than the other control points' do (a wrong coordinate).

:func:`likely_causes` runs the ones that fit a kind of failure, in that order of precedence.
"""

from __future__ import annotations


import numpy as np

from ..equations.observations import observations_of
from ..equations.parameters import build_layout, initial_state, reduction_offset
from ..equations.triangulation import GivenCoordinates, RayObservations, triangulate
from ..model import OBSERVED, Project
from .listing import FAR, LIST_MAX, centre_spread, group_quantile, more
from .orientations import find_turns, wrong_orientations
from .photo_groups import photo_groups

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
OUTSIDE_IMAGE = 2.0  # a plate coordinate this many times beyond the camera's EXTENT_QUANTILE lies off the image


def likely_causes(project: Project, failure: str) -> list[str]:
    """The likely causes of a failure of kind ``failure``, most specific first:

    * ``"iteration"`` (not converged, diverged): implausible values, extreme weights, the unit of c,
      grossly wrong approximate orientations, control points their rays miss;
    * ``"singular"`` (a singular normal matrix, a datum defect): extreme weights, photo groups
      without a datum, implausible values, the unit of c;
    * ``"overflow"`` (numbers that are not finite): implausible values, the unit of c, extreme
      weights.
    """
    with np.errstate(all="ignore"):
        if failure == "iteration":
            checks = (distance_scale, implausible_values, extreme_weights, absolute_extremes, camera_units,
                      principal_points, wrong_orientations, control_off_its_rays)
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


# ---------------------------------------------------------------------------------------- control

CONTROL_RATIO = 10.0  # a control point whose rays miss it this many times farther than the median one's
MIN_CONTROL = 4  # the comparison needs at least this many control points with rays


def control_off_its_rays(project: Project) -> list[str]:
    """Control points whose rays, at the approximate orientations, miss the given coordinates by
    more than CONTROL_RATIO times as much as the median control point's: a wrong coordinate in
    control.csv (a typo, another datum or unit). The miss of a point is the smallest residual of its
    rays on the plates when its given coordinates are held and the rest intersected
    (triangulation.triangulate): a wrong coordinate moves the point off every ray, a wrong plate
    measurement off one (gross_residuals names those); the approximations' own errors make every control point miss
    somewhat, so a point is judged against the other control points, not against its sigma.

    A gross control error makes the iteration of the method of conditions (which is not damped)
    wander instead of settling, so gross_residuals, which needs a settled iteration, cannot name
    it; this check does not depend on the iteration at all. Nothing is judged when a photo's
    approximate kappa is found turned (wrong_orientations): the control points on it miss as well."""
    pts, ip = project.points, project.image_points
    given = pts.given_axes
    control = given.any(axis=1) & (np.bincount(ip.point_index, minlength=len(pts)) > 0)
    if control.sum() < MIN_CONTROL or find_turns(project):  # a photo turned: its control points miss too
        return []
    offset = reduction_offset(project)
    state = initial_state(project, offset)
    if not (np.isfinite(state.xyz0).all() and np.isfinite(state.R_ground_from_cam).all()):
        return []
    obs = observations_of(project, offset)
    tri = triangulate(RayObservations(ip.photo_index, ip.point_index, obs.plate, ip.sigma_xy),
                      GivenCoordinates(obs.control, given, np.zeros_like(obs.q_control)),  # given: held
                      state=state, layout=build_layout(project), iterations=1, with_residuals=True)
    rows = np.flatnonzero((control & tri.determined)[ip.point_index])
    miss = np.full(len(pts), np.inf)  # the smallest miss of a point's rays: one bad plate measurement is not it
    np.minimum.at(miss, ip.point_index[rows], np.nan_to_num(np.linalg.norm(tri.residuals[rows], axis=1), nan=np.inf))
    judged = control & tri.determined
    if judged.sum() < MIN_CONTROL:
        return []
    median = float(np.median(miss[judged]))
    far = np.flatnonzero(judged & (miss > CONTROL_RATIO * median))
    if len(far) == 0 or median <= 0:
        return []
    far = far[np.argsort(-miss[far])]
    unit = project.settings.plate_unit
    items = [f"{pts.ids[i]} ({miss[i]:.4g} {unit})" for i in far[:LIST_MAX]]
    one = len(far) == 1
    return [f"a gross error in control.csv: at the approximate orientations the rays of control "
            f"point{'' if one else 's'} {', '.join(items)}{more(len(far))} miss {'its' if one else 'their'} given "
            f"coordinates on the plates by more than {CONTROL_RATIO:.0f} times as much as the median control "
            f"point's ({median:.3g} {unit}). Check {'its' if one else 'their'} coordinates in control.csv (a typo, "
            f"another datum, unit or axis order), or make {'it a check point' if one else 'them check points'} "
            f"to leave {'it' if one else 'them'} out of the adjustment."]


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
    sg = np.where(pts.given_state == OBSERVED, pts.sigma_given, np.nan)
    if np.isfinite(sg).any():
        med = float(np.nanmedian(sg))
        ratio = sg / med
        bad = np.flatnonzero(np.nan_to_num((ratio > SIGMA_RATIO) | (ratio < 1.0 / SIGMA_RATIO)).any(axis=1))
        items = [f"point {pts.ids[i]} (sigma {', '.join(f'{s:.3g}' for s in sg[i] if np.isfinite(s))})"
                 for i in bad[:LIST_MAX]]
        if len(bad):
            out.append(_weights_sentence("control coordinate", items, len(bad), med, "control.csv"))
    ph = project.photos
    for name, sig, state, elements in (("observed centre", ph.sigma_xyz0, ph.centre_state, ("X0", "Y0", "Z0")),
                                       ("observed angle", ph.sigma_angles, ph.angle_state, ("omega", "phi", "kappa"))):
        s = np.where(state == OBSERVED, sig, np.nan)
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

    def extreme(s, state, scale):
        s = np.where(state == OBSERVED, s, np.nan)
        return np.nan_to_num((s < ABSOLUTE_SMALL * scale) | (s > ABSOLUTE_LARGE * scale)).astype(bool)

    sg = np.where(pts.given_state == OBSERVED, pts.sigma_given, np.nan)
    bad = np.flatnonzero(extreme(pts.sigma_given, pts.given_state, extent).any(axis=1))
    if len(bad):
        items = [f"point {pts.ids[i]} (sigma {', '.join(f'{x:.3g}' for x in sg[i] if np.isfinite(x) and x > 0)} m)"
                 for i in bad[:LIST_MAX]]
        out.append(_absolute_sentence("control coordinate", items, len(bad), f"{extent:.4g} m", "control.csv"))
    for name, sig, state, elements, scale, unit in (
            ("observed centre", ph.sigma_xyz0, ph.centre_state, ("X0", "Y0", "Z0"), extent, "m"),
            ("observed angle", ph.sigma_angles, ph.angle_state, ("omega", "phi", "kappa"), 1.0, "rad")):
        bad = np.argwhere(extreme(sig, state, scale))
        if len(bad):
            items = [f"photo {ph.ids[i]} (sigma_{elements[a]} = {sig[i, a]:.3g} {unit})" for i, a in bad[:LIST_MAX]]
            out.append(_absolute_sentence(name, items, len(bad), f"{scale:.4g} {unit}", "photos.csv"))
    return out


def _absolute_sentence(kind: str, items: list[str], n: int, scale: str, file: str) -> str:
    listed = ", ".join(items) + (more(n - len(items)) if n > len(items) else "")
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
    return group_quantile(cam, d, n_cam, EXTENT_QUANTILE), np.bincount(cam, minlength=n_cam)


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
    middle, d, typical = centre_spread(O)
    bad = np.flatnonzero(~(d <= FAR * typical))
    if len(bad):
        items = [f"photo {ph.ids[i]} ({', '.join(f'{v:.6g}' for v in O[i])})" for i in bad[:LIST_MAX]]
        out.append(f"the approximate projection centre{'s' if len(bad) > 1 else ''} of "
                   f"{'; '.join(items)}{more(len(bad))} lie{'s' if len(bad) == 1 else ''} more than {FAR:.0f} times "
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
                   f"{more(len(bad))} lie more than {FAR:.0f} times farther from the photos than the block's extent: "
                   "check control.csv (a typo, or another unit or coordinate system than photos.csv).")
    if len(ip):
        cam = ph.camera_index[ip.photo_index]
        r = np.max(np.abs(ip.xy - cams.interior[cam, 1:3]), axis=1)
        typical_r = group_quantile(cam, r, len(cams), 0.5)[cam]
        bad = np.flatnonzero(~(r <= FAR * np.maximum(typical_r, 1e-300)))
        if len(bad):
            items = [f"point {pts.ids[ip.point_index[i]]} on photo {ph.ids[ip.photo_index[i]]} "
                     f"({ip.xy[i, 0]:.6g}, {ip.xy[i, 1]:.6g})" for i in bad[:LIST_MAX]]
            out.append(f"the plate coordinates of {'; '.join(items)}{more(len(bad))} lie more than {FAR:.0f} times "
                       "farther from the principal point than the other measurements of the camera: check "
                       "image_points.csv (a typo, or another unit).")
        extent = _plate_extent(project)[0][cam]
        off = np.flatnonzero((r <= FAR * np.maximum(typical_r, 1e-300)) & (r > OUTSIDE_IMAGE * extent))
        if len(off):
            items = [f"point {pts.ids[ip.point_index[i]]} on photo {ph.ids[ip.photo_index[i]]} "
                     f"({ip.xy[i, 0]:.6g}, {ip.xy[i, 1]:.6g})" for i in off[:LIST_MAX]]
            out.append(f"the plate coordinates of {'; '.join(items)}{more(len(off))} lie outside the image: more than "
                       f"{OUTSIDE_IMAGE:g} times as far from the principal point as {EXTENT_QUANTILE:.0%} of the "
                       "camera's measurements: check image_points.csv (a typo, or another unit).")
    return out
