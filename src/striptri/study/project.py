"""The method comparison on the user's own block (``striptri compare --project DIR``, issue 15):
the Monte Carlo study of docs/study.md on the strips and control of a project folder read as a
plan (docs/plan.md) instead of an invented strip.

The truth is the plan: its orientations, its planned ground points (plan.design.planned_points)
and the plate coordinates they predict. Each trial draws, from its own seed:

* plate measurements: the predicted ones plus normal noise of the plan's sigma_x, sigma_y (or, per
  configuration, of ``sigma_image`` for every coordinate, stated alike);
* weighted control (a finite sigma) and observed photo elements (GNSS/IMU, sigma > 0): the true
  value plus normal noise of that sigma; held values exact; check points carry the truth;
* approximate values of the free photo elements: the truth plus normal errors of
  APPROX_POSITION_ERROR (m) and APPROX_ANGLE_ERROR (deg), as ``striptri simulate`` draws them.

Every method of the study adjusts the same trial; the rows are study.csv's (study.trial.ROW_COLUMNS)
with ``layout`` "project", ``n_photos`` the project's photo count and the "last centre" the last
photo of photos.csv.

On a block of several strips (photos.csv ``strip_id``) the sequential method, which extends one
strip, adjusts each strip of the trial on its own, with the control its photos see, as a user of
an instrument-style triangulation would; its row pools the strips (pool_strip_rows): centre errors
over all photos, check-point RMS over every strip's determinations of its check points (a check
point in two strips counts twice: two independent determinations), the last centre from the strip
that holds the last photo. The simultaneous methods adjust the whole block.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.simulate.noise import NoiseOptions
from striptri.geometry.rotations import R_from_angles, angles_from_R
from striptri.study.options import SIMULTANEOUS, trial_seed
from striptri.study.trial import ROW_COLUMNS, adjust_by_methods
from ..model import FREE, OBSERVED

PROJECT_LAYOUT = "project"
APPROX_POSITION_ERROR = NoiseOptions().approx_position_error  # m
APPROX_ANGLE_ERROR = NoiseOptions().approx_angle_error  # deg


@dataclass(frozen=True)
class ProjectTask:
    """One trial on the plan. plan: the noise-free plan (plan.design.noise_free_project);
    sigma_image: None (the plan's plate sigmas) or one sigma for every plate coordinate; label:
    the sigma_image of the rows (the given one, or the median of the plan's)."""

    plan: model.Project
    trial: int
    seed: int
    methods: tuple[str, ...]
    sigma_image: float
    scale_sigma: bool

    layout = PROJECT_LAYOUT

    @property
    def n_photos(self) -> int:
        return len(self.plan.photos)

    @property
    def key(self) -> tuple:
        return (self.layout, self.n_photos, self.sigma_image, self.trial)


def project_tasks(plan: model.Project, methods, sigma_images, trials: int, seed: int) -> list[ProjectTask]:
    """The tasks of a study on ``plan``: one configuration per entry of sigma_images (empty: the
    plan's own sigmas), ``trials`` each; seeds as study.options.trial_seed with n the photo count."""
    median = float(np.median(plan.image_points.sigma_xy)) if len(plan.image_points) else 0.0
    configs = [(float(s), True) for s in sigma_images] or [(median, False)]
    return [ProjectTask(plan, t, trial_seed(seed, len(plan.photos), PROJECT_LAYOUT, s, t), tuple(methods), s, scaled)
            for s, scaled in configs for t in range(int(trials))]


def noisy_project(task: ProjectTask) -> model.Project:
    """One trial's project (module doc)."""
    plan, rng = task.plan, np.random.default_rng(task.seed)
    ip, ph, pts = plan.image_points, plan.photos, plan.points
    sigma_xy = np.full_like(ip.sigma_xy, task.sigma_image) if task.scale_sigma else ip.sigma_xy
    xy = ip.xy + rng.normal(0.0, 1.0, ip.xy.shape) * sigma_xy
    n = len(ph)
    centre, angle = ph.centre_state, ph.angle_state
    free_xyz, obs_xyz = centre == FREE, centre == OBSERVED
    xyz0 = ph.xyz0 + rng.normal(0.0, 1.0, (n, 3)) * np.where(
        free_xyz, APPROX_POSITION_ERROR, np.where(obs_xyz, np.nan_to_num(ph.sigma_xyz0), 0.0))
    free_ang, obs_ang = angle == FREE, angle == OBSERVED
    d_ang = rng.normal(0.0, 1.0, (n, 3)) * np.where(
        free_ang, np.radians(APPROX_ANGLE_ERROR), np.where(obs_ang, np.nan_to_num(ph.sigma_angles), 0.0))
    convention = plan.settings.rotation
    angles = angles_from_R(ph.R_ground_from_cam, convention) + d_ang
    R = R_from_angles(angles, convention)
    weighted = pts.given_state == OBSERVED
    given = pts.xyz_given + np.where(weighted, rng.normal(0.0, 1.0, pts.xyz_given.shape) * np.nan_to_num(pts.sigma_given), 0.0)
    return replace(plan,
                   image_points=replace(ip, xy=xy, sigma_xy=sigma_xy),
                   photos=replace(ph, xyz0=xyz0, R_ground_from_cam=R, angles=angles_from_R(R, convention)),
                   points=replace(pts, xyz_given=given, xyz_approx=None))


@dataclass(frozen=True)
class _Truth:
    xyz0: np.ndarray


def run_project_task(task: ProjectTask) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Adjust one trial by every method (study.trial.adjust_by_methods); on a block, the sequential
    method strip by strip (module doc). -> (rows, along), rows in the order of task.methods."""
    project = noisy_project(task)
    base = {"n_photos": task.n_photos, "layout": task.layout, "sigma_image": task.sigma_image, "trial": task.trial,
            "seed": task.seed}
    truth = _Truth(task.plan.photos.xyz0)
    strips = strip_rows(project.photos.strip_ids)
    if len(strips) < 2:
        return adjust_by_methods(project, truth, task.methods, base)
    whole = [m for m in task.methods if m in SIMULTANEOUS]
    by_strip = [m for m in task.methods if m not in SIMULTANEOUS]
    rows_whole, along = adjust_by_methods(project, truth, whole, base)
    row_of = dict(zip(whole, rows_whole))
    per_strip = []  # (photo rows, rows of by_strip, along of by_strip)
    for photos in strips:
        rows, strip_along = adjust_by_methods(strip_project(project, photos), _Truth(truth.xyz0[photos]), by_strip, base)
        per_strip.append((photos, rows, strip_along))
    n = len(project.photos)
    for k, label in enumerate(by_strip):
        row_of[label] = pool_strip_rows([(project.photos.strip_ids[photos[0]], photos, rows[k])
                                         for photos, rows, _ in per_strip], n)
        if all(label in a for _, _, a in per_strip):
            e = np.full(n, np.nan)
            for photos, _, a in per_strip:
                e[photos] = a[label]
            along[label] = e
    return [row_of[m] for m in task.methods], along


def strip_rows(strip_ids: list[str]) -> list[np.ndarray]:
    """The photo rows of each strip, strips in order of first appearance (photos.csv strip_id; an
    empty id is a strip of its own kind like any other)."""
    ids = np.asarray(strip_ids, dtype=object)
    order = list(dict.fromkeys(strip_ids))
    return [np.flatnonzero(ids == s) for s in order]


def strip_project(project: model.Project, photos: np.ndarray) -> model.Project:
    """The project with only the photos of rows ``photos`` (in that order), their plate
    measurements and the base components between two of them; cameras, points (control, check
    points) and settings as they are: a point no photo of the strip sees has no rays and takes no
    part."""
    ph, ip, bases = project.photos, project.image_points, project.bases
    new_index = np.full(len(ph), -1)
    new_index[photos] = np.arange(len(photos))
    keep = new_index[ip.photo_index] >= 0
    keep_base = (new_index[bases.photo_from] >= 0) & (new_index[bases.photo_to] >= 0)
    return replace(
        project,
        photos=replace(ph, ids=[ph.ids[i] for i in photos], camera_index=ph.camera_index[photos],
                       strip_ids=[ph.strip_ids[i] for i in photos], xyz0=ph.xyz0[photos],
                       R_ground_from_cam=ph.R_ground_from_cam[photos], angles=ph.angles[photos],
                       sigma_xyz0=ph.sigma_xyz0[photos], sigma_angles=ph.sigma_angles[photos]),
        image_points=replace(ip, photo_index=new_index[ip.photo_index[keep]], point_index=ip.point_index[keep],
                             xy=ip.xy[keep], sigma_xy=ip.sigma_xy[keep]),
        bases=replace(bases, photo_from=new_index[bases.photo_from[keep_base]],
                      photo_to=new_index[bases.photo_to[keep_base]], axis=bases.axis[keep_base],
                      value=bases.value[keep_base], sigma=bases.sigma[keep_base]),
    )


def pool_strip_rows(strip_rows_: list[tuple[str, np.ndarray, dict]], n_photos: int) -> dict:
    """One study.csv row of a method adjusted strip by strip: [(strip id, photo rows of the strip,
    its row)]. A failure of any strip is the row's status (naming the strip); else centre RMS
    over all photos, check-point RMS over all strips' check points (weighted by their counts),
    the last centre from the strip holding photo n_photos - 1, sigma0 the RMS of the strips',
    iterations the most, seconds the sum; no predicted precision (a sequential row has none)."""
    rows = [r for _, _, r in strip_rows_]
    pooled = dict(rows[0])
    pooled["seconds"] = float(sum(r["seconds"] or 0.0 for r in rows))
    failed = [(strip, r) for strip, _, r in strip_rows_ if r["status"] != "ok"]
    if failed:
        pooled.update({c: None for c in pooled if c.startswith(("check_", "centre_", "predicted_"))})
        pooled.update(sigma0=None, iterations=None, converged=None,
                      status=f"strip {failed[0][0]}: {failed[0][1]['status']}")
        return pooled
    counts = np.array([len(photos) for _, photos, _ in strip_rows_], dtype=float)
    pooled["centre_rms"] = float(np.sqrt(np.sum(counts * np.array([r["centre_rms"] for r in rows]) ** 2) / counts.sum()))
    n_check = np.array([r["check_n"] or 0 for r in rows], dtype=float)
    pooled["check_n"] = int(n_check.sum())
    for axis in "XYZ":
        rms = np.array([r[f"check_rms_{axis}"] if r["check_n"] else 0.0 for r in rows], dtype=float)
        pooled[f"check_rms_{axis}"] = float(np.sqrt(np.sum(n_check * rms**2) / n_check.sum())) if n_check.sum() else None
    last = next(r for _, photos, r in strip_rows_ if n_photos - 1 in photos)
    for key in ("centre_last", "centre_last_X", "centre_last_Y", "centre_last_Z"):
        pooled[key] = last[key]
    pooled["predicted_last"] = None
    pooled["sigma0"] = float(np.sqrt(np.mean([r["sigma0"] ** 2 for r in rows])))
    pooled["iterations"] = int(max(r["iterations"] for r in rows))
    pooled["converged"] = bool(all(r["converged"] for r in rows))
    return pooled


__all__ = ["PROJECT_LAYOUT", "ProjectTask", "ROW_COLUMNS", "noisy_project", "pool_strip_rows", "project_tasks",
           "run_project_task", "strip_project", "strip_rows"]
