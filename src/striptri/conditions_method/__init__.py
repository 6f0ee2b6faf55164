"""Schmid's method of conditions (BRL Report 961), the core of striptri: one simultaneous
least-squares adjustment of all photographs by condition equations (DESIGN section 4).

* :mod:`.adjust` -- the iteration: assembly of the whitened conditions into N, the solve, the back
  substitution, the final checks (``adjust_conditions``).

Its pieces below: striptri.conditions (the condition equations), striptri.linearise (their
linearisation per group), striptri.groups (the groups of rays), striptri.normal_equations
(whitening and the block pattern of N).
"""

from .adjust import Assembly, Sweep, adjust_conditions, normal_matrix_at_approximations

__all__ = ["Assembly", "Sweep", "adjust_conditions", "normal_matrix_at_approximations"]
