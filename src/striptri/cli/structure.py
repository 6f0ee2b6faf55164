"""``striptri structure``: the structure of a project's normal matrix as a figure."""

from __future__ import annotations

import click

from striptri.cli.base import _warn, main, reports_errors


@main.command()
@click.argument("project_dir", type=click.Path(file_okay=False))
@click.option("--out", "out_png", required=True, type=click.Path(dir_okay=False),
              help="PNG file to write (an existing file only if this command wrote it).")
@reports_errors
def structure(project_dir, out_png):
    """Draw the structure of the normal matrix of PROJECT_DIR (Schmid Fig. 10) into --out."""
    from striptri.pipeline import structure_figure

    click.echo(f"wrote {structure_figure(project_dir, out_png, on_warning=_warn)}")


# --------------------------------------------------------------------------- striptri convert
