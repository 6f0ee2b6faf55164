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
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.simulate.noise import NoiseOptions
from striptri.rotations import R_from_angles, angles_from_R
from striptri.study.options import trial_seed
from striptri.study.trial import ROW_COLUMNS, adjust_by_methods

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
    free_xyz, obs_xyz = np.isnan(ph.sigma_xyz0), np.nan_to_num(ph.sigma_xyz0) > 0
    xyz0 = ph.xyz0 + rng.normal(0.0, 1.0, (n, 3)) * np.where(
        free_xyz, APPROX_POSITION_ERROR, np.where(obs_xyz, np.nan_to_num(ph.sigma_xyz0), 0.0))
    free_ang, obs_ang = np.isnan(ph.sigma_angles), np.nan_to_num(ph.sigma_angles) > 0
    d_ang = rng.normal(0.0, 1.0, (n, 3)) * np.where(
        free_ang, np.radians(APPROX_ANGLE_ERROR), np.where(obs_ang, np.nan_to_num(ph.sigma_angles), 0.0))
    convention = plan.settings.rotation
    angles = angles_from_R(ph.R_ground_from_cam, convention) + d_ang
    R = R_from_angles(angles, convention)
    weighted = np.nan_to_num(pts.sigma_given) > 0
    given = pts.xyz_given + np.where(weighted, rng.normal(0.0, 1.0, pts.xyz_given.shape) * np.nan_to_num(pts.sigma_given), 0.0)
    return replace(plan,
                   image_points=replace(ip, xy=xy, sigma_xy=sigma_xy),
                   photos=replace(ph, xyz0=xyz0, R_ground_from_cam=R, angles=angles_from_R(R, convention)),
                   points=replace(pts, xyz_given=given, xyz_approx=None))


@dataclass(frozen=True)
class _Truth:
    xyz0: np.ndarray


def run_project_task(task: ProjectTask) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Adjust one trial by every method (study.trial.adjust_by_methods). -> (rows, along)."""
    project = noisy_project(task)
    base = {"n_photos": task.n_photos, "layout": task.layout, "sigma_image": task.sigma_image, "trial": task.trial,
            "seed": task.seed}
    return adjust_by_methods(project, _Truth(task.plan.photos.xyz0), task.methods, base)


__all__ = ["PROJECT_LAYOUT", "ProjectTask", "ROW_COLUMNS", "noisy_project", "project_tasks", "run_project_task"]
