"""Control layouts: which von Gruber pass points of a strip or block are control (ControlDesign.layout).

The pass points of a block of S strips and n columns form a grid of n columns x (2S + 1) rows
(see :class:`striptri.simulate.design.ControlDesign`). Rows run across the block from the right side
of the first strip towards the left, in the direction in which the block grows:

* row 0: the outer row of the first strip (its R points);
* row 2s + 1: the nadir row of strip s (0-based; its C points);
* row 2s, 0 < s < S: the row in the middle of the sidelap of strips s - 1 and s (shared by them);
* row 2S: the outer row of the last strip.

Even rows are the *lateral* rows. For one strip the rows are R, C, L.
"""

from __future__ import annotations

import numpy as np

from striptri.model import FULL, HEIGHT, PLAN, TIE
from striptri.simulate.design import EVERY_K_KINDS, ControlDesign

OMITTED = -1
# Pass point positions at a nadir, as a strip names them: left of its flight direction, on it, right.
POSITIONS = ("L", "C", "R")


def n_rows(n_strips: int) -> int:
    """Rows of pass points across a block of n_strips strips."""
    return 2 * n_strips + 1


def pass_point_kinds(control: ControlDesign, n_columns: int, n_strips: int = 1) -> np.ndarray:
    """Kind code of every pass point of a block. -> (n_columns, 2 n_strips + 1) ints (module doc for
    the rows); OMITTED where the layout has no point (only Schmid's minimal pair omits one)."""
    rows = n_rows(n_strips)
    kinds = np.full((n_columns, rows), TIE, dtype=int)
    layout, last = control.layout, n_columns - 1
    lateral = np.arange(0, rows, 2)
    outer = np.array([0, rows - 1])
    R, L = 0, rows - 1  # the pair layouts name the points of one strip
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
            kinds[inner[:, None], lateral] = EVERY_K_KINDS[control.every_k_kind]
        # the corners of the first model (columns 0, 1) and of the last (columns last-1, last)
        for column in (0, 1, last - 1, last):
            kinds[column, lateral] = FULL
    elif layout == "perimeter":
        columns = _every_k_columns(control.every_k, last)
        kinds[columns[:, None], lateral[1:-1]] = HEIGHT
        kinds[columns[:, None], outer] = FULL
        kinds[np.ix_([0, last], lateral)] = FULL
    elif layout == "sparse-height":
        columns = _every_k_columns(control.every_k, last)
        kinds[columns[:, None], lateral] = HEIGHT
        kinds[np.ix_([0, last], outer)] = FULL
    elif layout != "none":
        raise ValueError(f"unknown control layout {layout!r}")
    return kinds


def _every_k_columns(k: int, last: int) -> np.ndarray:
    """Columns 0, k, 2k, ... and the last column."""
    return np.union1d(np.arange(0, last + 1, k), [last])
