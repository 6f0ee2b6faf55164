"""Schmid's method of conditions (BRL Report 961), the core of striptri: one simultaneous
least-squares adjustment of all photographs by condition equations (DESIGN section 4).

* :mod:`.adjust` -- the iteration: assembly of the whitened conditions into N, the solve, the back
  substitution, the final checks (``adjust_conditions``).

Its pieces below: striptri.equations.conditions (the condition equations), striptri.equations.linearise (their
linearisation per group), striptri.equations.groups (the groups of rays), striptri.equations.normal_equations
(whitening and the block pattern of N).
"""

from ..equations.linearise import Sweep
from .adjust import Assembly, adjust_conditions, normal_matrix_at_approximations

__all__ = ["Assembly", "Sweep", "adjust_conditions", "normal_matrix_at_approximations"]
