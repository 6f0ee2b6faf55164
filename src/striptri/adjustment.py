"""The adjustment of a project: ``adjust(project, options)`` checks what no method can carry and
hands the project to one of three sibling methods (docs/architecture.md):

* ``conditions`` -- Schmid's simultaneous adjustment by condition equations (striptri.conditions_method);
* ``bundle`` -- the collinearity bundle adjustment with the points as unknowns (striptri.bundle);
* ``sequential`` -- the instrument-style sequential strip triangulation (striptri.sequential).

All three take the same AdjustmentOptions and return the same AdjustmentResult (striptri.core),
whose ``termination`` says why the iteration stopped. The names of striptri.core are re-exported
here: ``from striptri.adjustment import adjust, AdjustmentOptions`` is the Python API.
"""

from __future__ import annotations

import numpy as np

from .core import diagnosis, termination
from . import solvers
from .bundle import adjust_bundle
from .conditions_method import adjust_conditions
from .conditions_method.adjust import Assembly, assemble_normals, normal_matrix_at_approximations  # noqa: F401
from .equations.linearise import Sweep  # noqa: F401
from .core.convergence import (  # noqa: F401  (re-exported)
    CONTRACTION_MAX,
    ROUND_OFF_PER_UNKNOWN,
    ROUND_OFF_ULPS,
    ROUNDING_FLOOR,
    correction_in_sigma,
    energy_floor,
    has_converged,
    largest_correction,
    round_off_floor,
    stop_if_diverging,
)
from .core.explain import datum_defect_message, not_finite_message, singular_message  # noqa: F401
from .equations.observations import Observations, observations_of  # noqa: F401
from .core.options import (  # noqa: F401  (re-exported)
    DATUMS,
    INITS,
    METHODS,
    AdjustmentOptions,
    BundleOptions,
    ConditionsOptions,
    SequentialOptions,
)
from .core.result import (  # noqa: F401  (re-exported)
    DENSE_QXX_LIMIT,
    SUCCESSFUL_TERMINATIONS,
    TERMINATIONS,
    AdjustmentResult,
    Checks,
    Iteration,
    SequentialChecks,
    Timings,
)
from .errors import NumericalFailure
from .equations.joint_groups import check_distance_points, has_distances
from .model import Project
from .equations.parameters import uses_gnss
from .sequential import adjust_sequential, sequential_approximations

ADJUST = {"conditions": adjust_conditions, "bundle": adjust_bundle, "sequential": adjust_sequential}


def adjust(project: Project, options: AdjustmentOptions = AdjustmentOptions()) -> AdjustmentResult:
    """Adjust all photographs of the project by ``options.method`` (module doc), from the
    approximate values in the project or, with ``options.init == "sequential"``, from the
    sequential method's result.

    The result's ``termination`` says why the iteration stopped (core.result.TERMINATIONS;
    "converged" and "cost_flat" are results) and ``termination_message`` says it in words with the
    last figures of the history and the likely cause. An adjustment that stops at its iteration
    limit raises NumericalFailure with that message (reason "iteration_limit") unless
    ``options.keep_unconverged``. Everything else that gives no result raises NumericalFailure with
    its reason ("datum_defect", "singular", "not_finite", "diverged", or "failed"); never a bare
    SingularNormalMatrix or LinAlgError."""
    result = _adjust_explained(project, options)
    if not options.keep_unconverged and not result.converged:
        raise NumericalFailure(failure_message(result), reason=result.termination)
    return result


def failure_message(result: AdjustmentResult) -> str:
    """What to tell the user about an adjustment that did not converge: the method's own message
    or, failing that, the last figures of the iteration history."""
    if result.termination_message:
        return result.termination_message
    last = result.history[-3:]
    figures = "; ".join(f"v^T P v {h.vtpv:.6g}, largest correction {h.max_correction:.3g} sigma" for h in last)
    return (f"the {result.method} adjustment did not converge in {result.iterations} iterations (last: {figures}). "
            "Raise [adjustment] max_iterations in project.toml if the corrections were still shrinking; "
            "otherwise check the approximate orientations, the angle convention and the units of c and of the "
            "plate coordinates.")


def _adjust_explained(project: Project, options: AdjustmentOptions) -> AdjustmentResult:
    """One adjustment by options.method, returned whether it converged or not; singular systems
    without words of their own explained."""
    with np.errstate(all="ignore"):
        weights = diagnosis.extreme_weights(project)
    if weights:  # the normal equations cannot carry them: refuse before iterating into nonsense
        raise NumericalFailure("the adjustment cannot be carried out in double precision: " + " ".join(weights),
                               reason="singular")
    if options.method == "sequential" and uses_gnss(project):
        raise NumericalFailure("the sequential method does not carry the GNSS model (lever arm, boresight, shift, "
                               "drift: docs/decisions.md): adjust with the method conditions or bundle",
                               reason="failed")
    if has_distances(project) and options.method == "sequential":
        raise NumericalFailure("distances.csv: observed distances between object points are adjusted by the "
                               "simultaneous methods only (docs/decisions.md); run with --method conditions or bundle",
                               reason="failed")
    check_distance_points(project)
    try:
        # the adjustment tests its numbers for finiteness itself and explains what overflows, so
        # numpy's floating-point warnings would only repeat it on stderr
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            if options.init == "sequential" and options.method != "sequential":
                project = sequential_approximations(project, SequentialOptions.from_adjustment_options(options))
            return ADJUST[options.method](project, options)
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError) as exc:  # a path without its own words
        with np.errstate(all="ignore"):
            causes = diagnosis.likely_causes(project, "singular")
        raise NumericalFailure(f"{termination.what_of(options.method)} met a singular system of equations ({exc}); "
                               "some element is not determined by the measurements.\n"
                               + termination.causes_text(causes), reason="singular") from exc
