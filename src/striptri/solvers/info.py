"""What a solver reports of one solve (``SolveResult.info``, kept per outer iteration in
``Iteration.solver_info``): SolverInfo, one optional field per figure, None where the solver does
not report it (STYLE: a record of named fields, not a dict read back by string keys)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class SolverInfo:
    """One solve's report; every field None unless the solver named reports it.

    The iterative solvers (``gauss-seidel``, ``pcg``, ``strip-pcg``; solvers.iterative):

    inner_iterations: sweeps (Gauss-Seidel) or CG iterations of this solve (a count).
    relative_residual: ``|b~ - N~ y| / |b~|`` of the Jacobi-scaled system at the end (no unit).
    converged: whether relative_residual fell below the tolerance.
    slow: not converged, or more inner iterations than the solver's slow limit (the
        SlowConvergenceWarning was given).
    tolerance: SolverOptions.inner_tolerance, the relative residual aimed at (no unit).
    warm_start: SolverOptions.warm_start, where the iteration started ("zero", "previous", "projected").
    relaxation: ``gauss-seidel`` only, the over-relaxation factor omega (1: plain Gauss-Seidel).
    stagnated: ``gauss-seidel`` only, whether the sweeps stopped because the residual had not
        fallen by 1 % in STAGNATION_SWEEPS sweeps.
    restarts: ``pcg``/``strip-pcg``, the restarts of CG from the true residual (a count, at most 4).
    preconditioner: ``strip-pcg``, the relaxation over the strips ("jacobi" or "ssor").
    strips: ``strip-pcg``, the groups of columns relaxed as one block each (a count).
    dense_block: ``strip-pcg``, the columns of the dense block (cameras, photos of no strip).

    The direct solvers:

    bandwidth: ``banded``, the lower bandwidth of the banded part (columns); ``strip-pcg``, the
        widest strip's.
    border: ``banded``, the camera columns solved as a dense border (0: none).
    analyses: ``cholmod``/``cvxopt``, the symbolic factorisations made so far by this solver object
        (1 while N's pattern does not grow).
    mode: ``cholmod``, CHOLMOD's factorisation ("supernodal" or "simplicial").
    ordering: ``cholmod``, CHOLMOD's fill-reducing ordering ("nesdis", "amd", ...).
    orderings: ``sparse``, the block orderings computed so far by this solver object (a count).

    Added by the adjustment, not a solver:

    held_factor: True when the iteration solved on the factor of an earlier iteration's N (a chord
        step: conditions_method.adjust, where N is not formed anew, and bundle.adjust, where the
        reduced N is formed for the step's tests but not factorised); None when N was factorised.
    damping: the bundle only, the Levenberg-Marquardt factor lam (``N + lam diag(N)``) in force
        after the step's acceptance, i.e. the one the next step starts from (no unit); None when the
        iteration is plain Gauss-Newton.
    """

    inner_iterations: int | None = None
    relative_residual: float | None = None
    converged: bool | None = None
    slow: bool | None = None
    tolerance: float | None = None
    warm_start: str | None = None
    relaxation: float | None = None
    stagnated: bool | None = None
    restarts: int | None = None
    preconditioner: str | None = None
    strips: int | None = None
    dense_block: int | None = None
    bandwidth: int | None = None
    border: int | None = None
    analyses: int | None = None
    mode: str | None = None
    ordering: str | None = None
    orderings: int | None = None
    held_factor: bool | None = None
    damping: float | None = None

    def as_dict(self) -> dict:
        """The reported fields (not None), in field order (messages, benchmark records)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def merged(self, **changes) -> "SolverInfo":
        """A copy with ``changes`` (field=value; None withdraws a field)."""
        return replace(self, **changes)
