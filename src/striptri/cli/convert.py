"""``striptri convert``: a BAL problem, COLMAP model or DBAT script into a project (formats.convert)."""

from __future__ import annotations

import click

from striptri.cli.base import _Finite, _warn, main, reports_errors


@main.command()
@click.argument("src", type=click.Path())
@click.option("--to", "target", required=True, type=click.Choice(["bal", "colmap", "dbat", "project"]),
              help="Format to write (bal: a folder with problem.txt; dbat: a folder with the script project.xml).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Folder to write.")
@click.option("--from", "source", type=click.Choice(["bal", "colmap", "dbat", "project"]), default=None,
              help="Format of SRC [detected: an .xml file is a DBAT script, another file BAL, a folder with "
                   "cameras.txt COLMAP, with cameras.csv a project].")
@click.option("--pixel-size", type=_Finite(min=0.0, min_open=True), default=None,
              help="Plate units per pixel on the COLMAP or DBAT side: the plate unit of a COLMAP source (1: "
                   "pixels, [units] plate = \"px\"; otherwise mm per pixel, the pixel pitch), the pixel of COLMAP "
                   "or DBAT output from a project [1].")
@click.option("--drop-distortion", is_flag=True, default=False,
              help="BAL, DBAT: hold the distortion at 0 (a pinhole camera) instead of keeping it.")
@reports_errors
def convert(src, target, out_dir, source, pixel_size, drop_distortion):
    """Convert SRC (a BAL problem, a COLMAP text model, a DBAT script or a project) to --to in --out
    (docs/formats.md)."""
    from striptri.formats.convert import convert as run_convert

    result = run_convert(src, out_dir, target, source_format=source, pixel_size=pixel_size,
                         drop_distortion=drop_distortion, on_warning=_warn)
    click.echo(f"wrote {result.out_dir} ({result.target_format} from {result.source_format}): {result.n_cameras} cameras, "
               f"{result.n_photos} photos, {result.n_points} points, {result.n_image_points} image points")


# --------------------------------------------------------------------------- striptri compare
