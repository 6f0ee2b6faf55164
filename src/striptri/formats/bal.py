"""Bundle Adjustment in the Large (BAL) problems: reader and cost function (docs/formats.md).

File layout (Agarwal et al., https://grail.cs.washington.edu/projects/bal/):

* line 1: ``ncam npts nobs``;
* ``nobs`` lines ``cam pt x y``: observed image coordinates in pixels, origin at the image centre,
  y up (camera and point indices are 0-based);
* ``9 ncam`` numbers, per camera: rotation vector (3, Rodrigues, world-to-camera), t (3), f, k1, k2;
* ``3 npts`` numbers, per point: X, Y, Z.

Parameters may stand one per line (the published files) or several per line. Blank lines are
skipped. A problem needs at least one camera, one point and one observation. The counts of the
header are checked against the size of the file before anything is allocated: an observation line
takes at least MIN_OBSERVATION_BYTES bytes, a parameter MIN_NUMBER_BYTES; a header announcing more
than twice what the file can hold (and more than HEADER_SLACK_BYTES) is an error naming the header
line (a header claiming 10^12 observations is not a MemoryError). A file that is merely short is
read up to its end and the error names the line where it ends. Memory follows the size of the
file, never the header. Any other deviation is an :class:`InputError` naming the file, the line
and the reason.

Projection as BAL defines it: ``P = R X + t``, ``p = -P / P_z``,
``x = f (1 + k1 |p|^2 + k2 |p|^4) p``; residual = predicted - observed; cost = 0.5 sum r^2.
The camera looks down its -z axis, y up: the diapositive convention of striptri.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from striptri.errors import InputError
from striptri.io.csvtable import read_input_bytes
from striptri.geometry.rotations import exp_so3

# the fewest bytes an observation line "c p x y\n" and a parameter "v\n" take in a BAL file, and
# the margin below which a short file is read to its end (its last line named) rather than its header
MIN_OBSERVATION_BYTES = 8
MIN_NUMBER_BYTES = 2
HEADER_SLACK_BYTES = 1 << 20



@dataclass(frozen=True)
class BalProblem:
    """A BAL problem as struct of arrays.

    rotation_cam_from_world: (ncam, 3) rotation vectors of R (P = R X + t); t_cam_from_world:
    (ncam, 3); f: (ncam,) pixels; k1, k2: (ncam,) radial distortion of the BAL model;
    xyz_world: (npts, 3); camera_index, point_index: (nobs,) 0-based; xy_pixel: (nobs, 2) observed.
    camera_lines: (ncam,) line of the file where each camera's parameters start (for messages).
    """

    path: Path | None
    rotation_cam_from_world: np.ndarray
    t_cam_from_world: np.ndarray
    f: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    xyz_world: np.ndarray
    camera_index: np.ndarray
    point_index: np.ndarray
    xy_pixel: np.ndarray
    camera_lines: np.ndarray

    @property
    def n_cameras(self) -> int:
        return len(self.f)

    @property
    def n_points(self) -> int:
        return len(self.xyz_world)

    @property
    def n_observations(self) -> int:
        return len(self.camera_index)

    def R_cam_from_world(self) -> np.ndarray:
        """(ncam, 3, 3) rotation matrices of the rotation vectors."""
        return exp_so3(self.rotation_cam_from_world)


def bal_predict(problem: BalProblem) -> np.ndarray:
    """Predicted pixel coordinates of every observation by the BAL model. -> (nobs, 2)."""
    R = problem.R_cam_from_world()
    cam, pt = problem.camera_index, problem.point_index
    P = np.einsum("nij,nj->ni", R[cam], problem.xyz_world[pt]) + problem.t_cam_from_world[cam]
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    scale = problem.f[cam] * (1.0 + problem.k1[cam] * r2 + problem.k2[cam] * r2 * r2)
    return scale[:, None] * p


def bal_residuals(problem: BalProblem) -> np.ndarray:
    """BAL residuals, predicted - observed, pixels. -> (nobs, 2)."""
    return bal_predict(problem) - problem.xy_pixel


def bal_cost(problem: BalProblem) -> float:
    """BAL cost 0.5 sum r^2 over all residual components (pixels^2)."""
    r = bal_residuals(problem)
    return 0.5 * float(np.sum(r * r))


def read_bal(path: str | Path) -> BalProblem:
    """Read a BAL problem file (module doc). Raises InputError(file, line, reason); writes nothing."""
    path = Path(path)
    raw = read_input_bytes(path, "is a folder, not a BAL problem file")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(path, line, "not a BAL text file (non-ASCII bytes)") from None
    lines = [(n, line.split()) for n, line in enumerate(text.splitlines(), start=1)]
    lines = [(n, tokens) for n, tokens in lines if tokens]
    if not lines:
        raise InputError(path, None, "empty file (a BAL problem starts with 'ncam npts nobs')")

    header_line, header = lines[0]
    if len(header) != 3:
        raise InputError(path, header_line, f"header must be 'ncam npts nobs' (3 integers), found {len(header)} fields")
    ncam, npts, nobs = (_count(path, header_line, name, tok) for name, tok in zip(("ncam", "npts", "nobs"), header))
    if min(ncam, npts, nobs) == 0:
        raise InputError(path, header_line, f"header '{' '.join(header)}': a BAL problem needs at least one camera, "
                                            "one point and one observation")
    n_params = 9 * ncam + 3 * npts
    need = MIN_OBSERVATION_BYTES * nobs + MIN_NUMBER_BYTES * n_params
    if need > max(2 * len(raw), HEADER_SLACK_BYTES):
        raise InputError(path, header_line, f"the header announces {ncam} cameras, {npts} points and {nobs} "
                                            f"observations, which take at least {need} bytes; the file has "
                                            f"{len(raw)} (a wrong header, or a file cut short)")

    obs_lines = lines[1 : 1 + nobs]
    if len(obs_lines) < nobs:
        last = lines[-1][0]
        raise InputError(path, last, f"file ends after {len(obs_lines)} of {nobs} observations (the header, line "
                                     f"{header_line}, announces {nobs})")
    # nobs observation lines exist: the arrays below are no larger than the file
    camera_index = np.empty(nobs, dtype=np.int64)
    point_index = np.empty(nobs, dtype=np.int64)
    xy = np.empty((nobs, 2))
    for i, (n, tokens) in enumerate(obs_lines):
        if len(tokens) != 4:
            raise InputError(path, n, f"observation must be 'camera point x y' (4 fields), found {len(tokens)}")
        cam = _index(path, n, "camera", tokens[0], ncam)
        pt = _index(path, n, "point", tokens[1], npts)
        camera_index[i], point_index[i] = cam, pt
        xy[i, 0] = parse_number(path, n, "x", tokens[2])
        xy[i, 1] = parse_number(path, n, "y", tokens[3])

    short = sum(len(tokens) for _, tokens in lines[1 + nobs :]) < n_params  # reported after the numbers are checked
    values = np.empty(0 if short else n_params)
    value_lines = np.empty(0 if short else n_params, dtype=np.int64)
    k = 0
    for n, tokens in lines[1 + nobs :]:
        for tok in tokens:
            if k == n_params:
                raise InputError(path, n, f"more numbers than the {n_params} parameters of {ncam} cameras and {npts} points")
            what = "camera parameter" if k < 9 * ncam else "point coordinate"
            value = parse_number(path, n, what, tok)
            if not short:
                values[k], value_lines[k] = value, n
            k += 1
    if k < n_params:
        raise InputError(path, lines[-1][0], f"file ends after {k} of the {n_params} parameters "
                                             f"(9 per camera, 3 per point)")
    cams = values[: 9 * ncam].reshape(ncam, 9)
    return BalProblem(
        path=path,
        rotation_cam_from_world=cams[:, 0:3].copy(),
        t_cam_from_world=cams[:, 3:6].copy(),
        f=cams[:, 6].copy(),
        k1=cams[:, 7].copy(),
        k2=cams[:, 8].copy(),
        xyz_world=values[9 * ncam :].reshape(npts, 3).copy(),
        camera_index=camera_index,
        point_index=point_index,
        xy_pixel=xy,
        camera_lines=value_lines[: 9 * ncam : 9].copy(),
    )


def _count(path: Path, line: int, name: str, token: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputError(path, line, f"header: {name} '{token}' is not an integer") from None
    if value < 0:
        raise InputError(path, line, f"header: {name} is negative ({value})")
    return value


def _index(path: Path, line: int, name: str, token: str, n: int) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputError(path, line, f"{name} index '{token}' is not an integer") from None
    if not 0 <= value < n:
        raise InputError(path, line, f"{name} index {value} is out of range 0..{n - 1}")
    return value


def parse_number(path: Path, line: int, name: str, token: str) -> float:
    """A finite float from a token, or InputError(path, line) naming the field."""
    try:
        value = float(token)
    except ValueError:
        raise InputError(path, line, f"{name} '{token}' is not a number") from None
    if not math.isfinite(value):
        raise InputError(path, line, f"{name} '{token}' is not a finite number")
    return value


def behind_camera(bal: BalProblem) -> np.ndarray:
    """(nobs,) True where the observed point lies behind its camera (P_z > 0: BAL's cameras look
    down -z) at the problem's values. Ceres-based adjusters (COLMAP) give such observations no
    residual; striptri keeps every observation, so a comparison leaves them out of both."""
    R = bal.R_cam_from_world()
    P = np.einsum("nij,nj->ni", R[bal.camera_index], bal.xyz_world[bal.point_index]) + bal.t_cam_from_world[bal.camera_index]
    return P[:, 2] > 0


def without_observations(bal: BalProblem, drop: np.ndarray) -> BalProblem:
    """The problem without the observations where drop (nobs,) is True."""
    keep = ~np.asarray(drop, dtype=bool)
    return replace(bal, camera_index=bal.camera_index[keep], point_index=bal.point_index[keep],
                   xy_pixel=bal.xy_pixel[keep])


def bal_text(problem: BalProblem) -> str:
    """The BAL file of a problem (one number per parameter line, floats by repr), as the published
    files are laid out; read_bal reads it back unchanged."""
    lines = [f"{problem.n_cameras} {problem.n_points} {problem.n_observations}"]
    lines += [f"{int(c)} {int(p)} {float(x)!r} {float(y)!r}"
              for c, p, (x, y) in zip(problem.camera_index, problem.point_index, problem.xy_pixel)]
    params = np.column_stack([problem.rotation_cam_from_world, problem.t_cam_from_world, problem.f,
                              problem.k1, problem.k2]).ravel()
    lines += [repr(float(v)) for v in params]
    lines += [repr(float(v)) for v in problem.xyz_world.ravel()]
    return "\n".join(lines) + "\n"
