"""The bundle adjustment's checks after convergence (Schmid's final checks in the bundle's form):
:func:`final_checks`."""

from __future__ import annotations

import numpy as np

from .. import solvers
from ..core.explain import reduction_check
from ..core.result import Checks
from ..equations import weights
from ..errors import NumericalFailure
from .distances import linearise_distances
from .padding import real_rays
from .reduced import ReducedNormals


def final_checks(problem, solver, now, normals_at_solution: ReducedNormals | None = None, held: bool = False):
    """The reduced camera system at the solution and the checks after convergence.

    * ``max_condition_misclosure_sigma``: every observation equation holds for the adjusted
      observations (l + v of the last step) and the final unknowns: max |l^ - f(x^, X^)| / sigma
      (Schmid's final check);
    * ``max_BTk_sigma``: the reduced gradient vanishes at the solution (the bundle's form of
      Schmid 58): max |b_rcs,i| / sqrt(N_rcs,ii);
    * ``max_point_gradient_sigma``: likewise for the point coordinates, max |b_p,i| / sqrt(N_pp,ii);
    * ``vtpv_reduction_relative_difference``: v^T P v against the reduced sum
      ``e^T e - sum b_p^T N_pp^-1 b_p - b_rcs^T N_rcs^-1 b_rcs`` (Schmid 59).

    problem: the bundle's adjust._Problem; now: the estimate (orientations, points, adjusted
    observations); normals_at_solution: the undamped reduced normals the iteration formed there,
    with their kept chunks; formed here when not given. held: the solver holds the factor of an
    undamped Gauss-Newton step's N (adjust._Chord.usable): it solves (59) and the next correction,
    as the method of conditions does (docs/decisions.md "The final checks on the last factor": N
    at the solution differs from it by terms of the size of the last corrections, so b^T dx and
    the next correction change in their second order only); else the reduced system at the
    solution is factorised.

    Also returns the correction the next iteration would make (core.convergence.correction_in_sigma, as
    in the history; None when the system is singular), a by-product of (59).
    """
    obs = problem.obs
    state, xyz, plate_hat, control_hat, v_par, vtpv = now.state, now.xyz, now.plate_hat, now.control_hat, now.v_par, now.vtpv
    reuse = normals_at_solution is not None
    normals = normals_at_solution if reuse else problem.normals()
    max_g, max_gp = 0.0, 0.0
    # the distances' share of the points' gradient and of the diagonal of their normals (bundle.distances)
    b_dist, d_dist = np.zeros_like(xyz), np.zeros_like(xyz)
    if problem.distances is not None:
        e_d, Ja, Jb = linearise_distances(problem.distances, xyz, problem.unknowns.free)
        for ends, J in ((problem.distances.point_from, Ja), (problem.distances.point_to, Jb)):
            np.add.at(b_dist, ends, J * e_d[:, None])
            np.add.at(d_dist, ends, J**2)
    for chunk, scatters in zip(normals.kept if reuse else problem.chunks(state, xyz), problem.scatters):
        if not reuse:
            normals.add_points(chunk, state.camera_of_photo, scatters, keep=False)
        rows, e, sigma = real_rays(chunk.batch, chunk.batch.image_rows, chunk.e, chunk.sigma)
        # l^ - f = (l - f) + (l^ - l) = sigma e + v
        g = e + weights.whiten(plate_hat[rows] - obs.plate[rows], sigma)
        g_control = np.sqrt(chunk.weight) * (control_hat[chunk.batch.point_index] - xyz[chunk.batch.point_index])
        if g.size:
            max_g = max(max_g, float(np.max(np.abs(g))), float(np.max(np.abs(g_control))))
        pt = chunk.batch.point_index
        d = np.einsum("mii->mi", chunk.N_pp) + d_dist[pt]
        if chunk.b_p.size:
            max_gp = max(max_gp, float(np.max(np.where(chunk.free, np.abs(chunk.b_p + b_dist[pt]) / np.sqrt(d), 0.0))))
    if len(problem.pobs):
        J, cols, e = problem.parameter_rows(state)
        if not reuse:
            normals.add_rows(J, cols, e)
        max_g = max(max_g, float(np.max(np.abs(e + v_par / problem.pobs.sigma))))
    if not reuse:
        if problem.distances is not None:  # the chunks linearised again only for the distances' correction
            problem.couple(normals, list(problem.chunks(state, xyz)), xyz)
        else:
            normals.coupling = None
        normals.finish()
    normals.kept = []  # not needed beyond the checks
    d = normals.N.diagonal()
    btk = float(np.max(np.abs(normals.b) / np.sqrt(np.where(d > 0, d, 1.0)))) if len(d) else 0.0
    next_correction = None
    try:
        again = solver.solve_again(normals.b) if held and len(d) else None
        if again is not None:
            dx = again
        else:
            dx = problem.solve(normals, solver, state, xyz, target=False, explain=False).dx if len(d) else np.zeros(0)
        reduced = normals.ee - normals.reduced - float(normals.b @ dx)
        # the undamped step's d^T N d = b_rcs^T dx + sum b_p^T N_pp^-1 b_p (core.convergence.correction_in_sigma)
        next_correction = float(np.sqrt(max(float(normals.b @ dx) + normals.reduced, 0.0))) if len(d) else None
    except (solvers.SingularNormalMatrix, np.linalg.LinAlgError, NumericalFailure):
        reduced = float("nan")
    checks = Checks(max_condition_misclosure_sigma=max_g, max_BTk_sigma=btk,
                    vtpv_reduction_relative_difference=reduction_check(reduced, vtpv), max_point_gradient_sigma=max_gp)
    return normals, checks, next_correction
