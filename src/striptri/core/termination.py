"""Why an iteration stopped, and the message that says so (summary.json "termination").

The reasons (core.result.TERMINATIONS, docs/decisions.md "Termination"):

* ``converged`` - the correction below the tolerance in units of its standard deviation, in every
  element and every function of the elements (core.convergence.correction_in_sigma; or the round-off
  floor, core.convergence.has_converged); no message;
* ``cost_flat`` - bundle method: a step lowered the sum of squares by less than cost_tolerance of
  it while some correction was still above the tolerance; a result, with a message that says so;
* ``iteration_limit`` - max_iterations reached first; a failure unless kept;
* ``diverged`` - non-finite numbers, or corrections growing without bound; always a failure,
  raised as NumericalFailure with a message of the same kind.

A message has four parts: what happened (one sentence), the last TABLE_ROWS iterations of the
history (v^T P v, sigma0 and the largest correction in standard deviations, and, when the final
checks computed it, the correction the next iteration would make), what that means (still
converging, stalled, growing), and the likely cause: striptri.core.diagnosis's findings, or the usual
causes when it finds nothing.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

TABLE_ROWS = 3
# The next correction below this fraction of the last: still converging (a Gauss-Newton iteration
# that converges shrinks its corrections by far more: linearly at worst, quadratically near the end).
STILL_SHRINKING = 0.9
GROWING = 1.1

WHAT = {
    "conditions": "the adjustment by conditions",
    "bundle": "the bundle adjustment",
    "sequential": "the sequential triangulation",
}

USUAL_CAUSES = (
    "Likely causes: approximate orientations too far from the truth (check the unit and convention of the "
    "angles in project.toml, and the signs of omega, phi, kappa and the centres in photos.csv), a gross error "
    "in the measurements, or an element the measurements hardly determine (a weak geometry)."
)


def what_of(method: str) -> str:
    return WHAT.get(method, f"the {method} adjustment")


def _fmt(x: float, digits: int = 4) -> str:
    return "nan" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


ELEMENT_FOOTNOTE = "    (sd: a correction in units of the standard deviation its element would have if all others were known)"
FUNCTION_FOOTNOTE = ("    (sd: the largest correction of any element or function of the elements, in units of its standard "
                     "deviation)")


def table(history: Sequence, redundancy: int, next_correction: float | None = None, element: bool = False) -> str:
    """The last TABLE_ROWS iterations: v^T P v, sigma0 = sqrt(v^T P v / r) and the correction in
    standard deviations; a last row with the next iteration's correction when given. The correction
    is the history's convergence measure (max_correction), or with ``element`` the largest single
    element's (element_correction, the figure that shows divergence). The footnote says which: an
    iteration of the simultaneous adjustments carries an element_correction, the sequential
    method's measure is the element one."""
    simultaneous = bool(history) and not math.isnan(getattr(history[-1], "element_correction", float("nan")))
    column = "element_correction" if element and simultaneous else "max_correction"
    footnote = FUNCTION_FOOTNOTE if simultaneous and column == "max_correction" else ELEMENT_FOOTNOTE
    lines = ["    iteration       v^T P v        sigma0   largest correction"]
    first = max(len(history) - TABLE_ROWS, 0)
    for k in range(first, len(history)):
        h = history[k]
        s0 = math.sqrt(h.vtpv / redundancy) if redundancy > 0 and math.isfinite(h.vtpv) and h.vtpv >= 0 else float("nan")
        lines.append(f"    {k + 1:9d}  {_fmt(h.vtpv, 6):>12}  {_fmt(s0, 5):>12}   {_fmt(getattr(h, column), 3)} sd")
    if next_correction is not None and math.isfinite(next_correction):
        lines.append(f"    {'(next)':>9}  {'':>12}  {'':>12}   {_fmt(next_correction, 3)} sd")
    lines.append(footnote)
    return "\n".join(lines)


def trend(history: Sequence, next_correction: float | None = None) -> tuple[str, float]:
    """("shrinking" | "stalled" | "growing" | "unknown", the last ratio of consecutive corrections)."""
    c = [h.max_correction for h in history]
    if next_correction is not None and math.isfinite(next_correction):
        c.append(next_correction)
    if len(c) < 2 or not all(math.isfinite(x) for x in c[-3:]):
        return "unknown", float("nan")
    ratio = c[-1] / c[-2] if c[-2] > 0 else float("inf")
    if ratio < STILL_SHRINKING and (len(c) < 3 or c[-1] < c[-3]):
        return "shrinking", ratio
    if ratio > GROWING and (len(c) < 3 or c[-2] > c[-3]):
        return "growing", ratio
    return "stalled", ratio


def causes_text(causes: Sequence[str], fallback: str = USUAL_CAUSES) -> str:
    if not causes:
        return fallback
    if len(causes) == 1:
        return "Likely cause: " + causes[0]
    return "Likely causes:\n" + "\n".join(f"  - {c}" for c in causes)


def iteration_limit(method: str, history: Sequence, redundancy: int, max_iterations: int, tolerance: float,
                    next_correction: float | None, causes: Callable[[], list[str]]) -> str:
    """The message of an iteration that reached max_iterations before converging: still converging
    (raise the limit), or stalled / growing (more iterations will not help), and the likely cause
    (``causes()``, striptri.core.diagnosis). A sound but slow convergence without a cause gets only the
    advice to raise the limit; with a cause, the cause comes first."""
    n = len(history)
    head = (f"{what_of(method)} did not converge in {n} iteration{'s' if n != 1 else ''}: it reached the limit "
            f"[adjustment] max_iterations = {max_iterations} while the largest correction was still "
            f"{_fmt(history[-1].max_correction, 3)} sd (converged means below {tolerance:g} sd).")
    found = causes()
    state, ratio = trend(history, next_correction)
    if state == "shrinking":
        c = next_correction if next_correction is not None and math.isfinite(next_correction) else history[-1].max_correction
        more = math.ceil(math.log(tolerance / c) / math.log(ratio)) if 0 < ratio < 1 and c > tolerance else 1
        more = max(more, 1)
        suggest = max(30, max_iterations + 2 * more) if max_iterations < 30 else max_iterations + 2 * more
        raise_it = (f"Raise [adjustment] max_iterations in project.toml (or give --max-iterations), e.g. to "
                    f"{suggest}.")
        if not found:
            body = (f"The corrections were still shrinking (by a factor of {_fmt(1 / ratio, 3)} in the last step): "
                    f"the adjustment is converging and only needs more iterations (about {more} more at this rate). "
                    + raise_it)
            return "\n".join([head, table(history, redundancy, next_correction), body])
        body = (f"The corrections were still shrinking (by a factor of {_fmt(1 / ratio, 3)} in the last step), but "
                f"{_sigma0_words(history, redundancy)}, so more iterations are unlikely to give a sound result "
                "before the cause below is removed.")
        return "\n".join([head, table(history, redundancy, next_correction), body, causes_text(found)])
    if state == "unknown":
        meaning = ("After so few iterations no trend shows: raise [adjustment] max_iterations in project.toml (or "
                   "give --max-iterations); if it still does not converge, look at the causes below.")
    elif state == "growing":
        meaning = ("The corrections are growing: the iteration is moving away from a solution, and more iterations "
                   "will not help.")
    else:
        meaning = ("The corrections no longer shrink (they stall or oscillate): the iteration is not approaching a "
                   "solution, and more iterations will not help.")
    return "\n".join([head, table(history, redundancy, next_correction), meaning, causes_text(found)])


def _sigma0_words(history: Sequence, redundancy: int) -> str:
    vtpv = history[-1].vtpv
    if redundancy > 0 and math.isfinite(vtpv) and vtpv >= 0:
        return (f"sigma0 = {_fmt(math.sqrt(vtpv / redundancy), 4)} (the residuals are on average that many times "
                "their standard deviations)")
    return "the residuals are far from a solution's"


def diverged(method: str, history: Sequence, redundancy: int, causes: Callable[[], list[str]]) -> str:
    """The message of a diverging iteration (raised as NumericalFailure)."""
    last = history[-1]
    finite = math.isfinite(last.vtpv) and math.isfinite(last.max_correction)
    reason = ("its numbers became infinite or not a number (an overflow)" if not finite else
              "its corrections grew more than twofold in each of the last four iterations, far beyond any "
              "sensible step")
    head = f"{what_of(method)} diverged at iteration {len(history)}: {reason}."
    meaning = "The iteration is moving away from any solution; no result can be given."
    return "\n".join([head, table(history, redundancy, element=True), meaning, causes_text(causes())])


def became_singular(method: str, history: Sequence, redundancy: int, causes: Callable[[], list[str]]) -> str:
    """The message of an iteration whose normal matrix turned singular after regular ones (raised as
    NumericalFailure "diverged"): the control is the same as in the first iterations, so the datum is
    not what is missing; the iteration has wandered where the orientation is not determined."""
    head = (f"{what_of(method)} diverged at iteration {len(history) + 1}: its normal matrix became singular "
            f"there, though it was regular in the {len(history)} iteration{'s' if len(history) != 1 else ''} "
            "before with the same control and measurements, so the datum is not what is missing: the "
            "iteration has wandered to orientations that the measurements do not determine.")
    meaning = "The iteration is moving away from any solution; no result can be given."
    return "\n".join([head, table(history, redundancy, element=True), meaning, causes_text(causes())])


def cost_flat(method: str, history: Sequence, redundancy: int, cost_tolerance: float, tolerance: float) -> str:
    """The message of a bundle adjustment stopped by its cost tolerance (a result)."""
    n = len(history)
    head = (f"{what_of(method)} stopped at iteration {n} because its last step lowered the sum of squares by less "
            f"than [adjustment] cost_tolerance = {cost_tolerance:g} of it, while the largest correction was still "
            f"{_fmt(history[-1].max_correction, 3)} sd (above the tolerance {tolerance:g} sd).")
    meaning = ("This is a result: the fit to the measurements no longer changes, and the corrections that remain "
               "move the solution along directions the measurements hardly determine (points seen at narrow "
               "angles, weakly determined elements); their mean errors are large accordingly.")
    return "\n".join([head, table(history, redundancy), meaning])
