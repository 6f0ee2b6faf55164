"""``striptri compare --project DIR``: the method-comparison study on a project's own block
(study.project), written as ``striptri compare`` writes a study: study.csv, growth.csv,
precision.csv, along.csv and report.html, whole or not at all (docs/study.md, docs/plan.md)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from striptri.errors import InputError
from striptri.io.output import OutputReservation, check_output_location
from striptri.io.project_reader import read_project
from striptri.pipeline import input_paths
from striptri.plan.design import noise_free_project
from striptri.study.growth import along_strip
from striptri.study.options import METHOD_LABELS, StudyOptions
from striptri.study.pipeline import StudyResult, commit_study
from striptri.study.project import PROJECT_LAYOUT, project_tasks, run_project_task
from striptri.study.runner import Progress, run_tasks


@dataclass(frozen=True)
class ProjectStudyOptions:
    """A study on a project's own block: methods, labels of study.options.METHOD_SPECS (None: all
    six); sigma_images, plate sigmas of the configurations (empty: one configuration with the
    plan's own sigmas); trials per configuration and method; seed of the noise."""

    methods: tuple | None = None
    sigma_images: tuple = ()
    trials: int = 10
    seed: int = 0


def run_compare_project(out_dir, project_dir, options: ProjectStudyOptions = ProjectStudyOptions(),
                        workers: int | None = None, scheduler=None, progress: Progress | None = None) -> StudyResult:
    """Run the study ``options`` on the plan in ``project_dir`` and write ``out_dir``. The output
    location is checked before the project is read; InputError for bad input or options."""
    methods, sigma_images = options.methods, tuple(options.sigma_images)
    trials, seed = options.trials, options.seed
    methods = METHOD_LABELS if methods is None else tuple(methods)
    project_dir = Path(project_dir)
    inputs = input_paths(project_dir)
    check_output_location(out_dir, inputs)
    try:  # the study's own checks of methods, noise levels, trials and seed
        StudyOptions(methods=tuple(methods), sigma_images=tuple(sigma_images) or (0.005,), trials=trials, seed=seed)
    except ValueError as exc:
        raise InputError("command line", None, str(exc)) from None
    if any(s <= 0 for s in sigma_images):
        raise InputError("command line", None, "--sigma-image with --project: a positive plate sigma (the "
                         "weights of the adjustment are its inverse squares)")
    plan = noise_free_project(read_project(project_dir))
    tasks = project_tasks(plan, methods, sigma_images, trials, seed)
    with OutputReservation(out_dir, inputs) as reservation:
        results = run_tasks(tasks, workers=workers, scheduler=scheduler, progress=progress, run=run_project_task)
        rows = [row for _, task_rows, _ in results for row in task_rows]
        along = along_strip([(task, a) for task, _, a in results])
        described = SimpleNamespace(methods=tuple(methods), photos=(len(plan.photos),), layouts=(PROJECT_LAYOUT,),
                                    sigma_images=tuple(sorted({t.sigma_image for t in tasks})), trials=trials, seed=seed)
        return commit_study(reservation, described, rows, along)
