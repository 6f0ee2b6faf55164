"""``striptri compare``: a method-comparison study (striptri.study)."""

from __future__ import annotations

import click

from striptri.cli.base import _Finite, _ManyValues, main, reports_errors
from striptri.errors import InputError


@main.command()
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder to write.")
@click.option("--methods", multiple=True, cls=_ManyValues, default=None,
              type=click.Choice(["seq1-forward", "seq1-backward", "seq2-forward", "seq2-backward", "conditions", "bundle"]),
              help="Methods to compare [all six].")
@click.option("--photos", multiple=True, cls=_ManyValues, type=click.IntRange(4, 999), default=None,
              help="Strip lengths in photos [4 8 16 32].")
@click.option("--layouts", multiple=True, cls=_ManyValues, type=click.Choice(["cantilever", "ends", "every-k"]), default=None,
              help="Control layouts [cantilever ends].")
@click.option("--sigma-image", "sigma_images", multiple=True, cls=_ManyValues, type=_Finite(min=0.0), default=None,
              help="Plate noise, plate units [0.005].")
@click.option("--trials", type=click.IntRange(min=1), default=10, show_default=True, help="Trials per configuration.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Study seed.")
@click.option("--every-k", type=click.IntRange(min=1), default=2, show_default=True,
              help="Layout every-k: full control at every k-th nadir.")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Local worker processes [all cores].")
@click.option("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786): run the trials there.")
@click.option("--project", "project_dir", default=None, type=click.Path(file_okay=False),
              help="Run the study on this project's own block and control, read as a plan (docs/plan.md), "
                   "instead of invented strips (--photos, --layouts, --every-k do not apply; --sigma-image "
                   "replaces the plan's plate sigmas) [invented strips].")
@reports_errors
def compare(out_dir, project_dir, workers, scheduler, **given):
    """Method-comparison study: the sequential, conditions and bundle methods on simulated strips or
    your own block, Monte Carlo trials (docs/study.md), written to --out."""
    from striptri.study import StudyOptions, run_compare
    from striptri.study.progress import StderrProgress

    methods, photos, layouts, sigma_images = (given[k] for k in ("methods", "photos", "layouts", "sigma_images"))
    trials, seed, every_k = given["trials"], given["seed"], given["every_k"]
    lists = {"methods": methods, "photos": photos, "layouts": layouts, "sigma_images": sigma_images}
    if project_dir is not None:
        from striptri.study.project_pipeline import ProjectStudyOptions, run_compare_project

        if photos or layouts or every_k != 2:
            raise InputError("command line", None, "--photos, --layouts and --every-k describe invented strips; "
                             "with --project the strips and control are the project's")
        progress = StderrProgress()
        try:
            study = ProjectStudyOptions(methods=tuple(methods) or None, sigma_images=tuple(sigma_images),
                                        trials=trials, seed=seed)
            result = run_compare_project(out_dir, project_dir, study, workers=workers, scheduler=scheduler,
                                         progress=progress)
        finally:
            progress.close()
        failed = f", {result.n_failed} failed" if result.n_failed else ""
        click.echo(f"{len(result.rows)} adjustments{failed} -> {result.out_dir}")
        return
    options = StudyOptions(trials=trials, seed=seed, every_k=every_k,
                           **{k: tuple(v) for k, v in lists.items() if v})
    progress = StderrProgress()
    try:
        result = run_compare(out_dir, options, workers=workers, scheduler=scheduler, progress=progress)
    finally:
        progress.close()
    failed = f", {result.n_failed} failed" if result.n_failed else ""
    click.echo(f"{len(result.rows)} adjustments{failed} -> {result.out_dir}")


if __name__ == "__main__":
    main()
