"""Solving the normal equations of a simultaneous adjustment with every failure explained in a
photogrammetrist's words (a datum defect, an undetermined element, numbers that overflow), and
Schmid's check (59). Shared by the method of conditions and the bundle adjustment."""

from __future__ import annotations

import numpy as np

from ..equations import datum
from . import diagnosis, termination
from .. import selected_inverse, solvers
from ..errors import NumericalFailure
from ..solvers.base import pattern_matrix
from ..model import Project
from ..equations.parameters import State, UnknownLayout


def solver_for(options, layout: UnknownLayout, project: Project, pattern=None) -> solvers.NormalSolver:
    """The solver of ``options.solver`` for the normal equations of these unknowns, told their
    6x6 blocks and the strip of each (solvers.Structure), made once per adjustment; told N's
    pattern (a ReducedPattern: its index arrays) when the method knows it already
    (NormalSolver.prepare: CHOLMOD analyses it meanwhile)."""
    solver = solvers.make_solver(solvers.SolverOptions(name=options.solver),
                                 solvers.Structure(layout.n_unknowns, layout.block_starts(),
                                                   layout.block_groups(project.photos.strip_ids)))
    if pattern is not None and layout.n_unknowns == pattern.shape[0]:
        solver.prepare(pattern_matrix(pattern.indptr, pattern.indices, pattern.shape))
    return solver


def solve_or_explain(normals, rhs: np.ndarray, solver: solvers.NormalSolver, state: State, problem,
                     what: str = "the normal equations are singular", diagnose: bool = True) -> solvers.SolveResult:
    """Solve ``normals.N dx = rhs`` of a method's ``problem`` (its project, the layout of its
    unknowns and its reduction offset, as each method's problem holds them). A datum defect (tested before the solve when ``diagnose``, and
    whenever the solver finds N singular; datum.diagnose reads N and the misclosure sums of
    ``normals``) is a NumericalFailure "datum_defect" naming the free directions; any other
    singularity one "singular" naming the first element that is not determined (``what`` says
    which equations)."""
    project, layout, offset = problem.project, problem.layout, problem.offset
    defects = datum.diagnose(normals, state, layout, offset=offset) if diagnose else []
    if defects:
        raise datum_defect_failure(project, defects)
    # the precision's symbolic analysis needs only N's pattern: made beside the factorisations
    selected_inverse.for_layout_ahead(normals.N, layout)
    try:
        return solver.solve(normals.N, rhs)
    except solvers.SingularNormalMatrix as exc:
        defects = datum.diagnose(normals, state, layout, datum.LOOSE_TOLERANCE, offset)
        if defects:
            raise datum_defect_failure(project, defects) from exc
        raise NumericalFailure(singular_message(project, layout, exc.column, what), reason="singular") from exc


def reduction_check(reduced: float, vtpv: float) -> float:
    """Schmid's check (59): v^T P v against the reduced sum [LL.u] formed in the reduction of the
    normal equations, as their relative difference (absolute when v^T P v is round-off itself)."""
    return abs(reduced - vtpv) / max(vtpv, 1e-300) if vtpv > 1e-20 else abs(reduced - vtpv)


def not_finite_message(project: Project, points: np.ndarray, iteration: int) -> str:
    """The NumericalFailure text for conditions (or observation equations) that are not finite numbers."""
    names = [project.points.ids[i] for i in points[: diagnosis.LIST_MAX]]
    where = (f" for {len(points)} point{'s' if len(points) != 1 else ''} ({', '.join(names)}"
             f"{' ...' if len(points) > len(names) else ''})" if len(points) else "")
    return ("the equations of the adjustment cannot be formed at iteration "
            f"{iteration}: their numbers overflow (they are not finite){where}.\n"
            + termination.causes_text(diagnosis.likely_causes(project, "overflow"),
                                      "Likely cause: values far outside the block or in another unit in the input "
                                      "(photos.csv, cameras.csv, image_points.csv, control.csv)."))


def datum_defect_failure(project: Project, defects: list[str]) -> NumericalFailure:
    """The NumericalFailure of directions the datum test finds free: "datum_defect" with
    datum.explain's words, or "singular" when weights or values beyond reason fool the test
    (datum_defect_message names them instead)."""
    message = datum_defect_message(project, defects)
    trusted = not message.startswith(UNTRUSTED)
    return NumericalFailure(message, reason="datum_defect" if trusted else "singular")


UNTRUSTED = "the normal equations cannot be trusted: "


def datum_defect_message(project: Project, defects: list[str]) -> str:
    """datum.explain, unless weights beyond double precision fool the datum test (they are named
    instead); with photos in several groups that share no points, the groups are named too."""
    with np.errstate(all="ignore"):
        weights = diagnosis.extreme_weights(project)
        if weights:
            return (UNTRUSTED + " ".join(weights)
                    + " (With such weights the datum test reports directions as free that are not.)")
        groups = diagnosis.photo_groups(project).explain()
        values = diagnosis.implausible_values(project) + diagnosis.camera_units(project)
    if values:  # numbers that make the normal equations meaningless fool the datum test too
        return (UNTRUSTED + " ".join(values)
                + " (With such values the datum test reports directions as free that are not.)")
    return "\n".join([datum.explain(defects)] + groups)


def singular_message(project: Project, layout: UnknownLayout, column: int | None, what: str,
                     datum_fixed: bool = True) -> str:
    """The NumericalFailure text of a singular normal matrix: where it broke down and the likely
    cause (striptri.core.diagnosis: weights beyond double precision, photo groups without a datum,
    wild values, the unit of c); without one, the usual causes of an undetermined element."""
    labels = layout.column_labels(project.photos.ids, project.cameras.ids)
    where = f" (first at {labels[column]})" if column is not None and 0 <= column < len(labels) else ""
    with np.errstate(all="ignore"):
        causes = diagnosis.likely_causes(project, "singular")
    if causes:
        return f"{what}{where}: some element is not determined by the measurements.\n" + termination.causes_text(causes)
    datum_fixed = " although the control fixes the datum" if datum_fixed else ""
    return (f"{what}{datum_fixed}{where}: some orientation element is not determined by the measurements. Check "
            "that every photograph has enough well-distributed points (at least three, not on a line) and that "
            "each free camera constant is determined.")


def bundle_not_formed_message(project: Project, where: str = "at the approximate values") -> str:
    """Why the bundle's normal equations cannot be formed (``where``): numbers that overflow
    (wild values, c in another unit: core.diagnosis) or, failing those, a point in the plane of a
    camera."""
    with np.errstate(all="ignore"):
        causes = diagnosis.likely_causes(project, "overflow")
    if causes:
        return (f"the bundle adjustment cannot form its equations {where}: their numbers "
                "overflow (they are not finite).\n" + termination.causes_text(causes))
    return (f"a point lies in the plane of a camera {where} (its projection is undefined); check the approximate "
            "orientations and points")
