"""What the three adjustment methods share, below all of them (docs/architecture.md).

* :mod:`.options` -- AdjustmentOptions and the per-method option objects inside it;
* :mod:`.result` -- AdjustmentResult, Iteration, the termination reasons, typed checks and timings;
* :mod:`.observations` -- the observations of a project in the reduced frame;
* :mod:`.convergence` -- the convergence test, the round-off floors and the divergence rule;
* :mod:`.explain` -- solving the normal equations with a failure explained in a photogrammetrist's
  words (datum defect, singular system, overflow), and Schmid's check (59).

``striptri.adjustment.adjust`` dispatches to the methods (``striptri.conditions_method``,
``striptri.bundle``, ``striptri.sequential``); each of them imports from here and from the modules
below (parameters, solvers, datum, ...), never from another method or from ``striptri.adjustment``.
"""
