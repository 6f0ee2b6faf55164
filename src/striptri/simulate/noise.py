"""Noise: from the truth to what a photogrammetrist is given (cf. COLMAP's ``SyntheticNoiseOptions``).

``perturb(truth, noise, rng)`` returns a :class:`striptri.model.Project` with

* plate measurements = exact plate coordinates + normal noise of ``sigma_image`` per coordinate,
  stated in the project with ``stated_sigma_image`` (by default the same, or the file default
  0.005 when the data are noise-free, so that the weights stay finite);
* control (kinds XYZ, XY, Z): the given coordinates, exact and held fixed (empty sigma) when the
  control sigma is 0, otherwise truth + normal noise with that sigma stated; check points carry
  their true coordinates (they are the reference the adjustment is compared with);
* approximate orientations: true centre + normal error of ``approx_position_error`` (m) per axis and
  true omega, phi, kappa + normal error of ``approx_angle_error`` (deg) per angle, all free; or, with
  ``sigma_gnss``, centres observed by GNSS: true + normal noise of sigma_gnss, stated as
  sigma_X0 = sigma_Y0 = sigma_Z0 = sigma_gnss (they then replace the approximate centres).

Draws come from ``rng`` in a fixed order: centres, angles, plate noise, control noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri import model
from striptri.geometry.rotations import R_from_opk, opk_from_R
from striptri.simulate.truth import Truth

DEFAULT_STATED_SIGMA_IMAGE = model.ProjectSettings().sigma_image


@dataclass(frozen=True)
class NoiseOptions:
    """sigma_image: plate units; stated_sigma_image: what the files say (None: see module doc);
    sigma_control_xy, sigma_control_z: m, 0 = exact control held fixed; approx_position_error: m;
    approx_angle_error: deg; sigma_gnss: m or None (no GNSS)."""

    sigma_image: float = 0.005
    stated_sigma_image: float | None = None
    sigma_control_xy: float = 0.0
    sigma_control_z: float = 0.0
    approx_position_error: float = 10.0
    approx_angle_error: float = 1.0
    sigma_gnss: float | None = None

    def __post_init__(self):
        for name in ("sigma_image", "sigma_control_xy", "sigma_control_z", "approx_position_error", "approx_angle_error"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"noise: {name} must be non-negative")
        if self.stated_sigma_image is not None and not self.stated_sigma_image > 0:
            raise ValueError("noise: stated_sigma_image must be positive")
        if self.sigma_gnss is not None and not self.sigma_gnss > 0:
            raise ValueError("noise: sigma_gnss must be positive (None for no GNSS)")

    @property
    def stated_image_sigma(self) -> float:
        """The plate sigma written into the project (module doc)."""
        if self.stated_sigma_image is not None:
            return self.stated_sigma_image
        return self.sigma_image if self.sigma_image > 0 else DEFAULT_STATED_SIGMA_IMAGE


def perturb(truth: Truth, noise: NoiseOptions, rng: np.random.Generator) -> model.Project:
    """The project an adjustment is given: noisy plates, (noisy) control, approximate orientations."""
    settings = model.ProjectSettings(sigma_image=noise.stated_image_sigma)
    return model.Project(
        cameras=model.Cameras(
            ids=[truth.design.camera.camera_id],
            interior=truth.interior[None, :].copy(),
            sigma_interior=np.full((1, 3), np.nan),
        ),
        photos=_approximate_photos(truth, noise, rng),
        image_points=_measured_plates(truth, noise, rng),
        points=_given_points(truth, noise, rng),
        settings=settings,
    )


def _approximate_photos(truth: Truth, noise: NoiseOptions, rng) -> model.Photos:
    n = len(truth.photo_ids)
    if noise.sigma_gnss is None:
        xyz0 = truth.xyz0 + rng.normal(0.0, noise.approx_position_error, (n, 3))
        sigma_xyz0 = np.full((n, 3), np.nan)
    else:
        xyz0 = truth.xyz0 + rng.normal(0.0, noise.sigma_gnss, (n, 3))
        sigma_xyz0 = np.full((n, 3), noise.sigma_gnss)
    angles = opk_from_R(truth.R_ground_from_cam) + rng.normal(0.0, np.radians(noise.approx_angle_error), (n, 3))
    return model.Photos(
        ids=list(truth.photo_ids),
        camera_index=np.zeros(n, dtype=int),
        strip_ids=list(truth.strip_ids),
        xyz0=xyz0,
        R_ground_from_cam=R_from_opk(angles),
        angles=angles,
        sigma_xyz0=sigma_xyz0,
        sigma_angles=np.full((n, 3), np.nan),
    )


def _measured_plates(truth: Truth, noise: NoiseOptions, rng) -> model.ImagePoints:
    m = len(truth.photo_index)
    return model.ImagePoints(
        photo_index=truth.photo_index.copy(),
        point_index=truth.point_index.copy(),
        xy=truth.xy_plate + rng.normal(0.0, noise.sigma_image, (m, 2)),
        sigma_xy=np.full((m, 2), noise.stated_image_sigma),
    )


def _given_points(truth: Truth, noise: NoiseOptions, rng) -> model.ObjectPoints:
    """Given coordinates per kind (model.given_axes); check points keep their true coordinates."""
    n = len(truth.point_ids)
    given = model.given_axes(truth.kind).reshape(n, 3)
    sigma = np.array([noise.sigma_control_xy, noise.sigma_control_xy, noise.sigma_control_z])
    xyz_given = np.where(given, truth.xyz_ground + rng.normal(0.0, 1.0, (n, 3)) * sigma, np.nan)
    sigma_given = np.where(given & (sigma > 0), sigma, np.nan)
    check = truth.kind == model.CHECK
    xyz_given[check] = truth.xyz_ground[check]
    return model.ObjectPoints(
        ids=list(truth.point_ids),
        kind=truth.kind.copy(),
        xyz_given=xyz_given,
        sigma_given=sigma_given,
    )
