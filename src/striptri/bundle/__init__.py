"""The collinearity bundle adjustment (method "bundle"): object points among the unknowns,
eliminated point by point into the reduced camera system; the independent check of Schmid's
method of conditions (DESIGN section 4).

* observation equations: the collinearity of :mod:`striptri.geometry.collinearity` (Schmid 14, analytic Jacobians);
* :mod:`.points` - which point coordinates are unknowns, which points take part, start values;
* :mod:`.reduced` - per-point Schur complement, reduced camera system, back-substitution;
* :mod:`.dense` - the points' share of the reduced camera system summed dense (small blocks, long tracks);
* :mod:`.adjust` - the iteration: ``adjust_bundle(project, options) -> AdjustmentResult``.
"""

from .adjust import BundleSolution, adjust_bundle, solve_bundle

__all__ = ["BundleSolution", "adjust_bundle", "solve_bundle"]
