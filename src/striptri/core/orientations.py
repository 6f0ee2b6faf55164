"""Approximate orientations that do not fit (core.diagnosis): photos turned by a quarter or half turn in
kappa, the whole block turned, or a photo whose rays miss the epipolar planes of its neighbours'.
Measured by the ray pairs' misclosures (docs/decisions.md "Likely causes")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import plate_vector
from ..model import Project
from ..geometry.rotations import angles_from_R
from .listing import FAR, LIST_MAX, centre_spread, group_quantile

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

ANGLE_UNITS = {"deg": 180.0 / np.pi, "gon": 200.0 / np.pi, "rad": 1.0}
THIRD_ANGLE = {"omega-phi-kappa": "kappa", "alpha-omega-chi": "chi", "phi-omega-kappa": "kappa"}


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
    _, d, typical = centre_spread(ph.xyz0)
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
    med = np.stack([group_quantile(photos, np.concatenate([scores[0, t], scores[1, t]]), n, 0.5)
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
