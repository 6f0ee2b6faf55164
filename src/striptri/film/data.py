"""What the film inputs gave (striptri.io.film_reader), for the report and the output tables."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri.film.calibration import RadialFit
from striptri.film.fiducials import FiducialFit


@dataclass(frozen=True)
class CameraCalibration:
    """One camera of calibration.toml: the report's values and the fit (striptri.film.calibration).

    camera_id; focal_length_mm; pbs_mm, ppa_mm (2,) (ppa nan when not given); field_angle_deg (m,)
    (nan when the table is by radius); fit: RadialFit; elements: (NCP,) the camera model's elements.
    """

    camera_id: str
    focal_length_mm: float
    pbs_mm: np.ndarray
    ppa_mm: np.ndarray
    field_angle_deg: np.ndarray
    fit: RadialFit
    elements: np.ndarray


@dataclass(frozen=True)
class FilmData:
    """What the film inputs gave, for the report and the output tables.

    transformation: kind; sigma_px: default sigma of scan measurements; photo_ids: (P,) the photos
    with measured fiducials, in photos.csv order; fiducial_ids: (P, F) names ('' where a photo's
    camera has fewer); fit: FiducialFit or None (image points in plate units); calibrations: tuple of
    CameraCalibration.
    """

    transformation: str
    sigma_px: float
    photo_ids: list
    fiducial_ids: list
    fit: FiducialFit | None
    calibrations: tuple = ()
