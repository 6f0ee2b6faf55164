"""One task of a study: simulate one strip, adjust it by every method, measure the errors against the
truth. Pure: no files, no printing; what it returns is a list of rows (dicts) and the error of every
photo centre (for the error-along-the-strip figure)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from striptri import model
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.errors import NumericalFailure
from striptri.pipeline import check_point_statistics, triangulate_result
from striptri.simulate import ControlDesign, FlightDesign, NoiseOptions, SyntheticDesign, make_truth, perturb
from striptri.simulate.truth import Truth
from striptri.study.options import METHOD_SPECS, SIMULTANEOUS, Task

ROW_COLUMNS = (
    "method", "procedure", "direction", "n_photos", "layout", "sigma_image", "trial", "seed",
    "check_n", "check_rms_X", "check_rms_Y", "check_rms_Z",
    "centre_rms", "centre_last", "centre_last_X", "centre_last_Y", "centre_last_Z",
    "predicted_last", "sigma0", "iterations", "converged", "status", "seconds",
)


def design_of(task: Task) -> SyntheticDesign:
    """The strip of a task. cantilever is drawn as "ends" and relabelled (cantilever_project)."""
    if task.layout == "every-k":
        control = ControlDesign(layout="every-k", every_k=task.every_k, every_k_kind="XYZ", n_check=task.n_check)
    else:
        control = ControlDesign(layout="ends", n_check=task.n_check)
    return SyntheticDesign(flight=FlightDesign(n_photos=task.n_photos, overlap=task.overlap), control=control)


def simulate_task(task: Task) -> tuple[Truth, model.Project]:
    """Truth and project of a task; the seed is split as simulate_project splits it (truth, noise)."""
    truth_seed, noise_seed = np.random.SeedSequence(task.seed).spawn(2)
    truth = make_truth(design_of(task), np.random.default_rng(truth_seed))
    project = perturb(truth, NoiseOptions(sigma_image=task.sigma_image), np.random.default_rng(noise_seed))
    if task.layout == "cantilever":
        project = cantilever_project(project, truth.xyz_ground)
    return truth, project


def cantilever_project(project: model.Project, xyz_true: np.ndarray) -> model.Project:
    """Keep the control of the first model (points seen by both the first and the second photo of
    photos.csv); every other control point becomes a check point carrying its true coordinates."""
    ip, pts = project.image_points, project.points
    seen_by = lambda photo: np.bincount(ip.point_index[ip.photo_index == photo], minlength=len(pts)) > 0  # noqa: E731
    first_model = seen_by(0) & seen_by(1)
    control = np.isin(pts.kind, (model.FULL, model.PLAN, model.HEIGHT))
    to_check = control & ~first_model
    kind = np.where(to_check, model.CHECK, pts.kind)
    xyz_given = np.where(to_check[:, None], xyz_true, pts.xyz_given)
    sigma_given = np.where(to_check[:, None], np.nan, pts.sigma_given)
    points = dataclasses.replace(pts, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given)
    return dataclasses.replace(project, points=points)


def run_task(task: Task) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Adjust the task's strip by every method. -> (rows of study.csv, method -> (n,) centre errors (m)).
    A numerical failure of one method gives a row with status "failed: ..." and no errors."""
    truth, project = simulate_task(task)
    base = {"n_photos": task.n_photos, "layout": task.layout, "sigma_image": task.sigma_image, "trial": task.trial,
            "seed": task.seed}
    return adjust_by_methods(project, truth, task.methods, base)


def adjust_by_methods(project: model.Project, truth, methods, base: dict) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Adjust ``project`` by every method label of ``methods``: rows (``base`` with the method and
    its errors against ``truth``, which needs ``xyz0`` (n, 3) ground m) and label -> centre errors."""
    rows, along = [], {}
    for label in methods:
        method, procedure, direction = METHOD_SPECS[label]
        options = AdjustmentOptions.of(method=method, procedure=procedure or 1, direction=direction or "forward")
        row = {"method": method, "procedure": procedure, "direction": direction, **base}
        start = time.perf_counter()
        try:
            result = adjust(project, options)
            row.update(_errors(project, truth, result, label in SIMULTANEOUS))
            along[label] = np.linalg.norm(result.state.xyz0 + result.offset - truth.xyz0, axis=1)
        except NumericalFailure as exc:
            row.update(status=f"failed: {exc}")
        row["seconds"] = time.perf_counter() - start
        rows.append({c: row.get(c) for c in ROW_COLUMNS})
    return rows, along


def _errors(project: model.Project, truth: Truth, result, simultaneous: bool) -> dict:
    checks = check_point_statistics(project, result, triangulate_result(project, result))
    d = result.state.xyz0 + result.offset - truth.xyz0  # (n, 3) centre errors, ground m
    e = np.linalg.norm(d, axis=1)
    predicted = None
    if simultaneous:
        # a-priori mean error (sigma0 = 1: the stated plate sigma is the injected one) of the last centre
        sig_xyz, _ = result.photo_mean_errors("omega-phi-kappa")
        predicted = float(np.linalg.norm(sig_xyz[-1]) / result.sigma0_for_precision)
    return {
        "check_n": checks["n"], "check_rms_X": checks["rms_X"], "check_rms_Y": checks["rms_Y"],
        "check_rms_Z": checks["rms_Z"],
        "centre_rms": float(np.sqrt(np.mean(e**2))), "centre_last": float(e[-1]),
        "centre_last_X": float(d[-1, 0]), "centre_last_Y": float(d[-1, 1]), "centre_last_Z": float(d[-1, 2]),
        "predicted_last": predicted, "sigma0": float(result.sigma0), "iterations": int(result.iterations),
        "converged": bool(result.converged), "status": "ok",
    }
