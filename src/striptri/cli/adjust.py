"""``striptri adjust``: adjust a project and write its output folder (pipeline.run_adjust)."""

from __future__ import annotations

import click

from striptri.cli.base import _warn, main, reports_errors, threads_option
from striptri.core.options import DATUMS, METHODS
from striptri.errors import InputError
from striptri.solvers import SOLVERS


@main.command()
@click.argument("project_dir", type=click.Path(file_okay=False))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder to write.")
@click.option("--method", type=click.Choice(list(METHODS)), default=None,
              help="Adjustment method [project.toml or conditions].")
@click.option("--solver", type=click.Choice(list(SOLVERS)), default=None,
              help="Solver of the normal equations [project.toml or auto].")
@click.option("--max-iterations", type=click.IntRange(min=1), default=None, help="Iteration limit [30].")
@click.option("--scale-form", type=click.Choice(["3d", "xz"]), default=None,
              help="Scale-transfer condition: direction-free 3d (default) or Schmid's XZ form (94).")
@click.option("--datum", type=click.Choice(list(DATUMS)), default=None,
              help="Datum: from control (default; a defect is an error) or a free network by inner constraints "
                   "on the photos (inner) or on object points (inner-points).")
@click.option("--datum-points", default=None, metavar="POINTS",
              help="With --datum inner-points: the datum points (comma-separated ids, at least three) [project.toml "
                   "[datum] points, or every point of the adjustment].")
@click.option("--point-precision", type=click.Choice(["schmid90", "joint92"]), default="schmid90", show_default=True,
              help="Mean errors of the ground points: orientation part + measurement part (Schmid 90) "
                   "or the rigorous joint form (92).")
@click.option("--blunders", type=click.Choice(["off", "snoop", "snoop-classic", "robust", "robust-snoop"]), default="off",
              show_default=True,
              help="Gross errors: off (flag |w| > 3.29 only), snoop (Baarda data snooping: inseparable groups rejected "
                   "together, rejections re-tested), snoop-classic (only rows of equal |w| "
                   "rejected together, no re-test) "
                   "robust (re-weighting, then least squares of the survivors) or robust-snoop (re-weighting "
                   "finds the first rejections, then snooping from the survivors re-tests them: for automatic "
                   "tie points).")
@click.option("--covariance", "covariance_groups", default=None, metavar="GROUPS",
              help="Also write covariance.npz: the full covariance of these groups, comma-separated from photos, "
                   "camera, points (docs/file-formats.md); in the CRS's axes with [coordinates] crs.")
@click.option("--covariance-datum", default=None, metavar="POINTS",
              help="S-transform the covariance to the datum of these object points (comma-separated ids, at least "
                   "three): their inner constraints define it.")
@click.option("--covariance-rigid", is_flag=True, default=False,
              help="With --covariance-datum: a rigid motion (6 parameters; the scale stays the measurements') "
                   "instead of a similarity (7).")
@click.option("--procedure", type=click.Choice(["1", "2"]), default=None,
              help="Sequential method: Schut's procedure 1 (relative orientation, scale transfer) or 2 "
                   "(six elements by coplanarity and carried-over points) [1].")
@click.option("--direction", type=click.Choice(["forward", "backward"]), default=None,
              help="Sequential method: start from the first or the last photo [forward].")
@click.option("--polynomial-degree", type=click.IntRange(1, 3), default=None,
              help="Sequential method: polynomial strip correction after the similarity [none].")
@click.option("--init", type=click.Choice(["given", "sequential"]), default=None,
              help="Approximate values: as given, or from the sequential method (rough values suffice).")
@click.option("--earth-curvature/--no-earth-curvature", default=None,
              help="Correct the plate coordinates for the Earth's curvature (map coordinates only) "
                   "[project.toml [corrections] or off].")
@click.option("--refraction/--no-refraction", default=None,
              help="Correct the plate coordinates for atmospheric refraction [project.toml [corrections] or off].")
@click.option("--keep-unconverged", is_flag=True, default=False,
              help="Write the output of an adjustment that stopped without converging (converged: false in "
                   "summary.json, exit status 0) instead of failing with exit status 1.")
@click.option("--quiet", is_flag=True, default=False,
              help="No progress on stderr (shown otherwise once a run takes longer than 2 s: each iteration's "
                   "vTPv, largest correction and seconds, then the phases after the adjustment).")
@threads_option
@reports_errors
def adjust(project_dir, out_dir, quiet, **given):
    """Adjust the project in PROJECT_DIR and write the results to --out.

    The output folder is checked before anything is computed and written only when the adjustment
    succeeds; an adjustment that does not converge is a failure (exit status 1) unless
    --keep-unconverged."""
    import contextlib

    from striptri.report import drawing

    with drawing.early_worker(project_dir):  # before the pipeline's imports and the reading
        from striptri import progress
        from striptri.pipeline import run_adjust

        run = run_options(given)
        with contextlib.nullcontext() if quiet else progress.reporting(progress.StderrProgress()):
            products = run_adjust(project_dir, out_dir, run, on_warning=_warn)
    s = products.summary
    b = s["blunders"]
    if b["method"] != "off" or b["suspect"]:
        click.echo(f"gross errors ({b['method']}): {b['rejected']} measurements rejected, "
                   f"{b.get('inseparable', 0)} in inseparable groups, {b['suspect']} suspect, "
                   f"{b['dropped']} dropped, in {b['adjustments']} adjustments")
    auto = s.get("automatic_tie_points")
    if auto:
        rms = "n/a" if auto["rms_px"] is None else f"{auto['rms_px']:.3f} px"
        click.echo(f"automatic tie points: {auto['removed']} of {auto['rays']} rays removed as gross errors, "
                   f"{auto['points_left']} of {auto['points']} points left, image residual RMS {rms}")
    sigma0 = "n/a (no redundancy)" if s["sigma0"] is None else f"{s['sigma0']:.4f}"
    state = {"converged": "converged", "cost_flat": "converged (cost_flat: the sum of squares no longer decreased)"}.get(
        s["termination"], f"NOT converged ({s['termination']}; kept)")
    applied = s.get("plate_corrections")
    if applied:
        sizes = ", ".join(f"{name.replace('_', ' ')} up to {applied[name]['max']:.3g} {applied['plate_unit']} "
                          f"({applied[name]['direction']})" for name in ("earth_curvature", "refraction") if name in applied)
        click.echo(f"plate coordinates corrected: {sizes}")
    click.echo(f"{state} in {s['iterations']} iterations: sigma0 {sigma0}, redundancy {s['redundancy']}, "
               f"{s['n_photos']} photos, {s['n_points']} points -> {out_dir}")



# --------------------------------------------------------------------------- striptri plan
# (DESIGN section 10, issue 15: pre-analysis of a planned block; docs/plan.md)



def run_options(given: dict):
    """The options of ``striptri adjust`` (click's values by name) -> one core.runs.RunOptions;
    a bad combination of the covariance options is an InputError (exit status 2)."""
    from striptri.core.runs import RunOptions

    given = dict(given)
    covariance = _covariance_request(given.pop("covariance_groups"), given.pop("covariance_datum"),
                                     given.pop("covariance_rigid"))
    procedure, datum_points = given.pop("procedure"), _datum_points(given.pop("datum_points"))
    return RunOptions(**given, datum_points=datum_points, covariance=covariance,
                      procedure=None if procedure is None else int(procedure))


def _datum_points(text):
    """--datum-points P1,P2,... -> a tuple of ids (None when not given)."""
    if text is None:
        return None
    return tuple(p.strip() for p in text.split(",") if p.strip())


def _covariance_request(groups, datum, rigid):
    """--covariance, --covariance-datum, --covariance-rigid -> covariance_export.CovarianceRequest or
    None; a bad combination is an InputError (exit status 2)."""
    from striptri.precision.export import CovarianceRequest

    if groups is None:
        if datum is not None or rigid:
            raise InputError("command line", None, "--covariance-datum and --covariance-rigid need --covariance")
        return None

    def split(text):
        return tuple(t.strip() for t in text.split(",") if t.strip())
    try:
        return CovarianceRequest(split(groups), split(datum or ""), not rigid)
    except ValueError as exc:
        raise InputError("command line", None, str(exc)) from None
