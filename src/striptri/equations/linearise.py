"""Linearisation of the groups: the Gauss-Helmert blocks A, B, w and the cofactors Q.

For every group j (DESIGN section 4), at the current estimates (l^, x^):
``A = dg/dl``, ``B = dg/dx``, ``w = g(l^, x^) + A (l - l^)``, with Q the diagonal cofactors of the
group's observations (plate coordinates, then, for control, X, Y, Z with cofactor 0 where the
coordinate is held fixed). This module is the functional model's only contact with weights: it
scales each condition to unit variance at l^ (a constant per iteration, which leaves the adjustment
unchanged) so that the 2x2 ... blocks M = A Q A^T are well conditioned.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..geometry.camera import plate_vector
from ..errors import NumericalFailure
from ..parallel import map_ordered
from ..solvers.threads import chunk_threads
from ..geometry.lens import NCP, IdealPoints, ideal_from_observed
from .conditions import collinearity, expanded, of_rays, ray_chain, ray_conditions
from .groups import COLLINEARITY, GroupBatch, sweep_size
from .observations import Observations
from .parameters import State, UnknownLayout
from . import weights


@dataclass
class GroupSystem:
    """Linearised groups of one chunk. A: (m, nc, no), B: (m, nc, nu), cols: (m, nu) global columns
    (-1 = fixed), w: (m, nc), Q: (m, no), l, l_hat: (m, no) original and current observations.

    B is held in the compact form of the conditions where they have one (``per_ray`` (m, nc, t,
    nu / k): each condition's derivatives for its t rays ``rays`` (nc, t); conditions module doc)
    and spread over all k rays when first read; ``per_ray`` and ``rays`` are None otherwise.
    Products by ray (ray_columns) read the compact form."""

    A: np.ndarray
    dense_B: np.ndarray | None
    cols: np.ndarray
    w: np.ndarray
    Q: np.ndarray
    l: np.ndarray
    l_hat: np.ndarray
    g: np.ndarray
    per_ray: np.ndarray | None = None
    rays: np.ndarray | None = None

    @property
    def B(self) -> np.ndarray:
        if self.dense_B is None:
            m, nc = self.g.shape
            self.dense_B = expanded(self.per_ray, self.rays, self.cols.shape[1] // self.per_ray.shape[3]).reshape(
                m, nc, self.cols.shape[1])
        return self.dense_B


def group_observations(batch: GroupBatch, obs: Observations, plate_hat, control_hat):
    """Original and current observation vectors of each group and their cofactors: (m, no)."""
    m, k = batch.image_rows.shape
    parts_l = [obs.plate[batch.image_rows].reshape(m, 2 * k)]
    parts_h = [plate_hat[batch.image_rows].reshape(m, 2 * k)]
    parts_q = [obs.q_plate[batch.image_rows].reshape(m, 2 * k)]
    if batch.has_control:
        parts_l.append(obs.control[batch.point_index])
        parts_h.append(control_hat[batch.point_index])
        parts_q.append(obs.q_control[batch.point_index])
    return np.concatenate(parts_l, 1), np.concatenate(parts_h, 1), np.concatenate(parts_q, 1)


def evaluate(batch: GroupBatch, state: State, plate_hat, control_hat, scale_form: str = "3d",
             with_lens: bool | IdealPoints = True, plate_measured=None, ray_function=None):
    """Conditions and primitive derivatives of a chunk at (l^, x^): conditions.Linearised, with
    ``d_interior`` (m, nc, k, NCP) with respect to all camera elements (striptri.geometry.lens).

    The conditions see the ideal plate points of the observations (lens.ideal_from_observed);
    their derivatives are carried on to the observations and the camera elements by the chain
    rule. with_lens=False skips the camera model (allowed only when no additional parameter is
    nonzero or estimated: the ideal points are then the observations); the sweep's
    :func:`lens_table` (the ideal plate points of every image row at this (x^, l^)) is read instead
    of computing them for the chunk. plate_measured: the
    measurements (all image rows) when plate_hat are adjusted observations (lens doc: the plate
    convention corrects the measurement and adds the residual). ray_function: callable(r, O) ->
    conditions.RayConditions evaluated instead of the group's ray conditions (e.g.
    conditions.first_pair_intersection: the point as its group defines it).

    The group's own conditions come in the compact form of striptri.equations.conditions (each
    condition's derivatives for its own rays, ``rays``; conditions.expanded spreads them over all
    k); a ray_function's in the form it gives (first_pair_intersection: all k rays).
    """
    xy = plate_hat[batch.image_rows]
    R_ground_from_cam = state.R_ground_from_cam[batch.photo_index]
    xyz_centre = state.xyz0[batch.photo_index]
    params, conv = state.camera_terms(batch.photo_index)
    xyz_control = control_hat[batch.point_index]
    meas = None if plate_measured is None else plate_measured[batch.image_rows]
    if isinstance(with_lens, IdealPoints):
        r, table = batch.image_rows, with_lens
        ideal = IdealPoints(table.xy[r], table.d_obs[r], table.d_camera[r], table.converged[r])
    else:
        ideal = ideal_from_observed(xy, params, conv, meas) if with_lens else None
    if ideal is not None:
        if not ideal.converged.all():
            raise NumericalFailure(
                f"the lens distortion of {int((~ideal.converged).sum())} measurements cannot be inverted at the "
                "current camera elements (the distortion polynomial of an image-convention camera folds back "
                "inside the measured area). The method of conditions needs the rays of the measurements; the "
                "bundle method projects forward and does not (--method bundle), or give better starting "
                "values of k1, k2, k3")
        xy = ideal.xy
    if batch.family == COLLINEARITY:
        lin = collinearity(xy, R_ground_from_cam, xyz_centre, params[..., :3], xyz_control, compact=True)
    else:
        p = plate_vector(xy, params[..., :3])
        r = np.einsum("mkij,mkj->mki", R_ground_from_cam, p)
        rc = (ray_conditions(r, xyz_centre, xyz_control, batch.given_axes, scale_form, batch.star, compact=True)
              if ray_function is None else ray_function(r, xyz_centre))
        lin = ray_chain(rc, R_ground_from_cam, p)
    d_camera = np.zeros(lin.d_interior.shape[:-1] + (NCP,))
    d_camera[..., :3] = lin.d_interior
    if ideal is None:
        return replace(lin, d_interior=d_camera)
    # chain rule through the lens model, per condition and ray: row vectors (m, nc, k or t, 1, 2)
    # times the ray's (2, NCP) and (2, 2) derivatives (batched matmul: einsum has no BLAS path here)
    rows = lin.d_plate[..., None, :]
    d_camera += np.matmul(rows, of_rays(ideal.d_camera, lin.rays))[..., 0, :]
    d_plate = np.matmul(rows, of_rays(ideal.d_obs, lin.rays))[..., 0, :]
    return replace(lin, d_plate=d_plate, d_interior=d_camera)


class At(NamedTuple):
    """Where the conditions are linearised: the unknowns x^ (``state``, with their columns
    ``layout`` and rotation_maps (n_photos, 3, 3) from UnknownLayout.rotation_maps) and the adjusted
    observations l^ (``plate_hat``, ``control_hat``) of the observations ``obs``."""

    state: State
    layout: UnknownLayout
    rotation_maps: np.ndarray
    obs: Observations
    plate_hat: np.ndarray
    control_hat: np.ndarray

    @classmethod
    def of(cls, state: State, layout: UnknownLayout, obs: Observations, plate_hat: np.ndarray,
           control_hat: np.ndarray) -> "At":
        return cls(state, layout, layout.rotation_maps(state), obs, plate_hat, control_hat)

    @classmethod
    def of_result(cls, result, obs: Observations) -> "At":
        """At an adjustment's result (core.result.AdjustmentResult): its unknowns and adjusted
        observations, where its precision and reliability are evaluated."""
        return cls.of(result.state, result.layout, obs, result.plate_adjusted, result.control_adjusted)


# The ideal plate points of all image rows are computed once per sweep (lens_table) up to this many
# rows (208 bytes each: 52 MB); beyond, chunk by chunk.
LENS_TABLE_ROWS = 250_000


def lens_table(batches, at: At) -> IdealPoints | None:
    """The ideal plate points of the image rows of ``batches`` at ``at`` (lens.ideal_from_observed,
    indexed by image row; rows of no batch read zero), in one call: where the camera model is in
    play (self-calibration, distortion) and there are at most LENS_TABLE_ROWS rows; else None.

    The undistortion's Newton iterations are a few dozen small numpy operations whatever the
    number of rays; chunk by chunk (one call per chunk, a chunk per ray count) they held the
    interpreter for most of their time: the close-range block's conditions method made 413
    calls of a median 120 rays, 0.52 s in all, on the chunk threads."""
    if not batches or not at.layout.lens_in_play(at.state):
        return None
    rows = np.concatenate([b.image_rows.ravel() for b in batches])
    if len(rows) > LENS_TABLE_ROWS:
        return None
    params, conv = at.state.camera_terms(np.concatenate([b.photo_index.ravel() for b in batches]))
    ideal = ideal_from_observed(at.plate_hat[rows], params, conv, at.obs.plate[rows])
    n = len(at.obs.plate)
    table = IdealPoints(np.zeros((n, 2)), np.zeros((n, 2, 2)), np.zeros((n, 2, NCP)), np.ones(n, dtype=bool))
    table.xy[rows], table.d_obs[rows], table.d_camera[rows] = ideal.xy, ideal.d_obs, ideal.d_camera
    table.converged[rows] = ideal.converged
    return table


def linearise(batch: GroupBatch, at: At, scale_form: str = "3d", transform=None,
              lens: IdealPoints | None = None) -> GroupSystem:
    """The Gauss-Helmert blocks of a chunk of groups (module doc), linearised ``at`` (x^, l^).

    transform: optional callable(batch) -> (m, nc, nc) invertible matrices that recombine each
    group's conditions (used by the tests to show the result does not depend on it). lens: the
    sweep's :func:`lens_table` (None: the ideal plate points computed for this chunk).
    """
    state, layout, rotation_maps, obs, plate_hat, control_hat = at
    lin = evaluate(batch, state, plate_hat, control_hat, scale_form,
                   layout.lens_in_play(state) if lens is None else lens, obs.plate)
    m, nc = lin.g.shape
    k = batch.k
    l, l_hat, Q = group_observations(batch, obs, plate_hat, control_hat)
    A_parts = [expanded(lin.d_plate, lin.rays, k).reshape(m, nc, 2 * k)]
    if batch.has_control:
        A_parts.append(lin.d_control)
    A = np.concatenate(A_parts, 2)

    per_ray, cols = unknown_blocks(lin, batch, state, layout, rotation_maps, compact=True)

    g = lin.g
    scale = weights.inverse_sigma(np.matmul(A * A, Q[..., None])[..., 0])  # 1 / sigma of each condition
    A, per_ray, g = A * scale[..., None], per_ray * scale[..., None, None], g * scale
    rays = lin.rays
    if transform is not None:  # recombined conditions are no longer compact
        B = expanded(per_ray, rays, k).reshape(m, nc, cols.shape[1])
        Tg = transform(batch)
        A, per_ray, rays, g = Tg @ A, (Tg @ B).reshape(m, nc, k, -1), None, np.einsum("mab,mb->ma", Tg, g)
    w = g + np.einsum("mco,mo->mc", A, l - l_hat)
    if rays is None:
        return GroupSystem(A=A, dense_B=per_ray.reshape(m, nc, cols.shape[1]), cols=cols, w=w, Q=Q, l=l,
                           l_hat=l_hat, g=g)
    return GroupSystem(A=A, dense_B=None, cols=cols, w=w, Q=Q, l=l, l_hat=l_hat, g=g, per_ray=per_ray, rays=rays)


def unknown_blocks(lin, batch: GroupBatch, state: State, layout: UnknownLayout, rotation_maps: np.ndarray,
                   compact: bool = False):
    """B (m, nc, k (6 + camera_width)) and its global columns (m, k (6 + camera_width)), -1 fixed:
    per ray its photo's centre and rotation unknowns, then its camera's estimated elements, from
    the primitive derivatives lin (conditions.Linearised, nc rows, either form) of a chunk.
    compact: B as (m, nc, t or k, 6 + camera_width), in lin's form (for lin.rays, or all k rays)."""
    m, nc = lin.g.shape
    k = batch.k
    T = of_rays(rotation_maps[batch.photo_index], lin.rays)  # (m, nc, t, 3, 3) or (m, 1, k, 3, 3)
    d_rot = np.matmul(lin.d_rot[..., None, :], T)[..., 0, :]  # row vectors times T (m, nc, k or t, 3)
    width = 6 + layout.camera_width
    cam = state.camera_of_photo[batch.photo_index]
    B_parts, col_parts = [lin.d_centre, d_rot], [layout.photo_cols[batch.photo_index]]
    if layout.camera_width:
        elements = layout.camera_elements
        B_parts.append(lin.d_interior[..., elements])
        col_parts.append(layout.camera_cols[cam][..., elements])
    per_ray = np.concatenate(B_parts, 3)
    cols = np.concatenate(col_parts, 2).reshape(m, width * k)
    if compact:
        return per_ray, cols
    return expanded(per_ray, lin.rays, k).reshape(m, nc, width * k), cols


PRECISION_CHUNK = 1024  # groups at once in the precision passes (precision_options)


def precision_options(options):
    """``options`` with at most PRECISION_CHUNK groups linearised at once: for the passes at the
    result (residual cofactors, separability, the joint point precision), which hold per group
    more than the assembly does (M^-1, K, the blocks of Qxx gathered for G Qxx G^T). On the
    5,000-photo block of bench_scale half the assembly's 2,048 groups took the residual cofactors'
    traced peak from 115 to 69 MiB in the same time (0.50 s); a quarter, to 40 MiB in 3 % more.
    (The assembly's default chunk is 1,024 groups too since then: core.options.)"""
    return replace(options, chunk_size=min(options.chunk_size, PRECISION_CHUNK))


class Sweep:
    """One sweep over all groups at a fixed (x^, l^): their linearised systems chunk by chunk
    (:meth:`systems`, :func:`linearise`) and those of the joint groups (:meth:`joint_systems`); the
    conditions method iterates over it, the precision and separability rebuild it at the result."""

    def __init__(self, batches, at: At, options, joint=None, distance_hat=None):
        """batches: the groups (groups.build_batches); at: where (At); options: core.options.AdjustmentOptions."""
        self.batches, self.at, self.options = batches, at, options
        self.state, self.layout, self.T, self.obs, self.plate_hat, self.control_hat = at
        self.seconds = 0.0  # time spent evaluating and linearising the conditions
        # the joint groups of the points joined by distances (joint_groups; None without) and the
        # adjusted distances d + v_d (the observed ones when None)
        self.joint, self.distance_hat = joint, distance_hat
        self._lens = None  # (lens_table,), worked out at the first systems()

    def joint_systems(self) -> list:
        """The linearised joint groups (joint_groups.JointSystem) of this sweep; none without distances."""
        if self.joint is None:
            return []
        t0 = time.perf_counter()
        d_hat = self.joint.project.distances.distance if self.distance_hat is None else self.distance_hat
        out = self.joint.systems(self.at, d_hat, self.options.conditions.scale_form,
                                 self.options.conditions.condition_transform)
        self.seconds += time.perf_counter() - t0
        return out

    def systems(self, then=None, alongside=None):
        """(chunk, system) of every chunk in turn, or (chunk, system, then(chunk, system)): then is
        work on each chunk done in the same thread (the whitening of the assembly, the residual
        cofactors); it must not change shared state. alongside: one value per chunk, in the
        chunks' order, given to then as a third argument (the assembly's scatters). The chunks are
        linearised on solvers.threads.chunk_threads threads ahead of the caller
        (parallel.map_ordered); :attr:`seconds` counts the time the caller waited for them (with one
        thread, the time of the linearisation and of then)."""
        scale_form, transform = self.options.conditions.scale_form, self.options.conditions.condition_transform

        if self._lens is None:
            self._lens = (lens_table(self.batches, self.at),)
        lens = self._lens[0]

        def work(item):
            chunk, extra = item
            system = linearise(chunk, self.at, scale_form, transform, lens)
            if then is None:
                return chunk, system
            return chunk, system, (then(chunk, system) if alongside is None else then(chunk, system, extra))

        chunks = (chunk for batch in self.batches for chunk in batch.chunks(self.options.chunk_size))
        chunks = zip(chunks, alongside, strict=True) if alongside is not None else ((chunk, None) for chunk in chunks)
        done = map_ordered(work, chunks, chunk_threads(sweep_size(self.batches)))
        try:
            while True:
                t0 = time.perf_counter()
                try:
                    out = next(done)
                except StopIteration:
                    return
                finally:
                    self.seconds += time.perf_counter() - t0
                yield out
        finally:
            done.close()
