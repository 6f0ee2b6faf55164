"""Precision and the cofactors of the residuals (DESIGN section 6).

Mean errors of the unknowns and of functions of them live on AdjustmentResult
(``mean_error``, ``photo_mean_errors``); this module adds what needs one more pass over the
groups: the cofactor matrix of the residuals of each group,

    Qvv = Q A^T M^-1 (M - B Qxx B^T) M^-1 A Q,

its diagonal gives the redundancy numbers ``r_i = qvv_i / q_i`` (they add up to the redundancy)
and the normalised residuals ``w_i = v_i / (sigma_prior sqrt(qvv_i))`` of Baarda's w-test, with
the a-priori sigma0 = 1 (the plate sigmas are taken as known).

A bundle result (without distances or free network) takes the same numbers from the collinearity
form, points as unknowns, O(k^2) per point of k rays instead of O(k^3) (bundle.precision;
``residual_cofactors(form=...)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..equations.linearise import At, Sweep, precision_options
from ..parallel import map_ordered
from ..solvers.threads import chunk_threads
from . import collinearity_form
from ..equations.observations import observations_of
from ..core.options import AdjustmentOptions
from ..core.result import AdjustmentResult
from ..selected_inverse.covariance import ray_slots, strongest_correlations
from ..equations.groups import build_batches
from ..equations.joint_groups import JointGroups, has_distances, joint_intersections
from ..model import Project
from ..equations.parameter_observations import build_parameter_observations
from ..equations.triangulation import ray_terms, safe_inverse
from ..equations import ray_columns, weights
from ..equations.point_precision import joint_form

W_CRITICAL = 3.29  # two-sided, alpha0 = 0.001 (Baarda)


@dataclass
class ResidualCofactors:
    plate: np.ndarray  # (m_ip, 2) qvv of the plate coordinates
    control: np.ndarray  # (n_pt, 3) qvv of weighted control coordinates (0 elsewhere)
    parameters: np.ndarray  # (p,) qvv of observed elements
    # with plate_blocks: per chunk (image_rows (m, k), Qvv (m, 2k, 2k)), the plate part of each
    # group's Qvv, (x, y) per ray in chain order (reliability.separability's blocks); a joint group
    # of points joined by distances (joint_groups) is one block over all its rays
    plate_blocks: list | None = None
    distances: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (r,) qvv of distances.csv's rows (m^2)
    # (r,) |X_a - X_b| of the points as their groups define them at the result (m, reduced frame)
    distance_adjusted: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # (n_pt,) points whose conditions are degenerate at the adjusted values (singular A Q A^T): their
    # qvv are nan, so nothing tests their measurements
    undetermined: np.ndarray | None = None

    def redundancy_numbers(self, project: Project, result: AdjustmentResult) -> dict:
        obs = observations_of(project, result.offset)
        pobs = build_parameter_observations(project, result.offset)
        return {
            "plate": self.plate / obs.q_plate,
            "control": np.where(obs.q_control > 0, self.control / np.where(obs.q_control > 0, obs.q_control, 1), 0),
            "parameters": weights.weigh(self.parameters, pobs.sigma) if len(pobs) else np.zeros(0),
            "distances": weights.weigh(self.distances, project.distances.sigma) if len(self.distances) else np.zeros(0),
        }


def residual_cofactors(project: Project, result: AdjustmentResult, options: AdjustmentOptions = AdjustmentOptions(),
                       plate_blocks: bool = False, form: str = "auto") -> ResidualCofactors:
    """Diagonal of Qvv for every observation, at the converged solution; with ``plate_blocks`` also
    each group's whole plate block of Qvv from the same products (the correlations of its w-tests,
    reliability.separability), at a small fraction of the pass's cost.

    form: "conditions" (below), "collinearity" (bundle.precision: points as unknowns, for a bundle
    result) or "auto": the collinearity form where ``bundle.precision.applies``, else the conditions
    form. Both give the same numbers (tests/test_bundle_precision.py).

    Per batch of groups, by matrix products (no einsum of three operands): ``M = (A Q) A^T``,
    ``B Qxx B^T`` by Covariance.group_forms (Qxx read by blocks of photo pairs), ``K = M^-1 (M - B Qxx
    B^T) M^-1`` and ``qvv_o = sum_c (K A Q)_co (A Q)_co``. Memory is that of one chunk of groups.
    A result of the method of conditions that kept its final checks' whitened groups
    (core.result.SolutionSystems) gives them to the conditions form, once (_solution_cofactors)."""
    if form not in ("auto", "conditions", "collinearity"):
        raise ValueError(f"unknown form {form!r}")
    kept = result.solution_systems.take(project) if result.solution_systems is not None else None
    if form == "collinearity" or (form == "auto" and collinearity_form.applies(project, result)):
        return _collinearity_cofactors(project, result, options, plate_blocks)
    if kept is not None:
        q_plate, q_control, blocks, undetermined = _solution_cofactors(project, result, options, plate_blocks, kept)
        q_distance = d_adjusted = np.zeros(0)
    else:
        q_plate, q_control, blocks, q_distance, d_adjusted, undetermined = _conditions_cofactors(
            project, result, options, plate_blocks)
    return ResidualCofactors(plate=q_plate, control=q_control, parameters=_parameter_cofactors(project, result),
                             plate_blocks=blocks, distances=q_distance, distance_adjusted=d_adjusted,
                             undetermined=undetermined)


def plate_blocks_of(project: Project, result: AdjustmentResult, options: AdjustmentOptions,
                    points: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The plate blocks of Qvv (``residual_cofactors(..., plate_blocks=True).plate_blocks``) of the
    groups of the points ``points`` (n_pt,) bool only: the w-tests' correlations of the points
    that data snooping suspects (reliability.separability), without the blocks of every other
    point. A project with distances: every group's (joint groups couple points)."""
    if collinearity_form.applies(project, result):
        return _collinearity_cofactors(project, result, options, True, points).plate_blocks
    if getattr(project, "distances", None) is not None:
        return _conditions_cofactors(project, result, options, True)[2]
    return _conditions_cofactors(project, result, options, True, points=points)[2]


def _collinearity_cofactors(project: Project, result: AdjustmentResult, options: AdjustmentOptions,
                            plate_blocks: bool, points: np.ndarray | None = None) -> ResidualCofactors:
    """The collinearity form (bundle.precision), with the points where its subtraction ``q - J Qxx
    J^T`` would lose digits (a redundancy number below bundle.precision.R_SUBTRACTION) taken from
    the conditions form, which forms their qvv without it. points: (n_pt,) bool, only these."""
    c = collinearity_form.residual_cofactors(project, result, plate_blocks, points=points)
    q_plate, q_control, blocks, undetermined = _conditions_form_of(project, result, options, c.imprecise, c.plate,
                                                                   c.control, c.plate_blocks)
    return ResidualCofactors(plate=q_plate, control=q_control, parameters=_parameter_cofactors(project, result),
                             plate_blocks=blocks, undetermined=undetermined)


def _conditions_form_of(project: Project, result: AdjustmentResult, options: AdjustmentOptions, points: np.ndarray,
                        q_plate: np.ndarray, q_control: np.ndarray, blocks: list | None):
    """The cofactors q_plate, q_control and blocks (None: not formed) with those of the points
    ``points`` (n_pt,) bool replaced by the conditions form's (_conditions_cofactors), which also
    tells which of them are undetermined. -> (q_plate, q_control, blocks, undetermined (n_pt,))."""
    if not points.any():
        return q_plate, q_control, blocks, np.zeros(len(project.points), dtype=bool)
    q_p, q_c, b, _, _, undetermined = _conditions_cofactors(project, result, options, blocks is not None,
                                                            points=points)
    rows = points[project.image_points.point_index]
    q_plate[rows] = q_p[rows]
    q_control[points] = q_c[points]
    if blocks is not None:  # each chunk without those points, then theirs
        point_of = project.image_points.point_index
        kept = []
        for r, q in blocks:
            keep = ~points[point_of[r[:, 0]]]
            if keep.any():
                kept.append((r[keep], q[keep]))
        blocks = kept + b
    return q_plate, q_control, blocks, undetermined


def _solution_cofactors(project: Project, result: AdjustmentResult, options: AdjustmentOptions, plate_blocks: bool,
                        kept: list):
    """The conditions form from the whitened groups the final checks kept (core.result.SolutionSystems,
    Bw = L^-1 B, Gt = L^-1 A Q with M = L L^T): ``Q A^T K A Q = Gt^T (I - Bw Qxx Bw^T) Gt``, the
    same Qvv as _conditions_cofactors' without linearising the groups again. The points of groups
    whose M is not clearly regular (the conditions form tells the degenerate ones: group_inverse)
    and of chunks kept without their systems (long tracks, whose B by ray the conditions form
    reads) are formed by the conditions form. Each chunk is let go once used. -> (q_plate, q_control,
    blocks, undetermined) as _conditions_cofactors' (a project without distances)."""
    obs = observations_of(project, result.offset)
    cov = result.covariance
    q_plate, q_control = np.zeros_like(obs.plate), np.zeros_like(obs.control)
    blocks = [] if plate_blocks else None
    again = np.zeros(len(project.points), dtype=bool)  # the points formed by the conditions form

    def cofactors(i):  # a chunk's qvv (m, no) and plate blocks, in a chunk thread
        white, kept[i] = kept[i], None
        if white.Bw is None:
            return white, None, None
        K = cov.group_forms(group_slots(white.Bw, white.chunk, result))  # Bw Qxx Bw^T, then I - it
        np.negative(K, out=K)
        diagonal = np.arange(K.shape[1])
        K[:, diagonal, diagonal] += 1.0
        KG = K @ white.Gt
        block = None
        if plate_blocks:
            n = 2 * white.chunk.image_rows.shape[1]
            block = (white.chunk.image_rows, np.swapaxes(white.Gt[:, :, :n], 1, 2) @ KG[:, :, :n])
        return white, np.einsum("mco,mco->mo", KG, white.Gt), block

    pairs = sum(w.chunk.photo_index.size * w.chunk.photo_index.shape[1] for w in kept)
    for white, qvv, block in map_ordered(cofactors, range(len(kept)), chunk_threads(pairs)):
        chunk = white.chunk
        if qvv is None:
            again[chunk.point_index] = True
            continue
        again[chunk.point_index[~white.clear]] = True
        m, k = chunk.image_rows.shape
        if block is not None:
            blocks.append(block)
        q_plate[chunk.image_rows] = qvv[:, : 2 * k].reshape(m, k, 2)
        if chunk.has_control:
            q_control[chunk.point_index] = qvv[:, 2 * k:]  # 0 where Q is (Gt's column of zeros)
    return _conditions_form_of(project, result, options, again, q_plate, q_control, blocks)


def _conditions_cofactors(project: Project, result: AdjustmentResult, options: AdjustmentOptions,
                          plate_blocks: bool, points: np.ndarray | None = None):
    """The conditions form (residual_cofactors' doc) of every group, or of the groups of the points
    ``points`` (n_pt,) bool (a project without distances). -> (q_plate (m_ip, 2), q_control (n_pt, 3),
    blocks or None, the distances' qvv (r,), their adjusted values (r,); joint_groups, and the
    points left untested (n_pt,): those whose conditions are degenerate at the adjusted values
    (singular A Q A^T); their qvv are nan and they have no block)."""
    undetermined = np.zeros(len(project.points), dtype=bool)
    obs = observations_of(project, result.offset)
    joint = None
    if points is None:
        batches, joint = JointGroups.of(project, build_batches(project))
    else:  # the batches of the points' own rows (a group's chain depends on its rows only), rows mapped back
        ip = project.image_points
        rows = np.flatnonzero(points[ip.point_index])
        own = replace(project, image_points=replace(ip, photo_index=ip.photo_index[rows],
                                                    point_index=ip.point_index[rows], xy=ip.xy[rows],
                                                    sigma_xy=ip.sigma_xy[rows]))
        batches = [replace(b, image_rows=rows[b.image_rows]) for b in build_batches(own)]
    sweep = Sweep(batches, At.of_result(result, obs), precision_options(options), joint)
    cov = result.covariance
    q_plate = np.zeros_like(obs.plate)
    q_control = np.zeros_like(obs.control)
    blocks = [] if plate_blocks else None

    def cofactors(chunk, s):  # a chunk's qvv (m, no), degenerate groups (m,) and plate blocks, in a chunk thread
        AQ = s.A * s.Q[:, None, :]  # (m, nc, no): A Q
        M = AQ @ np.swapaxes(s.A, 1, 2)
        Minv, bad = group_inverse(M, chunk)
        K = Minv @ (M - cov.group_forms(group_slots(s.B, chunk, result, ray_columns.of_system(s)))) @ Minv
        KAQ = K @ AQ
        qvv = np.einsum("mco,mco->mo", KAQ, AQ)
        qvv[bad] = np.nan
        block = None
        if plate_blocks and not bad.all():
            good, n = ~bad, 2 * chunk.image_rows.shape[1]
            block = (chunk.image_rows[good], np.swapaxes(AQ[good, :, :n], 1, 2) @ KAQ[good, :, :n])
        return qvv, bad, block

    for chunk, s, (qvv, bad, block) in sweep.systems(cofactors):
        undetermined[chunk.point_index[bad]] = True
        m, k = chunk.image_rows.shape
        if block is not None:
            blocks.append(block)
        q_plate[chunk.image_rows] = qvv[:, : 2 * k].reshape(m, k, 2)
        if chunk.has_control:
            q_control[chunk.point_index] = np.where(s.Q[:, 2 * k:] > 0, qvv[:, 2 * k:], 0.0)
    q_distance, d_adjusted = _joint_residual_cofactors(sweep.joint_systems(), result, project, q_plate, q_control,
                                                       blocks, undetermined)
    return q_plate, q_control, blocks, q_distance, d_adjusted, undetermined


def _parameter_cofactors(project: Project, result: AdjustmentResult) -> np.ndarray:
    """qvv (p,) of the observed elements: ``sigma^2 - g^T Qxx g`` (g the gradient of each)."""
    pobs = build_parameter_observations(project, result.offset)
    if not len(pobs):
        return np.zeros(0)
    _, grad, cols = pobs.evaluate(result.state, result.layout, result.layout.rotation_maps(result.state))
    Qloc = result.covariance.entries(cols[:, :, None], cols[:, None, :])
    return pobs.sigma**2 - np.einsum("pi,pi->p", (Qloc @ grad[:, :, None])[:, :, 0], grad)


def distance_cofactors(project: Project, result: AdjustmentResult,
                       options: AdjustmentOptions = AdjustmentOptions()) -> tuple[np.ndarray, np.ndarray]:
    """qvv (r,) of distances.csv's rows and the adjusted distances (r,) (m), from the joint groups
    alone (joint_groups; the same numbers as residual_cofactors, without the pass over the other
    groups). Empty arrays without distances."""
    obs = observations_of(project, result.offset)
    _, joint = JointGroups.of(project, build_batches(project))
    sweep = Sweep([], At.of_result(result, obs), options, joint)
    return _joint_residual_cofactors(sweep.joint_systems(), result, project, np.zeros_like(obs.plate),
                                     np.zeros_like(obs.control), None)


def _joint_residual_cofactors(systems: list, result: AdjustmentResult, project: Project, q_plate: np.ndarray,
                              q_control: np.ndarray, blocks: list | None,
                              undetermined: np.ndarray | None = None) -> np.ndarray:
    """Qvv of the joint groups (joint_groups.JointSystem, one at a time: few) into q_plate (m_ip, 2)
    and q_control (n_pt, 3), each group's plate block appended to blocks (image rows (1, K) of all
    its rays, Qvv (1, 2K, 2K)); returns the distances' qvv (r,) and their adjusted values (r,) (m),
    |X_a - X_b| of the points as their groups define them (empty without distances)."""
    if not systems:
        return np.zeros(0), np.zeros(0)
    q_distance = np.zeros(len(project.distances))
    adjusted = np.zeros(len(project.distances))
    cov = result.covariance
    for js in systems:
        AQ = js.A * js.Q[None, :]
        M = AQ @ js.A.T
        chunk = _JointChunk(js.photo_index[None], js.point_index)
        Minv, bad = group_inverse(M[None], chunk)
        Minv = Minv[0]
        K = Minv @ (M - cov.group_forms(group_slots(js.B[None], chunk, result))[0]) @ Minv
        KAQ = K @ AQ
        qvv = np.einsum("co,co->o", KAQ, AQ)
        if bad[0]:  # the joint group's conditions are degenerate: none of its observations is tested
            qvv[:] = np.nan
            if undetermined is not None:
                undetermined[js.point_index] = True
        q_plate.reshape(-1)[js.plate_target] = qvv[js.plate_pos]
        q_control.reshape(-1)[js.control_target] = qvv[js.control_pos]
        q_distance[js.component.distances] = qvv[js.distance_pos]
        ends = js.component.ends
        adjusted[js.component.distances] = np.linalg.norm(js.xyz[ends[:, 0]] - js.xyz[ends[:, 1]], axis=1)
        if blocks is not None and not bad[0]:
            p = js.plate_pos
            blocks.append((np.concatenate(js.member_rays)[None], (AQ[:, p].T @ KAQ[:, p])[None]))
    return q_distance, adjusted


@dataclass(frozen=True)
class _JointChunk:
    """What group_slots and group_inverse read of a chunk, for one joint group: photo_index
    (1, K) and the member points (point_index, for messages)."""

    photo_index: np.ndarray
    point_index: np.ndarray


def group_slots(G: np.ndarray, chunk, result: AdjustmentResult, by_ray=None) -> list:
    """covariance.Slots of derivatives G (m, r, k * width) with respect to the columns ``cols`` of a
    chunk's GroupSystem (per ray: its photo's 6 columns, then its camera's estimated elements);
    by_ray: G grouped by ray (ray_columns.of_system of the chunk's system), where it has that form."""
    lay = result.layout
    m, k = chunk.photo_index.shape
    G = G.reshape(m, G.shape[1], k, 6 + lay.camera_width)
    camera = result.state.camera_of_photo[chunk.photo_index]
    return ray_slots(G, chunk.photo_index, lay.photo_cols, camera, lay.camera_cols[:, lay.camera_elements], by_ray)


def group_inverse(M: np.ndarray, chunk) -> tuple[np.ndarray, np.ndarray]:
    """M^-1 (m, nc, nc) of every group of a chunk (M = A Q A^T) and which are degenerate (m,): a group
    whose M is singular or not finite (its conditions degenerate at the adjusted values: rays along
    the base, standard deviations of zero or beyond double precision) gets nan; its point is not
    determined by its rays, and the caller leaves it untested (docs/decisions.md "Undetermined
    points")."""
    Minv, regular = safe_inverse(M)
    return Minv, ~regular


def normalised_residuals(v: np.ndarray, qvv: np.ndarray) -> np.ndarray:
    """w = v / sqrt(qvv) (a-priori sigma0 = 1); nan where the observation has no redundancy."""
    ok = qvv > 1e-12 * np.max(np.abs(qvv), initial=1.0)
    return np.where(ok, v / np.sqrt(np.where(ok, qvv, 1.0)), np.nan)


def joint_point_covariance(project: Project, result: AdjustmentResult, tri, options: AdjustmentOptions = AdjustmentOptions()):
    """Point cofactors by Schmid's rigorous joint form (92): ``m_F^2 = m^2 F^T R F`` with R the joint
    cofactor matrix of the adjusted unknowns and the adjusted observations of the point's group.

    For a group (DESIGN section 4) the estimator is linear in its observations l:
    ``Cov(l^) = Q - Qvv``, ``Cov(x^, l^) = -Qxx B^T M^-1 A Q`` (the correlation of the adjusted
    unknowns with the adjusted observations; Cov(x^, v) = 0). The point X(x^, l^) is the least-squares
    intersection of the group's adjusted rays with its given coordinates (held or weighted), so
    ``dX/dl^ = Qm [J^T P, P_given]`` and ``dX/dx^ = -Qm J^T P J_x`` with ``Qm = (J^T P J + P_given)^-1``.

    tri: triangulation.Triangulated (its coordinates; its (90) cofactors are kept for points that
    form no group). Returns (n_points, 3, 3) cofactors (times sigma0^2 for covariances).
    """
    obs = observations_of(project, result.offset)
    sweep = Sweep(build_batches(project), At.of_result(result, obs), precision_options(options))
    cov = result.covariance
    out = tri.cov_measurement + tri.cov_orientation
    state = result.state
    for chunk, s in sweep.systems():
        m, k = chunk.image_rows.shape
        AQ = s.A * s.Q[:, None, :]
        M = AQ @ np.swapaxes(s.A, 1, 2)
        Minv, bad = group_inverse(M, chunk)  # a degenerate group keeps its (90) cofactors, nan where undefined
        # the intersection's derivatives, rays in the group's chain order
        ph = chunk.photo_index
        params, conv = state.camera_terms(ph)
        xyz_ground = tri.xyz[chunk.point_index]
        rows = chunk.image_rows
        _, dX, dO, drot, dcam = ray_terms(state.R_ground_from_cam[ph], state.xyz0[ph], params, conv, xyz_ground,
                                          result.plate_adjusted[rows], obs.plate[rows],
                                          result.layout.lens_in_play(state))
        T = sweep.T[ph]
        J_parts = [dO, np.einsum("mkai,mkij->mkaj", drot, T)]
        if result.layout.camera_width:
            J_parts.append(dcam[..., result.layout.camera_elements])
        J_x = np.concatenate(J_parts, 3)  # (m, k, 2, 6 + camera_width): the columns of s.cols
        JX = dX.reshape(m, 2 * k, 3)
        p_plate = weights.inverse_variance(s.Q[:, : 2 * k])
        n_obs = s.Q.shape[1]
        if chunk.has_control:
            q_c = s.Q[:, 2 * k:]
            given = np.array(chunk.given_axes)[None, :] & np.ones((m, 1), dtype=bool)
            fixed = given & (q_c == 0)
            p_c = weights.variance_weight(q_c, q_c > 0)
        else:
            fixed = np.zeros((m, 3), dtype=bool)
            p_c = np.zeros((m, 0))
        JXp = JX * p_plate[:, :, None]  # (m, 2k, 3): P J
        Nx = np.swapaxes(JX, 1, 2) @ JXp
        if chunk.has_control:
            Nx = Nx + p_c[:, :, None] * np.eye(3)
        free = ~fixed
        Nx = np.where(free[:, :, None] & free[:, None, :], Nx, 0.0) + fixed[:, :, None] * np.eye(3)
        Qm = safe_inverse(Nx)[0] * (free[:, :, None] & free[:, None, :])  # nan: the point is not determined
        F = np.zeros((m, 3, n_obs))
        F[:, :, : 2 * k] = Qm @ np.swapaxes(JXp, 1, 2)
        if chunk.has_control:
            F[:, :, 2 * k:] = Qm * p_c[:, None, :]
        G = -np.einsum("mika,mkac->mikc", F[:, :, : 2 * k].reshape(m, 3, k, 2), J_x).reshape(m, 3, -1)
        # G Qxx G^T, G Qxx B^T and B Qxx B^T at once (Qxx read by blocks, matrix products)
        HQH = cov.group_forms(group_slots(np.concatenate([G, s.B], 1), chunk, result))
        GQG, GQB, BQB = HQH[:, :3, :3], HQH[:, :3, 3:], HQH[:, 3:, 3:]
        good = ~bad
        out[chunk.point_index[good]] = joint_form(GQG, GQB, BQB, M, Minv, AQ, s.Q, F)[good]
    if has_distances(project):  # the points joined by distances: one joint intersection per joint group
        _joint_groups_92(project, result, tri, options, out)
    return out


def _joint_groups_92(project: Project, result: AdjustmentResult, tri, options: AdjustmentOptions,
                     out: np.ndarray) -> None:
    """The form (92) of joint_point_covariance for the points joined by distances (joint_groups):
    X of the members intersected together from the joint group's adjusted observations (rays, given
    coordinates, distances) with the orientation held, ``dX/dl = F``, ``dX/dx = G``
    (joint_groups.JointIntersection), and ``Cov(l^)``, ``Cov(x^, l^)`` of the joint group. Writes
    the members' 3x3 blocks into out (n_points, 3, 3)."""
    cov = result.covariance
    for js, inter in joint_intersections(project, result, tri.xyz, options.conditions.scale_form):
        n3 = len(inter.G)
        AQ = js.A * js.Q[None, :]
        M = AQ @ js.A.T
        chunk = _JointChunk(js.photo_index[None], js.point_index)
        Minv, bad = group_inverse(M[None], chunk)
        if bad[0]:  # degenerate: the members keep their (90) cofactors
            continue
        HQH = cov.group_forms(group_slots(np.concatenate([inter.G, js.B], 0)[None], chunk, result))
        GQG, GQB, BQB = HQH[:, :n3, :n3], HQH[:, :n3, n3:], HQH[:, n3:, n3:]
        full = joint_form(GQG, GQB, BQB, M[None], Minv, AQ[None], js.Q[None], inter.F[None])[0]
        for j, p in enumerate(js.point_index):
            out[p] = full[3 * j:3 * j + 3, 3 * j:3 * j + 3]


PHOTO_ELEMENTS = ("X0", "Y0", "Z0", "rot1", "rot2", "rot3")


def camera_correlations(result) -> list[dict]:
    """Correlations of the estimated camera elements (DESIGN section 6), per camera with any:

    ``camera`` (index), ``elements`` (indices into lens.CAMERA_ELEMENTS), ``sigma`` (mean errors),
    ``matrix`` (correlations among them) and ``exterior``: for each element the exterior element
    it is most correlated with, as (photo index, element index 0-5: X0, Y0, Z0 and the three
    rotation unknowns, correlation); (-1, -1, nan) when no exterior element is estimated.
    """
    lay, cov = result.layout, result.covariance
    s0 = result.sigma0_for_precision
    photo_cols = lay.photo_cols.ravel()
    q_photo = np.append(cov.diag(), 0.0)[photo_cols]  # -1, a held element, reads zero
    s_photo = np.sqrt(np.maximum(np.where(photo_cols >= 0, q_photo, np.nan), 0.0))
    out = []
    for j in range(len(lay.camera_cols)):
        est = np.flatnonzero(lay.camera_cols[j] >= 0)
        if not len(est):
            continue
        c = lay.camera_cols[j][est]
        Q = cov.entries(c[:, None], c[None, :])
        s = np.sqrt(np.maximum(np.diag(Q), 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            matrix = Q / np.outer(s, s)
            ext = cov.entries(c[:, None], photo_cols[None, :]) / (s[:, None] * s_photo[None, :])
        out.append({"camera": j, "elements": est, "sigma": s0 * s, "matrix": matrix,
                    "exterior": strongest_correlations(ext, 6)})
    return out
