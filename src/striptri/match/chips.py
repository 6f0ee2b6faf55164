"""Image chips of the control points (issue 28; ``striptri match``, OUT/chips/; docs/matching.md).

Where each control point (and check point) with plan coordinates falls in each photo is predicted
from the approximate orientations (collinearity with photos.csv's values and the camera's
interior orientation); for every photo whose image holds the prediction, a square chip of the
full-resolution image around it is written as PNG with the predicted position marked by a thin
open cross (the centre left free, so the target stays visible), so that a user can measure the
point there or confirm a measurement. ``chips/chips.csv`` lists each chip: point_id, photo_id,
the predicted position (col, row: image pixels, the top-left pixel's centre at (0.5, 0.5)), the
chip's file and the image pixel of its top-left corner (col0, row0), so that a position measured
in the chip, (u, v) in the same convention, is (col0 + u, row0 + v) in the image. The measurements
go into image_points.csv as always: plate coordinates of a digital camera (striptri.geometry.pixels),
scan pixels of film (the chips of scans are predicted through each scan's fiducial transformation).

A point whose height alone is given (kind Z) has no plan position to predict from and gets no chip.
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import in_front, project as plate_of
from ..model import CHECK, FULL, PLAN, Project
from .features import cv2_module
from .frames import ImageFrames

CHIP_PX = 201  # the side of a chip (odd: the predicted pixel in the middle)
MARK = (0, 0, 255)  # red (OpenCV's blue, green, red)


def predictions(project: Project, frames: ImageFrames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """-> (point, photo, colrow) of every control or check point with plan coordinates that the
    approximate orientation of a photo puts inside its image area (kind, plan, in front of the
    camera; frames: the photos' pixels, match.frames)."""
    pts, ph, cams = project.points, project.photos, project.cameras
    xyz = pts.xyz_given
    usable = np.flatnonzero(np.isin(pts.kind, [FULL, PLAN, CHECK]) & np.isfinite(xyz[:, :2]).all(1))
    if not len(usable):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    point, photo = (g.ravel() for g in np.meshgrid(usable, np.arange(len(ph)), indexing="ij"))
    X = xyz[point].copy()
    X[:, 2] = np.where(np.isfinite(X[:, 2]), X[:, 2], np.nanmean(xyz[usable, 2]) if np.isfinite(xyz[usable, 2]).any()
                       else 0.0)
    cam = ph.camera_index[photo]
    front = in_front(ph.R_ground_from_cam[photo], ph.xyz0[photo], X)
    plate = plate_of(ph.R_ground_from_cam[photo], ph.xyz0[photo], cams.interior[cam, :3], X)
    colrow = frames.pixel(photo, plate)
    inside = front & frames.in_image(photo, colrow)
    return point[inside], photo[inside], colrow[inside]


def chip_files(project: Project, frames: ImageFrames, image_paths: list,
               chip_px: int = CHIP_PX) -> dict[str, bytes | str]:
    """OUT/chips/<point_id>_<photo_id>.png for every prediction, and chips/chips.csv (module doc).
    Each photo's image is read once, at full resolution."""
    cv2 = cv2_module()
    point, photo, colrow = predictions(project, frames)
    files: dict[str, bytes | str] = {}
    lines = ["point_id,photo_id,col,row,chip,col0,row0"]
    half = chip_px // 2
    for k in np.unique(photo):  # one image read per photo
        image = cv2.imread(str(image_paths[k]), cv2.IMREAD_GRAYSCALE)
        if image is None:
            continue
        H, W = image.shape
        for j in np.flatnonzero(photo == k):
            c, r = (float(v) for v in colrow[j])
            # the chip's top-left pixel: the predicted pixel (index floor(c), floor(r)) in the middle
            i0, j0 = int(np.floor(c)) - half, int(np.floor(r)) - half
            chip = np.zeros((chip_px, chip_px), dtype=np.uint8)
            a0, b0 = max(i0, 0), max(j0, 0)
            a1, b1 = min(i0 + chip_px, W), min(j0 + chip_px, H)
            if a1 > a0 and b1 > b0:
                chip[b0 - j0:b1 - j0, a0 - i0:a1 - i0] = image[b0:b1, a0:a1]
            files_name = f"chips/{project.points.ids[point[j]]}_{project.photos.ids[k]}.png"
            files[files_name] = _marked(cv2, chip, c - i0, r - j0)
            lines.append(f"{project.points.ids[point[j]]},{project.photos.ids[k]},{c!r},{r!r},"
                         f"{files_name[len('chips/'):]},{i0},{j0}")
    if len(lines) > 1:
        files["chips/chips.csv"] = "\n".join(lines) + "\n"
    return files


def _marked(cv2, chip: np.ndarray, u: float, v: float) -> bytes:
    """The chip in colour with an open cross at (u, v) (chip pixels, corner origin), as PNG."""
    colour = cv2.cvtColor(chip, cv2.COLOR_GRAY2BGR)
    shift = 4  # OpenCV draws with 4 fractional bits: the cross at subpixel position
    cu, cv_ = int(round((u - 0.5) * 16)), int(round((v - 0.5) * 16))
    gap, arm = 6 * 16, 20 * 16
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        cv2.line(colour, (cu + du * gap, cv_ + dv * gap), (cu + du * arm, cv_ + dv * arm), MARK, 1, cv2.LINE_AA, shift)
    ok, data = cv2.imencode(".png", colour)
    return data.tobytes()
