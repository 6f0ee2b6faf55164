"""Approximate orientations of a block from its strips, for photographs that come without any
(docs/matching.md, "Photos without orientations").

Each strip is built photo by photo in a frame of its own by the sequential method
(:func:`.strip.build_strip_model`, procedure 1, from parallel photographs one base apart: the
relative orientations try both directions of flight). The strips are then placed one at a time,
each by a 3D similarity (:func:`.absolute.umeyama`) on the points it shares with the ground known
so far: at first the full control points (kind XYZ), then also every point of a strip already
placed. The strip with the most such points goes first; a strip with fewer than three, or with
three on a line, waits for its neighbours. A fit is trimmed twice: points more than TRIM times
the robust spread (1.4826 median) of the residuals are left out and the similarity fitted again,
so that a few false tie points do not bend a strip.

The result is a start for the simultaneous adjustment, which then uses every observation; its
quality is that of a strip triangulation (a strip placed through its neighbours bends with
theirs), enough for the adjustment and its blunder detection (tests/test_match_unoriented.py).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.options import SequentialOptions
from ..errors import NumericalFailure
from ..model import FULL, BaseComponents, Project
from .absolute import Similarity, umeyama
from .strip import ON_A_LINE, build_strip_model, distortion_free

TRIM = 3.0  # residuals beyond TRIM x 1.4826 x median are left out of a strip's similarity
TRIM_ROUNDS = 2


@dataclass(frozen=True)
class PlacedStrip:
    """How one strip was placed: on ``points`` points (``control`` of them control points), with
    the RMS of the similarity's residuals ``rms_m`` (m) over the points kept, after ``dropped``
    were trimmed; ``after``: the strips placed before it whose points it used (empty: control only)."""

    strip: str
    photos: int
    points: int
    control: int
    dropped: int
    rms_m: float
    after: tuple


@dataclass(frozen=True)
class BlockFromStrips:
    """R_ground_from_cam (n, 3, 3) and xyz0 (n, 3) of every photograph (ground frame), the strips in
    the order placed, and xyz (n_pt, 3) the points' ground coordinates from the strip models
    (nan: in no model)."""

    R_ground_from_cam: np.ndarray
    xyz0: np.ndarray
    xyz: np.ndarray
    strips: list[PlacedStrip]


def block_from_strips(project: Project, options: SequentialOptions | None = None) -> BlockFromStrips:
    """The approximate orientations of every photo of ``project`` from its image points and full
    control alone (module doc); its own orientations are not used. NumericalFailure, in words,
    when a strip cannot be built or placed."""
    options = options or SequentialOptions(procedure=1)
    ph, pts = project.photos, project.points
    names, first = np.unique(np.asarray(ph.strip_ids), return_index=True)
    names = [str(s) for s in names[np.argsort(first)]]
    members = [np.flatnonzero(np.asarray(ph.strip_ids) == s) for s in names]
    models = []
    for idx in members:
        alone, centres = _strip_alone(project, idx)
        models.append(build_strip_model(alone, options, centres))
    control = (pts.kind == FULL) & np.isfinite(pts.xyz_given).all(1)
    ground = np.where(control[:, None], pts.xyz_given, np.nan)
    source = np.where(control, -1, -2)  # -1 control, k >= 0 the k-th strip placed, -2 unknown
    R = np.full((len(ph), 3, 3), np.nan)
    O = np.full((len(ph), 3), np.nan)
    placed: list[PlacedStrip] = []
    left = set(range(len(names)))
    while left:
        usable = {s: np.flatnonzero(models[s].have & (source > -2)) for s in left}
        usable = {s: k for s, k in usable.items() if _spread_out(ground[k])}
        if not usable:
            raise NumericalFailure(_unplaced_text(names, members, models, left, source, placed))
        s = max(usable, key=lambda k: (len(usable[k]), -k))
        k = usable[s]
        sim, kept = _trimmed_similarity(models[s].xyz_model[k], ground[k])
        fitted = sim.apply(models[s].xyz_model[k[kept]])
        rms = float(np.sqrt(np.mean(np.sum((fitted - ground[k[kept]]) ** 2, axis=1))))
        after = tuple(sorted({placed[j].strip for j in source[k] if j >= 0}))
        placed.append(PlacedStrip(names[s], len(members[s]), len(k), int((source[k] == -1).sum()),
                                  int((~kept).sum()), rms, after))
        new = np.flatnonzero(models[s].have & (source == -2))
        ground[new] = sim.apply(models[s].xyz_model[new])
        source[new] = len(placed) - 1
        R[members[s]] = sim.R_ground_from_model @ models[s].R_model
        O[members[s]] = sim.apply(models[s].xyz0_model)
        left.remove(s)
    return BlockFromStrips(R, O, np.where(source[:, None] > -2, ground, np.nan), placed)


def _strip_alone(project: Project, idx: np.ndarray) -> tuple[Project, np.ndarray]:
    """The project of the photos idx (one strip, in their order) with parallel photographs one
    model unit apart as approximations, free of distortion (the camera held for this purpose),
    and those approximate centres."""
    ph, ip, cams = project.photos, project.image_points, project.cameras
    n = len(idx)
    centres = np.zeros((n, 3))
    centres[:, 0] = np.arange(n)
    photos = replace(ph, ids=[ph.ids[i] for i in idx], camera_index=ph.camera_index[idx],
                     strip_ids=[ph.strip_ids[i] for i in idx], xyz0=centres,
                     R_ground_from_cam=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), angles=np.zeros((n, 3)),
                     sigma_xyz0=np.full((n, 3), np.nan), sigma_angles=np.full((n, 3), np.nan))
    local = -np.ones(len(ph), dtype=np.int64)
    local[idx] = np.arange(n)
    rows = local[ip.photo_index] >= 0
    points = replace(ip, photo_index=local[ip.photo_index[rows]], point_index=ip.point_index[rows],
                     xy=ip.xy[rows], sigma_xy=ip.sigma_xy[rows])
    held = replace(cams, sigma_interior=np.full_like(cams.sigma_interior, np.nan))
    alone = replace(project, photos=photos, image_points=points, cameras=held, bases=BaseComponents.empty(),
                    gnss=None, inactive_image_points=None, distances=None)
    return distortion_free(alone), centres


def _spread_out(xyz: np.ndarray) -> bool:
    """At least three points, not on a line (strip.ON_A_LINE)."""
    if len(xyz) < 3:
        return False
    d = xyz - xyz.mean(0)
    sv = np.linalg.svd(d, compute_uv=False)
    return bool(sv[1] > ON_A_LINE * max(float(np.ptp(xyz, 0).max()), 1e-300))


def _trimmed_similarity(model: np.ndarray, ground: np.ndarray) -> tuple[Similarity, np.ndarray]:
    """umeyama(model, ground) with the points whose residual exceeds TRIM robust spreads left out
    (module doc) -> (similarity, kept (k,) bool)."""
    kept = np.ones(len(model), dtype=bool)
    sim = umeyama(model, ground)
    for _ in range(TRIM_ROUNDS):
        e = np.linalg.norm(sim.apply(model) - ground, axis=1)
        spread = 1.4826 * float(np.median(e[kept]))
        keep = e <= max(TRIM * spread, 1e-9 * sim.scale * float(np.ptp(model, 0).max()))
        if keep.sum() < 3 or not _spread_out(ground[keep]) or np.array_equal(keep, kept):
            break
        kept = keep
        sim = umeyama(model[kept], ground[kept])
    return sim, kept


def _unplaced_text(names, members, models, left, source, placed) -> str:
    """Why the strips in ``left`` cannot be placed, in words."""
    lines = []
    for s in sorted(left):
        k = models[s].have & (source > -2)
        lines.append(f"  strip {names[s]} ({len(members[s])} photos): {int((k & (source == -1)).sum())} full control "
                     f"points and {int((k & (source >= 0)).sum())} points of strips already placed in its model")
    done = ", ".join(p.strip for p in placed) or "none"
    return ("The photographs have no approximate orientations, and these strips cannot be placed on the ground: a "
            "strip needs three full control points (kind XYZ, measured in two successive photos of it), or three "
            "points shared with a strip already placed, not on a line.\n" + "\n".join(lines)
            + f"\nStrips placed: {done}. Give approximate orientations (GNSS/IMU or the flight plan) in photos.csv, "
              "or measure more control.")
