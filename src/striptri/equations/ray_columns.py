"""Products with a long track's B in the compact form, where each condition involves few rays.

A group of k rays has nc ~ 2k conditions (a chain of pair coplanarities and scale transfers,
conditions module doc), each of them on two or three rays: B (nc, k w) is almost all zero (a
66-ray close-range target: 129 conditions x 726 columns, 2 % nonzero). The dense products of the
assembly and of the precision passes cost ``nc (k w)^2`` per group (40 MFlop for the 66-ray
target). Grouped by ray instead, every product below costs ``k n w (columns of the other
factor)``, n the conditions of one ray (at most five or six in a chain): some ten times less.

:class:`RayColumns` holds, for a chunk of m groups of k rays, the derivatives of the conditions
of each ray, ``X`` (m, k, n, w) (zero rows pad the rays with fewer than n conditions), and which
condition each row is, ``cond`` (k, n), and each condition's derivatives summed over its rays,
``summed`` (m, nc, w) (the columns of an unknown all the rays share, as a camera). Every product is a gather of the other factor's
condition rows or columns and one batched matmul over the rays:

- ``left(D)``: D B for D (m, p, nc), as (m, p, k, w);
- ``transposed(Y)``: B^T Y for Y (m, nc, q), as (m, k, w, q);
- ``times(Z)``: B Z for Z (m, k, w, q), as (m, nc, q) (the ray products summed back to the
  conditions through ``slot``);
- ``quadratic(Q)``: B Q B^T (m, nc, nc), and ``quadratic_blocks(S)``: the ray-pair blocks of
  B^T S B (m, k, k, w, w).

The compact form pays for long tracks only: :func:`of_system` gives None below
FULL_PRODUCT_RAYS rays or when a ray has more than MAX_CONDITIONS_PER_RAY conditions (the hub of
a star chain), and the callers take the dense products.
"""

from __future__ import annotations

import numpy as np

COMPACT_RAYS = 12  # tracks of this many rays and more (normal_equations.FULL_PRODUCT_RAYS)
MAX_CONDITIONS_PER_RAY = 12


class RayColumns:
    """B of a chunk of groups grouped by ray (module doc)."""

    def __init__(self, per_ray: np.ndarray, rays: np.ndarray, k: int):
        """per_ray (m, nc, t, w): the derivatives of each condition with respect to the w columns of
        each of its t rays ``rays`` (nc, t) (conditions.Linearised's compact form; a ray named
        twice in one condition counts with the sum of its derivatives)."""
        m, nc, t, w = per_ray.shape
        self.m, self.nc, self.k, self.w = m, nc, k, w
        self.summed = per_ray.sum(axis=2)  # (m, nc, w): each condition's derivatives summed over its rays
        # a ray named twice in a condition (a pair's (first, second, second)): one entry, summed
        keep = np.ones((nc, t), dtype=bool)
        values = per_ray
        for s in range(1, t):
            same = np.zeros(nc, dtype=bool)
            for s0 in range(s):
                dup = keep[:, s0] & (rays[:, s] == rays[:, s0]) & ~same
                if dup.any():
                    if values is per_ray:
                        values = per_ray.copy()
                    values[:, dup, s0] += values[:, dup, s]
                    same |= dup
            keep[same, s] = False
        flat = np.flatnonzero(keep.ravel())  # the entries (condition, slot) kept, as c t + s
        ray = rays.ravel()[flat]
        order = np.argsort(ray, kind="stable")
        count = np.bincount(ray, minlength=k)
        self.n = int(count.max()) if len(count) else 0
        start = np.cumsum(count) - count
        place = np.empty(len(flat), dtype=np.int64)  # each kept entry's row among its ray's, as i n + j
        place[order] = ray[order] * self.n + (np.arange(len(flat)) - np.repeat(start, count))
        table = np.full(k * self.n, nc * t, dtype=np.int64)  # padding reads an appended zero row
        table[place] = flat
        padded = np.concatenate([values.reshape(m, nc * t, w), np.zeros((m, 1, w))], axis=1)
        self.X = _rows(padded, table.reshape(k, self.n), 1)
        self.cond = np.where(table < nc * t, table // t, 0).reshape(k, self.n)  # padding: any row (X is zero)
        # for times(): each condition's kept entries as rows of the (k n) ray products; a dropped
        # slot reads an appended zero row
        slot = np.full(nc * t, k * self.n, dtype=np.int64)
        slot[flat] = place
        self.slot = slot.reshape(nc, t)

    def groups(self, part: slice) -> "RayColumns":
        """The same for the groups ``part`` of the chunk."""
        out = object.__new__(RayColumns)
        out.__dict__.update(self.__dict__)
        out.X, out.summed = self.X[part], self.summed[part]
        out.m = out.X.shape[0]
        return out

    def left(self, D: np.ndarray, width: int | None = None) -> np.ndarray:
        """D B (m, p, k, w') for D (m, p, nc), over the first ``width`` columns of each ray (all)."""
        X = self.X if width is None else self.X[..., :width]
        Dg = np.swapaxes(_rows(D, self.cond, 2), 1, 2)  # (m, k, p, n)
        return np.swapaxes(np.matmul(Dg, X), 1, 2)

    def transposed(self, Y: np.ndarray, width: int | None = None) -> np.ndarray:
        """B^T Y (m, k, w', q) for Y (m, nc, q), over the first ``width`` columns of each ray (all)."""
        X = self.X if width is None else self.X[..., :width]
        return np.matmul(np.swapaxes(X, 2, 3), _rows(Y, self.cond, 1))

    def quadratic_blocks(self, S: np.ndarray, width: int) -> np.ndarray:
        """The ray-pair blocks of ``B^T S B`` (m, k, k, width, width) for a symmetric S (m, nc, nc),
        block (a, b) the rays a and b, over the first ``width`` columns of each ray: ``Y = S B``
        laid out by ray (m, k, nc, width), then block (a, b) ``Y[b][cond(a)]^T X[a]`` (the transpose
        of block (b, a)), which comes out contiguous in this order."""
        m, k = self.m, self.k
        X = self.X[..., :width]
        Y = np.matmul(np.swapaxes(_rows(S, self.cond, 1), 2, 3), X)  # (m, k, nc, width): S B (S symmetric)
        Yg = _rows(Y, self.cond, 2)  # (m, k, k, n, width)
        out = np.empty((m, k, k, width, width))  # matmul would lay out its own by the inputs' strides
        return np.matmul(np.swapaxes(Yg, -1, -2), X[:, None], out=out)

    def times(self, Z: np.ndarray) -> np.ndarray:
        """B Z (m, nc, q) for Z (m, k, w', q), w' the first columns of each ray (w' <= w)."""
        m, k, width, q = Z.shape
        R = np.matmul(self.X[..., :width], Z).reshape(m, k * self.n, q)  # each ray's conditions' rows
        R = np.concatenate([R, np.zeros((m, 1, q))], axis=1)
        return _rows(R, self.slot, 1).sum(axis=2)

    def quadratic(self, Q: np.ndarray, width: int) -> np.ndarray:
        """B Q B^T (m, nc, nc) for Q (m, k width, k width) over the first ``width`` columns of each
        ray (set-major, as covariance.Slots): (B (B Q)^T) with Q symmetric."""
        m, k = self.m, self.k
        BQ = self.times(Q.reshape(m, k, width, k * width))  # (m, nc, k width)
        return self.times(np.swapaxes(BQ, 1, 2).reshape(m, k, width, self.nc))


def _rows(a: np.ndarray, index: np.ndarray, axis: int) -> np.ndarray:
    """``a`` indexed along ``axis`` by the integer array ``index`` (its shape replacing that axis):
    np.take, which copies whole rows, several times faster here than the same fancy indexing."""
    taken = np.take(a, index.ravel(), axis=axis)
    return taken.reshape(a.shape[:axis] + index.shape + a.shape[axis + 1 :])


def of_system(system) -> RayColumns | None:
    """The RayColumns of a chunk's GroupSystem (linearise.GroupSystem: per_ray and rays), or None
    where the dense products serve as well (module doc)."""
    if system.rays is None:
        return None
    k = system.cols.shape[1] // system.per_ray.shape[3]
    if k < COMPACT_RAYS:
        return None
    rc = RayColumns(system.per_ray, system.rays, k)
    return rc if rc.n <= MAX_CONDITIONS_PER_RAY else None
