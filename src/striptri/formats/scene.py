"""What a conversion hands on (docs/formats.md): a :class:`Scene`, and the minimal datum by photos
(:func:`photo_datum`) that the BAL and DBAT conversions give a project without control.

The layer below :mod:`striptri.formats.conversions` (BAL, COLMAP) and :mod:`striptri.formats.dbat`;
it knows no file format.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from striptri import model


@dataclass(frozen=True)
class Scene:
    """A project and approximate ground coordinates of its object points.

    xyz_ground: (n_points, 3), nan where not known. plate_units_per_pixel: the pixel size in plate
    units when the plate coordinates came from pixels (BAL: 1.0), else None. notes: what the
    conversion dropped or assumed, in words for the user.
    """

    project: model.Project
    xyz_ground: np.ndarray
    plate_units_per_pixel: float | None = None
    notes: list[str] = field(default_factory=list)


def photo_datum(photos: model.Photos, ref: int = 0, unit: str = "m"):
    """A minimal datum by photos (DBAT's 'depend'): the six elements of photo ``ref`` held, and of
    the photo farthest from it (approximate positions) the base component of largest magnitude
    held too: six plus one, the scale from the longest base. -> (photos with sigma 0 on those
    elements, a note)."""
    i = ref
    base = photos.xyz0 - photos.xyz0[i]
    j = int(np.argmax(np.linalg.norm(base, axis=1)))
    axis = int(np.argmax(np.abs(base[j])))
    sx, sa = photos.sigma_xyz0.copy(), photos.sigma_angles.copy()
    sx[i], sa[i] = 0.0, 0.0
    sx[j, axis] = 0.0
    note = (f"datum by photos (DBAT's 'depend'): photo {photos.ids[i]} held (6 elements) and {'XYZ'[axis]}0 of "
            f"photo {photos.ids[j]} (the longest base, {np.linalg.norm(base[j]):.3f} {unit}) held")
    return replace(photos, sigma_xyz0=sx, sigma_angles=sa), note
