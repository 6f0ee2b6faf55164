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
    click.echo(f"wrote {structure_figure(project_dir, out_png, on_warning=_warn)}")


STRUCTURE_SOFTWARE = "striptri structure"  # the PNG Software text of the figures this command writes


def structure_figure(project_dir, out_png, on_warning=None):
    """Write the normal matrix's structure (Schmid Fig. 10) of a project as a PNG. An existing
    file is replaced only when it is a figure this command wrote (its PNG Software text). The
    project's notes (input not used) go to ``on_warning``. Returns the file's path."""
    from pathlib import Path

    from striptri.adjustment import normal_matrix_at_approximations
    from striptri.io.output import OutputReservation, check_output_location
    from striptri.io.png import software_of, with_software
    from striptri.io.project_reader import read_project
    from striptri.pipeline import input_paths, structure_labels
    from striptri.report.figures import normal_matrix_structure

    project_dir = Path(project_dir)
    inputs = input_paths(project_dir)

    def owned(path: Path) -> bool:
        return software_of(path) == STRUCTURE_SOFTWARE

    check_output_location(out_png, inputs, kind="file", owned=owned)
    project = read_project(project_dir)
    for note in project.notes:
        if on_warning is not None:
            on_warning(str(note))
    with OutputReservation(out_png, inputs, kind="file", owned=owned) as reservation:
        N, layout = normal_matrix_at_approximations(project)
        png = normal_matrix_structure(N, layout.block_starts(), len(project.photos),
                                      labels=structure_labels(project, layout))
        return reservation.commit(with_software(png, STRUCTURE_SOFTWARE))


# --------------------------------------------------------------------------- striptri convert
