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
    ph, cams = project.photos, project.cameras
    cam = ph.camera_index[photo]
    p = np.concatenate([plate - cams.interior[cam, 1:3], -cams.interior[cam, :1]], 1)
    r = np.einsum("nij,nj->ni", ph.R_ground_from_cam[photo], p)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    O = ph.xyz0[photo]
    P = np.eye(3) - r[:, :, None] * r[:, None, :]  # projector across each ray
    A = np.zeros((n_tracks, 3, 3))
    b = np.zeros((n_tracks, 3))
    np.add.at(A, track, P)
    np.add.at(b, track, np.einsum("nij,nj->ni", P, O))
    count = np.bincount(track, minlength=n_tracks)
    ok = count >= 2
    X = np.full((n_tracks, 3), np.nan)
    with np.errstate(invalid="ignore"):
        good = ok & (np.abs(np.linalg.det(A)) > 1e-12)
        X[good] = np.linalg.solve(A[good], b[good][..., None])[..., 0]
    d = X[track] - O
    miss = np.linalg.norm(d - np.einsum("ni,ni->n", d, r)[:, None] * r, axis=1)
    far = np.zeros(n_tracks)
    np.maximum.at(far, track, np.nan_to_num(miss, nan=np.inf))
    behind = np.zeros(n_tracks, dtype=bool)
    np.logical_or.at(behind, track, ~(np.einsum("ni,ni->n", d, r) > 0))
    above = float(np.median(np.abs(ph.xyz0[:, 2] - h)))
    with np.errstate(invalid="ignore"):
        level = np.abs(X[:, 2] - h) <= HEIGHT_RANGE * above
    return good & (far <= tolerance * above) & ~behind & level
