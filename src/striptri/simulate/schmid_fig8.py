"""Schmid's worked strip (BRL Report 961, section V: Fig. 8 and the table of observational
equations that follows it).

"a strip of 5 photographs with 2/3 overlap ... Twelve points are common to two photographs and 18
points are common to three photographs. Consequently, we have (12 * 2 + 18 * 3) * 2 = 156
residuals" and 77 observational equations for 5 * 6 = 30 unknowns. His table gives the equations
point by point; the counts fix the kinds: points 1 and 30 are absolute (full) points in two
photographs (4 equations each), 16 an absolute point in three (6), 3 a height point in two (2), 14 a
height point in three (4), all others relative points (1 in two photographs, 3 in three).

With 2/3 overlap the strip falls into sections one air base long: photos 1-2 only at the start,
the triple overlaps 1-2-3, 2-3-4, 3-4-5, and photos 4-5 only at the end. Points 1-6 lie in the first
section, 7-24 in the three triple sections, 25-30 in the last (the table's counts say so). Each
section carries six points in two columns a quarter base in from the section's ends; a column holds
three points across the strip: left of the flight direction (``lateral_offset`` of the design), on
the flight line, right. Schmid's figure does not survive in our copy of the report well enough to
read the order within a column; we number column by column, left-centre-right, so that the control
points sit at 1 = first column left, 3 = first column right, 14 = fifth column centre, 16 = sixth
column left, 30 = last column right: three non-collinear full points spread along the strip.
"""

from __future__ import annotations

import numpy as np

from striptri.model import FULL, HEIGHT, TIE

N_PHOTOS = 5
OVERLAP = 2.0 / 3.0
N_COLUMNS = 10
FULL_POINTS = (1, 16, 30)
HEIGHT_POINTS = (3, 14)
# Along-track position of each column, in air bases from the nadir of the first photo: a quarter
# base in from the ends of the sections [-0.5, 0.5], [0.5, 1.5], ... [3.5, 4.5].
COLUMN_ALONG = -0.25 + 0.5 * np.arange(N_COLUMNS)
# A nominal photo covers 1.5 bases either side of its nadir with 2/3 overlap.
_HALF_COVER = 1.5


def kinds() -> np.ndarray:
    """Kind code of points 1..30 (index 0 = point 1). -> (30,) ints."""
    kind = np.full(3 * N_COLUMNS, TIE, dtype=int)
    kind[np.array(FULL_POINTS) - 1] = FULL
    kind[np.array(HEIGHT_POINTS) - 1] = HEIGHT
    return kind


def expected_photos() -> np.ndarray:
    """Which of the five photos sees each point nominally. -> (30, 5) bool."""
    column = np.repeat(np.arange(N_COLUMNS), 3)
    distance = np.abs(COLUMN_ALONG[column][:, None] - np.arange(N_PHOTOS)[None, :])
    return distance < _HALF_COVER


def ground_xy(nadir0_xy: np.ndarray, along: np.ndarray, left: np.ndarray, base: float, offset: float) -> np.ndarray:
    """Ground XY of points 1..30 of a strip whose first nadir is nadir0_xy, flown along ``along``
    (unit, (2,)) with its left side ``left``; base and lateral offset in metres. -> (30, 2)."""
    a = np.repeat(COLUMN_ALONG * base, 3)
    b = np.tile([offset, 0.0, -offset], N_COLUMNS)
    return nadir0_xy + a[:, None] * along + b[:, None] * left


def require_pattern(seen: np.ndarray) -> None:
    """Raise ValueError unless the photos see the 30 points exactly as in Schmid's strip.
    seen: (5, 30) bool, photo by point."""
    wrong = np.flatnonzero(np.any(seen.T != expected_photos(), axis=1))
    if len(wrong):
        k = wrong[0]
        got = [i + 1 for i in np.flatnonzero(seen[:, k])]
        want = [i + 1 for i in np.flatnonzero(expected_photos()[k])]
        raise ValueError(
            f"design: Schmid's point {k + 1} is seen by photos {got} instead of {want}; "
            "lower the relief or the deviations from the ideal flight"
        )
