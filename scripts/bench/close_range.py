"""A synthetic close-range project with long tracks and self-calibration (bench_scale.py's case).

Like the real project of the performance issue: convergent photos all round an object, every
target seen by about 60 % of the photos (~66 rays per target with 115 photos and 150 targets), and
the camera calibrated in the adjustment (c, xp, yp, k1, k2 free). Deterministic: one
``numpy.random.Generator`` from ``seed``, drawn in a fixed order.

Geometry (ground metres, Z up):

* targets: ``n_targets`` retro-reflective targets on a dome (a half-ellipsoid, semi-axes
  ``DOME_AXES``) at Fibonacci-lattice directions above 8 deg of elevation, jittered; each faces
  outwards (its normal is the dome's);
* photos: ``n_photos`` on rings around the dome (elevations ``RING_ELEVATIONS_DEG``, photos shared in
  proportion to the ring's circumference), at ``DISTANCE`` m (+- 5 %) from the aim point, each aimed
  at a point near the dome's centre and rolled by 0, 90, 180 or 270 deg in turn (+- 3 deg), the
  usual network for self-calibration;
* a target is seen by a photo when it is in front, inside the format less a margin, and the ray
  makes less than ``MAX_INCIDENCE_DEG`` with the target's normal (which also hides the far side of
  the convex dome).

Camera: c = 24 mm, format 36 x 24 mm; plate units mm; distortion in the ``image`` convention
(applied to the projected point, k dimensionless, as COLMAP's RADIAL camera), so the pycolmap
comparison solves the same least-squares problem. Truth: c 24.2 mm, xp 0.12 mm, yp -0.08 mm,
k1 -0.06, k2 0.015; approximations: c 24 mm, xp = yp = k1 = k2 = 0, all five free.
Plate noise N(0, sigma_image) per coordinate (sigma_image 0.5 um, a tenth of a 5 um pixel).
Approximate orientations: centres off by N(0, 0.05 m) per axis, omega, phi, kappa by N(0, 1 deg).
Datum and scale: ``n_control`` full control points held fixed (the targets spread most evenly:
farthest-point selection from the first one).

The measurements are made by striptri's own camera model (``camera.project`` for the ideal plate
point, ``lens.observed_from_ideal`` for the distortion), so the project read back reproduces them.

    python scripts/bench/close_range.py OUT_DIR [--photos 115] [--targets 150] [--seed 3]
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from striptri.geometry import lens
from striptri.geometry.camera import in_front
from striptri.geometry.camera import project as project_plate
from striptri.geometry.rotations import R_from_opk, opk_from_R

C_TRUE, XP_TRUE, YP_TRUE, K1_TRUE, K2_TRUE = 24.2, 0.12, -0.08, -0.06, 0.015
C_APPROX = 24.0
FORMAT = (36.0, 24.0)  # mm, x by y
MARGIN = 0.5  # mm inside the format
SIGMA_IMAGE = 0.0005  # mm
DOME_AXES = (1.2, 1.0, 0.5)  # m
MIN_TARGET_ELEVATION_DEG = 8.0
RING_ELEVATIONS_DEG = (20.0, 40.0, 60.0, 75.0)
DISTANCE = 2.8  # m from the aim point
AIM = (0.0, 0.0, 0.2)  # m
MAX_INCIDENCE_DEG = 76.0
APPROX_POSITION_ERROR = 0.05  # m
APPROX_ANGLE_ERROR = 1.0  # deg


@dataclass(frozen=True)
class CloseRange:
    """The true network and the measurements (struct of arrays)."""

    interior: np.ndarray  # (10,) true camera elements (lens.CAMERA_ELEMENTS)
    xyz0: np.ndarray  # (n, 3) true centres
    R_ground_from_cam: np.ndarray  # (n, 3, 3) true rotations
    ring: np.ndarray  # (n,) ring of each photo (its strip id)
    xyz_ground: np.ndarray  # (p, 3) true targets
    control: np.ndarray  # (k,) indices of the full control points
    photo_index: np.ndarray  # (m,) observations, photo-major
    point_index: np.ndarray  # (m,)
    xy_plate: np.ndarray  # (m, 2) measured (noisy) plate coordinates, mm
    xyz0_approx: np.ndarray  # (n, 3)
    R_approx: np.ndarray  # (n, 3, 3)

    @property
    def rays_per_target(self) -> np.ndarray:
        return np.bincount(self.point_index, minlength=len(self.xyz_ground))


def true_interior() -> np.ndarray:
    p = np.zeros(lens.NCP)
    p[[lens.C, lens.XP, lens.YP, lens.K1, lens.K2]] = C_TRUE, XP_TRUE, YP_TRUE, K1_TRUE, K2_TRUE
    return p


def _targets(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (n, 3), outward unit normals (n, 3)) on the dome."""
    golden = np.pi * (3.0 - np.sqrt(5.0))
    k = np.arange(n) + 0.5
    zmin = np.sin(np.radians(MIN_TARGET_ELEVATION_DEG))
    z = 1.0 - k / n * (1.0 - zmin)  # unit-sphere heights, equal areas
    az = golden * k + rng.uniform(-0.15, 0.15, n)
    z = np.clip(z + rng.uniform(-0.3, 0.3, n) * (1.0 - zmin) / n, zmin, 1.0)
    rho = np.sqrt(1.0 - z * z)
    u = np.column_stack([rho * np.cos(az), rho * np.sin(az), z])
    a = np.asarray(DOME_AXES)
    xyz = u * a
    normal = u / a
    return xyz, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def _photos(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centres (n, 3), R_ground_from_cam (n, 3, 3), ring (n,))."""
    elev = np.radians(RING_ELEVATIONS_DEG)
    share = np.cos(elev) / np.cos(elev).sum() * n
    counts = np.floor(share).astype(int)
    counts[np.argsort(share - counts)[::-1][: n - counts.sum()]] += 1
    ring = np.repeat(np.arange(len(elev)), counts)
    az = np.concatenate([(np.arange(c) + 0.5 * (i % 2)) / c * 2 * np.pi for i, c in enumerate(counts)])
    az = az + rng.uniform(-0.02, 0.02, n)
    e = elev[ring] + np.radians(rng.uniform(-2.0, 2.0, n))
    dist = DISTANCE * rng.uniform(0.95, 1.05, n)
    aim = np.asarray(AIM) + rng.uniform(-0.1, 0.1, (n, 3))
    xyz0 = aim + dist[:, None] * np.column_stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.sin(e)])
    back = xyz0 - aim  # the camera looks along -z: z_cam points back from the object
    z_cam = back / np.linalg.norm(back, axis=1, keepdims=True)
    x_cam = np.cross(-z_cam, [0.0, 0.0, 1.0])
    x_cam /= np.linalg.norm(x_cam, axis=1, keepdims=True)
    y_cam = np.cross(z_cam, x_cam)
    R = np.stack([x_cam, y_cam, z_cam], axis=-1)  # columns: camera axes in the ground frame
    roll = np.radians(90.0 * (np.arange(n) % 4) + rng.uniform(-3.0, 3.0, n))
    return xyz0, R @ R_from_opk(np.column_stack([np.zeros(n), np.zeros(n), roll])), ring


def _farthest_points(xyz: np.ndarray, k: int) -> np.ndarray:
    chosen = [0]
    d = np.linalg.norm(xyz - xyz[0], axis=1)
    for _ in range(k - 1):
        j = int(np.argmax(d))
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(xyz - xyz[j], axis=1))
    return np.array(sorted(chosen))


def make_close_range(n_photos: int = 115, n_targets: int = 150, n_control: int = 6, seed: int = 3) -> CloseRange:
    rng = np.random.default_rng(seed)
    interior = true_interior()
    xyz, normal = _targets(n_targets, rng)
    xyz0, R, ring = _photos(n_photos, rng)
    # visibility of every target in every photo (n_photos x n_targets: small here)
    ph, pt = (a.ravel() for a in np.meshgrid(np.arange(n_photos), np.arange(n_targets), indexing="ij"))
    ideal = project_plate(R[ph], xyz0[ph], interior[:3], xyz[pt])
    measured = lens.observed_from_ideal(ideal, interior, lens.IMAGE)
    ray = xyz0[ph] - xyz[pt]
    cos_incidence = np.einsum("mi,mi->m", ray, normal[pt]) / np.linalg.norm(ray, axis=1)
    half = np.asarray(FORMAT) / 2 - MARGIN
    seen = (in_front(R[ph], xyz0[ph], xyz[pt]) & np.all(np.abs(measured) <= half, axis=1)
            & (cos_incidence >= np.cos(np.radians(MAX_INCIDENCE_DEG))))
    photo_index, point_index = ph[seen], pt[seen]
    xy = measured[seen] + rng.normal(0.0, SIGMA_IMAGE, (int(seen.sum()), 2))
    rays = np.bincount(point_index, minlength=n_targets)
    if rays.min() < 2:
        raise ValueError(f"close range: {int((rays < 2).sum())} targets seen by fewer than two photos")
    xyz0_approx = xyz0 + rng.normal(0.0, APPROX_POSITION_ERROR, xyz0.shape)
    R_approx = R @ R_from_opk(np.radians(rng.normal(0.0, APPROX_ANGLE_ERROR, (n_photos, 3))))
    return CloseRange(
        interior=interior, xyz0=xyz0, R_ground_from_cam=R, ring=ring, xyz_ground=xyz,
        control=_farthest_points(xyz, n_control), photo_index=photo_index, point_index=point_index,
        xy_plate=xy, xyz0_approx=xyz0_approx, R_approx=R_approx,
    )


def photo_ids(n: int) -> list[str]:
    return [f"P{i + 1:03d}" for i in range(n)]


def target_ids(n: int) -> list[str]:
    return [f"T{j + 1:03d}" for j in range(n)]


def _write(path: Path, header: list[str], rows) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _opk_deg(R: np.ndarray) -> np.ndarray:
    return np.degrees(opk_from_R(R))


def write_close_range(out: Path, net: CloseRange) -> Path:
    """The project folder (docs/file-formats.md) with truth/photos.csv, truth/points.csv and
    truth/cameras.csv. Floats written with repr (round trip exact)."""
    out = Path(out)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    pids, tids = photo_ids(len(net.xyz0)), target_ids(len(net.xyz_ground))
    (out / "project.toml").write_text(
        "# synthetic close-range block (scripts/bench/close_range.py)\n[units]\nangles = \"deg\"\n"
        "rotation = \"omega-phi-kappa\"\n\n[defaults]\n"
        f"sigma_image = {SIGMA_IMAGE!r}\n"
    )
    _write(out / "cameras.csv",
           ["camera_id", "c", "xp", "yp", "k1", "k2", "distortion", "sigma_c", "sigma_xp", "sigma_yp", "sigma_k1",
            "sigma_k2"],
           [["CAM", repr(C_APPROX), "0.0", "0.0", "0.0", "0.0", "image", "free", "free", "free", "free", "free"]])
    angles = _opk_deg(net.R_approx)
    _write(out / "photos.csv", ["photo_id", "camera_id", "strip_id", "X0", "Y0", "Z0", "omega", "phi", "kappa"],
           [[pids[i], "CAM", str(net.ring[i] + 1), *map(repr, net.xyz0_approx[i].tolist()),
             *map(repr, angles[i].tolist())] for i in range(len(pids))])
    _write(out / "image_points.csv", ["photo_id", "point_id", "x", "y"],
           [[pids[i], tids[j], repr(x), repr(y)]
            for i, j, (x, y) in zip(net.photo_index.tolist(), net.point_index.tolist(), net.xy_plate.tolist())])
    _write(out / "control.csv", ["point_id", "kind", "X", "Y", "Z"],
           [[tids[j], "XYZ", *map(repr, net.xyz_ground[j].tolist())] for j in net.control.tolist()])
    true_angles = _opk_deg(net.R_ground_from_cam)
    _write(out / "truth" / "photos.csv", ["photo_id", "X0", "Y0", "Z0", "omega", "phi", "kappa"],
           [[pids[i], *map(repr, net.xyz0[i].tolist()), *map(repr, true_angles[i].tolist())] for i in range(len(pids))])
    control = set(net.control.tolist())
    _write(out / "truth" / "points.csv", ["point_id", "kind", "X", "Y", "Z"],
           [[tids[j], "XYZ" if j in control else "tie", *map(repr, net.xyz_ground[j].tolist())]
            for j in range(len(tids))])
    _write(out / "truth" / "cameras.csv", ["camera_id", "c", "xp", "yp", "k1", "k2"],
           [["CAM", *map(repr, net.interior[[lens.C, lens.XP, lens.YP, lens.K1, lens.K2]].tolist())]])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--photos", type=int, default=115)
    ap.add_argument("--targets", type=int, default=150)
    ap.add_argument("--control", type=int, default=6)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args(argv)
    net = make_close_range(args.photos, args.targets, args.control, args.seed)
    write_close_range(args.out, net)
    rays = net.rays_per_target
    print(f"wrote {args.out}: {len(net.xyz0)} photos, {len(net.xyz_ground)} targets ({len(net.control)} full "
          f"control), {len(net.photo_index)} plate measurements, rays per target {rays.mean():.1f} "
          f"(min {rays.min()}, max {rays.max()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
