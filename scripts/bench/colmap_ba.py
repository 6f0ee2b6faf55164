"""The same adjustment by pycolmap's bundle adjustment (COLMAP, Ceres), for comparison.

pycolmap is not a dependency of striptri; it is used by the benchmark only: ``pip install pycolmap``
(measured with pycolmap 4.2.1). Without it the benchmark skips this column.

The striptri project becomes a pycolmap.Reconstruction:

* one camera. Without distortion a PINHOLE camera, f = c / pixel_size pixels; with distortion in
  the ``image`` convention (lens.py: applied to the projected point, k dimensionless) and only
  k1, k2 a RADIAL camera (f, cx, cy, k1, k2), which is the same model. The format is the image
  size. A plate point (x right, y up, mm, origin at the fiducial centre) becomes the pixel
  ``u = width/2 + x / pixel_size, v = height/2 - y / pixel_size`` (origin top left, v down), and the
  principal point ``cx = width/2 + xp / pixel_size, cy = height/2 - yp / pixel_size``.
  pixel_size equals the plate sigma (PIXEL_SIZE, 0.005 mm, for the aerial cases), so one pixel is
  one standard deviation: Ceres' cost ``1/2 sum r^2`` is ``v^T P v / 2``.
* COLMAP's camera looks along +z with y down; striptri's along -z with y up (p = (x, y, -c)).
  With D = diag(1, -1, -1): ``cam_from_world = D R_ground_from_cam^T (X - O)``, i.e. rotation
  D R^T and translation -D R^T O.
* coordinates in striptri's reduced frame (ground minus adjustment.reduction_offset), as striptri
  adjusts them;
* points: every point that takes part in striptri's adjustment (groups.build_batches). Full
  control points at their given coordinates, held constant (the datum, like striptri's fixed
  control); the others start at the least-squares intersection of their rays from the approximate
  orientations and camera (triangulation.intersect_rays, as striptri's bundle starts);
* intrinsics: held, or estimated as striptri estimates them (c free: the focal length; xp, yp
  free: the principal point; k1, k2 free: the extra parameters; elements observed with a sigma
  have no counterpart and are refused); poses start at the project's approximate orientations.

Ceres: linear solver SPARSE_SCHUR forced (COLMAP's automatic choice takes a dense or iterative
solver by image count), trust region Levenberg-Marquardt, the stopping tolerances one of
TOLERANCES (function, gradient, parameter): bench_scale.py sweeps them with the threads and takes as
the peer the fastest run that reaches striptri's solution (issue 29). The earlier benchmark held
Ceres to "1e-16" only, which costs it iterations that no printed digit shows: a handicapped peer.

:func:`prepare` needs striptri (imported there); :func:`load`, :func:`build` and :func:`solve`
need only numpy and pycolmap, so that a process running pycolmap (bench_scale.py's worker) holds
nothing of striptri's.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

PIXEL_SIZE = 0.005  # mm per pixel
# Ceres' stopping tolerances (function, gradient, parameter) swept by bench_scale.py: Ceres' own
# defaults, three steps tighter, and the old benchmark's (issue 29: a handicapped peer)
TOLERANCES = {
    "ceres-default": (1e-6, 1e-10, 1e-8),
    "1e-8": (1e-8, 1e-10, 1e-8),
    "1e-10": (1e-10, 1e-12, 1e-10),
    "1e-12": (1e-12, 1e-14, 1e-12),
    "1e-16": (1e-16, 1e-16, 1e-12),
}
INSTALL_HINT = "pip install pycolmap"
D = np.diag([1.0, -1.0, -1.0])


def pycolmap_module():
    """The pycolmap module, or None when it is not installed."""
    try:
        import pycolmap
    except ImportError:
        return None
    return pycolmap


@dataclass
class ColmapData:
    """What the reconstruction is built from (numpy only, built once per case)."""

    offset: np.ndarray  # (3,) reduction offset
    point_index: np.ndarray  # (p,) striptri points that take part
    xyz_start: np.ndarray  # (p, 3) reduced frame
    constant: np.ndarray  # (p,) bool: full control held fixed
    uv: np.ndarray  # (m, 2) pixels of every image point
    photo_of_row: np.ndarray  # (m,)
    point_of_row: np.ndarray  # (m,) position in point_index, -1 if the point takes no part
    xyz0: np.ndarray  # (n, 3) approximate centres, reduced frame
    R: np.ndarray  # (n, 3, 3) approximate R_ground_from_cam
    camera_model: str  # "PINHOLE" or "RADIAL"
    camera_params: np.ndarray  # COLMAP's: PINHOLE (f, f, cx, cy), RADIAL (f, cx, cy, k1, k2), pixels
    refine: np.ndarray  # (3,) bool: focal length, principal point, extra parameters
    width: int
    height: int
    pixel_size: float  # plate units per pixel


def save(data: ColmapData, path) -> None:
    """ColmapData to an .npz file (for a process that should not import striptri)."""
    np.savez(path, **{f.name: np.asarray(getattr(data, f.name)) for f in fields(ColmapData)})


def load(path) -> ColmapData:
    with np.load(Path(path)) as z:
        values = {f.name: z[f.name] for f in fields(ColmapData)}
    for name, kind in (("camera_model", str), ("width", int), ("height", int), ("pixel_size", float)):
        values[name] = kind(values[name])
    return ColmapData(**values)


def prepare(project, format_mm=230.0, pixel_size: float = PIXEL_SIZE) -> ColmapData:
    """Pixels, start points, camera and datum of a project with one camera and full (fixed)
    control only. format_mm: the image size, square (a number) or (width, height)."""
    from striptri.geometry import lens
    from striptri.geometry.camera import ray_ground
    from striptri.equations.groups import build_batches
    from striptri.model import FULL
    from striptri.equations.parameters import reduction_offset
    from striptri.equations.triangulation import intersect_rays

    if len(project.cameras) != 1:
        raise ValueError("the pycolmap comparison handles one camera")
    interior = project.cameras.interior[0]
    sigma = project.cameras.sigma_interior[0]
    convention = int(project.cameras.convention[0])
    if np.any(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError("the pycolmap comparison estimates a camera element freely or holds it: observed elements "
                         "are not supported")
    free = np.isinf(sigma)
    c, xp, yp = interior[:3]
    offset = reduction_offset(project)
    xyz0 = project.photos.xyz0 - offset
    R = project.photos.R_ground_from_cam
    pts = project.points
    ip = project.image_points
    ideal = lens.ideal_from_observed(ip.xy, interior, convention).xy
    xyz = np.full((len(pts), 3), np.nan)
    for batch in build_batches(project):
        if batch.family == "collinearity":
            xyz[batch.point_index] = pts.xyz_given[batch.point_index] - offset
            continue
        ph, rows = batch.photo_index, batch.image_rows
        r = ray_ground(R[ph], ideal[rows], interior[:3])
        xyz[batch.point_index] = intersect_rays(xyz0[ph], r)
    taking_part = np.flatnonzero(np.isfinite(xyz[:, 0]))
    constant = pts.kind[taking_part] == FULL
    if np.any(np.isfinite(pts.sigma_given[taking_part][constant])):
        raise ValueError("the pycolmap comparison holds control fixed: weighted control is not supported")
    position = np.full(len(pts), -1)
    position[taking_part] = np.arange(len(taking_part))
    width_mm, height_mm = np.broadcast_to(np.asarray(format_mm, dtype=float), (2,))
    width, height = int(round(width_mm / pixel_size)), int(round(height_mm / pixel_size))
    uv = np.column_stack([width / 2 + ip.xy[:, 0] / pixel_size, height / 2 - ip.xy[:, 1] / pixel_size])
    f, cx, cy = c / pixel_size, width / 2 + xp / pixel_size, height / 2 - yp / pixel_size
    others = np.ones(lens.NCP, dtype=bool)
    others[[lens.C, lens.XP, lens.YP, lens.K1, lens.K2]] = False
    radial = bool(free[lens.K1] or free[lens.K2] or interior[lens.K1] or interior[lens.K2])
    if np.any(interior[others] != 0) or np.any(free[others]):
        raise ValueError("the pycolmap comparison supports radial distortion k1, k2 only")
    if radial and convention != lens.IMAGE:
        raise ValueError("the pycolmap comparison needs the image convention of distortion (COLMAP's model)")
    if free[lens.XP] != free[lens.YP] or free[lens.K1] != free[lens.K2]:
        raise ValueError("pycolmap refines xp and yp together, and k1 and k2 together")
    params = [f, cx, cy, interior[lens.K1], interior[lens.K2]] if radial else [f, f, cx, cy]
    return ColmapData(
        offset=offset, point_index=taking_part, xyz_start=xyz[taking_part], constant=constant, uv=uv,
        photo_of_row=ip.photo_index, point_of_row=position[ip.point_index], xyz0=xyz0, R=R,
        camera_model="RADIAL" if radial else "PINHOLE", camera_params=np.array(params, dtype=float),
        refine=np.array([free[lens.C], free[lens.XP], free[lens.K1]]), width=width, height=height,
        pixel_size=float(pixel_size),
    )


def build(pycolmap, data: ColmapData):
    """-> (reconstruction, config, point3D ids (p,))."""
    camera = pycolmap.Camera(model=data.camera_model, width=data.width, height=data.height,
                             params=data.camera_params.tolist(), camera_id=1)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(camera)
    config = pycolmap.BundleAdjustmentConfig()
    if not data.refine.any():
        config.set_constant_cam_intrinsics(1)
    n = len(data.xyz0)
    order = np.argsort(data.photo_of_row, kind="stable")
    starts = np.searchsorted(data.photo_of_row[order], np.arange(n + 1))
    rows_of_photo = [order[starts[i] : starts[i + 1]] for i in range(n)]
    for i in range(n):
        R_cam_from_world = D @ data.R[i].T
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R_cam_from_world), -R_cam_from_world @ data.xyz0[i])
        image = pycolmap.Image(name=f"{i}", keypoints=data.uv[rows_of_photo[i]], camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pose)
        config.add_image(i + 1)
    # tracks: (image id, index of the keypoint in that image) per row
    index_in_image = np.empty(len(data.uv), dtype=int)
    for i in range(n):
        index_in_image[rows_of_photo[i]] = np.arange(len(rows_of_photo[i]))
    rows = np.flatnonzero(data.point_of_row >= 0)
    rows = rows[np.argsort(data.point_of_row[rows], kind="stable")]
    bounds = np.searchsorted(data.point_of_row[rows], np.arange(len(data.point_index) + 1))
    ids = np.empty(len(data.point_index), dtype=np.int64)
    for j in range(len(data.point_index)):
        r = rows[bounds[j] : bounds[j + 1]]
        track = pycolmap.Track([pycolmap.TrackElement(int(data.photo_of_row[k]) + 1, int(index_in_image[k])) for k in r])
        ids[j] = rec.add_point3D(data.xyz_start[j], track)
        if data.constant[j]:
            config.add_constant_point(int(ids[j]))
    return rec, config, ids


def options(pycolmap, threads: int, initial_radius: float | None = None, max_iterations: int = 100,
            refine_intrinsics: bool = False, tolerance: str = "1e-16",
            refine: tuple[bool, bool, bool] | None = None, function_tolerance: float | None = None):
    """COLMAP's bundle adjustment options with intrinsics constant (refine_intrinsics: focal length
    and extra parameters estimated, the principal point held; refine: focal length, principal point,
    extra parameters, overriding refine_intrinsics), SPARSE_SCHUR forced and the stopping
    tolerances TOLERANCES[tolerance] (function_tolerance, if given, instead of its first). initial_radius: Ceres' initial trust region radius (None:
    COLMAP's 1e4)."""
    focal, principal, extra = (refine_intrinsics, False, refine_intrinsics) if refine is None else map(bool, refine)
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = focal
    opts.refine_principal_point = principal
    opts.refine_extra_params = extra
    opts.refine_sensor_from_rig = False
    opts.print_summary = False
    ceres = opts.ceres
    ceres.auto_select_solver_type = False
    ceres.use_gpu = False
    so = ceres.solver_options
    so.linear_solver_type = pycolmap._core.pyceres.LinearSolverType.SPARSE_SCHUR
    so.num_threads = threads
    so.max_num_iterations = max_iterations
    so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = TOLERANCES[tolerance]
    if function_tolerance is not None:
        so.function_tolerance = function_tolerance
    if initial_radius is not None:
        so.initial_trust_region_radius = initial_radius
        so.max_trust_region_radius = max(so.max_trust_region_radius, initial_radius)
    ceres.solver_options = so
    opts.ceres = ceres
    return opts


@dataclass
class ColmapRun:
    seconds: float  # adjuster set-up and solve
    cpu_seconds: float  # the same in CPU time of this process
    ceres_seconds: float  # Ceres' own total time
    build_seconds: float  # the Reconstruction from the project (Python)
    iterations: int
    initial_cost: float
    final_cost: float
    linear_solver: str
    termination: str
    xyz0: np.ndarray  # (n, 3) adjusted centres, ground frame (offset added)
    R: np.ndarray  # (n, 3, 3) adjusted R_ground_from_cam
    xyz_points: np.ndarray  # (p, 3) ground frame, rows of data.point_index
    camera_params: np.ndarray  # COLMAP's camera parameters after the adjustment

    @property
    def vtpv(self) -> float:
        """2 x final cost: one pixel is one sigma (module doc)."""
        return 2.0 * self.final_cost


def run(pycolmap, data: ColmapData, threads: int, initial_radius: float | None = None,
        tolerance: str = "1e-16") -> ColmapRun:
    return solve(pycolmap, data, threads, initial_radius, tolerance)[0]


def solve(pycolmap, data: ColmapData, threads: int, initial_radius: float | None = None, tolerance: str = "1e-16"):
    """Build the reconstruction and run the bundle adjustment (Ceres' tolerances TOLERANCES[tolerance]).
    -> (ColmapRun, reconstruction, adjuster, point3D ids)."""
    t0 = time.perf_counter()
    rec, config, ids = build(pycolmap, data)
    t1, c1 = time.perf_counter(), time.process_time()
    opts = options(pycolmap, threads, initial_radius, refine=tuple(data.refine), tolerance=tolerance)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    summary = adjuster.solve()
    t2, c2 = time.perf_counter(), time.process_time()
    cs = summary.ceres_summary
    n = len(data.xyz0)
    centres = np.array([rec.image(i + 1).projection_center() for i in range(n)]) + data.offset
    R = np.array([rec.image(i + 1).cam_from_world().rotation.matrix() for i in range(n)])
    R_ground_from_cam = np.swapaxes(R, 1, 2) @ D  # (D R^T)^T = R D
    xyz_points = np.array([rec.point3D(int(i)).xyz for i in ids]) + data.offset
    result = ColmapRun(
        seconds=t2 - t1,
        cpu_seconds=c2 - c1,
        ceres_seconds=float(cs.total_time_in_seconds),
        build_seconds=t1 - t0,
        iterations=int(cs.num_successful_steps + cs.num_unsuccessful_steps),
        initial_cost=float(cs.initial_cost),
        final_cost=float(cs.final_cost),
        linear_solver=str(cs.linear_solver_type_used).split(".")[-1],
        termination=str(cs.termination_type).split(".")[-1],
        xyz0=centres,
        R=R_ground_from_cam,
        xyz_points=xyz_points,
        camera_params=np.array(rec.camera(1).params, dtype=float),
    )
    return result, rec, adjuster, ids


def interior_from_params(data: ColmapData, params: np.ndarray) -> dict:
    """striptri's c, xp, yp (plate units) and k1, k2 from COLMAP's camera parameters."""
    ps = data.pixel_size
    if data.camera_model == "RADIAL":
        f, cx, cy, k1, k2 = params
    else:
        f, _, cx, cy = params
        k1 = k2 = 0.0
    return {"c": f * ps, "xp": (cx - data.width / 2) * ps, "yp": (data.height / 2 - cy) * ps, "k1": k1, "k2": k2}


def dense_covariance_bytes(data: ColmapData) -> float:
    """Size of one dense matrix over the pose (and camera) parameters: COLMAP's covariance
    estimate inverts the reduced camera system densely."""
    n = 6 * len(data.xyz0) + len(data.camera_params)
    return 8.0 * n * n


def covariance(pycolmap, rec, adjuster, ids, n_images: int) -> dict:
    """COLMAP's covariance estimate of the adjusted problem (pycolmap.estimate_ba_covariance,
    every parameter: poses, points, camera), then every pose and point covariance taken out of
    it. -> seconds of each step and whether it succeeded."""
    t0 = time.perf_counter()
    opts = pycolmap.BACovarianceOptions(params=pycolmap.BACovarianceOptionsParams.ALL)
    cov = pycolmap.estimate_ba_covariance(opts, rec, adjuster)
    t1 = time.perf_counter()
    if cov is None:
        return {"estimate_seconds": t1 - t0, "ok": False}
    poses = [cov.get_cam_cov_from_world(i + 1) for i in range(n_images)]
    points = [cov.get_point_cov(int(i)) for i in ids]
    t2 = time.perf_counter()
    return {"estimate_seconds": t1 - t0, "extract_seconds": t2 - t1, "ok": True,
            "poses": sum(p is not None for p in poses), "points": sum(p is not None for p in points)}


def main(argv=None) -> int:
    """python scripts/bench/colmap_ba.py PROJECT_DIR OUT.npz [--format W [H]] [--pixel-size P]:
    the ColmapData of a project folder, saved (bench_scale.py runs it in its own process)."""
    import argparse

    from striptri.io import read_project

    ap = argparse.ArgumentParser(description=main.__doc__.splitlines()[0])
    ap.add_argument("project", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--format", type=float, nargs="+", default=[230.0], help="image size, plate units [230]")
    ap.add_argument("--pixel-size", type=float, default=PIXEL_SIZE, help=f"plate units per pixel [{PIXEL_SIZE}]")
    args = ap.parse_args(argv)
    data = prepare(read_project(args.project), args.format if len(args.format) == 2 else args.format[0],
                   args.pixel_size)
    save(data, args.out)
    print(json.dumps({"dense_covariance_bytes": dense_covariance_bytes(data)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
