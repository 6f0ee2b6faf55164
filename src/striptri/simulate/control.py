"""Control layouts: which von Gruber pass points of a flight line are control (ControlDesign.layout)."""

from __future__ import annotations

import numpy as np

from striptri.model import FULL, HEIGHT, PLAN, TIE
from striptri.simulate.design import EVERY_K_KINDS, ControlDesign

OMITTED = -1
# Pass point positions at a nadir, in this column order: left of the flight direction, on it, right.
POSITIONS = ("L", "C", "R")
L, C, R = 0, 1, 2


def pass_point_kinds(control: ControlDesign, n_nadirs: int) -> np.ndarray:
    """Kind code of every pass point of one flight line. -> (n_nadirs, 3) ints, columns L, C, R;
    OMITTED where the layout has no point (only Schmid's minimal configuration omits one)."""
    kinds = np.full((n_nadirs, 3), TIE, dtype=int)
    layout, last = control.layout, n_nadirs - 1
    if layout == "corners":
        kinds[:, [L, R]] = FULL
    elif layout == "mixed":
        kinds[0, L], kinds[1, R] = FULL, FULL
        kinds[0, R], kinds[1, L] = PLAN, HEIGHT
    elif layout == "schmid-minimal":
        # Two full points in the overlap (8 conditions), one height point (2) and two relative
        # points (1 each): 12 conditions for the 12 exterior elements of the pair.
        kinds[0, L], kinds[1, R] = FULL, FULL
        kinds[1, L] = HEIGHT
        kinds[0, R] = OMITTED
    elif layout in ("ends", "every-k"):
        if layout == "every-k":
            inner = np.arange(control.every_k, last, control.every_k)
            kinds[inner[:, None], [L, R]] = EVERY_K_KINDS[control.every_k_kind]
        # the four corners of the first model (nadirs 0, 1) and of the last (nadirs last-1, last)
        for nadir in (0, 1, last - 1, last):
            kinds[nadir, [L, R]] = FULL
    elif layout != "none":
        raise ValueError(f"unknown control layout {layout!r}")
    return kinds
