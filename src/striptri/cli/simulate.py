"""``striptri simulate``: a synthetic pair, strip or block project (striptri.simulate)."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import click

from striptri.cli.base import _Finite, _Fraction, main, reports_errors

_DEFAULT_PHOTOS = {"pair": 2, "strip": 8, "block": 6}
_DEFAULT_STRIPS = {"pair": 1, "strip": 1, "block": 3}
_DEFAULT_LAYOUT = {"pair": "corners", "strip": "ends", "block": "perimeter"}
_LAYOUT_CHOICES = ["corners", "mixed", "schmid-minimal", "ends", "every-k", "perimeter", "sparse-height",
                   "schmid-fig8", "none"]
_DEFAULT_OVERLAP = 0.6


class _ImageSize(click.ParamType):
    """--image-size: N or WxH pixels, each 64 .. 20000 -> (W, H)."""

    name = "N|WxH"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).lower().split("x")
        try:
            sides = tuple(int(p) for p in parts)
        except ValueError:
            sides = ()
        if len(sides) not in (1, 2) or not all(64 <= s <= 20000 for s in sides):
            self.fail(f"{value!r} is not N or WxH with sides of 64 .. 20000 pixels", param, ctx)
        return sides * 2 if len(sides) == 1 else sides


@main.command()
@click.argument("kind", type=click.Choice(["pair", "strip", "block"]))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Project folder to write.")
@click.option("--photos", type=click.IntRange(min=2), default=None,
              help="Photos per strip [pair: 2, strip: 8, block: 6; schmid-fig8: 5].")
@click.option("--strips", type=click.IntRange(min=1), default=None, help="Parallel strips [pair, strip: 1; block: 3].")
@click.option("--overlap", type=_Fraction(), default=None, help="Forward overlap (0.6, 2/3 ...) [0.6; schmid-fig8: 2/3].")
@click.option("--sidelap", type=_Fraction(), default=0.3, show_default=True, help="Sidelap of neighbouring strips (0.2 .. 0.6).")
@click.option("--alternate/--same-direction", default=True, show_default=True,
              help="Fly every other strip of a block the other way, or all strips the same way.")
@click.option("--flying-height", type=_Finite(min=0, min_open=True), default=1500.0, show_default=True, help="Metres above mean terrain.")
@click.option("--heading", type=_Finite(), default=0.0, show_default=True, help="Flight direction of the first strip, deg from +X towards +Y.")
@click.option("--relief", type=_Finite(min=0), default=50.0, show_default=True, help="Terrain relief amplitude (m).")
@click.option("--attitude-std", type=_Finite(min=0), default=1.0, show_default=True, help="Std of true omega, phi, kappa about the ideal (deg).")
@click.option("--position-std", type=_Finite(min=0), default=5.0, show_default=True, help="Std of true centres about the ideal flight line (m).")
@click.option("--control", "layout", type=click.Choice(_LAYOUT_CHOICES), default=None,
              help="Control layout [pair: corners, strip: ends, block: perimeter].")
@click.option("--every-k", type=click.IntRange(min=1), default=2, show_default=True,
              help="every-k, perimeter, sparse-height layouts: control every k models.")
@click.option("--every-k-kind", type=click.Choice(["Z", "XY", "XYZ"]), default="Z", show_default=True,
              help="every-k layout: kind of the inner control points.")
@click.option("--extra-ties", type=click.IntRange(min=0), default=0, show_default=True, help="Random tie points per model.")
@click.option("--check-points", type=click.IntRange(min=0), default=0, show_default=True, help="Tie points made check points.")
@click.option("--single-photo-control", type=click.IntRange(0, 2), default=0, show_default=True,
              help="Full control points seen by one photo only (at the ends of the first strip).")
@click.option("--sigma-image", type=_Finite(min=0), default=0.005, show_default=True, help="Plate noise (plate units); 0 = noise-free.")
@click.option("--sigma-control", type=_Finite(min=0), default=0.0, show_default=True,
              help="Control noise and stated sigma (m); 0 = exact, held fixed.")
@click.option("--sigma-control-z", type=_Finite(min=0), default=None, help="Control noise in Z (m) [--sigma-control].")
@click.option("--approx-position-error", type=_Finite(min=0), default=10.0, show_default=True, help="Std of the approximate centres' errors (m).")
@click.option("--approx-angle-error", type=_Finite(min=0), default=1.0, show_default=True, help="Std of the approximate angles' errors (deg).")
@click.option("--gnss-sigma", type=_Finite(min=0, min_open=True), default=None, help="Observe the centres by GNSS with this sigma (m).")
@click.option("--gnss-lever", type=str, default=None, metavar="X,Y,Z",
              help="A GNSS block (docs/decisions.md): antenna lever arm in the camera frame (m); needs --gnss-sigma.")
@click.option("--gnss-shift-std", type=_Finite(min=0), default=0.3, show_default=True,
              help="GNSS block: std of the true per-strip shifts (m).")
@click.option("--gnss-drift-std", type=_Finite(min=0), default=0.002, show_default=True,
              help="GNSS block: std of the true per-strip drifts (m/s).")
@click.option("--gnss-interval", type=_Finite(min=0, min_open=True), default=3.0, show_default=True,
              help="GNSS block: seconds between exposures (photos.csv time).")
@click.option("--boresight", type=str, default="0,0,0", show_default=True, metavar="X,Y,Z",
              help="GNSS block: true boresight rotation vector (deg, camera frame).")
@click.option("--imu-sigma", type=_Finite(min=0, min_open=True), default=None,
              help="GNSS block: observe the angles by an IMU with this sigma (deg).")
@click.option("--lever-arm", "lever_mode", type=click.Choice(["held", "free", "observed"]), default="free",
              show_default=True, help="GNSS block: how the project states the lever arm.")
@click.option("--boresight-mode", type=click.Choice(["held", "free", "observed"]), default="held",
              show_default=True, help="GNSS block: how the project states the boresight.")
@click.option("--shift", "shift_mode", type=click.Choice(["none", "free", "observed"]), default="free",
              show_default=True, help="GNSS block: per-strip shift unknowns.")
@click.option("--drift", "drift_mode", type=click.Choice(["none", "free", "observed"]), default="free",
              show_default=True, help="GNSS block: per-strip drift unknowns.")
@click.option("--crs", default=None,
              help="Make the block on the ellipsoid and write it in this projected CRS (EPSG:326zz or WKT) with "
                   "project.toml [coordinates]; without it the block is in a local Cartesian frame.")
@click.option("--heights", type=click.Choice(["ellipsoidal", "orthometric"]), default="ellipsoidal", show_default=True,
              help="With --crs: the kind of the heights written.")
@click.option("--geoid-undulation", type=_Finite(min=-200, max=200), default=None,
              help="With --crs and --heights orthometric: the constant geoid undulation N (m), h = H + N.")
@click.option("--centre-lat", type=_Finite(min=-80, max=84), default=48.0, show_default=True,
              help="With --crs: latitude of the block's centre (deg).")
@click.option("--centre-lon", type=_Finite(min=-180, max=180), default=None,
              help="With --crs: longitude of the block's centre (deg) [3 deg east of the CRS's central meridian].")
@click.option("--naive", is_flag=True, default=False,
              help="With --crs: write the same map coordinates without project.toml [coordinates], so that "
                   "striptri adjusts them as Cartesian grid coordinates (the flat-Earth comparison).")
@click.option("--images", is_flag=True, default=False,
              help="Render every photo into OUT/images/ from a textured terrain (the extra images: OpenCV); the "
                   "camera becomes a digital frame camera and image_points.csv keeps only the control and check "
                   "points, leaving the tie points to striptri match.")
@click.option("--image-size", type=_ImageSize(), default="1000", show_default=True,
              help="With --images: the images' size in pixels, N (square) or WxH, e.g. 3000x2000 (the camera's "
                   "square format spans the shorter side; a longer width adds forward overlap).")
@click.option("--image-noise", type=_Finite(min=0), default=0.0, show_default=True,
              help="With --images: standard deviation of the noise added to the grey values (grey levels).")
@click.option("--jpeg-quality", type=click.IntRange(1, 100), default=None,
              help="With --images: write JPEG of this quality instead of PNG.")
@click.option("--film", is_flag=True, default=False,
              help="With strip --images: scanned film instead of a digital camera: the synthetic film strip "
                   "(153 mm camera, 60 % overlap, 4 control points at the start only) rendered as scans turned "
                   "by up to 2 degrees and shifted on the scanner, with fiducial marks; fiducial_measurements.csv "
                   "is left to striptri match (the true marks in truth/fiducial_marks.csv). Takes --photos, "
                   "--check-points, --sigma-image and the image options.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@reports_errors
def simulate(kind, out_dir, seed, **given):
    """Write a synthetic KIND project (pair, strip or block) to --out, with its truth in OUT/truth/.

    --control schmid-fig8 is Schmid's worked strip (BRL 961, Fig. 8): 5 photos, 2/3 overlap and his
    30 points; --photos and --overlap default to those values and may not differ from them."""
    from striptri import simulate as sim
    from striptri.io.output import check_output_location
    from striptri.io.project_writer import write_project

    check_output_location(out_dir)
    o = SimpleNamespace(**given)  # the command's options by name
    if o.film:
        return _simulate_film_images(kind, out_dir, seed, o)
    if o.images:
        return _simulate_images(kind, out_dir, seed, o)
    if (o.image_size, o.image_noise, o.jpeg_quality) != ((1000, 1000), 0.0, None):
        raise click.UsageError("--image-size, --image-noise and --jpeg-quality need --images")
    try:
        project, truth = sim.simulate_project(kind, simulate_options(kind, o), seed)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from exc
    if o.crs is not None:
        project, truth = _in_map_coordinates(project, truth, o)
        if o.naive:
            project = replace(project, settings=replace(project.settings, coordinates=None))
    elif o.heights != "ellipsoidal" or o.geoid_undulation is not None or o.centre_lon is not None or o.naive:
        raise click.UsageError("--heights, --geoid-undulation, --centre-lon and --naive need --crs")
    folder = write_project(out_dir, project, truth_tables=truth)
    click.echo(f"wrote {folder}: {len(project.photos)} photos, {len(project.points)} points, "
               f"{len(project.image_points)} plate measurements")


def _simulate_images(kind: str, out_dir, seed: int, o: SimpleNamespace) -> None:
    """simulate --images: the project of a digital frame camera, and its photos rendered
    (simulate.render) into OUT/images/, written whole or not at all."""
    from striptri import simulate as sim
    from striptri.io.project_writer import project_files
    from striptri.match.features import cv2_module
    from striptri.simulate import render

    if o.crs is not None:
        raise click.UsageError("--images renders the photos in the local frame: leave out --crs")
    cv2_module()  # the extra images, or a clear message before anything is computed
    try:
        options = simulate_options(kind, o)
        image_options = render.ImageOptions(o.image_size[0], o.image_noise, o.jpeg_quality, o.image_size[1])
        project, tables, truth = sim.simulate_with_truth(kind, options, seed)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from exc
    camera_format = options.design.camera.format
    project = render.digital_project(project, camera_format, image_options)
    folder = _write_rendered(out_dir, project_files(project), tables,
                             render.render_images(truth, camera_format, image_options, sim.images_rng(seed)),
                             len(project.photos))
    click.echo(f"wrote {folder}: {len(project.photos)} photos rendered ({o.image_size[0]} x {o.image_size[1]} px), "
               f"{len(project.points)} points, {len(project.image_points)} plate measurements of control "
               f"and check points")


def _write_rendered(out_dir, files: dict, tables: dict, images, n: int):
    """OUT: the project's files, its truth tables in truth/ and the rendered images (name, bytes)
    staged into images/ one by one as they come, all or nothing (io.output.OutputReservation)."""
    from striptri.io.csvtable import format_csv
    from striptri.io.output import OutputReservation

    files = {**files, **{f"truth/{name}": format_csv(columns) for name, columns in tables.items()}}
    with OutputReservation(out_dir) as reservation:
        for k, (name, data) in enumerate(images):
            reservation.stage({f"images/{name}": data})
            click.echo(f"rendered {k + 1} of {n}: images/{name}", err=True)
        return reservation.commit(files)


FILM_OPTIONS = {"film", "images", "photos", "check_points", "sigma_image", "image_size", "image_noise", "jpeg_quality"}


def _simulate_film_images(kind: str, out_dir, seed: int, o: SimpleNamespace) -> None:
    """simulate strip --film --images: the rendered film strip (simulate.film_render), the project
    of its scans without fiducial measurements, written whole or not at all."""
    from click.core import ParameterSource

    from striptri.match.features import cv2_module
    from striptri.simulate import film, film_render, images_rng
    from striptri.simulate.render import ImageOptions

    ctx = click.get_current_context()
    others = sorted(name for name in ctx.params if name not in FILM_OPTIONS | {"kind", "out_dir", "seed"}
                    and ctx.get_parameter_source(name) is not ParameterSource.DEFAULT)
    if kind != "strip" or not o.images:
        raise click.UsageError("--film renders a strip of film scans: striptri simulate strip --film --images ...")
    if others:
        raise click.UsageError("--film makes the synthetic film strip of striptri.simulate.film; it takes --photos, "
                               "--check-points, --sigma-image and the image options, not "
                               + ", ".join("--" + n.replace("_", "-") for n in others))
    if o.image_size[0] != o.image_size[1]:
        raise click.UsageError("--film renders square scans: give --image-size N")
    cv2_module()  # the extra images, or a clear message before anything is computed
    image = ImageOptions(o.image_size[0], o.image_noise, o.jpeg_quality)
    options = film_render.film_scan_options(o.photos or 8, o.image_size[0], o.sigma_image, o.check_points)
    lens = film.FilmLens()
    files, tables, truth, params = film.film_files_and_truth(options, lens, seed, rendered=True)
    folder = _write_rendered(out_dir, files, tables,
                             film_render.render_film_images(truth, params, lens, options, image, images_rng(seed)),
                             len(params))
    click.echo(f"wrote {folder}: {len(params)} film scans rendered ({o.image_size[0]} x {o.image_size[0]} px, "
               f"{1000 * options.pixel_mm:.0f} um), without fiducial measurements (striptri match "
               f"--scan-pixel-size {1000 * options.pixel_mm:g} finds them)")


def simulate_options(kind: str, o: SimpleNamespace):
    """The options of ``striptri simulate`` (by name, in ``o``) -> simulate.SimulateOptions (the
    design of the flight, terrain, points and control, the noise, and GNSS when --gnss-lever is
    given). ValueError for a combination that cannot be simulated."""
    from striptri import simulate as sim

    layout = o.layout or _DEFAULT_LAYOUT[kind]
    photos, overlap = o.photos, o.overlap
    if layout == sim.SCHMID_FIG8:
        photos, overlap = 5 if photos is None else photos, 2 / 3 if overlap is None else overlap
    design = sim.SyntheticDesign(
        flight=sim.FlightDesign(
            n_photos=_DEFAULT_PHOTOS[kind] if photos is None else photos,
            overlap=_DEFAULT_OVERLAP if overlap is None else overlap,
            n_strips=_DEFAULT_STRIPS[kind] if o.strips is None else o.strips, sidelap=o.sidelap,
            alternate=o.alternate, flying_height=o.flying_height, heading_deg=o.heading,
            attitude_std_deg=(o.attitude_std,) * 3, position_std_m=(o.position_std,) * 3,
        ),
        terrain=sim.TerrainDesign(relief=o.relief),
        points=sim.PointDesign(extra_ties_per_model=o.extra_ties),
        control=sim.ControlDesign(
            layout=layout, every_k=o.every_k, every_k_kind=o.every_k_kind,
            n_check=o.check_points, n_single_photo=o.single_photo_control,
        ),
    )
    noise = sim.NoiseOptions(
        sigma_image=o.sigma_image, sigma_control_xy=o.sigma_control,
        sigma_control_z=o.sigma_control if o.sigma_control_z is None else o.sigma_control_z,
        approx_position_error=o.approx_position_error, approx_angle_error=o.approx_angle_error,
        sigma_gnss=o.gnss_sigma,
    )
    gnss = None
    if o.gnss_lever is not None:
        if o.gnss_sigma is None:
            raise ValueError("--gnss-lever makes a GNSS block: give --gnss-sigma too")
        gnss = sim.GnssOptions(lever_arm=_triple(o.gnss_lever, "--gnss-lever"), shift_std=o.gnss_shift_std,
                               drift_std=o.gnss_drift_std, sigma_gnss=o.gnss_sigma, interval=o.gnss_interval,
                               boresight=_triple(o.boresight, "--boresight"), sigma_imu=o.imu_sigma,
                               lever_mode=o.lever_mode, boresight_mode=o.boresight_mode, shift_mode=o.shift_mode,
                               drift_mode=o.drift_mode)
    return sim.SimulateOptions(design, noise, gnss)


def _triple(text: str, option: str) -> tuple:
    """"x,y,z" -> three finite floats (ValueError naming the option)."""
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{option}: expected three numbers x,y,z, got {text!r}")
    return values


def _in_map_coordinates(project, truth, o: SimpleNamespace):
    """simulate --crs: the project and truth on the ellipsoid, in the CRS (simulate.map_coordinates);
    o: the command's options (crs, heights, geoid_undulation, centre_lat, centre_lon)."""
    from striptri.model import CoordinateSettings
    from striptri.simulate.map_coordinates import central_meridian, to_map_coordinates

    crs, heights, geoid_undulation, centre_lon = o.crs, o.heights, o.geoid_undulation, o.centre_lon
    if (heights == "orthometric") != (geoid_undulation is not None):
        raise click.UsageError("--heights orthometric needs --geoid-undulation, and --geoid-undulation needs "
                               "--heights orthometric")
    try:
        if centre_lon is None:
            meridian = central_meridian(crs)
            if meridian is None:
                raise ValueError(f"{crs!r} has no central meridian: give --centre-lon")
            centre_lon = meridian + 3.0
        coordinates = CoordinateSettings(crs=crs, heights=heights, geoid_undulation=geoid_undulation)
        return to_map_coordinates(project, truth, coordinates, o.centre_lat, centre_lon)
    except ValueError as exc:
        raise click.UsageError(f"--crs: {exc}") from exc


# --------------------------------------------------------------------------- striptri adjust
# (DESIGN section 10: `striptri adjust DIR --out OUT ...`; decorate it with @reports_errors too.)
