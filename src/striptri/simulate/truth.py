"""The true flight: photos, terrain, object points and their exact plate coordinates.

``make_truth(design, rng)`` draws everything random of the design (terrain, deviations of the
photos from the ideal flight line, extra tie points) from the generator it is given, and nothing
else: noise comes later (``striptri.simulate.noise``).

Ids: photo ``<strip><k:03d>`` ("1001", "1002", ... for the first strip, "2001", ... for the second),
k counted in flight order (with 1,000 photos per strip or more, k gets as many digits as the
largest k has, "100001", so that ids stay unique); the pass points at the nadir of that photo ``<photo id>L``,
``<photo id>C``, ``<photo id>R`` (left of that strip's flight direction, on it, right; left is +y on
the plate). A pass point in the middle of a sidelap is seen by both strips and named once, by the
photo of the earlier strip (so a later strip names only its nadir point and the point on its side
away from the earlier strip). Extra tie points ``T<first photo id of the model>_<i:02d>``;
single-photo control ``<photo id>S``. Schmid's Fig. 8 strip numbers its points "1" ... "30" as he
does (:mod:`striptri.simulate.schmid_fig8`).

Photos are listed strip after strip, each strip in flight order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri.geometry.camera import in_front, project
from striptri.model import CHECK, FULL, TIE
from striptri.geometry.rotations import R_from_opk
from striptri.simulate import schmid_fig8
from striptri.simulate.control import OMITTED, POSITIONS, pass_point_kinds
from striptri.simulate.design import SCHMID_FIG8, SyntheticDesign
from striptri.simulate.terrain import Terrain, make_terrain

# Extra tie points are drawn in the nominal overlap of two photos shrunk by this factor, so that
# terrain relief and the deviations from the ideal flight keep them on both plates.
_TIE_AREA_SHRINK = 0.8


@dataclass(frozen=True)
class FlightLine:
    """Nominal geometry of one strip. nadir_xy: (n, 2) ground XY of the ideal nadirs (m), in flight
    order; along, left: (2,) unit vectors of this strip's flight direction and of its left side in
    ground XY; heading: its flight direction (rad from +X towards +Y). index: 0-based strip number;
    columns: (n,) the block column of each photo (control.py)."""

    strip_id: str
    photo_ids: list[str]
    nadir_xy: np.ndarray
    along: np.ndarray
    left: np.ndarray
    heading: float
    index: int
    columns: np.ndarray


@dataclass(frozen=True)
class Truth:
    """Everything true about a synthetic project, struct of arrays.

    interior: (3,) c, xp, yp of the one camera (plate units).
    Photos: photo_ids, strip_ids (n,); xyz0: (n, 3) ground m; R_ground_from_cam: (n, 3, 3).
    Points: point_ids (np,); kind: (np,) codes of striptri.model (TIE, HEIGHT, PLAN, FULL, CHECK);
    xyz_ground: (np, 3) m.
    Observations, one row per visible (photo, point), photo-major: photo_index, point_index (m,);
    xy_plate: (m, 2) exact plate coordinates (striptri.geometry.camera.project).
    """

    design: SyntheticDesign
    terrain: Terrain
    interior: np.ndarray
    photo_ids: list[str]
    strip_ids: list[str]
    xyz0: np.ndarray
    R_ground_from_cam: np.ndarray
    point_ids: list[str]
    kind: np.ndarray
    xyz_ground: np.ndarray
    photo_index: np.ndarray
    point_index: np.ndarray
    xy_plate: np.ndarray

    def rays_per_point(self) -> np.ndarray:
        """Number of photos that see each point. -> (np,) ints."""
        return np.bincount(self.point_index, minlength=len(self.point_ids))


def make_truth(design: SyntheticDesign, rng: np.random.Generator) -> Truth:
    """The true project of ``design``, random parts drawn from ``rng``.

    Raises ValueError when the design cannot be realised: a pass point or control point seen by
    fewer than two photos, a single-photo control point seen by more than one, too few tie points
    for the check points asked for.
    """
    camera = design.camera
    interior = np.array([camera.c, camera.xp, camera.yp])
    terrain = make_terrain(design.terrain, camera.format * design.scale, rng)
    lines = _flight_lines(design)
    xyz0, R = _true_photos(design, lines, rng)

    ids, kind, xy = _pass_points(design, lines)
    single_ids, single_xy, single_photo = _single_photo_points(design, lines)
    xyz_fixed = _on_terrain(terrain, np.concatenate([xy, single_xy]))
    photo_of, point_of = _visible_pairs(design, xyz0, R, interior, xyz_fixed)

    n_pass = len(ids)
    _require_rays(np.bincount(point_of, minlength=len(xyz_fixed))[:n_pass], ids)
    if design.control.layout == SCHMID_FIG8:
        seen = np.zeros((len(xyz0), n_pass), dtype=bool)
        pass_rows = point_of < n_pass
        seen[photo_of[pass_rows], point_of[pass_rows]] = True
        schmid_fig8.require_pattern(seen)
    if single_ids:
        single_rows = point_of >= n_pass
        on_own = np.bincount(point_of[single_rows] - n_pass, minlength=len(single_ids))
        right = np.zeros(len(single_ids), dtype=bool)
        right[point_of[single_rows] - n_pass] = photo_of[single_rows] == single_photo[point_of[single_rows] - n_pass]
        if np.any(on_own != 1) or not right.all():
            raise ValueError("design: a single-photo control point is not seen by exactly one photo; lower the overlap")

    tie_ids, tie_xyz = _extra_ties(design, lines, terrain, xyz0, R, interior, rng)
    point_ids = ids + tie_ids + single_ids
    kind = np.concatenate([kind, np.full(len(tie_ids), TIE), np.full(len(single_ids), FULL)]).astype(int)
    xyz_ground = np.concatenate([xyz_fixed[:n_pass], tie_xyz, xyz_fixed[n_pass:]])
    kind = _with_check_points(kind, xyz_ground, lines, design.strip_spacing, design.control.n_check)

    photo_index, point_index = _visible_pairs(design, xyz0, R, interior, xyz_ground)
    xy_plate = project(R[photo_index], xyz0[photo_index], interior, xyz_ground[point_index])
    return Truth(
        design=design,
        terrain=terrain,
        interior=interior,
        photo_ids=[pid for line in lines for pid in line.photo_ids],
        strip_ids=[line.strip_id for line in lines for _ in line.photo_ids],
        xyz0=xyz0,
        R_ground_from_cam=R,
        point_ids=point_ids,
        kind=kind,
        xyz_ground=xyz_ground,
        photo_index=photo_index,
        point_index=point_index,
        xy_plate=xy_plate,
    )


def _flight_lines(design: SyntheticDesign) -> list[FlightLine]:
    """The nominal flight lines: ``n_strips`` parallel strips, strip s (0-based) ``s * spacing`` to the
    left of the first; with ``alternate`` the odd strips are flown backwards, starting where the
    previous strip ended."""
    flight = design.flight
    h = np.radians(flight.heading_deg)
    along = np.array([np.cos(h), np.sin(h)])
    left = np.array([-np.sin(h), np.cos(h)])
    k = np.arange(flight.n_photos)
    width = max(3, len(str(flight.n_photos)))
    lines = []
    for s in range(flight.n_strips):
        backwards = flight.alternate and s % 2 == 1
        columns = k[::-1] if backwards else k
        nadir_xy = np.asarray(flight.start_xy) + (columns * design.base)[:, None] * along + (s * design.strip_spacing) * left
        sign = -1.0 if backwards else 1.0
        strip = str(s + 1)
        lines.append(FlightLine(
            strip_id=strip, photo_ids=[f"{strip}{i + 1:0{width}d}" for i in k], nadir_xy=nadir_xy,
            along=sign * along, left=sign * left, heading=h + (np.pi if backwards else 0.0), index=s,
            columns=columns,
        ))
    return lines


def _true_photos(design: SyntheticDesign, lines: list[FlightLine], rng) -> tuple[np.ndarray, np.ndarray]:
    """True centres and rotations: the ideal (nadir at flying height, R = Rz(heading of the strip))
    plus normal deviations of position (along, across, up) and of omega, phi, kappa.
    -> (n, 3), (n, 3, 3)."""
    flight = design.flight
    z0 = design.terrain.mean_z + flight.flying_height
    xyz0, angles = [], []
    for line in lines:
        n = len(line.photo_ids)
        d = rng.normal(0.0, 1.0, (n, 3)) * np.asarray(flight.position_std_m)
        xy = line.nadir_xy + d[:, :1] * line.along + d[:, 1:2] * line.left
        xyz0.append(np.column_stack([xy, z0 + d[:, 2]]))
        a = rng.normal(0.0, 1.0, (n, 3)) * np.radians(flight.attitude_std_deg)
        a[:, 2] += line.heading
        angles.append(a)
    return np.concatenate(xyz0), R_from_opk(np.concatenate(angles))


def _pass_points(design: SyntheticDesign, lines: list[FlightLine]):
    """Von Gruber pass points of the block with their kinds (control.py for the rows), strip after
    strip, photo after photo in flight order, L, C, R; a sidelap point is listed with the earlier
    strip. Schmid's Fig. 8 strip has its own 30 points. -> ids, kind (p,), xy (p, 2)."""
    if design.control.layout == SCHMID_FIG8:
        line = lines[0]
        xy = schmid_fig8.ground_xy(line.nadir_xy[0], line.along, line.left, design.base,
                                   design.points.lateral_offset * design.scale)
        return [str(n) for n in range(1, len(xy) + 1)], schmid_fig8.kinds(), xy
    offset = design.points.lateral_offset * design.scale
    n_strips, spacing = len(lines), design.strip_spacing
    # across-track position of every row from the axis of the first strip, towards its left (m)
    row_across = np.arange(2 * n_strips + 1) * spacing / 2 - spacing / 2
    row_across[0], row_across[-1] = -offset, (n_strips - 1) * spacing + offset
    row_across[1::2] = np.arange(n_strips) * spacing
    left0 = lines[0].left
    grid = pass_point_kinds(design.control, design.flight.n_photos, n_strips)
    ids, kinds, xys = [], [], []
    for s, line in enumerate(lines):
        sign = int(round(float(line.left @ left0)))  # -1 for a strip flown backwards
        for k, photo_id in enumerate(line.photo_ids):
            column = line.columns[k]
            for j, position in enumerate(POSITIONS):
                row = 2 * s + 1 + sign * (1 - j)
                if (s > 0 and row == 2 * s) or grid[column, row] == OMITTED:
                    continue  # named by the previous strip / not in the layout
                ids.append(f"{photo_id}{position}")
                kinds.append(grid[column, row])
                xys.append(line.nadir_xy[k] + (row_across[row] - row_across[2 * s + 1]) * left0)
    return ids, np.array(kinds, dtype=int), np.array(xys).reshape(-1, 2)


def _single_photo_points(design: SyntheticDesign, lines: list[FlightLine]):
    """Full control points seen by one photo only: in the middle of the part of the first (last)
    photo of the first strip that no other photo of it covers, on its flight line; in a block
    moved ``lateral_offset`` to the outer side, away from the second strip.
    -> ids, xy (s, 2), photo index (s,)."""
    n = design.control.n_single_photo
    line = lines[0]
    footprint = design.camera.format * design.scale
    back = (footprint - design.base) / 2  # from the end nadir to the middle of its own part
    ends = [(0, -back), (len(line.photo_ids) - 1, back)][:n]
    ids = [f"{line.photo_ids[k]}S" for k, _ in ends]
    xy = np.array([line.nadir_xy[k] + a * line.along for k, a in ends]).reshape(-1, 2)
    if len(lines) > 1:
        xy = xy - design.points.lateral_offset * design.scale * line.left
    return ids, xy, np.array([k for k, _ in ends], dtype=int)


def _extra_ties(design, lines, terrain, xyz0, R, interior, rng):
    """``extra_ties_per_model`` random tie points in the (shrunk) nominal overlap of each model,
    each seen by at least two photos: 4 n candidates are drawn per model (model after model, a
    along then b across), the first n seen twice are kept. -> ids, xyz (t, 3)."""
    n = design.points.extra_ties_per_model
    if n == 0:
        return [], np.zeros((0, 3))
    half = design.camera.half_usable * design.scale  # half the usable ground footprint
    base = design.base
    n_try = 4 * n
    centre, along, left, names = [], [], [], []
    for line in lines:
        centre.append((line.nadir_xy[:-1] + line.nadir_xy[1:]) / 2)
        along.append(np.broadcast_to(line.along, (len(line.photo_ids) - 1, 2)))
        left.append(np.broadcast_to(line.left, (len(line.photo_ids) - 1, 2)))
        names += line.photo_ids[:-1]
    centre, along, left = np.concatenate(centre), np.concatenate(along), np.concatenate(left)
    n_models = len(centre)
    ab = rng.uniform(-1.0, 1.0, (n_models, 2, n_try))  # the same stream as a and b drawn model by model
    a = ab[:, 0] * _TIE_AREA_SHRINK * (half - base / 2)
    b = ab[:, 1] * _TIE_AREA_SHRINK * half
    xy = centre[:, None, :] + a[..., None] * along[:, None, :] + b[..., None] * left[:, None, :]
    candidates = _on_terrain(terrain, xy.reshape(-1, 2))
    _, point_of = _visible_pairs(design, xyz0, R, interior, candidates)
    good = (np.bincount(point_of, minlength=len(candidates)) >= 2).reshape(n_models, n_try)
    if np.any(good.sum(axis=1) < n):
        raise ValueError("design: cannot place the extra tie points inside the overlap; lower the deviations")
    rank = np.cumsum(good, axis=1)
    chosen = good & (rank <= n)  # the first n good candidates of each model, in draw order
    ids = [f"T{name}_{i + 1:02d}" for name in names for i in range(n)]
    return ids, candidates.reshape(n_models, n_try, 3)[chosen]


def _with_check_points(kind: np.ndarray, xyz_ground: np.ndarray, lines: list[FlightLine], spacing: float,
                       n_check: int) -> np.ndarray:
    """Turn n_check tie points into check points, evenly spread along the flight. In a block every
    tie point belongs to the strip whose axis is nearest (a sidelap point to the later strip); the
    check points are shared out over the strips (the first n_check % S strips get one more) and
    spread along each."""
    if n_check == 0:
        return kind
    ties = np.flatnonzero(kind == TIE)
    if n_check > len(ties):
        raise ValueError(f"design: {n_check} check points asked for, but only {len(ties)} tie points")
    kind = kind.copy()
    if len(lines) == 1:
        kind[_spread_along(ties, xyz_ground, lines[0], n_check)] = CHECK
        return kind
    across = (xyz_ground[ties, :2] - lines[0].nadir_xy[0]) @ lines[0].left
    strip_of = np.clip(np.floor(across / spacing + 0.5), 0, len(lines) - 1).astype(int)
    share = n_check // len(lines) + (np.arange(len(lines)) < n_check % len(lines))
    for line, n in zip(lines, share):
        mine = ties[strip_of == line.index]
        if n > len(mine):
            raise ValueError(f"design: {n} check points asked for in strip {line.strip_id}, but it has only {len(mine)} tie points")
        if n:
            kind[_spread_along(mine, xyz_ground, line, int(n))] = CHECK
    return kind


def _spread_along(ties: np.ndarray, xyz_ground: np.ndarray, line: FlightLine, n: int) -> np.ndarray:
    """n of the points ``ties`` evenly spread along ``line``: the middle point of each of n equal runs
    of them sorted along track (then from left to right). -> (n,) point indices."""
    along = (xyz_ground[ties, :2] - line.nadir_xy[0]) @ line.along
    across = (xyz_ground[ties, :2] - line.nadir_xy[0]) @ line.left
    order = ties[np.lexsort((-across, along))]
    return order[((np.arange(n) + 0.5) * len(ties) / n).astype(int)]


def _on_terrain(terrain: Terrain, xy: np.ndarray) -> np.ndarray:
    """Ground points on the terrain surface. xy: (p, 2) -> (p, 3)."""
    return np.column_stack([xy, terrain.z(xy)])


def _visible_pairs(design: SyntheticDesign, xyz0, R, interior, xyz_ground) -> tuple[np.ndarray, np.ndarray]:
    """Which photo sees which point: in front of the camera and inside the usable format.
    xyz0: (n, 3), R: (n, 3, 3), xyz_ground: (p, 3) -> photo_index, point_index (m,), photo-major
    and by point within a photo (the order of np.nonzero on an (n, p) visibility matrix).

    Only the points within reach of a photo are projected (a k-d tree on the ground XY): the
    farthest visible point lies within (Z0 - lowest point) tan(field angle to the format corner +
    tilt) of the nadir, so memory and time grow with the observations, not with photos x points."""
    from scipy.spatial import cKDTree

    if len(xyz0) == 0 or len(xyz_ground) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    half_usable = design.camera.half_usable
    corner = np.arctan(np.hypot(half_usable + abs(interior[1]), half_usable + abs(interior[2])) / interior[0])
    tilt = np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0))  # between the camera axis -R e3 and the plumb line -e3
    reach_angle = np.minimum(corner + tilt, np.radians(89.0))
    height = np.maximum(xyz0[:, 2] - xyz_ground[:, 2].min(), 0.0)
    reach = height * np.tan(reach_angle) * 1.01 + 1.0
    tree = cKDTree(xyz_ground[:, :2])
    near = tree.query_ball_point(xyz0[:, :2], reach, return_sorted=True)
    counts = np.fromiter((len(c) for c in near), dtype=np.int64, count=len(near))
    photo = np.repeat(np.arange(len(xyz0)), counts)
    point = np.fromiter((j for c in near for j in c), dtype=np.int64, count=int(counts.sum()))
    front = in_front(R[photo], xyz0[photo], xyz_ground[point])
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = project(R[photo], xyz0[photo], interior, xyz_ground[point])
    inside = front & np.all(np.abs(xy) <= half_usable, axis=-1)
    return photo[inside], point[inside]


def _require_rays(rays: np.ndarray, ids: list[str]) -> None:
    """Every pass point must be seen by two photos at least. rays: (p,) photos per pass point."""
    bad = np.flatnonzero(rays < 2)
    if len(bad):
        k = bad[0]
        raise ValueError(
            f"design: pass point {ids[k]} is seen by {rays[k]} photo(s); "
            "lower the lateral offset, the relief or the deviations from the ideal flight"
        )
