"""The ``striptri`` command (DESIGN section 10). Thin: parse options, call one pipeline function,
write its result. Errors reach the user through :func:`reports_errors`:

* :class:`striptri.errors.InputError` -> ``striptri: error: <message>`` on stderr, exit status 2;
* :class:`striptri.errors.NumericalFailure` -> the same message form, exit status 1.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
import os
import signal
import sys

import click

from striptri import __version__
from striptri.solvers import threads
from striptri.core.options import DATUMS, METHODS
from striptri.errors import InputError, Interrupted, NumericalFailure
from striptri.io.output import committed_outputs
from striptri.solvers import SOLVERS

EXIT_INPUT, EXIT_NUMERICAL = 2, 1
TERMINATION_SIGNALS = (signal.SIGTERM, signal.SIGHUP)  # raised as errors.Interrupted; SIGINT: KeyboardInterrupt


def reports_errors(command):
    """Decorate a command so that every way it can end is one message and an exit status, never a
    traceback (README "Safety"):

    * InputError (bad input, an unusable output location) -> exit status 2;
    * NumericalFailure (a datum defect, divergence, no convergence) -> exit status 1;
    * MemoryError -> exit status 1, saying so;
    * SIGINT, SIGTERM, SIGHUP -> the output reservation cleans up, then exit 128 + the signal's
      number, as a shell reports a killed program (also when compiled code that called back into
      Python turned the interruption into an error of its own);
    * anything else is a defect of striptri: one line naming it, exit status 1 (the traceback only
      with STRIPTRI_DEBUG=1).
    """

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        previous = _raise_on_signals()
        try:
            with threads.single_threaded():  # BLAS threads set here, not by the environment
                return command(*args, **kwargs)
        except InputError as exc:
            _fail(exc, EXIT_INPUT)
        except NumericalFailure as exc:
            reason = "" if exc.reason == "failed" else f"\n(termination: {exc.reason}; nothing was written)"
            _fail(f"{exc}{reason}", EXIT_NUMERICAL)
        except MemoryError:
            _fail("not enough memory for this project on this machine (the arrays of the adjustment did not fit); "
                  "nothing was written", EXIT_NUMERICAL)
        except KeyboardInterrupt:
            _interrupted(signal.SIGINT)
        except Interrupted as exc:
            _interrupted(exc.signum)
        except BrokenPipeError:
            _quiet_broken_pipe()
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise  # click's own usage errors (exit status 2) and exits
        except Exception as exc:  # noqa: BLE001 - the last line of defence: one message, no traceback
            signum = _interrupted_inside_an_extension()
            if signum is not None:  # the interruption, turned into another error by compiled code
                _interrupted(signum)
            if os.environ.get("STRIPTRI_DEBUG"):
                raise
            _fail(f"internal error ({type(exc).__name__}: {exc}). This is a defect of striptri; please report it "
                  "with the command that caused it (STRIPTRI_DEBUG=1 shows the traceback).", EXIT_NUMERICAL)
        finally:
            _restore_signals(previous)

    return wrapper


_RECEIVED: list[int] = []  # the termination signals received while the command runs


def _interrupted(signum: int):
    """Exit 128 + signum with a message that says what state the output is in."""
    name = signal.Signals(signum).name
    written = committed_outputs()
    if written:
        _fail(f"interrupted ({name}) after the output was complete: {written[-1]} holds this run's whole "
              "result", 128 + signum)
    _fail(f"interrupted ({name}); no output was left half-written", 128 + signum)


def _raise_interrupted(signum, frame):
    _RECEIVED.append(signum)
    raise Interrupted(signum)


def _raise_keyboard_interrupt(signum, frame):
    _RECEIVED.append(signum)
    raise KeyboardInterrupt


def _interrupted_inside_an_extension() -> int | None:
    """The signal, when one was received during the command: a compiled extension that calls back
    into Python (matplotlib's Agg renderer) may turn the Interrupted or KeyboardInterrupt its
    callback raised into an error of its own ("ValueError: Invalid bounding box"); the run was
    interrupted all the same."""
    return _RECEIVED[-1] if _RECEIVED else None


def _raise_on_signals() -> dict:
    """Turn SIGTERM and SIGHUP into Interrupted, and SIGINT into KeyboardInterrupt (even when the
    shell started striptri with SIGINT ignored), while the command runs (main thread only).

    A Python signal handler runs at the next bytecode boundary, which may lie in a finaliser or a
    weakref callback (a garbage collection); Python ignores an exception raised there, prints
    "Exception ignored in ..." with a traceback and goes on. :func:`_redeliver_swallowed_signals`
    (sys.unraisablehook while the command runs) catches exactly that case, prints nothing and sends
    the signal again a moment later, when the main thread is back in ordinary code."""
    previous = {}
    _RECEIVED.clear()
    handlers = {**{sig: _raise_interrupted for sig in TERMINATION_SIGNALS}, signal.SIGINT: _raise_keyboard_interrupt}
    for sig, handler in handlers.items():
        try:
            previous[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread: leave the signals as they are
            break
    if previous:
        previous["unraisablehook"] = sys.unraisablehook
        sys.unraisablehook = functools.partial(_redeliver_swallowed_signals, previous["unraisablehook"])
    return previous


REDELIVERY_DELAY_S = 0.01


def _redeliver_swallowed_signals(hook, unraisable) -> None:
    """sys.unraisablehook: an Interrupted or KeyboardInterrupt that Python had to ignore (raised by
    a signal handler inside a finaliser or weakref callback) is sent again as its signal from a
    timer thread, so that it interrupts the command where it can; anything else goes to ``hook``."""
    exc = unraisable.exc_value
    if isinstance(exc, Interrupted):
        signum = exc.signum
    elif isinstance(exc, KeyboardInterrupt):
        signum = signal.SIGINT
    else:
        hook(unraisable)
        return
    import threading

    threading.Timer(REDELIVERY_DELAY_S, os.kill, (os.getpid(), signum)).start()


def _restore_signals(previous: dict) -> None:
    for sig, handler in previous.items():
        if sig == "unraisablehook":
            sys.unraisablehook = handler
        else:
            signal.signal(sig, handler)


def _quiet_broken_pipe():
    """stdout was closed by the reader (``striptri ... | head``): stop without a message."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    sys.exit(EXIT_NUMERICAL)


def _warn(message: str) -> None:
    click.echo(f"striptri: warning: {message}", err=True)


def _fail(exc, status: int):
    click.echo(f"striptri: error: {exc}", err=True)
    sys.exit(status)


@click.group()
@click.version_option(__version__, prog_name="striptri")
def main():
    """striptri: analytical aerial triangulation after H. H. Schmid (BRL Report 961, 1955)."""


# --------------------------------------------------------------------------- striptri simulate

_DEFAULT_PHOTOS = {"pair": 2, "strip": 8, "block": 6}
_DEFAULT_STRIPS = {"pair": 1, "strip": 1, "block": 3}
_DEFAULT_LAYOUT = {"pair": "corners", "strip": "ends", "block": "perimeter"}
_LAYOUT_CHOICES = ["corners", "mixed", "schmid-minimal", "ends", "every-k", "perimeter", "sparse-height",
                   "schmid-fig8", "none"]
_DEFAULT_OVERLAP = 0.6


class _Finite(click.FloatRange):
    """A finite number (nan and inf are refused) within the given range."""

    name = "float"

    def _describe_range(self) -> str:
        """The range for --help ("x>=0"); nothing without bounds (click would print "x<=None")."""
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


class _Fraction(click.ParamType):
    """A number given as a decimal (0.6) or as a fraction (2/3)."""

    name = "fraction"

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            return value
        try:
            num, _, den = str(value).partition("/")
            number = float(num) / float(den) if den else float(num)
        except (ValueError, ZeroDivisionError):
            self.fail(f"{value!r} is not a number or a fraction such as 2/3", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


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
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@reports_errors
def simulate(kind, out_dir, photos, strips, overlap, sidelap, alternate, flying_height, heading, relief, attitude_std,
             position_std, layout, every_k, every_k_kind, extra_ties, check_points, single_photo_control, sigma_image,
             sigma_control, sigma_control_z, approx_position_error, approx_angle_error, gnss_sigma, gnss_lever,
             gnss_shift_std, gnss_drift_std, gnss_interval, boresight, imu_sigma, lever_mode, boresight_mode,
             shift_mode, drift_mode, crs, heights, geoid_undulation, centre_lat, centre_lon, naive, seed):
    """Write a synthetic KIND project (pair, strip or block) to --out, with its truth in OUT/truth/.

    --control schmid-fig8 is Schmid's worked strip (BRL 961, Fig. 8): 5 photos, 2/3 overlap and his
    30 points; --photos and --overlap default to those values and may not differ from them."""
    from striptri import simulate as sim
    from striptri.io.output import check_output_location
    from striptri.io.project_writer import write_project

    check_output_location(out_dir)
    layout = layout or _DEFAULT_LAYOUT[kind]
    if layout == sim.SCHMID_FIG8:
        photos, overlap = 5 if photos is None else photos, 2 / 3 if overlap is None else overlap
    try:
        design = sim.SyntheticDesign(
            flight=sim.FlightDesign(
                n_photos=_DEFAULT_PHOTOS[kind] if photos is None else photos,
                overlap=_DEFAULT_OVERLAP if overlap is None else overlap,
                n_strips=_DEFAULT_STRIPS[kind] if strips is None else strips, sidelap=sidelap, alternate=alternate,
                flying_height=flying_height, heading_deg=heading, attitude_std_deg=(attitude_std,) * 3,
                position_std_m=(position_std,) * 3,
            ),
            terrain=sim.TerrainDesign(relief=relief),
            points=sim.PointDesign(extra_ties_per_model=extra_ties),
            control=sim.ControlDesign(
                layout=layout, every_k=every_k, every_k_kind=every_k_kind,
                n_check=check_points, n_single_photo=single_photo_control,
            ),
        )
        noise = sim.NoiseOptions(
            sigma_image=sigma_image, sigma_control_xy=sigma_control,
            sigma_control_z=sigma_control if sigma_control_z is None else sigma_control_z,
            approx_position_error=approx_position_error, approx_angle_error=approx_angle_error, sigma_gnss=gnss_sigma,
        )
        gnss = None
        if gnss_lever is not None:
            if gnss_sigma is None:
                raise ValueError("--gnss-lever makes a GNSS block: give --gnss-sigma too")
            gnss = sim.GnssOptions(lever_arm=_triple(gnss_lever, "--gnss-lever"), shift_std=gnss_shift_std,
                                   drift_std=gnss_drift_std, sigma_gnss=gnss_sigma, interval=gnss_interval,
                                   boresight=_triple(boresight, "--boresight"), sigma_imu=imu_sigma,
                                   lever_mode=lever_mode, boresight_mode=boresight_mode, shift_mode=shift_mode,
                                   drift_mode=drift_mode)
        project, truth = sim.simulate_project(kind, sim.SimulateOptions(design, noise, gnss), seed)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from exc
    if crs is not None:
        project, truth = _in_map_coordinates(project, truth, crs, heights, geoid_undulation, centre_lat, centre_lon)
        if naive:
            project = replace(project, settings=replace(project.settings, coordinates=None))
    elif heights != "ellipsoidal" or geoid_undulation is not None or centre_lon is not None or naive:
        raise click.UsageError("--heights, --geoid-undulation, --centre-lon and --naive need --crs")
    folder = write_project(out_dir, project, truth_tables=truth)
    click.echo(f"wrote {folder}: {len(project.photos)} photos, {len(project.points)} points, "
               f"{len(project.image_points)} plate measurements")


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


def _in_map_coordinates(project, truth, crs, heights, geoid_undulation, centre_lat, centre_lon):
    """simulate --crs: the project and truth on the ellipsoid, in the CRS (simulate.map_coordinates)."""
    from striptri.model import CoordinateSettings
    from striptri.simulate.map_coordinates import central_meridian, to_map_coordinates

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
        return to_map_coordinates(project, truth, coordinates, centre_lat, centre_lon)
    except ValueError as exc:
        raise click.UsageError(f"--crs: {exc}") from exc


# --------------------------------------------------------------------------- striptri adjust
# (DESIGN section 10: `striptri adjust DIR --out OUT ...`; decorate it with @reports_errors too.)


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
@click.option("--blunders", type=click.Choice(["off", "snoop", "snoop-classic", "robust"]), default="off",
              show_default=True,
              help="Gross errors: off (flag |w| > 3.29 only), snoop (Baarda data snooping: inseparable groups rejected "
                   "together, rejections re-tested), snoop-classic (only rows of equal |w| "
                   "rejected together, no re-test) "
                   "or robust (re-weighting, then least squares of the survivors).")
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
@reports_errors
def adjust(project_dir, out_dir, method, solver, max_iterations, scale_form, datum, datum_points, point_precision,
           blunders,
           covariance_groups, covariance_datum, covariance_rigid,
           procedure, direction, polynomial_degree, init, earth_curvature, refraction, keep_unconverged, quiet):
    """Adjust the project in PROJECT_DIR and write the results to --out.

    The output folder is checked before anything is computed and written only when the adjustment
    succeeds; an adjustment that does not converge is a failure (exit status 1) unless
    --keep-unconverged."""
    import contextlib

    from striptri import progress
    from striptri.pipeline import run_adjust

    covariance = _covariance_request(covariance_groups, covariance_datum, covariance_rigid)
    with contextlib.nullcontext() if quiet else progress.reporting(progress.StderrProgress()):
        products = run_adjust(project_dir, out_dir, point_precision=point_precision, blunders=blunders,
                              covariance=covariance, keep_unconverged=keep_unconverged, on_warning=_warn,
                              corrections={"earth_curvature": earth_curvature, "refraction": refraction},
                              method=method, solver=solver, init=init, direction=direction,
                              procedure=None if procedure is None else int(procedure),
                              polynomial_degree=polynomial_degree,
                              max_iterations=max_iterations, scale_form=scale_form, datum=datum,
                              datum_points=_datum_points(datum_points))
    s = products.summary
    b = s["blunders"]
    if b["method"] != "off" or b["suspect"]:
        click.echo(f"gross errors ({b['method']}): {b['rejected']} measurements rejected, "
                   f"{b.get('inseparable', 0)} in inseparable groups, {b['suspect']} suspect, "
                   f"{b['dropped']} dropped, in {b['adjustments']} adjustments")
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
@reports_errors
def plan(project_dir, out_dir, method, solver, drop_control, add_control, sigma_image, keep_every, overlap, von_gruber,
         plate_format, terrain_height, rank_control):
    """Pre-analysis of the planned block in PROJECT_DIR: a-priori precision (sigma0 = 1), internal and
    external reliability, what-ifs and the control ranking, from the design alone (docs/plan.md)."""
    from striptri.plan.pipeline import run_plan

    products = run_plan(project_dir, out_dir, drop_control=drop_control, add_control=add_control,
                        sigma_image=sigma_image, keep_every=keep_every, rank_control=rank_control, on_warning=_warn,
                        von_gruber=von_gruber, plate_format=plate_format, terrain_height=terrain_height,
                        overlap=overlap, method=method, solver=solver)
    p = products.summary["plan"]["precision"]
    click.echo(f"plan: {products.summary['n_photos']} photos, {products.summary['n_points']} points; "
               f"worst sigma_XY {p['worst_sigma_XY']:.4g} m, worst sigma_Z {p['worst_sigma_Z']:.4g} m "
               f"(a priori); {len(products.whatifs) - 1} what-ifs -> {out_dir}")


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


class _ManyValues(click.Option):
    """An option with multiple=True that also takes several values after one flag:
    ``--photos 4 8 16`` as well as ``--photos 4 --photos 8``. The values run to the next option."""

    def add_to_parser(self, parser, ctx):
        result = super().add_to_parser(parser, ctx)
        for name in self.opts:
            option = parser._long_opt.get(name) or parser._short_opt.get(name)
            if option is not None:
                previous = option.process

                def process(value, state, previous=previous, prefixes=option.prefixes):
                    previous(value, state)
                    while state.rargs and not any(state.rargs[0].startswith(p) for p in prefixes):
                        previous(state.rargs.pop(0), state)

                option.process = process
        return result


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
def compare(out_dir, methods, photos, layouts, sigma_images, trials, seed, every_k, workers, scheduler, project_dir):
    """Method-comparison study: the sequential, conditions and bundle methods on simulated strips or
    your own block, Monte Carlo trials (docs/study.md), written to --out."""
    from striptri.study import StudyOptions, run_compare
    from striptri.study.progress import StderrProgress

    given = {"methods": methods, "photos": photos, "layouts": layouts, "sigma_images": sigma_images}
    if project_dir is not None:
        from striptri.study.project_pipeline import run_compare_project

        if photos or layouts or every_k != 2:
            raise InputError("command line", None, "--photos, --layouts and --every-k describe invented strips; "
                             "with --project the strips and control are the project's")
        progress = StderrProgress()
        try:
            result = run_compare_project(out_dir, project_dir, methods=tuple(methods) or None, trials=trials,
                                         sigma_images=tuple(sigma_images), seed=seed, workers=workers,
                                         scheduler=scheduler, progress=progress)
        finally:
            progress.close()
        failed = f", {result.n_failed} failed" if result.n_failed else ""
        click.echo(f"{len(result.rows)} adjustments{failed} -> {result.out_dir}")
        return
    options = StudyOptions(trials=trials, seed=seed, every_k=every_k,
                           **{k: tuple(v) for k, v in given.items() if v})
    progress = StderrProgress()
    try:
        result = run_compare(out_dir, options, workers=workers, scheduler=scheduler, progress=progress)
    finally:
        progress.close()
    failed = f", {result.n_failed} failed" if result.n_failed else ""
    click.echo(f"{len(result.rows)} adjustments{failed} -> {result.out_dir}")


if __name__ == "__main__":
    main()


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
