"""The instrument-style sequential strip triangulation (Schut's procedures 1 and 2; DESIGN section 8).

The strip model is built photograph by photograph in a *model frame*: the frame of the starting
photograph (its centre at the origin, ``R = I``), at the scale of the first model's base, which is
held at the approximate base length. Then the strip model is fitted to the control.

* Procedure 1: dependent relative orientation of photo j to the preceding photo i (5 elements:
  rotation of j, by and bz; the base component along the plate axis nearest the flight direction
  held), least squares by coplanarity (Schmid 20); the model (i, j) is intersected from the adjusted
  rays and scaled about O_i so that the points it shares with the strip model built so far agree with
  their strip-model coordinates in the least-squares sense (``s = sum d.(P - O_i) / sum d.d``,
  d = model point - O_i, P = strip-model point); its new points join the strip model.
* Procedure 2 (Schmid's "(20) & (14)"): the six elements of photo j in one least-squares adjustment of
  the coplanarity of the points new in model (i, j) and the collinearity of the carried-over points
  (their strip-model coordinates held). The first model is a relative orientation as in procedure 1,
  and every step starts from procedure 1's result.
* Both: a strip model point keeps the coordinates of the model it first appears in.
* Absolute orientation: 3D similarity to the full, plan and height control (7 parameters, least
  squares, all given coordinates weighted alike), then optionally the polynomial strip correction
  (absolute.fit_strip_polynomial) applied to points and centres, after which every photograph is
  resected (collinearity, six elements) from its corrected points.

``direction``: "forward" starts at the first photograph of photos.csv, "backward" at the last.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from pathlib import Path

import numpy as np

from ..geometry.camera import plate_vector
from ..equations.conditions import closest_scales
from ..core.options import DIRECTIONS, PROCEDURES, SequentialOptions  # noqa: F401  (re-exported)
from ..errors import InputError, NumericalFailure
from ..geometry.lens import DISTORTION_ELEMENTS, has_distortion, ideal_from_observed
from ..model import CHECK, HELD, Project
from ..equations.parameters import reduction_offset
from ..core.termination import table, trend
from ..equations.triangulation import intersect_rays
from .absolute import (
    Similarity,
    StripPolynomial,
    fit_similarity,
    fit_strip_polynomial,
    umeyama,
)
from .photo_step import PhotoStep, Pose, StepMeasurements, orient_photo

# A start of a relative orientation from the linear base (_linear_base) only when its component
# along the held axis exceeds this fraction of the base (a smaller one scales the others wildly).
LINEAR_BASE_MIN = 0.1
# Two converged relative orientations whose v^T P v differ by less than this fraction are the same
# solution: the first found is kept (the starts are tried in order of plausibility).
SAME_SOLUTION = 1e-9
# Full control points whose second singular value is below this fraction of their extent lie on a
# line: they cannot start the absolute orientation alone, the approximate centres are added.
ON_A_LINE = 1e-3


@dataclass
class SequentialSolution:
    """Everything the sequential method computes. Ground coordinates in the reduced frame (+ offset).

    order: photo indices in the order oriented. R_model, xyz0_model: (n, ...) photos in the model
    frame; xyz_model: (n_pt, 3) the strip model (nan where a point is in no model).
    steps: the per-photo adjustments (steps[s] orients order[s + 1]; for procedure 2 from the second
    model on, the relative orientation that started it is in relative_steps). scale_residuals: per step
    the (k, 3) differences strip model - scaled model at the common points (model frame).
    similarity, control_residuals (n_pt, 3, given - similarity, nan where not given), polynomial.
    R_ground, xyz0_ground, xyz_ground: the result in the ground frame.
    """

    options: SequentialOptions
    offset: np.ndarray
    order: np.ndarray
    R_model: np.ndarray
    xyz0_model: np.ndarray
    xyz_model: np.ndarray
    steps: list[PhotoStep]
    relative_steps: list[PhotoStep]
    scale_factors: np.ndarray
    scale_residuals: list[np.ndarray]
    similarity: Similarity
    control_residuals: np.ndarray
    similarity_iterations: int
    polynomial: StripPolynomial | None
    R_ground: np.ndarray
    xyz0_ground: np.ndarray
    xyz_ground: np.ndarray
    resections: list[PhotoStep] = field(default_factory=list)
    similarity_converged: bool = True

    @property
    def vtpv(self) -> float:
        return float(sum(s.vtpv for s in self.steps))

    @property
    def redundancy(self) -> int:
        return int(sum(s.redundancy for s in self.steps))


def _single_strip(project: Project) -> None:
    """The sequential method refused for a project it cannot take: bad input for this method (exit
    status 2, naming photos.csv), not numerical trouble."""
    strips = set(project.photos.strip_ids)
    photos_csv = Path(project.source or ".") / "photos.csv"
    if len(strips) > 1:
        raise InputError(photos_csv, None, f"the sequential method (--method sequential) triangulates one strip; this "
                         f"project has {len(strips)} strips (column strip_id). Adjust a block with the simultaneous "
                         "methods (conditions, bundle).")
    if len(project.photos) < 2:
        raise InputError(photos_csv, None, "the sequential method (--method sequential) needs at least two photographs")


def _relative_orientation(held_photo: Pose, interior_j, approximate, measured: StepMeasurements, kw,
                          names) -> PhotoStep:
    """Dependent relative orientation of photo j to photo i (``held_photo``), robust to rough
    approximations. approximate: (R_rel0, b_cam0), the approximate relative rotation ``R_i^T R_j``
    and base (camera frame of i); measured: the points for coplanarity (StepMeasurements).

    The held base component (Schut's bx) is the one along the plate axis nearest the base as the
    plates show it (the base that best satisfies coplanarity with parallel photographs), held at +/-
    the approximate base length ``|b_cam0|``. Coplanarity has false solutions, so the adjustment is
    started from eight sets of values: both signs of the held component, the approximate relative
    rotation ``R_i^T R_j`` or none (consecutive photographs of a strip are nearly parallel), each with
    the base that best satisfies coplanarity for that rotation (linear in b: the right singular vector
    of the smallest singular value of the rows ``p_i x R_rel p_j``) or a base along the held axis. Of
    the converged solutions that put every point in front of both photographs the one with the
    smallest v^T P v is taken.
    """
    R_i, O_i, interior_i = held_photo
    R_rel0, b_cam0 = approximate
    cop_xy, cop_sig = measured.cop_xy, measured.cop_sigma
    b_image = _linear_base(np.eye(3), cop_xy, interior_i, interior_j)
    held = int(np.argmax(np.abs(b_image)))
    length = float(np.linalg.norm(b_cam0))
    first = 1.0 if b_cam0[held] >= 0 else -1.0
    best, tried, closest = None, 0, None
    starts = []
    for sign in (first, -first):
        b_axis = np.zeros(3)
        b_axis[held] = sign * length
        for R_rel in (R_rel0, np.eye(3)):
            b_lin = _linear_base(R_rel, cop_xy, interior_i, interior_j)
            if abs(b_lin[held]) > LINEAR_BASE_MIN:
                starts.append((R_rel, b_lin * (sign * length / b_lin[held])))
            starts.append((R_rel, b_axis))
    for R_rel, b in starts:
        try:
            ro = orient_photo("relative", Pose(R_i, O_i, interior_i), Pose(R_i @ R_rel, O_i + R_i @ b, interior_j),
                              StepMeasurements(cop_xy, cop_sig), held_axis=held,
                              label=f"photo {names[1]} relative to photo {names[0]}", **kw)
        except NumericalFailure:
            continue
        tried += 1
        if not ro.converged:
            if closest is None or ro.max_correction < closest.max_correction:
                closest = ro
            continue
        if not _in_front(R_i, O_i, ro, interior_i, interior_j):
            continue
        if best is None or ro.vtpv < best.vtpv * (1 - SAME_SOLUTION):
            best = ro
    if best is None:
        text = (f"the relative orientation of photographs {names[0]} and {names[1]} did not converge to a solution "
                f"with the points in front of both ({len(starts)} starts, {tried} of them without numerical failure).")
        if closest is not None and closest.history:
            text += (f"\nThe start that came closest stopped at the limit of {closest.iterations} iterations with "
                     f"its largest correction still {closest.max_correction:.3g} sd:\n"
                     + table(closest.history, closest.redundancy))
            if trend(closest.history)[0] == "shrinking":
                text += ("\nIts corrections were still shrinking: raise [adjustment] max_iterations in project.toml "
                         "(each step of the sequential method may take max(30, max_iterations) iterations).")
        raise NumericalFailure(text, reason="iteration_limit" if closest is not None else "failed")
    return best


def _linear_base(R_rel, cop_xy, interior_i, interior_j) -> np.ndarray:
    """The unit base (frame of photo i, sign arbitrary) that minimises sum (b . (p_i x R_rel p_j))^2
    (coplanarity is linear in b once the rotation is given)."""
    xy = np.asarray(cop_xy).reshape(-1, 2, 2)
    p_i = plate_vector(xy[:, 0], interior_i)
    p_j = plate_vector(xy[:, 1], interior_j) @ R_rel.T
    return np.linalg.svd(np.cross(p_i, p_j))[2][-1]


def _in_front(R_i, O_i, ro: PhotoStep, interior_i, interior_j) -> bool:
    """Every model point of the step lies in front of both photographs (positive ray scales)."""
    xy = ro.plate_cop.reshape(-1, 2, 2)
    p = plate_vector(xy, np.stack([interior_i, interior_j]))
    r = np.einsum("kab,mkb->mka", np.stack([R_i, ro.R_j]), p)
    s, t, _, _ = closest_scales(np.broadcast_to(ro.O_j - O_i, r[:, 0].shape), r[:, 0], r[:, 1])
    return bool(np.all(s > 0) and np.all(t > 0))


def distortion_free(project: Project) -> Project:
    """The project with its measurements replaced by their ideal plate points (striptri.geometry.lens) and
    the additional parameters set to 0: the sequential method holds the camera, so the camera
    model is applied once, before the strip is built (docs/camera-model.md)."""
    cams, ip = project.cameras, project.image_points
    free = cams.interior_state[:, DISTORTION_ELEMENTS] != HELD
    if free.any():
        raise InputError(Path(project.source or ".") / "cameras.csv", None,
                         "the sequential method (--method sequential) holds the camera; it cannot estimate lens "
                         "distortion. Use the conditions or bundle method for self-calibration.")
    if not has_distortion(cams.interior):
        return project
    cam = project.photos.camera_index[ip.photo_index]
    ideal = ideal_from_observed(ip.xy, cams.interior[cam], cams.convention[cam])
    if not ideal.converged.all():
        raise NumericalFailure("the lens distortion of some measurements cannot be inverted")
    interior = cams.interior.copy()
    interior[:, DISTORTION_ELEMENTS] = 0.0
    return replace(project, image_points=replace(ip, xy=ideal.xy), cameras=replace(cams, interior=interior))


@dataclass
class StripModel:
    """The strip model in the frame of its starting photograph (module doc): order, R_model,
    xyz0_model, xyz_model as in SequentialSolution; have (n_pt,) the points in the model; row
    (n, n_pt) the image point row of each photo and point (-1: none); the steps and scale
    transfers."""

    order: np.ndarray
    R_model: np.ndarray
    xyz0_model: np.ndarray
    xyz_model: np.ndarray
    have: np.ndarray
    row: np.ndarray
    steps: list[PhotoStep]
    relative_steps: list[PhotoStep]
    scale_factors: np.ndarray
    scale_residuals: list[np.ndarray]


def triangulate_strip(project: Project, options: SequentialOptions | None = None) -> SequentialSolution:
    """Build the strip model photo by photo, then orient it absolutely (module doc)."""
    options = options or SequentialOptions()
    _single_strip(project)
    project = distortion_free(project)
    offset = reduction_offset(project)
    m = build_strip_model(project, options, project.photos.xyz0 - offset)
    ph, ip, pts = project.photos, project.image_points, project.points
    n = len(ph)
    Oa = ph.xyz0 - offset
    order, Rm, Om, Xm, have, row = m.order, m.R_model, m.xyz0_model, m.xyz_model, m.have, m.row
    interior = project.cameras.interior[ph.camera_index, :3]
    kw = {"tolerance": options.tolerance, "max_iterations": options.max_iterations}
    # absolute orientation
    given = pts.given_axes & np.isfinite(pts.xyz_given) & have[:, None] & (pts.kind != CHECK)[:, None]
    xyz_given = pts.xyz_given - offset
    full = np.flatnonzero(given.all(1))
    start_m, start_g = Xm[full], xyz_given[full]
    spread = np.linalg.svd(start_m - start_m.mean(0), compute_uv=False)[1] if len(full) >= 3 else 0.0
    if len(full) < 3 or spread < ON_A_LINE * np.ptp(start_m, 0).max():
        start_m = np.concatenate([start_m, Om])  # the approximate centres help to start
        start_g = np.concatenate([start_g, Oa])
    fit = fit_similarity(np.where(have[:, None], Xm, 0.0), np.where(given, xyz_given, 0.0), given,
                         umeyama(start_m, start_g))
    sim = fit.similarity
    X_g = np.where(have[:, None], sim.apply(np.where(have[:, None], Xm, 0.0)), np.nan)
    O_g = sim.apply(Om)
    R_g = sim.R_ground_from_model @ Rm
    poly, resections = None, []
    if options.polynomial_degree is not None:
        poly = fit_strip_polynomial(fit.residuals, np.where(have[:, None], X_g, 0.0), O_g[order],
                                    options.polynomial_degree)
        X_g = np.where(have[:, None], X_g + poly.correction(np.where(have[:, None], X_g, 0.0)), np.nan)
        O_g = O_g + poly.correction(O_g)
        for j in range(n):
            seen = np.flatnonzero(have & (row[j] >= 0))
            pose = Pose(R_g[j], O_g[j], interior[j])
            measured = StepMeasurements(np.zeros((0, 4)), np.zeros((0, 4)), ip.xy[row[j, seen]],
                                        ip.sigma_xy[row[j, seen]], X_g[seen])
            rs = orient_photo("full", pose, pose, measured,
                              label=f"photo {ph.ids[j]} (resection after the strip correction)", **kw)
            R_g[j], O_g[j] = rs.R_j, rs.O_j
            resections.append(rs)
    return SequentialSolution(
        options=options, offset=offset, order=order, R_model=Rm, xyz0_model=Om, xyz_model=Xm, steps=m.steps,
        relative_steps=m.relative_steps, scale_factors=m.scale_factors, scale_residuals=m.scale_residuals,
        similarity=sim, control_residuals=fit.residuals, similarity_iterations=fit.iterations, polynomial=poly,
        similarity_converged=fit.converged,
        R_ground=R_g, xyz0_ground=O_g, xyz_ground=X_g, resections=resections,
    )


def build_strip_model(project: Project, options: SequentialOptions, centres: np.ndarray) -> StripModel:
    """The strip model of ``project`` (one strip, free of distortion) photo by photo in the frame of
    its starting photograph (module doc, procedures 1 and 2). centres: (n, 3) the approximate
    centres (reduced frame): with the approximate rotations they give each relative orientation
    its start and the length of its held base component."""
    ph, ip = project.photos, project.image_points
    n, n_pt = len(ph), len(project.points)
    Ra, Oa = ph.R_ground_from_cam, centres
    interior = project.cameras.interior[ph.camera_index, :3]
    order = np.arange(n) if options.direction == "forward" else np.arange(n)[::-1]
    row = -np.ones((n, n_pt), dtype=int)
    row[ip.photo_index, ip.point_index] = np.arange(len(ip))

    Rm = np.zeros((n, 3, 3))
    Om = np.zeros((n, 3))
    Rm[order[0]] = np.eye(3)
    Xm = np.full((n_pt, 3), np.nan)
    have = np.zeros(n_pt, dtype=bool)
    steps, relative_steps, scales, scale_res = [], [], [], []
    kw = {"tolerance": options.tolerance, "max_iterations": options.max_iterations}
    for s in range(1, n):
        i, j = order[s - 1], order[s]
        common = np.flatnonzero((row[i] >= 0) & (row[j] >= 0))
        if len(common) < 5:
            raise NumericalFailure(f"photographs {ph.ids[i]} and {ph.ids[j]} share {len(common)} points; a relative "
                                   "orientation needs at least five.")
        cop_rows = np.stack([row[i, common], row[j, common]], 1)
        cop_xy = ip.xy[cop_rows].reshape(-1, 4)
        cop_sig = ip.sigma_xy[cop_rows].reshape(-1, 4)
        ro = _relative_orientation(Pose(Rm[i], Om[i], interior[i]), interior[j],
                                   (Ra[i].T @ Ra[j], Ra[i].T @ (Oa[j] - Oa[i])), StepMeasurements(cop_xy, cop_sig), kw,
                                   (ph.ids[i], ph.ids[j]))
        # the model (i, j) from the adjusted rays, at the scale of the held base component
        xy = ro.plate_cop.reshape(-1, 2, 2)
        Rij = np.stack([Rm[i], ro.R_j])
        Oij = np.stack([Om[i], ro.O_j])
        p = plate_vector(xy, interior[[i, j]])
        r = np.einsum("kab,mkb->mka", Rij, p)
        X_unit = intersect_rays(np.broadcast_to(Oij, r.shape), r)
        known = have[common]
        d = X_unit[known] - Om[i]
        if s == 1:
            scale = 1.0
        elif known.any():
            P = Xm[common[known]] - Om[i]
            scale = float(np.sum(d * P) / np.sum(d * d))
        else:
            raise NumericalFailure(f"model {ph.ids[i]}-{ph.ids[j]} shares no point with the preceding model: the "
                                   "scale cannot be carried on.")
        scales.append(scale)
        scale_res.append(Xm[common[known]] - (Om[i] + scale * d))
        O_j = Om[i] + scale * (ro.O_j - Om[i])
        R_j = ro.R_j
        new = common[~known]
        X_new = Om[i] + scale * (X_unit[~known] - Om[i])
        step = ro
        if options.procedure == 2 and s > 1:
            carried = np.flatnonzero(have & (row[j] >= 0))
            new_rows = np.stack([row[i, new], row[j, new]], 1)
            measured = StepMeasurements(ip.xy[new_rows].reshape(-1, 4), ip.sigma_xy[new_rows].reshape(-1, 4),
                                        ip.xy[row[j, carried]], ip.sigma_xy[row[j, carried]], Xm[carried])
            step = orient_photo("full", Pose(Rm[i], Om[i], interior[i]), Pose(R_j, O_j, interior[j]), measured,
                                label=f"photo {ph.ids[j]}", **kw)
            relative_steps.append(ro)
            R_j, O_j = step.R_j, step.O_j
            if len(new):
                xy = step.plate_cop.reshape(-1, 2, 2)
                p = plate_vector(xy, interior[[i, j]])
                r = np.einsum("kab,mkb->mka", np.stack([Rm[i], R_j]), p)
                X_new = intersect_rays(np.broadcast_to(np.stack([Om[i], O_j]), r.shape), r)
        Rm[j], Om[j] = R_j, O_j
        Xm[new] = X_new
        have[new] = True
        steps.append(step)
    return StripModel(order=order, R_model=Rm, xyz0_model=Om, xyz_model=Xm, have=have, row=row, steps=steps,
                      relative_steps=relative_steps, scale_factors=np.array(scales), scale_residuals=scale_res)
