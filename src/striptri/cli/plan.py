"""``striptri plan``: pre-analysis of a planned block (plan.pipeline.run_plan)."""

from __future__ import annotations

import click

from striptri.cli.base import _warn, main, reports_errors, threads_option
from striptri.solvers import SOLVERS


@main.command()
@click.argument("project_dir", type=click.Path(file_okay=False))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder to write.")
@click.option("--method", type=click.Choice(["conditions", "bundle"]), default=None,
              help="Adjustment method whose precision is predicted [project.toml or conditions].")
@click.option("--solver", type=click.Choice(list(SOLVERS)), default=None,
              help="Solver of the normal equations [project.toml or auto].")
@click.option("--drop-control", multiple=True, metavar="ID|KIND[,...]",
              help="What-if: these control points (ids, or a kind XYZ, XY, Z) become check points. Repeatable.")
@click.option("--add-control", multiple=True, metavar="ID=KIND[:SIGMA]",
              help="What-if: the tie or check point ID becomes control of KIND (XYZ, XY, Z), held fixed or with "
                   "mean error SIGMA (m) on each given axis. Repeatable.")
@click.option("--sigma-image", multiple=True, type=float, metavar="SIGMA",
              help="What-if: every plate coordinate with this sigma (plate units). Repeatable.")
@click.option("--keep-every", multiple=True, type=click.IntRange(min=2), metavar="K",
              help="What-if (overlap): only every K-th photo of each strip; forward overlap p becomes 1 - K(1 - p). "
                   "Repeatable.")
@click.option("--overlap", multiple=True, type=float, metavar="P",
              help="What-if (overlap): every strip re-spaced along its flight line for forward overlap P (0.6 = 60 %), "
                   "von Gruber points regenerated; needs the format. Repeatable.")
@click.option("--von-gruber", is_flag=True, default=False,
              help="Plan the tie points as von Gruber points per model (the default without image_points.csv), "
                   "replacing image_points.csv's tie points.")
@click.option("--format", "plate_format", default=None, metavar="W[xH]",
              help="Camera format in plate units (e.g. 230 for 23 x 23 cm film) for the von Gruber points and "
                   "--overlap [project.toml [plan] format].")
@click.option("--terrain-height", type=float, default=None, metavar="Z",
              help="Mean terrain height (m) of the von Gruber points [project.toml [plan] terrain_height, else the "
                   "mean Z of the control points].")
@click.option("--rank-control/--no-rank-control", default=None,
              help="Rank the control points by the loss of precision when each is dropped [on; where the "
                   "rank-3 update does not apply (self-calibration, distortion, free network) only up to 40 "
                   "control points].")
@threads_option
@reports_errors
def plan(project_dir, out_dir, **given):
    """Pre-analysis of the planned block in PROJECT_DIR: a-priori precision (sigma0 = 1), internal and
    external reliability, what-ifs and the control ranking, from the design alone (docs/plan.md)."""
    from striptri.plan.pipeline import PlanOptions, run_plan

    products = run_plan(project_dir, out_dir, PlanOptions(**given), on_warning=_warn)
    p = products.summary["plan"]["precision"]
    click.echo(f"plan: {products.summary['n_photos']} photos, {products.summary['n_points']} points; "
               f"worst sigma_XY {p['worst_sigma_XY']:.4g} m, worst sigma_Z {p['worst_sigma_Z']:.4g} m "
               f"(a priori); {len(products.whatifs) - 1} what-ifs -> {out_dir}")
