"""The tracks checked with the approximate orientations: false ones do not meet on the ground."""

from __future__ import annotations

import numpy as np

from ..model import Project

HEIGHT_RANGE = 0.3  # a tie point further from the terrain height than this share of the flying height is false


def ground_consistent(project: Project, track, photo, plate, h: float, tolerance: float, n_tracks: int) -> np.ndarray:
    """(n_tracks,) bool: the tracks whose rays, with the approximate orientations, meet. Each track
    is intersected (least squares over its rays); it is false when a ray passes further from the
    intersection than ``tolerance`` times the height above the terrain (approximations within
    about 3 degrees), when the intersection lies behind a photo, or when it lies further from the
    terrain height h than HEIGHT_RANGE times the height above it: a false match along the
    epipolar line of a flat scene passes the epipolar test and its rays do meet, but hundreds of
    metres above or below the ground (on the flat rendered block of tests/test_match_command.py,
    7 of 3,857 tracks). A ray's miss distance, unlike its footprint on a plane, does not grow with
    the relief: tracks on hills seen from two strips are kept."""
    ph = project.photos
    track = np.asarray(track, dtype=np.int64)
    r = _unit_rays(project, photo, plate)
    O = ph.xyz0[photo]
    count = np.bincount(track, minlength=n_tracks)
    # each track's intersection: sum (I - r r^T) X = sum (I - r r^T) O, summed per track by bincount
    # (no (rays, 3, 3) array: the block's rays run into millions)
    A = np.zeros((n_tracks, 3, 3))
    for i in range(3):
        A[:, i, i] = count
        for j in range(i, 3):
            s = np.bincount(track, weights=r[:, i] * r[:, j], minlength=n_tracks)
            A[:, i, j] -= s
            if j != i:
                A[:, j, i] -= s
    along = np.einsum("ni,ni->n", r, O)
    b = np.column_stack([np.bincount(track, weights=O[:, k] - r[:, k] * along, minlength=n_tracks)
                         for k in range(3)])
    ok = count >= 2
    X = np.full((n_tracks, 3), np.nan)
    with np.errstate(invalid="ignore"):
        good = ok & (np.abs(np.linalg.det(A)) > 1e-12)
        X[good] = np.linalg.solve(A[good], b[good][..., None])[..., 0]
    d = X[track] - O
    ahead = np.einsum("ni,ni->n", d, r)
    miss = np.linalg.norm(d - ahead[:, None] * r, axis=1)
    far = np.zeros(n_tracks)
    np.maximum.at(far, track, np.nan_to_num(miss, nan=np.inf))
    behind = np.bincount(track, weights=~(ahead > 0), minlength=n_tracks) > 0
    above = float(np.median(np.abs(ph.xyz0[:, 2] - h)))
    with np.errstate(invalid="ignore"):
        level = np.abs(X[:, 2] - h) <= HEIGHT_RANGE * above
    return good & (far <= tolerance * above) & ~behind & level


def _unit_rays(project: Project, photo: np.ndarray, plate: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """(n, 3) unit ground directions of the rays (photo, plate), with the approximate orientations;
    the rotations are gathered ``chunk`` rays at a time."""
    ph, cams = project.photos, project.cameras
    r = np.empty((len(photo), 3))
    for s in range(0, len(photo), chunk):
        k = photo[s:s + chunk]
        cam = ph.camera_index[k]
        p = np.concatenate([plate[s:s + chunk] - cams.interior[cam, 1:3], -cams.interior[cam, :1]], 1)
        r[s:s + chunk] = np.einsum("nij,nj->ni", ph.R_ground_from_cam[k], p)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    return r
