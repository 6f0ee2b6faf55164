"""The instrument-style sequential strip triangulation (Schut's procedures 1 and 2, DESIGN section 8).

* :mod:`.photo_step` -- one photograph oriented to the preceding one (and to known points);
* :mod:`.absolute` -- 3D similarity to the control and the polynomial strip correction;
* :mod:`.strip` -- the strip model built photo by photo, forward or backward (``triangulate_strip``);
* :mod:`.result` -- ``adjust_sequential`` (an AdjustmentResult, method "sequential") and
  ``sequential_approximations`` (approximate values for the simultaneous adjustment).
"""

from .result import adjust_sequential, result_of, sequential_approximations
from .strip import (
    DIRECTIONS,
    PROCEDURES,
    SequentialOptions,
    SequentialSolution,
    triangulate_strip,
)

__all__ = [
    "DIRECTIONS",
    "PROCEDURES",
    "SequentialOptions",
    "SequentialSolution",
    "adjust_sequential",
    "result_of",
    "sequential_approximations",
    "triangulate_strip",
]
