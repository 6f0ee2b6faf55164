"""The tables of a project folder: cameras.csv, photos.csv, control.csv, image_points.csv,
approx_points.csv and bases.csv into the arrays of striptri.model, every problem an InputError
with file, line and reason (io.project_reader's module doc holds the choices made)."""

from __future__ import annotations

import math
from itertools import repeat

import numpy as np

from striptri.geometry import balanced, rotations
from striptri import model
from striptri.geometry.lens import CAMERA_ELEMENTS, CONVENTIONS, NCP
from striptri.geometry.rotations import RADIANS_PER_UNIT
from striptri.io import plausibility as limits
from striptri.errors import InputError
from striptri.io.csvtable import CsvTable


# Names of the three angle columns of photos.csv for each rotation convention.
ANGLE_COLUMNS = {
    "omega-phi-kappa": ("omega", "phi", "kappa"),
    "alpha-omega-chi": ("alpha", "omega", "chi"),
    "phi-omega-kappa": ("phi", "omega", "kappa"),
}
# Base components of bases.csv (Schmid 17, 24): component -> ground axis.
BASE_AXES = {"bx": 0, "by": 1, "bz": 2}


AFFINITY_LIMIT = 0.5  # |b1|, |b2| at or beyond this: no camera's affinity or shear (b1 = -1 makes x vanish)


def _read_cameras(table: CsvTable) -> model.Cameras:
    """cameras.csv: camera_id, c, xp, yp[, k1, k2, k3, p1, p2, b1, b2][, distortion]
    [, sigma_<element> ...] (docs/camera-model.md). Additional parameters default to 0, held."""
    table.require("camera_id", "c", "xp", "yp")
    ids = table.strings("camera_id")
    _check_unique(table, "camera_id", ids)
    n = len(ids)
    interior = np.zeros((n, NCP))
    interior[:, :3] = np.column_stack([table.floats(name) for name in ("c", "xp", "yp")]).reshape(-1, 3)
    for i in np.flatnonzero(interior[:, 0] <= 0):
        raise table.error(i, f"principal distance c must be > 0 (got {table.text(i, 'c')})")
    _check_limit(table, ("c", "xp", "yp"), interior[:, :3], limits.PLATE_LIMIT, "plate units")
    for j, name in enumerate(CAMERA_ELEMENTS[3:], start=3):
        interior[:, j] = np.nan_to_num(table.optional_floats(name), nan=0.0)
    for name in ("b1", "b2"):  # affinity and shear: c (1 + b1) is the x scale, c b2 the shear
        j = CAMERA_ELEMENTS.index(name)
        for i in np.flatnonzero(~(np.abs(interior[:, j]) < AFFINITY_LIMIT))[:1]:
            raise table.error(i, f"column '{name}': {table.text(i, name)} is no affinity or shear of a camera "
                                 f"(|{name}| must be below {AFFINITY_LIMIT:g}; a real camera's is below 1e-3): "
                                 f"{'c (1 + b1) is the scale of x' if name == 'b1' else 'c b2 shears x by y'}")
    sigma = np.column_stack(
        [_sigma_column(table, f"sigma_{name}", zero_means_fixed=True, free_word=True) for name in CAMERA_ELEMENTS]
    ).reshape(-1, NCP)
    convention = np.zeros(n, dtype=int)
    for i, word in enumerate(table.optional_strings("distortion", "plate")):
        word = word.strip().lower() or "plate"
        if word not in CONVENTIONS:
            raise table.error(i, f"distortion must be 'plate' (the measured coordinates are corrected, "
                                 f"DBAT/photogrammetry) or 'image' (applied to the projected point, "
                                 f"BAL/COLMAP/OpenCV), not '{word}'")
        convention[i] = CONVENTIONS[word]
    size_px, pixel_size = _digital_frame(table)
    r0 = _balanced_radius(table, sigma) if table.has("r0") else None
    if r0 is not None:
        interior = balanced.gaussian_from_balanced(interior, r0, convention)
        for i in np.flatnonzero(np.isfinite(r0) & ~(interior[:, 0] > 0)):
            raise table.error(i, f"with r0 = {table.text(i, 'r0')} the balanced radial distortion gives a principal "
                                 f"distance {interior[i, 0]:.6g} <= 0: check k1, k2, k3 and r0")
    return model.Cameras(ids=ids, interior=interior, sigma_interior=sigma, convention=convention, r0=r0,
                         size_px=size_px, pixel_size=pixel_size)


DIGITAL_FRAME = ("width_px", "height_px", "pixel_size")
SOURCES = ("manual", "auto", "")  # image_points.csv's source: by a person, by striptri match (empty: manual)


def _digital_frame(table: CsvTable) -> tuple[np.ndarray | None, np.ndarray | None]:
    """cameras.csv's optional width_px, height_px, pixel_size (a digital frame camera,
    striptri.geometry.pixels): the three columns together; per row all three or none; width and
    height whole numbers > 0, pixel_size > 0 (plate units per pixel). -> (size_px (n, 2),
    pixel_size (n,)), nan where a row has none; (None, None) without the columns."""
    present = [name for name in DIGITAL_FRAME if table.has(name)]
    if not present:
        return None, None
    if len(present) < len(DIGITAL_FRAME):
        missing = [name for name in DIGITAL_FRAME if name not in present]
        raise InputError(table.path, table.header_line, f"a digital frame camera needs width_px, height_px and "
                                                        f"pixel_size together: {', '.join(missing)} missing")
    values = np.column_stack([table.optional_floats(name) for name in DIGITAL_FRAME])
    given = np.isfinite(values)
    for i in np.flatnonzero(given.any(axis=1) & ~given.all(axis=1))[:1]:
        raise table.error(i, "width_px, height_px and pixel_size: give all three or none")
    for j, name in enumerate(DIGITAL_FRAME):
        for i in np.flatnonzero(given[:, j] & ~(values[:, j] > 0))[:1]:
            raise table.error(i, f"column '{name}' must be > 0 (got {table.text(i, name)})")
        if j < 2:
            for i in np.flatnonzero(given[:, j] & (values[:, j] != np.round(values[:, j])))[:1]:
                raise table.error(i, f"column '{name}' must be a whole number of pixels (got {table.text(i, name)})")
    return values[:, :2], values[:, 2]


def _balanced_radius(table: CsvTable, sigma: np.ndarray) -> np.ndarray:
    """cameras.csv's optional r0 (striptri.geometry.balanced): empty = Gaussian; otherwise > 0 (plate units,
    or normalised for distortion = image), and c, k1-k3, p1, p2 held or free, not observed (their
    weights would not carry over exactly)."""
    r0 = table.optional_floats("r0")
    for i in np.flatnonzero(r0 <= 0):
        raise table.error(i, f"column 'r0': the zero-crossing radius must be > 0 (got {table.text(i, 'r0')})")
    observed = np.isfinite(sigma[:, list(balanced.CHANGED)]) & np.isfinite(r0)[:, None]
    for i in np.flatnonzero(observed.any(axis=1))[:1]:
        names = [CAMERA_ELEMENTS[e] for e, o in zip(balanced.CHANGED, observed[i]) if o]
        raise table.error(i, f"with r0 (balanced radial distortion) {', '.join(names)} may be held (empty sigma) or "
                             "'free', not observed with a standard deviation: the balanced elements' weights do not "
                             "carry over to the Gaussian form the adjustment uses")
    return r0


# ---------------------------------------------------------------------------------------------
# photos.csv


def _read_photos(table: CsvTable, cameras: model.Cameras, settings: model.ProjectSettings) -> model.Photos:
    """photos.csv: photo_id, camera_id, strip_id, X0, Y0, Z0, three angles[, their sigmas].

    Angles in settings.angle_unit, named after settings.rotation; converted to radians and to
    R_ground_from_cam with rotations.R_from_angles. Sigma: empty = free (nan), 0 = fixed, > 0 observed.
    """
    angle_names = ANGLE_COLUMNS[settings.rotation]
    table.require("photo_id", "camera_id", "strip_id", "X0", "Y0", "Z0", *angle_names)
    ids = table.strings("photo_id")
    _check_unique(table, "photo_id", ids)
    camera_of = {cid: k for k, cid in enumerate(cameras.ids)}
    camera_ids = table.strings("camera_id")
    camera_index = np.fromiter(map(camera_of.get, camera_ids, repeat(-1)), dtype=np.int64, count=len(ids))
    for i in np.flatnonzero(camera_index < 0)[:1]:
        raise table.error(i, f"unknown camera_id '{camera_ids[i]}' (not in cameras.csv)")
    to_rad = RADIANS_PER_UNIT[settings.angle_unit]
    xyz0 = np.column_stack([table.floats(n) for n in ("X0", "Y0", "Z0")]).reshape(-1, 3)
    _check_limit(table, ("X0", "Y0", "Z0"), xyz0, limits.GROUND_LIMIT_M, "m for ground coordinates")
    angles_file = np.column_stack([table.floats(n) for n in angle_names]).reshape(-1, 3)
    _check_limit(table, angle_names, angles_file, limits.angle_limit(to_rad),
                 f"{settings.angle_unit} ({limits.ANGLE_LIMIT_TURNS} full turns) for an angle")
    angles = angles_file * to_rad
    sigma_xyz0 = np.column_stack(
        [_sigma_column(table, f"sigma_{n}", zero_means_fixed=False) for n in ("X0", "Y0", "Z0")]
    ).reshape(-1, 3)
    sigma_angles = (
        np.column_stack([_sigma_column(table, f"sigma_{n}", zero_means_fixed=False) for n in angle_names]).reshape(
            -1, 3
        )
        * to_rad
    )
    table.optional_strings("image")  # the photo's image, for striptri match (match.pipeline reads it)
    return model.Photos(
        ids=ids,
        camera_index=camera_index,
        strip_ids=table.strings("strip_id", allow_empty=True),
        xyz0=xyz0,
        R_ground_from_cam=rotations.R_from_angles(angles, settings.rotation).reshape(-1, 3, 3),
        angles=angles,
        sigma_xyz0=sigma_xyz0,
        sigma_angles=sigma_angles,
    )


# ---------------------------------------------------------------------------------------------
# control.csv


class _Control:
    """The rows of control.csv: ids in file order, kind codes, given xyz and sigmas (nan = not given /
    held fixed)."""

    def __init__(self, ids: list[str], kind: np.ndarray, xyz: np.ndarray, sigma: np.ndarray):
        self.ids, self.kind, self.xyz, self.sigma = ids, kind, xyz, sigma

    @staticmethod
    def empty() -> "_Control":
        return _Control([], np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))


def _read_control(table: CsvTable) -> _Control:
    """control.csv: point_id, kind, X, Y, Z[, sigma_X, sigma_Y, sigma_Z].

    kind XYZ / XY / Z / check (case-insensitive). Coordinates the kind does not give are stored as
    nan (and ignored if present); check points keep their reference X, Y, Z and no sigma.
    Sigma: empty or 0 = held fixed (nan), > 0 = weighted control.
    """
    table.require("point_id", "kind", "X", "Y", "Z")
    ids = table.strings("point_id")
    _check_unique(table, "point_id", ids)
    texts = table.strings("kind", allow_empty=True)
    kind = np.fromiter(map(model.KIND_CODES.get, map(str.upper, texts), repeat(-1)), dtype=np.int64, count=len(ids))
    for i in np.flatnonzero(kind < 0)[:1]:
        raise table.error(i, f"unknown kind '{texts[i]}' (accepted: XYZ, XY, Z, check)")
    xyz_file = np.column_stack([table.optional_floats(n) for n in "XYZ"]).reshape(-1, 3)
    _check_limit(table, tuple("XYZ"), xyz_file, limits.GROUND_LIMIT_M, "m for ground coordinates")
    sigma_file = np.column_stack(
        [_sigma_column(table, f"sigma_{n}", zero_means_fixed=True) for n in "XYZ"]
    ).reshape(-1, 3)
    needed = model.needed_axes(kind).reshape(-1, 3)
    for i, j in zip(*np.nonzero(needed & np.isnan(xyz_file))):
        name = model.KIND_NAMES[kind[i]]
        raise table.error(i, f"kind {name} needs {'XYZ'[j]} but it is empty (kind {name} needs "
                             f"{', '.join(a for a, n in zip('XYZ', needed[i]) if n)})")
    xyz = np.where(needed, xyz_file, np.nan)
    given = model.given_axes(kind).reshape(-1, 3)
    sigma = np.where(given, sigma_file, np.nan)
    return _Control(ids, kind, xyz, sigma)


# ---------------------------------------------------------------------------------------------
# image_points.csv and the object points


def _read_image_points(
    table: CsvTable, photos: model.Photos, control: _Control, settings: model.ProjectSettings, active: np.ndarray
) -> tuple[model.ImagePoints, model.ObjectPoints]:
    """image_points.csv: photo_id, point_id, x, y[, sigma_x, sigma_y] (plate units).

    Empty sigma -> settings.sigma_image; a sigma must be > 0. Object points: control points in
    control.csv order, then tie points by first measurement. active (m,) bool (the ``active``
    column): a point may be measured on a photo once among the active rows; inactive rows of the same
    photo and point beside it (a rejected measurement kept with its re-measurement) are allowed.
    """
    table.require("photo_id", "point_id", "x", "y")
    sources = table.optional_strings("source", "manual")  # striptri match (docs/matching.md)
    if not all(word.strip().lower() in SOURCES for word in set(sources)):  # each distinct word once
        for i, word in enumerate(sources):
            if word.strip().lower() not in SOURCES:
                raise table.error(i, f"column 'source': '{word}' is not one of {', '.join(SOURCES)} "
                                     "(how the row was measured)")
    photo_of = {pid: k for k, pid in enumerate(photos.ids)}
    photo_ids = table.strings("photo_id")
    measured_ids = table.strings("point_id")
    photo_index = np.fromiter(map(photo_of.get, photo_ids, repeat(-1)), dtype=np.int64, count=len(table))
    # points: the control points in their order, then the others by first measurement
    point_of = {pid: k for k, pid in enumerate(control.ids)}
    for pid in dict.fromkeys(measured_ids):
        point_of.setdefault(pid, len(point_of))
    point_ids = list(point_of)
    point_index = np.fromiter(map(point_of.__getitem__, measured_ids), dtype=np.int64, count=len(table))
    # the first row that is an error: an unknown photo, or a point measured twice on one photo
    unknown = np.flatnonzero(photo_index < 0)
    key = photo_index * max(len(point_ids), 1) + point_index
    key = np.where(active, key, -1 - np.arange(len(key)))  # inactive rows never repeat a key
    order = np.argsort(key, kind="stable")
    repeated = np.flatnonzero(key[order][1:] == key[order][:-1]) + 1  # in order: a later row of the same key
    first_unknown = int(unknown[0]) if len(unknown) else len(table)
    first_repeat = int(order[repeated].min()) if len(repeated) else len(table)
    if first_unknown < len(table) and first_unknown <= first_repeat:
        raise table.error(first_unknown, f"unknown photo_id '{photo_ids[first_unknown]}' (not in photos.csv)")
    if first_repeat < len(table):
        i = first_repeat
        first = int(np.flatnonzero(key == key[i])[0])
        also = "" if active.all() else "; an inactive row (active = 0) may repeat it"
        raise table.error(i, f"duplicate measurement of point '{measured_ids[i]}' on photo '{photo_ids[i]}' "
                             f"(first on line {table.lines[first]}{also})")
    xy = np.column_stack([table.floats("x"), table.floats("y")]).reshape(-1, 2)
    _check_limit(table, ("x", "y"), xy, limits.PLATE_LIMIT, "plate units")
    sigma_xy = np.column_stack(
        [_image_sigma(table, name, settings.sigma_image) for name in ("sigma_x", "sigma_y")]
    ).reshape(-1, 2)
    image_points = model.ImagePoints(photo_index=photo_index, point_index=point_index, xy=xy, sigma_xy=sigma_xy)
    return image_points, _object_points(point_ids, control)


ACTIVE_WORDS = {"1": True, "true": True, "0": False, "false": False}  # image_points.csv's active, any case


def _active_column(table: CsvTable) -> np.ndarray:
    """image_points.csv's optional ``active`` column -> (m,) bool: 1/true (or empty) = adjusted,
    0/false = kept and reported but not adjusted (striptri.report.inactive). Anything else: InputError."""
    words = table.optional_strings("active", "1")
    meaning = {w: ACTIVE_WORDS.get(w.lower() or "1") for w in set(words)}  # each distinct word once
    if None in meaning.values():
        for i, w in enumerate(words):
            if meaning[w] is None:
                raise table.error(i, f"column 'active': '{table.text(i, 'active')}' is not 1, 0, true or false")
    return np.fromiter(map(meaning.__getitem__, words), dtype=bool, count=len(words))


def _rows(ip: model.ImagePoints, keep: np.ndarray) -> model.ImagePoints:
    return model.ImagePoints(photo_index=ip.photo_index[keep], point_index=ip.point_index[keep], xy=ip.xy[keep],
                             sigma_xy=ip.sigma_xy[keep])


def _image_sigma(table: CsvTable, name: str, default: float) -> np.ndarray:
    """An image sigma column: empty -> default; must be > 0 and within the plausible range."""
    values = table.optional_floats(name)
    for i in np.flatnonzero(values <= 0):
        raise table.error(i, f"column '{name}': a plate measurement sigma must be > 0 (got {table.text(i, name)})")
    _check_sigma_range(table, name, values)
    return np.where(np.isnan(values), default, values)


def _check_plate_geometry(table: CsvTable, camera_table: CsvTable, image_points: model.ImagePoints,
                          photos: model.Photos, cameras: model.Cameras) -> None:
    """Plate coordinates against their camera (striptri.io.plausibility): a ray at most
    MAX_OFF_AXIS_DEG off the axis, r = |(x - xp, y - yp)| <= c tan(89 deg); and per camera the
    measured points not all within MIN_FIELD c of the principal point (numerically parallel rays)."""
    cam = photos.camera_index[image_points.photo_index]
    c = cameras.interior[cam, 0]
    r = np.hypot(*(image_points.xy - cameras.interior[cam, 1:3]).T)
    for i in np.flatnonzero(r > limits.MAX_RADIUS_PER_C * c)[:1]:
        off = math.degrees(math.atan2(float(r[i]), float(c[i])))
        raise table.error(i, f"plate point ({table.text(i, 'x')}, {table.text(i, 'y')}) lies "
                             f"{float(r[i]):.6g} plate units from the principal point of camera "
                             f"'{cameras.ids[cam[i]]}' (c = {float(c[i]):.6g}): a ray {off:.2f} deg off the "
                             f"camera axis, which a frame camera cannot image (limit {limits.MAX_OFF_AXIS_DEG:g} "
                             "deg); check the plate coordinates, their units and c")
    r_max = np.full(len(cameras), -1.0)
    np.maximum.at(r_max, cam, r)
    narrow = (r_max >= 0) & (r_max < limits.MIN_FIELD * cameras.interior[:, 0])
    for j in np.flatnonzero(narrow)[:1]:
        cj = float(cameras.interior[j, 0])
        raise camera_table.error(j, f"camera '{cameras.ids[j]}': c = {camera_table.text(j, 'c')} but every point "
                                    f"measured with it lies within {float(r_max[j]):.6g} plate units of the principal "
                                    f"point ({float(r_max[j]) / cj:.3g} c: every ray within "
                                    f"{math.degrees(math.atan2(float(r_max[j]), cj)) * 3600:.3g} arc seconds of the "
                                    f"camera axis), so its rays are numerically parallel (limit "
                                    f"{limits.number_text(limits.MIN_FIELD)} c); check c and the units of the plate "
                                    "coordinates")


def _object_points(point_ids: list[str], control: _Control) -> model.ObjectPoints:
    """ObjectPoints for point_ids, whose first len(control.ids) entries are the control points."""
    n, n_control = len(point_ids), len(control.ids)
    kind = np.full(n, model.TIE, dtype=np.int64)
    xyz_given = np.full((n, 3), np.nan)
    sigma_given = np.full((n, 3), np.nan)
    kind[:n_control] = control.kind
    xyz_given[:n_control] = control.xyz
    sigma_given[:n_control] = control.sigma
    return model.ObjectPoints(ids=point_ids, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given)


# ---------------------------------------------------------------------------------------------
# approx_points.csv


def _read_approx_points(table: CsvTable, points: model.ObjectPoints) -> np.ndarray:
    """approx_points.csv: point_id, X, Y, Z (empty = unknown): approximate coordinates of object
    points (starting values of the bundle method, written by striptri convert). Every id must be
    a point of the project. -> (n_points, 3), nan where not given."""
    table.require("point_id", "X", "Y", "Z")
    index = {pid: j for j, pid in enumerate(points.ids)}
    out = np.full((len(points), 3), np.nan)
    ids = table.strings("point_id")
    _check_unique(table, "point_id", ids)
    xyz = np.column_stack([table.optional_floats(a) for a in "XYZ"]).reshape(-1, 3)
    _check_limit(table, tuple("XYZ"), xyz, limits.GROUND_LIMIT_M, "m for ground coordinates")
    for i, pid in enumerate(ids):
        if pid not in index:
            raise table.error(i, f"point_id '{pid}' is not measured in image_points.csv nor given in control.csv")
        out[index[pid]] = xyz[i]
    return out


# ---------------------------------------------------------------------------------------------
# bases.csv


def _read_bases(table: CsvTable, photos: model.Photos) -> model.BaseComponents:
    """bases.csv: photo_from, photo_to, component (bx|by|bz), value, sigma (our extension, Schmid 17, 24).

    value = O[photo_to, axis] - O[photo_from, axis] in metres. sigma: empty or 0 = enforced exactly,
    > 0 = observed (e.g. statoscope bz).
    """
    table.require("photo_from", "photo_to", "component", "value", "sigma")
    photo_of = {pid: k for k, pid in enumerate(photos.ids)}
    index = table.id_indices(("photo_from", "photo_to"), photo_of, "photos.csv")
    axis = np.zeros(len(table), dtype=np.int64)
    first_line: dict[tuple[int, int, int], int] = {}
    for i, text in enumerate(table.strings("component")):
        if text.lower() not in BASE_AXES:
            raise table.error(i, f"unknown component '{text}' (accepted: bx, by, bz)")
        axis[i] = BASE_AXES[text.lower()]
        if index["photo_from"][i] == index["photo_to"][i]:
            raise table.error(i, "photo_from and photo_to are the same photo")
        key = (int(index["photo_from"][i]), int(index["photo_to"][i]), int(axis[i]))
        if key in first_line:
            raise table.error(i, f"duplicate base component {text.lower()} (first on line {first_line[key]})")
        first_line[key] = table.lines[i]
    value = table.floats("value")
    _check_limit(table, ("value",), value, limits.GROUND_LIMIT_M, "m for a base component")
    return model.BaseComponents(
        photo_from=index["photo_from"],
        photo_to=index["photo_to"],
        axis=axis,
        value=value,
        sigma=_sigma_column(table, "sigma", zero_means_fixed=False),
    )


# ---------------------------------------------------------------------------------------------
# shared


def _check_unique(table: CsvTable, column: str, ids: list[str]) -> None:
    """InputError on the second occurrence of an id, naming the line of the first."""
    if len(set(ids)) == len(ids):
        return
    first_line: dict[str, int] = {}
    for i, value in enumerate(ids):
        if value in first_line:
            raise table.error(i, f"duplicate {column} '{value}' (first on line {first_line[value]})")
        first_line[value] = table.lines[i]


def _sigma_column(table: CsvTable, name: str, zero_means_fixed: bool, free_word: bool = False) -> np.ndarray:
    """An optional sigma column -> (n,): empty = nan, negative = InputError.

    zero_means_fixed: 0 -> nan (files where nan means "held fixed"). free_word: accept ``free`` -> inf.
    """
    values = table.optional_floats(name, keywords={"free": math.inf} if free_word else None)
    for i in np.flatnonzero(values < 0):
        raise table.error(i, f"column '{name}': a standard deviation cannot be negative (got {table.text(i, name)})")
    _check_sigma_range(table, name, values)
    if zero_means_fixed:
        values = np.where(values == 0, np.nan, values)
    return values


def _check_sigma_range(table: CsvTable, name: str, values: np.ndarray) -> None:
    """A sigma that is an observation (finite, > 0) must lie in [SIGMA_MIN, SIGMA_MAX]."""
    i = limits.first_sigma_out_of_range(values)
    if i is not None:
        raise table.error(i, f"column '{name}': a standard deviation of {table.text(i, name)} is outside the plausible "
                             f"range [{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}]: its weight 1/sigma^2 is not a "
                             "meaningful number")


def _check_limit(table: CsvTable, names: tuple[str, ...], values: np.ndarray, limit: float, what: str) -> None:
    """InputError at the first value of the columns ``names`` (values (n, len(names))) beyond +-limit."""
    hit = limits.first_beyond(values, limit)
    if hit is not None:
        i, j = hit
        raise table.error(i, f"column '{names[j]}': {table.text(i, names[j])} exceeds the plausibility limit of "
                             f"{limits.number_text(limit)} {what}, in magnitude (docs/file-formats.md, Limits)")
