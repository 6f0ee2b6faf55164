"""A synthetic close-range project with long tracks and self-calibration (the third case of the issue).

115 convergent photos on three rings around a target field of 150 targets, each target seen by
about 66 photos; one camera with c, xp, yp, k1, k2 free (the measurements carry a true radial
distortion; c starts 0.2 mm off, xp, yp, k1, k2 from 0); six full control points held fixed; plate
sigma 1 um. The geometry:

* targets: a 2 m x 2 m x 0.6 m field (a wall with relief: X, Y in [-1, 1] m, Z in [0, 0.6] m);
* photos: rings of radius 4.0, 3.6 and 3.2 m at heights 1.5, 2.5 and 3.5 m (45, 40 and 30
  photos), every photo looking at a point near the field's centre, rolled by 0, 90, 180 or 270 deg
  in turn (the rolls separate the principal point from the exterior elements);
* camera: c = 24 mm on a 36 x 24 mm format (a target is seen when it projects inside the format and
  lies in front); a target of each photo's view is dropped at random with probability 0.43, so
  tracks are about 66 rays long;
* approximations: centres off by N(0, 5 cm), angles by N(0, 0.5 deg).

    python scripts/bench/close_range_case.py --out DIR [--seed 7]

Writes DIR as a project folder (striptri.io.write_project) with DIR/truth/photos.csv and points.csv.
"""

from __future__ import annotations

import argparse

import numpy as np

from striptri.geometry import lens
from striptri import model
from striptri.geometry.camera import in_front
from striptri.geometry.camera import project as project_plate
from striptri.io import write_project
from striptri.geometry.rotations import R_from_opk, opk_from_R

C_TRUE = 24.0  # mm
FORMAT = (36.0, 24.0)  # mm
K1_TRUE, K2_TRUE = 6e-5, -4e-8  # plate convention, mm units: about 0.2 mm at the format's corner
SIGMA_IMAGE = 0.001  # mm
RINGS = ((4.0, 1.5, 45), (3.6, 2.5, 40), (3.2, 3.5, 30))  # radius, height, photos
N_TARGETS = 150
DROP = 0.43


def _look_at(O: np.ndarray, target: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """R_ground_from_cam of cameras at O looking at target (camera -z along the view), rolled."""
    z = O - target
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    R0 = np.stack([x, y, z], axis=2)  # columns: camera axes in the ground frame
    c, s = np.cos(roll), np.sin(roll)
    Rz = np.zeros((len(roll), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    return R0 @ Rz


def close_range_project(seed: int = 7):
    """(project, truth tables) of the case in the module doc."""
    rng = np.random.default_rng(seed)
    targets = np.column_stack([rng.uniform(-1, 1, N_TARGETS), rng.uniform(-1, 1, N_TARGETS),
                               rng.uniform(0, 0.6, N_TARGETS)])
    O, look = [], []
    for radius, height, n in RINGS:
        a = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, 2 * np.pi / n)
        O.append(np.column_stack([radius * np.cos(a), radius * np.sin(a), np.full(n, height)]))
        look.append(rng.normal(0, 0.15, (n, 3)) * [1, 1, 0.5] + [0, 0, 0.3])
    O, look = np.vstack(O), np.vstack(look)
    n_ph = len(O)
    R = _look_at(O, look, np.radians(90.0 * (np.arange(n_ph) % 4)))
    interior = np.array([C_TRUE, 0.0, 0.0])
    prm = np.zeros(lens.NCP)
    prm[:3] = interior
    prm[lens.K1], prm[lens.K2] = K1_TRUE, K2_TRUE

    ph, pt = np.meshgrid(np.arange(n_ph), np.arange(N_TARGETS), indexing="ij")
    ph, pt = ph.ravel(), pt.ravel()
    xy_ideal = project_plate(R[ph], O[ph], interior, targets[pt])
    seen = (in_front(R[ph], O[ph], targets[pt]) & (np.abs(xy_ideal[:, 0]) < FORMAT[0] / 2)
            & (np.abs(xy_ideal[:, 1]) < FORMAT[1] / 2) & (rng.uniform(size=len(ph)) > DROP))
    ph, pt, xy_ideal = ph[seen], pt[seen], xy_ideal[seen]
    xy = lens.observed_from_ideal(xy_ideal, prm, lens.PLATE) + rng.normal(0, SIGMA_IMAGE, xy_ideal.shape)
    order = np.lexsort((pt, ph))
    ph, pt, xy = ph[order], pt[order], xy[order]

    control = np.zeros(N_TARGETS, dtype=bool)
    control[rng.choice(N_TARGETS, 6, replace=False)] = True
    kind = np.where(control, model.FULL, model.TIE)
    point_ids = [f"T{i:03d}" for i in range(N_TARGETS)]
    photo_ids = [f"P{i:03d}" for i in range(n_ph)]
    opk = opk_from_R(R) + rng.normal(0, np.radians(0.5), (n_ph, 3))
    start = prm.copy()
    start[0] += 0.2
    start[3:] = 0.0
    sigma_cam = np.full((1, lens.NCP), np.nan)
    sigma_cam[0, [lens.C, lens.XP, lens.YP, lens.K1, lens.K2]] = np.inf
    project = model.Project(
        cameras=model.Cameras(["CAM"], start[None, :], sigma_cam),
        photos=model.Photos(photo_ids, np.zeros(n_ph, dtype=int), ["1"] * n_ph, O + rng.normal(0, 0.05, O.shape),
                            R_from_opk(opk), opk, np.full((n_ph, 3), np.nan), np.full((n_ph, 3), np.nan)),
        image_points=model.ImagePoints(ph, pt, xy, np.full(xy.shape, SIGMA_IMAGE)),
        points=model.ObjectPoints(point_ids, kind, np.where(control[:, None], targets, np.nan),
                                  np.full((N_TARGETS, 3), np.nan)),
        settings=model.ProjectSettings(sigma_image=SIGMA_IMAGE),
    )
    opk_true = np.degrees(opk_from_R(R))
    truth = {
        "photos.csv": {"photo_id": photo_ids, "X0": O[:, 0], "Y0": O[:, 1], "Z0": O[:, 2],
                       "omega": opk_true[:, 0], "phi": opk_true[:, 1], "kappa": opk_true[:, 2]},
        "points.csv": {"point_id": point_ids, "X": targets[:, 0], "Y": targets[:, 1], "Z": targets[:, 2]},
    }
    return project, truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    project, truth = close_range_project(args.seed)
    write_project(args.out, project, truth)
    rays = np.bincount(project.image_points.point_index)
    print(f"{args.out}: {len(project.photos)} photos, {len(project.points)} targets, "
          f"{len(project.image_points)} image points, rays per target {rays.min()}-{rays.max()} (mean {rays.mean():.1f})")


if __name__ == "__main__":
    main()
