"""The benchmark cases: synthetic strips and blocks with full control only.

Every case is made by striptri's own generator (striptri.simulate) with one design:

* camera c = 152 mm, format 230 mm; flying height 1500 m; forward overlap 60 %, sidelap 30 %;
* von Gruber pass points at every nadir plus ``EXTRA_TIES`` random tie points per model;
* plate noise sigma 0.005 mm (stated so in the project);
* approximations: centres off by N(0, 3 m) per axis, omega, phi, kappa off by N(0, 0.5 deg);
* control: full (XYZ) points only, held fixed (sigma 0). A strip has layout ``every-k`` with
  ``every_k_kind="XYZ"`` (the corners of the first and last model and the lateral points of every
  ``EVERY_K``-th model); a block has layout ``perimeter`` (XYZ around the perimeter every ``EVERY_K``
  models) with its interior height points turned into tie points.

Why full control only: pycolmap can hold a whole 3D point constant but not one coordinate of it,
so a height point has no counterpart there; with full control only both programs solve the same
least-squares problem (the comparison in bench_adjust.py needs that).

Strips longer than 999 photos: FlightDesign allows at most 999 photos per strip (three-digit photo
numbers), and ``simulate.truth.make_truth`` tests the visibility of every point in every photo,
an (n_photos x n_points) computation that does not fit in memory for 10,000 photos. For those
:func:`long_strip_truth` builds the same truth from the same random draws but tests each point
only against the photos near it; :func:`check_long_strip_generator` shows that it reproduces
``make_truth`` exactly on a strip short enough for both.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.geometry.camera import in_front
from striptri.geometry.camera import project as project_plate
from striptri.simulate import (
    CameraDesign,
    ControlDesign,
    FlightDesign,
    NoiseOptions,
    PointDesign,
    SyntheticDesign,
    Truth,
    make_truth,
    perturb,
)
from striptri.simulate import truth as truth_module
from striptri.simulate.terrain import make_terrain

SIGMA_IMAGE = 0.005  # mm
APPROX_POSITION_ERROR = 3.0  # m
APPROX_ANGLE_ERROR = 0.5  # deg
EXTRA_TIES = 4  # per model
EVERY_K = 4  # models between control columns
MAX_PHOTOS_PER_STRIP = 999  # FlightDesign's limit
NEIGHBOURS = 4  # photos on either side tested for visibility by long_strip_truth


@dataclass(frozen=True)
class Case:
    """name: e.g. strip-100; kind: "strip" or "block"; n_photos per strip, n_strips."""

    name: str
    kind: str
    n_photos: int
    n_strips: int = 1

    @property
    def total_photos(self) -> int:
        return self.n_photos * self.n_strips


CASES = {
    "strip-100": Case("strip-100", "strip", 100),
    "strip-1000": Case("strip-1000", "strip", 1000),
    "strip-10000": Case("strip-10000", "strip", 10000),
    "block-100": Case("block-100", "block", 20, 5),
    "block-1000": Case("block-1000", "block", 100, 10),
}
QUICK = ("strip-100", "block-100")


def design_of(case: Case) -> SyntheticDesign:
    layout = "every-k" if case.kind == "strip" else "perimeter"
    flight = FlightDesign(
        n_photos=min(case.n_photos, MAX_PHOTOS_PER_STRIP), n_strips=case.n_strips, overlap=0.6, sidelap=0.3
    )
    if case.n_photos > MAX_PHOTOS_PER_STRIP:
        flight = copy.copy(flight)
        object.__setattr__(flight, "n_photos", case.n_photos)  # past the 3-digit photo numbers (module doc)
    return SyntheticDesign(
        camera=CameraDesign(),
        flight=flight,
        points=PointDesign(extra_ties_per_model=EXTRA_TIES),
        control=ControlDesign(layout=layout, every_k=EVERY_K, every_k_kind="XYZ"),
    )


NOISE = NoiseOptions(
    sigma_image=SIGMA_IMAGE, approx_position_error=APPROX_POSITION_ERROR, approx_angle_error=APPROX_ANGLE_ERROR
)


def make_case(case: Case, seed: int) -> tuple[model.Project, np.ndarray, np.ndarray]:
    """-> (project, true centres (n, 3), true R_ground_from_cam (n, 3, 3)).

    Same seeding as simulate.simulate_project: one SeedSequence spawned into truth and noise."""
    design = design_of(case)
    truth_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(truth_seed)
    truth = long_strip_truth(design, rng) if case.n_photos > MAX_PHOTOS_PER_STRIP else make_truth(design, rng)
    project = full_control_only(perturb(truth, NOISE, np.random.default_rng(noise_seed)))
    return project, truth.xyz0, truth.R_ground_from_cam


def full_control_only(project: model.Project) -> model.Project:
    """Height and plan points become tie points (module doc)."""
    pts = project.points
    partial = (pts.kind == model.HEIGHT) | (pts.kind == model.PLAN)
    if not partial.any():
        return project
    kind = np.where(partial, model.TIE, pts.kind)
    xyz_given = np.where(partial[:, None], np.nan, pts.xyz_given)
    sigma_given = np.where(partial[:, None], np.nan, pts.sigma_given)
    return replace(project, points=replace(pts, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given))


# --- strips longer than FlightDesign allows -----------------------------------------------------


def long_strip_truth(design: SyntheticDesign, rng: np.random.Generator) -> Truth:
    """make_truth for one strip (no single-photo points, no check points), testing each point only
    against the NEIGHBOURS photos on either side of its nearest nadir. Same draws in the same
    order as make_truth, so the same truth whenever no point is seen from farther away."""
    camera, flight = design.camera, design.flight
    assert flight.n_strips == 1 and design.control.n_single_photo == 0 and design.control.n_check == 0
    interior = np.array([camera.c, camera.xp, camera.yp])
    terrain = make_terrain(design.terrain, camera.format * design.scale, rng)
    lines = truth_module._flight_lines(design)
    line = lines[0]
    xyz0, R = truth_module._true_photos(design, lines, rng)
    ids, kind, xy = truth_module._pass_points(design, lines)
    xyz_pass = truth_module._on_terrain(terrain, xy)
    tie_ids, tie_xyz = _extra_ties_windowed(design, line, terrain, xyz0, R, interior, rng)
    xyz_ground = np.concatenate([xyz_pass, tie_xyz])
    photo_index, point_index = _visible_pairs(design, line, xyz0, R, interior, xyz_ground)
    rays = np.bincount(point_index, minlength=len(xyz_ground))
    if np.any(rays[: len(ids)] < 2):
        raise ValueError("long strip: a pass point is seen by fewer than two photos")
    kind = np.concatenate([kind, np.full(len(tie_ids), model.TIE)]).astype(int)
    return Truth(
        design=design,
        terrain=terrain,
        interior=interior,
        photo_ids=list(line.photo_ids),
        strip_ids=[line.strip_id] * len(line.photo_ids),
        xyz0=xyz0,
        R_ground_from_cam=R,
        point_ids=ids + tie_ids,
        kind=kind,
        xyz_ground=xyz_ground,
        photo_index=photo_index,
        point_index=point_index,
        xy_plate=project_plate(R[photo_index], xyz0[photo_index], interior, xyz_ground[point_index]),
    )


def _nearest_nadir(design: SyntheticDesign, line, xyz_ground: np.ndarray) -> np.ndarray:
    along = (xyz_ground[:, :2] - line.nadir_xy[0]) @ line.along
    return np.clip(np.rint(along / design.base), 0, len(line.nadir_xy) - 1).astype(int)


def _visible_pairs(design, line, xyz0, R, interior, xyz_ground):
    """(photo, point) pairs that see each other, photo-major like np.nonzero of make_truth's mask."""
    n = len(xyz0)
    near = _nearest_nadir(design, line, xyz_ground)
    offsets = np.arange(-NEIGHBOURS, NEIGHBOURS + 1)
    photo = (near[:, None] + offsets[None, :]).ravel()
    point = np.repeat(np.arange(len(xyz_ground)), len(offsets))
    keep = (photo >= 0) & (photo < n)
    photo, point = photo[keep], point[keep]
    seen = _sees(design, xyz0[photo], R[photo], interior, xyz_ground[point])
    photo, point = photo[seen], point[seen]
    order = np.lexsort((point, photo))
    return photo[order], point[order]


def _sees(design, O, R, interior, X) -> np.ndarray:
    """make_truth's visibility test (in front, inside the usable format), pair by pair."""
    front = in_front(R, O, X)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = project_plate(R, O, interior, X)
    return front & np.all(np.abs(xy) <= design.camera.half_usable, axis=-1)


def _extra_ties_windowed(design, line, terrain, xyz0, R, interior, rng):
    """simulate.truth._extra_ties for one strip, visibility tested against nearby photos only."""
    n = design.points.extra_ties_per_model
    if n == 0:
        return [], np.zeros((0, 3))
    half = design.camera.half_usable * design.scale
    base = design.base
    shrink = truth_module._TIE_AREA_SHRINK
    n_photos = len(line.photo_ids)
    ids, xyz = [], []
    for k in range(n_photos - 1):
        centre = (line.nadir_xy[k] + line.nadir_xy[k + 1]) / 2
        n_try = 4 * n
        a = rng.uniform(-1.0, 1.0, n_try) * shrink * (half - base / 2)
        b = rng.uniform(-1.0, 1.0, n_try) * shrink * half
        candidates = truth_module._on_terrain(terrain, centre + a[:, None] * line.along + b[:, None] * line.left)
        near = np.arange(max(k - NEIGHBOURS, 0), min(k + 1 + NEIGHBOURS, n_photos))
        seen = _sees(design, xyz0[near][:, None], R[near][:, None], interior, candidates[None])
        good = np.flatnonzero(seen.sum(0) >= 2)
        if len(good) < n:
            raise ValueError("long strip: cannot place the extra tie points inside the overlap")
        ids += [f"T{line.photo_ids[k]}_{i + 1:02d}" for i in range(n)]
        xyz.append(candidates[good[:n]])
    return ids, np.concatenate(xyz)


def check_long_strip_generator(n_photos: int = 100, seed: int = 7) -> bool:
    """long_strip_truth equals make_truth on a strip both can make."""
    design = design_of(Case("check", "strip", n_photos))
    a = make_truth(design, np.random.default_rng(seed))
    b = long_strip_truth(design, np.random.default_rng(seed))
    return (
        a.point_ids == b.point_ids
        and a.photo_ids == b.photo_ids
        and np.array_equal(a.kind, b.kind)
        and np.array_equal(a.photo_index, b.photo_index)
        and np.array_equal(a.point_index, b.point_index)
        and np.allclose(a.xyz_ground, b.xyz_ground, rtol=0, atol=1e-9)
        and np.allclose(a.xy_plate, b.xy_plate, rtol=0, atol=1e-12)
    )
