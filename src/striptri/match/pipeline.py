"""``striptri match PROJECT --images DIR --out OUT``: automatic tie points for a block of digital
frame photographs (docs/matching.md).

Read the project (image_points.csv optional), find the features of each photo's image at ``scale``
(match.features), pair the photos (match.pairs: footprints at the terrain height from the
approximate orientations, else the strips), match and verify each pair (match.pair_matching), join
the matches into tracks (match.tracks), thin them (match.thinning) and write OUT: a complete project
folder, every input file as it was, and image_points.csv with the user's rows (``source`` manual)
followed by the automatic ones (``source`` auto). OUT is written whole or not at all.

Cameras are digital frame cameras (cameras.csv width_px, height_px, pixel_size), or the photos are
film scans (project.toml ``[film] image_points = "scan_px"``): then the fiducial marks are taken from
fiducial_measurements.csv or found in the scans (match.film_scans), each photo's fiducial
transformation carries the features to the plate (match.frames), and the automatic rows are written
in scan pixels like the user's.
"""

from __future__ import annotations

import csv
import io
import resource
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.csvtable import input_present, read_input_bytes
from ..io.output import OutputReservation, check_output_location
from ..io.project_reader import FILE_NAMES, parse_project, read_project
from ..model import FULL, HEIGHT, Project
from . import film_scans, unoriented
from ..parallel import map_unordered
from .frames import FiducialMeasurements, digital_frames, film_frames
from .stages import FeatureTask, find_features, match_pairs, pair_tasks
from .pair_matching import RANSAC_PX, sigma_from_epipolar
from .pairs import footprints, overlap_pairs, strip_pairs
from .ground_check import ground_consistent
from .thinning import thin_tracks
from .image_names import image_column
from .tracks import build_tracks, same_place, two_view_consistent

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
REPORT_NAME = "match_report.html"  # the matching report, in OUT beside the project files
FALLBACK_SIGMA_PX = 0.3  # an automatic tie point's sigma where the matches cannot tell (planar scenes only)


@dataclass(frozen=True)
class MatchOptions:
    """scale: the pyramid level the features are found on (0.25: a quarter of the width);
    max_features per image; terrain_height (m) for the footprints (None: the mean height of the
    control points, else 0); cells, per_cell: the thinning; sigma_px: the standard deviation of an
    automatic tie point's plate coordinates, in pixels (None: estimated from the verified matches'
    epipolar residuals, match.pair_matching.sigma_from_epipolar; FALLBACK_SIGMA_PX where every pair
    is of a planar scene); ground_tolerance: a track one of whose rays, with the approximate
    orientations, passes further from the track's intersection than this share of the height
    above the terrain is a false one (0.10: approximations within about 2 degrees, 3 standard
    deviations; match.ground_check); fiducials: finding the marks of film scans (match.film_scans);
    workers, scheduler: where the features and the pairs are worked on (striptri.parallel: local
    processes, one per core by default, or a Dask cluster)."""

    scale: float = 0.25
    max_features: int = 8000
    terrain_height: float | None = None
    cells: int = 3
    per_cell: int = 4
    sigma_px: float | None = None
    ground_tolerance: float = 0.10
    fiducials: film_scans.FiducialOptions = film_scans.FiducialOptions()
    refine: bool = False  # refine the tie points by least-squares matching at full resolution (match.lsm)
    workers: int | None = None  # local processes for features and pairs (None: one per core; 1: this one)
    scheduler: object = None  # a Dask scheduler address or Client: features and pairs on that cluster


@dataclass
class MatchProducts:
    """What a run found: per photo the number of features; the candidate pairs and the verified
    matches of each; the tracks before and after thinning and the rays written."""

    features: list = field(default_factory=list)
    pairs: int = 0
    verified_pairs: int = 0
    matches: int = 0
    tracks: int = 0
    split: int = 0
    inconsistent: int = 0
    kept_tracks: int = 0
    rays: int = 0
    sigma_px: float = float("nan")
    sigma_estimated: bool = False
    sigma_how: str = ""
    out: Path | None = None
    # for the matching report (match.report)
    photo_ids: list = field(default_factory=list)
    centres: np.ndarray | None = None  # (n, 2) the approximate centres X0, Y0
    pair_list: np.ndarray | None = None  # (pairs, 2) the candidate pairs
    pair_matches: np.ndarray | None = None  # (pairs,) verified matches of each (0: not verified)
    track_lengths: np.ndarray | None = None  # (tracks,) rays of every track, before the ground check
    kept_lengths: np.ndarray | None = None  # (kept,) rays of the tracks written
    ray_photo: np.ndarray | None = None  # (rays,) the photo of each ray written
    ray_plate: np.ndarray | None = None  # (rays, 2) its plate coordinates
    half_format: np.ndarray | None = None  # (n, 2) each photo's half width and height (plate units)
    seconds: dict = field(default_factory=dict)  # stage -> seconds
    peak_mb: dict = field(default_factory=dict)  # stage -> this process's peak memory at its end (MB)
    chips: int = 0  # image chips of control points written (match.chips)
    refined: int = -1  # rays moved by least-squares matching (-1: not asked for)
    refinable: int = 0  # rays it tried (all but each track's reference ray)
    refine_shift: float = float("nan")  # their median shift (px)
    fiducials: list | None = None  # film: per photo (id, marks, of, largest residual px, sigma0, not found)
    fiducials_found: bool = False  # film: the marks were found in the scans (not given)
    strips: list | None = None  # photos without orientations: how each strip was placed (sequential.block)


def run_match(project_dir, images_dir, out_dir, options: MatchOptions = MatchOptions(), on_progress=None,
              database=None) -> MatchProducts:
    """Match the photos of ``project_dir`` (module doc). InputError for bad input (exit status 2).
    database: instead of images_dir, a COLMAP database whose keypoints and verified matches
    (two_view_geometries) are taken as they are (match.colmap_database)."""
    project_dir = Path(project_dir)
    source = Path(database if database is not None else images_dir)
    inputs = [*_input_paths(project_dir), source]
    check_output_location(out_dir, inputs)
    film = film_scans.film_setting(project_dir)
    scans = None
    stand_in = _placeholder_photos(project_dir)  # photos without orientations (match.unoriented)
    if film is None:
        project = read_project(project_dir, plate_measurements_optional=True) if stand_in is None else \
            unoriented.read_with(project_dir, stand_in)
        cams = project.cameras
        if cams.size_px is None or not np.isfinite(cams.size_px[project.photos.camera_index]).all():
            raise InputError(project_dir / "cameras.csv", None, "automatic tie points need digital frame cameras "
                             "(give width_px, height_px and pixel_size of every camera the photos use) or scanned "
                             "film (project.toml [film] image_points = \"scan_px\", with fiducials.csv)")
    else:
        if database is not None:
            raise InputError(source, None, "a project of scanned film takes its tie points from the scans: give "
                                           "--images (the fiducial marks are found there too)")
        project, files_read = film_scans.read_film_project(project_dir, stand_in)
        scans = _Scans(film, film_scans.calibrated_fiducials(project_dir, files_read, project),
                       options.fiducials)
        if film_scans.MEASUREMENTS in files_read:
            scans.given = film_scans.given_measurements(project_dir, files_read, project, scans.fiducials, film)
        elif options.fiducials.pixel_size_um is None:
            raise InputError(project_dir / film_scans.MEASUREMENTS, None,
                             "not found, so the fiducial marks are to be found in the scans: give "
                             "--scan-pixel-size (the scans' pixel size in micrometres, e.g. 15)")
    if stand_in is not None:
        unoriented.check_control(project, project_dir)
    say = on_progress or (lambda text: None)
    products = MatchProducts(photo_ids=list(project.photos.ids), centres=project.photos.xyz0[:, :2].copy())
    clock = _Clock(products.seconds, say, products.peak_mb)
    height = _terrain_height(project, options)
    paths = None
    if database is None:
        paths = _image_paths(project, source, project_dir)
        out_parent = Path(out_dir).resolve().parent
        while not out_parent.is_dir():  # OUT's folders are made when it is written
            out_parent = out_parent.parent
        with tempfile.TemporaryDirectory(prefix=".striptri-match-", dir=out_parent) as work:
            xy, a, b, score, epipolar, frames = _matched_images(project, paths, options, products, clock,
                                                                height if stand_in is None else None, scans, work)
    else:
        from .colmap_database import matches_for_project

        found = matches_for_project(source, project, project_dir)
        xy, a, b, score, epipolar = found.xy, found.a, found.b, found.score, []
        frames = digital_frames(project)
        products.features = [len(x) for x in xy]
        products.pairs = products.verified_pairs = len(found.pairs)
        products.pair_list, products.pair_matches = found.pairs, found.pair_matches
        clock.lap("reading the database")
        say(f"database: {len(found.pairs)} verified pairs, {len(a)} matches")
    products.sigma_px, how = float(options.sigma_px or "nan"), "given"
    if options.sigma_px is None:
        products.sigma_px, how = sigma_from_epipolar(np.concatenate(epipolar) if epipolar else np.zeros(0)), \
            "estimated from the epipolar residuals"
        if not np.isfinite(products.sigma_px):
            products.sigma_px, how = FALLBACK_SIGMA_PX, ("the default: no pair but planar ones to estimate it from"
                                                         if database is None else "the default for a COLMAP database")
    products.sigma_estimated, products.sigma_how = how.startswith("estimated"), how
    say(f"pairs: {products.verified_pairs} of {products.pairs} verified; image coordinates to "
        f"{products.sigma_px:.3f} px ({how})")
    photo_of = np.repeat(np.arange(len(xy)), [len(x) for x in xy])
    xy_px = np.concatenate(xy) if xy else np.zeros((0, 2))
    products.matches = len(a)
    twin = same_place(photo_of, xy_px)  # one feature per place: SIFT's orientations of one keypoint
    tracks = build_tracks(photo_of, twin[a], twin[b], score)
    products.tracks, products.split = tracks.n_tracks, tracks.split
    rows = np.flatnonzero(tracks.track >= 0)
    products.track_lengths = np.bincount(tracks.track[rows], minlength=tracks.n_tracks)
    plate = frames.plate(photo_of, xy_px) if len(xy_px) else np.zeros((0, 2))
    products.half_format = frames.half
    if stand_in is None:  # the tracks checked with the approximate orientations
        consistent = ground_consistent(project, tracks.track[rows], photo_of[rows], plate[rows], height,
                                 options.ground_tolerance, tracks.n_tracks)
    else:  # without them, with each matched pair's two-view geometry
        consistent = two_view_consistent(tracks.track, photo_of, xy_px, twin[a], twin[b], tracks.n_tracks, RANSAC_PX)
    products.inconsistent = int((~consistent).sum())
    rows = rows[consistent[tracks.track[rows]]]
    keep = thin_tracks(tracks.track[rows], photo_of[rows], plate[rows], frames.half, options.cells, options.per_cell,
                       n_tracks=tracks.n_tracks)
    keep &= consistent
    products.kept_tracks = int(keep.sum())
    chosen = rows[keep[tracks.track[rows]]]
    products.rays = len(chosen)
    products.kept_lengths = products.track_lengths[keep]
    clock.lap("tracks and thinning")
    off = "off the approximate orientations" if stand_in is None else "off their pairs' two-view geometry"
    say(f"tracks: {tracks.n_tracks} ({tracks.split} split, {products.inconsistent} {off}), {products.kept_tracks} "
        f"kept, {products.rays} rays")
    if options.refine and paths is not None:  # least-squares matching at full resolution (match.lsm)
        xy_px, plate = xy_px.copy(), plate.copy()
        xy_px[chosen] = _refine(tracks.track[chosen], photo_of[chosen], xy_px[chosen], paths, options, products)
        plate[chosen] = frames.plate(photo_of[chosen], xy_px[chosen])
        clock.lap("least-squares matching")
        say(f"least-squares matching: {products.refined} of {products.refinable} rays refined (median shift "
            f"{products.refine_shift:.3f} px); image coordinates to {products.sigma_px:.3f} px "
            f"({products.sigma_how})")
    def tables(chosen):
        if frames.units == "plate":  # digital: plate coordinates and sigmas in plate units
            measured, sigma = plate[chosen], products.sigma_px * frames.mm_per_px[photo_of[chosen]]
        else:  # film: scan pixels (col, row), sigmas in pixels
            measured, sigma = xy_px[chosen], np.full(len(chosen), products.sigma_px)
        files = _output_files(project_dir, project, tracks.track[chosen], photo_of[chosen], measured, sigma)
        if scans is not None and scans.found is not None:
            files[film_scans.MEASUREMENTS] = film_scans.measurements_csv(project, scans.found)
        return files

    files = tables(chosen)
    clock.lap("output tables")
    if stand_in is not None:  # approximate orientations from the strips (match.unoriented)
        tolerance = RANSAC_PX * float(np.median(frames.mm_per_px))
        oriented = unoriented.orient(project_dir, files, stand_in, tolerance, options.ground_tolerance,
                                     _terrain_height(project, options))
        false = np.array([t for t, pid in _auto_ids(project, tracks.track[chosen]).items()
                          if pid in oriented.false_points], dtype=np.int64)
        keep[false] = False
        chosen = chosen[keep[tracks.track[chosen]]]
        products.inconsistent += len(false)
        products.kept_tracks, products.rays = int(keep.sum()), len(chosen)
        products.kept_lengths = products.track_lengths[keep]
        files = {**tables(chosen), unoriented.PHOTOS: oriented.photos_csv}
        project = replace(project, photos=replace(project.photos, xyz0=oriented.block.xyz0,
                                                  R_ground_from_cam=oriented.block.R_ground_from_cam))
        products.strips, products.centres = oriented.block.strips, oriented.block.xyz0[:, :2].copy()
        clock.lap("orientations from the strips")
        say(f"orientations: {len(products.strips)} strips built and placed on the control (largest RMS "
            f"{max(p.rms_m for p in products.strips):.2f} m); tie points off them left out: "
            f"{len(oriented.false_points)}")
    products.ray_photo, products.ray_plate = photo_of[chosen], plate[chosen]
    if paths is not None:  # the control points' chips (match.chips)
        from .chips import chip_files

        chips = chip_files(project, frames, paths)
        products.chips = sum(name.endswith(".png") for name in chips)
        files.update(chips)
        clock.lap("control point chips")
        if products.chips:
            say(f"chips: {products.chips} of control and check points (chips/chips.csv)")
    if scans is not None:  # OUT must read as a whole project: the fiducials carry every image point
        parse_project({k: v for k, v in files.items() if k in FILE_NAMES}, project_dir)
    from .report import match_report  # matplotlib: only once there is something to draw

    files[REPORT_NAME] = match_report(products, project_dir, source)
    clock.lap("report")
    with OutputReservation(out_dir, inputs) as reservation:
        products.out = reservation.commit(files)
    return products


def _placeholder_photos(project_dir: Path) -> str | None:
    """photos.csv with zero orientations when the user's has none (match.unoriented), else None."""
    path = project_dir / unoriented.PHOTOS
    return unoriented.placeholder(project_dir, read_input_bytes(path)) if input_present(path) else None


def _refine(track, photo, colrow, paths, options, products) -> np.ndarray:
    """The rays (track, photo, colrow) refined by least-squares matching (match.lsm) -> their new
    colrow; unless --sigma-px was given, the sigma estimated again from the matching's closures
    (match.lsm.closure_sigma)."""
    from .lsm import closure_sigma, refine

    r = refine(track, photo, colrow, paths, options.workers, options.scheduler)
    products.refined, products.refinable = int(r.refined.sum()), int(np.isfinite(r.correlation).sum())
    products.refine_shift = float(np.median(r.shift[r.refined])) if r.refined.any() else float("nan")
    if options.sigma_px is None:
        sigma, used = closure_sigma(track, photo, r, paths, options.workers, options.scheduler)
        if np.isfinite(sigma) and used >= MIN_CLOSURES:
            products.sigma_px = sigma
            products.sigma_how = f"estimated from {used} closures of the least-squares matching"
    return r.colrow


MIN_CLOSURES = 20  # the sigma after least-squares matching needs at least this many closures


@dataclass
class _Scans:
    """A project of scanned film (match.film_scans): its setting and calibrated fiducials; the
    marks given (fiducial_measurements.csv) or found in the scans (per photo)."""

    setting: film_scans.FilmSetting
    fiducials: dict
    options: film_scans.FiducialOptions
    given: FiducialMeasurements | None = None
    found: list | None = None


def _matched_images(project, paths, options, products, clock, height, scans=None, work=None):
    """Features and verified matches from the images (paths: one per photo): -> (xy per photo, a,
    b, score, epipolar distances of the non-planar pairs, the ImageFrames); a, b index the photos'
    features concatenated. The features of each photo, and for scans their fiducial marks unless
    given, are found by the tasks of match.stages (local processes, or the cluster of
    options.scheduler) and written to the work folder ``work``; the pairs are matched from there.
    Scans: only the features inside the image area (not the frame, film base or marks) are matched.
    height: the terrain height of the footprints (None: the photos have no orientations, the pairs
    come from the strips)."""
    ids = project.photos.ids
    cams = project.cameras
    tasks = []
    for k, path in enumerate(paths):
        if scans is None:
            size = tuple(float(v) for v in cams.size_px[project.photos.camera_index[k]])
            tasks.append(FeatureTask(k, str(path), str(work), options.scale, options.max_features, size))
        else:
            camera = scans.fiducials[int(project.photos.camera_index[k])] if scans.given is None else None
            tasks.append(FeatureTask(k, str(path), str(work), options.scale, options.max_features, None,
                                     None if camera is None else {f: tuple(xy) for f, xy in camera.items()},
                                     scans.options))
    xy, marks = [None] * len(paths), [None] * len(paths)
    for done, (k, (found, found_marks)) in enumerate(map_unordered(find_features, tasks, options.workers,
                                                                   options.scheduler), start=1):
        xy[k], marks[k] = found, found_marks
        text = f"features: photo {ids[k]}: {len(found)} ({done} of {len(paths)})"
        if found_marks is not None:
            missed = [f"{m.fiducial_id} ({m.reason})" for m in found_marks if not m.found]
            text += (f"; fiducial marks: {len(found_marks) - len(missed)} of {len(found_marks)}"
                     + (f", not found: {', '.join(missed)}" if missed else ""))
        clock.say(text)
    products.features = [len(f) for f in xy]
    clock.lap("features" if scans is None else "features and fiducial marks")
    if scans is None:
        frames = digital_frames(project)
    else:
        if scans.given is None:
            scans.found = marks
            measurements = film_scans.found_measurements(project, scans.fiducials, scans.setting, marks, paths)
        else:
            measurements = scans.given
        frames, fit = film_frames(measurements)
        products.fiducials = _fiducial_summary(project, measurements, fit, marks if scans.given is None else None)
        products.fiducials_found = scans.given is None
        products.features = [int(frames.in_image(np.full(len(f), k), f).sum()) if len(f) else 0
                             for k, f in enumerate(xy)]
    pairs = np.asarray(_pairs(project, height, frames.half), dtype=np.int64).reshape(-1, 2)
    products.pairs = len(pairs)
    products.pair_list = pairs
    products.pair_matches = np.zeros(len(pairs), dtype=np.int64)
    clock.lap("candidate pairs")
    found_pairs = [None] * len(pairs)
    jobs = pair_tasks(pairs, work, frames if scans is not None else None)
    for _, results in map_unordered(match_pairs, jobs, options.workers, options.scheduler):
        for n, *rest in results:
            found_pairs[n] = rest
    offsets = np.cumsum([0] + [len(f) for f in xy])
    a, b, score, epipolar = [], [], [], []
    for n, (p, q) in enumerate(pairs):  # in the order of the pairs: the tracks do not depend on the workers
        i, j, distance, planar, residuals = found_pairs[n]
        products.pair_matches[n] = len(i)
        if len(i):
            products.verified_pairs += 1
            a.append(offsets[p] + i), b.append(offsets[q] + j), score.append(distance)
            if not planar:
                epipolar.append(residuals)
    clock.say(f"pairs: {len(pairs)} matched")
    clock.lap("pair matching")
    cat = (lambda x: np.concatenate(x) if x else np.zeros(0, dtype=np.int64))  # noqa: E731
    return xy, cat(a), cat(b), (np.concatenate(score) if score else np.zeros(0)), epipolar, frames


def _fiducial_summary(project, marks: FiducialMeasurements, fit, found) -> list:
    """Per photo for the report: (photo_id, marks measured, marks of the camera, the fit's largest
    residual (px), sigma0, the marks not found with the reason ('' where given))."""
    out = []
    for k, pid in enumerate(project.photos.ids):
        total = sum(bool(n) for n in marks.names[k])
        v = fit.v[k][marks.measured[k]]
        largest = float(np.sqrt((v ** 2).sum(1)).max()) if len(v) else float("nan")
        missed = "" if found is None else "; ".join(f"{m.fiducial_id}: {m.reason}" for m in found[k] if not m.found)
        out.append((pid, int(marks.measured[k].sum()), total, largest, float(fit.sigma0[k]), missed))
    return out


class _Clock:
    """Seconds per stage, into ``seconds``, and the peak resident memory of this process at the end
    of each stage (MB), into ``peak``; say(text): the progress on the terminal."""

    def __init__(self, seconds: dict, say=None, peak: dict | None = None):
        self.seconds, self.t = seconds, time.perf_counter()
        self.peak = {} if peak is None else peak
        self.say = say or (lambda text: None)

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self.t
        self.peak[stage] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
        self.t = now


def _input_paths(project_dir: Path) -> list[Path]:
    return [project_dir, *(project_dir / name for name in FILE_NAMES)]


def _image_paths(project: Project, images_dir: Path, project_dir: Path) -> list[Path]:
    """The image of each photo: photos.csv's ``image`` (a path inside DIR, relative to it) where
    given, else DIR/<photo_id>.<ext> (IMAGE_EXTENSIONS, any case). InputError naming the first
    photo without one, or the line of an ``image`` outside DIR or missing."""
    if not images_dir.is_dir():
        raise InputError(images_dir, None, "--images must be a folder of one image per photo")
    by_stem: dict[str, Path] = {}
    for f in images_dir.iterdir():
        if f.suffix.lower() in IMAGE_EXTENSIONS:
            by_stem.setdefault(f.stem, f)
    named = image_column(project_dir / "photos.csv")
    root = images_dir.resolve()
    out = []
    for pid in project.photos.ids:
        if pid in named:
            line, text = named[pid]
            path = (images_dir / text).resolve()
            if Path(text).is_absolute() or root not in path.parents:
                raise InputError(project_dir / "photos.csv", line, f"image '{text}' of photo '{pid}' must be a path "
                                                                   "inside --images, relative to it")
            if not path.is_file():
                raise InputError(project_dir / "photos.csv", line, f"image '{text}' of photo '{pid}' is not in "
                                                                   f"{images_dir}")
            out.append(path)
        elif pid in by_stem:
            out.append(by_stem[pid])
        else:
            raise InputError(images_dir, None, f"no image of photo '{pid}' (expected {pid}.jpg, .png or .tif, or "
                                               "photos.csv's column image)")
    return out


def _terrain_height(project: Project, options: MatchOptions) -> float:
    """--terrain-height, else the mean height of the control points, else 0."""
    if options.terrain_height is not None:
        return float(options.terrain_height)
    pts = project.points
    control = np.isin(pts.kind, [FULL, HEIGHT]) & np.isfinite(pts.xyz_given[:, 2])
    return float(np.mean(pts.xyz_given[control, 2])) if control.any() else 0.0


def _pairs(project: Project, h: float | None, half: np.ndarray) -> np.ndarray:
    """Candidate pairs: footprints at the terrain height h, else (h None: no orientations, or a
    footprint that does not reach the terrain) the strips (match.pairs); half (n, 2) each photo's
    half format (plate units)."""
    ph, cams = project.photos, project.cameras
    if h is None:
        return strip_pairs(ph.strip_ids)
    cam = ph.camera_index
    try:
        fp = footprints(ph.R_ground_from_cam, ph.xyz0, cams.interior[cam, :3], half, h)
    except ValueError:
        return strip_pairs(ph.strip_ids)
    return overlap_pairs(fp)


def _auto_ids(project: Project, track: np.ndarray) -> dict[int, str]:
    """The point id of each track written: auto_<n>, n counting up over the ids the project uses."""
    taken = set(project.points.ids)
    n, prefix = 0, "auto_"
    ids = {}
    for t in np.unique(track):
        while f"{prefix}{n}" in taken:
            n += 1
        ids[int(t)] = f"{prefix}{n}"
        n += 1
    return ids


def _output_files(project_dir: Path, project: Project, track, photo, plate, sigma) -> dict[str, bytes | str]:
    """Every input file as it is, and image_points.csv with the user's rows (source manual) and the
    automatic ones (source auto; point ids auto_<n>, unused by the project). plate, sigma: the
    automatic rows' x, y and sigma in the units of the project's image points (plate, or scan
    pixels)."""
    files: dict[str, bytes | str] = {}
    for name in FILE_NAMES:
        f = project_dir / name
        if f.is_file() and name != "image_points.csv":
            files[name] = f.read_bytes()
    given = project_dir / "image_points.csv"
    header, rows = ["photo_id", "point_id", "x", "y", "sigma_x", "sigma_y"], []
    if given.is_file():
        reader = csv.DictReader(io.StringIO(given.read_text(encoding="utf-8-sig")))
        header = list(reader.fieldnames or header)
        rows = [dict(r) for r in reader]
    for name in ("sigma_x", "sigma_y"):
        if name not in header:
            header.append(name)
    if "source" not in header:
        header.append("source")
        for r in rows:
            r["source"] = "manual"
    ids = _auto_ids(project, track)
    for t, p, xy, s in zip(track.tolist(), photo.tolist(), plate, sigma):
        rows.append({"photo_id": project.photos.ids[p], "point_id": ids[t], "x": repr(float(xy[0])),
                     "y": repr(float(xy[1])), "sigma_x": repr(float(s)), "sigma_y": repr(float(s)),
                     "source": "auto"})
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=header, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    files["image_points.csv"] = out.getvalue()
    return files
