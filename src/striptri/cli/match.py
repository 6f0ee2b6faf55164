"""``striptri match``: automatic tie points for a block of digital frame photographs or film scans
(docs/matching.md)."""

from __future__ import annotations

from types import SimpleNamespace

import click

from striptri.cli.base import main, reports_errors


@main.command()
@click.argument("project_dir", type=click.Path(file_okay=False))
@click.option("--images", "images_dir", default=None, type=click.Path(file_okay=False),
              help="Folder with one image per photo, named <photo_id>.jpg (.png, .tif).")
@click.option("--colmap-database", "database", default=None, type=click.Path(dir_okay=False),
              help="Instead of --images: a COLMAP database.db whose keypoints and verified matches are taken "
                   "(images named <photo_id>.<ext>, or photos.csv's image).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Project folder to write: the inputs, image_points.csv with the automatic tie points appended.")
@click.option("--scale", type=click.Choice(["1", "0.5", "0.25", "0.125"]), default="0.25", show_default=True,
              help="Pyramid level the features are found on (JPEGs are decoded at that size).")
@click.option("--features", "max_features", type=click.IntRange(min=100), default=8000, show_default=True,
              help="Features per image (the strongest).")
@click.option("--terrain-height", type=float, default=None,
              help="Terrain height (m) for the photos' footprints [the mean height of the control points, else 0].")
@click.option("--per-cell", type=click.IntRange(min=1), default=4, show_default=True,
              help="Tie points kept per cell of a 3 x 3 grid over each photo (the longest tracks first).")
@click.option("--sigma-px", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="Standard deviation of an automatic tie point's image coordinates (pixels) "
                   "[estimated from the verified matches' epipolar residuals].")
@click.option("--scan-pixel-size", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="Scanned film: the scans' pixel size in micrometres, to find the fiducial marks (needed unless "
                   "the project has fiducial_measurements.csv).")
@click.option("--fiducial-mark", default="cross", show_default=True,
              help="Scanned film: the mark to find, 'cross', 'dot', or an image of one mark cut from a scan "
                   "(its centre the mark's centre).")
@click.option("--mark-size", type=click.FloatRange(min=0.0, min_open=True), default=5.0, show_default=True,
              help="Scanned film: a synthetic cross's extent, tip to tip (mm on the film).")
@click.option("--mark-line", type=click.FloatRange(min=0.0, min_open=True), default=0.5, show_default=True,
              help="Scanned film: a synthetic mark's line width, or a dot's diameter (mm on the film).")
@click.option("--refine", is_flag=True, default=False,
              help="Refine the tie points by least-squares matching at full resolution (worth it with --scale "
                   "below 1); their sigma is then estimated from the refined points.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local processes for the features and the pairs [one per core]; 1: in this process.")
@click.option("--scheduler", default=None,
              help="Dask scheduler address (tcp://host:8786): find the features and match the pairs there (the "
                   "workers must see the images and OUT's folder at the same paths).")
@reports_errors
def match(project_dir, out_dir, **given):
    """Find tie points in the images of the photos of PROJECT_DIR and write a project to --out that
    `striptri adjust` takes (false matches are expected: adjust it with --blunders robust-snoop or snoop)."""
    from striptri.match.film_scans import FiducialOptions
    from striptri.match.pipeline import MatchOptions, run_match

    o = SimpleNamespace(**given)  # the command's options by name
    if (o.images_dir is None) == (o.database is None):
        raise click.UsageError("give --images (find the tie points) or --colmap-database (take COLMAP's matches)")
    options = MatchOptions(scale=float(o.scale), max_features=o.max_features, terrain_height=o.terrain_height,
                           per_cell=o.per_cell, sigma_px=o.sigma_px,
                           fiducials=FiducialOptions(o.scan_pixel_size, o.fiducial_mark, o.mark_size, o.mark_line),
                           refine=o.refine, workers=o.workers, scheduler=o.scheduler)
    p = run_match(project_dir, o.images_dir, out_dir, options, on_progress=lambda text: click.echo(text, err=True),
                  database=o.database)
    click.echo(f"{len(p.features)} photos, median {int(sorted(p.features)[len(p.features) // 2]) if p.features else 0} "
               f"features; {p.verified_pairs} of {p.pairs} pairs verified, {p.matches} matches; {p.tracks} tracks, "
               f"{p.kept_tracks} kept with {p.rays} rays, sigma {p.sigma_px:.3f} px -> {p.out}")
