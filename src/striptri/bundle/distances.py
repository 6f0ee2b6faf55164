"""Distance observations between object points (scale bars, taped distances) in the bundle method.

A distance is the observation equation ``|X_a - X_b| = d + v`` with standard deviation sigma;
whitened, ``Jd dX = e_d + v~`` with ``e_d = (d - |X_a^ - X_b^|) / sigma`` and the rows
``+u^T / sigma`` for point a, ``-u^T / sigma`` for point b (u the unit vector from b to a; held
coordinates have zero columns, as in Jp).

The distance rows couple the two points, so the point-by-point elimination of bundle.reduced no
longer gives the Schur complement. With ``P = N_pp^-1`` (block diagonal, as eliminated) and
``Y = N_cp P``, the Woodbury identity for ``(N_pp + Jd^T Jd)^-1`` gives the exact correction
(r distances, ``G = Jd P Jd^T``, ``M = I + G`` (r, r), ``q = Jd P b_p``, ``U = Y Jd^T`` (n, r)):

    N_rcs' = N_rcs + U M^-1 U^T          b_rcs' = b_rcs + U M^-1 (q - e_d)
    dX'    = dX + P Jd^T M^-1 (e_d - Jd dX)      (dX the point-by-point back substitution)

and the points' share of the reduced sum of squares grows by
``2 q^T e_d + e_d^T G e_d - (q + G e_d)^T M^-1 (q + G e_d)``. The correction enters the reduced
normals as r rows ``L^-1 U^T`` with misclosures ``L^-1 (q - e_d)`` (M = L L^T), in the columns of
the photos (and cameras) that see the distance points. Only the distance points' blocks are
touched, batched by chunk; Jd is sparse (two points a row), so thousands of distances among
hundreds of points cost one dense Cholesky of M (r x r).
"""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np

from ..model import Distances  # noqa: F401  (the observations these functions take)
from ..equations import weights


def linearise_distances(dist: Distances, xyz: np.ndarray, free: np.ndarray):
    """Whitened misclosures e (r,) and rows Ja, Jb (r, 3) of the points from and to at xyz (n_pt, 3);
    free (n_pt, 3) the unknown coordinates (others get zero columns)."""
    delta = xyz[dist.point_from] - xyz[dist.point_to]
    length = np.linalg.norm(delta, axis=1)
    u = delta / length[:, None]
    s = dist.sigma[:, None]
    e = weights.whiten(dist.distance - length, dist.sigma)
    return e, weights.whiten(u, s) * free[dist.point_from], weights.whiten(-u, s) * free[dist.point_to]


def distance_cost(dist: Distances, xyz: np.ndarray) -> float:
    """Sum of the squared whitened distance residuals at xyz."""
    length = np.linalg.norm(xyz[dist.point_from] - xyz[dist.point_to], axis=1)
    return float(np.sum(weights.whiten(dist.distance - length, dist.sigma) ** 2))


def locate_points(chunk_point_index: list[np.ndarray], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chunk number and row in it (each (len(points),)) of the given points, from the point_index
    of each chunk in assembly order; -1 for a point in no chunk."""
    chunk_of = np.full(points.max() + 1 if len(points) else 0, -1)
    row_of = np.full_like(chunk_of, -1)
    wanted = np.zeros(len(chunk_of), dtype=bool)
    wanted[points] = True
    for c, pt in enumerate(chunk_point_index):
        inside = pt < len(wanted)
        hit = np.flatnonzero(inside)[wanted[pt[inside]]]
        chunk_of[pt[hit]] = c
        row_of[pt[hit]] = hit
    return chunk_of[points], row_of[points]


@dataclass
class Coupling:
    """The Woodbury correction of one assembly (module doc). points (nD,) distance points;
    J (r, 3 nD) sparse: the whitened distance rows over the points' coordinates (two points a row);
    P (nD, 3, 3); M (r, r); e (r,) whitened misclosures."""

    points: np.ndarray
    J: object
    P: np.ndarray
    M: np.ndarray
    e: np.ndarray

    def point_shift(self, dX_points: np.ndarray) -> np.ndarray:
        """dX' - dX (nD, 3) for the point-by-point corrections dX_points (nD, 3) of the distance points."""
        w = np.linalg.solve(self.M, self.e - self.J @ dX_points.reshape(-1))
        return np.einsum("pij,pj->pi", self.P, (self.J.T @ w).reshape(-1, 3))

    def residuals(self, dX_points: np.ndarray) -> np.ndarray:
        """Whitened linearised residuals (r,) ``Jd dX' - e`` for the corrected dX_points (nD, 3)."""
        return self.J @ dX_points.reshape(-1) - self.e


def couple(dist: Distances, kept: list, where: tuple[np.ndarray, np.ndarray], points: np.ndarray,
           xyz: np.ndarray, free: np.ndarray, n: int):
    """The Woodbury correction of the reduced normals (module doc) from the linearised chunks
    kept (bundle.reduced.PointChunk, assembly order) at xyz.

    where: locate_points of ``points`` (nD,), the distance points; n: the number of unknowns of
    the reduced system. Returns (Coupling, rows J (r, w), cols (r, w), f (r,), e_d^T e_d, the
    growth of the reduced sum of squares).

    Batched over the chunks (a few), never over points or distances: a distance row touches two
    points, so Jd is a sparse (r, 3 nD) matrix and ``G = Jd P Jd^T`` a sparse product; only M (r, r)
    is dense (its Cholesky factor, for thousands of distances among hundreds of points)."""
    import scipy.sparse as sp

    e, Ja, Jb = linearise_distances(dist, xyz, free)
    r, nD = len(dist), len(points)
    slot = np.full(int(points.max()) + 1 if nD else 0, -1)
    slot[points] = np.arange(nD)
    ia, ib = slot[dist.point_from], slot[dist.point_to]
    rows = np.repeat(np.arange(r), 6)
    cols = (3 * np.stack([ia, ia, ia, ib, ib, ib], axis=1) + np.tile(np.arange(3), 2)).ravel()
    J = sp.csr_matrix((np.concatenate([Ja, Jb], axis=1).ravel(), (rows, cols)), shape=(r, 3 * nD))
    P = np.zeros((nD, 3, 3))
    bP = np.zeros((nD, 3))
    U = np.zeros((n + 1, r))  # row n collects the held columns (-1)
    chunk_of, row_of = where
    for c in np.unique(chunk_of):  # a loop over the chunks that hold distance points (a few)
        mine = np.flatnonzero(chunk_of == c)
        chunk, rr = kept[int(c)], row_of[mine]
        P[mine] = np.linalg.inv(chunk.N_pp[rr])
        bP[mine] = np.einsum("mij,mj->mi", P[mine], chunk.b_p[rr])
        Y = chunk.N_cp[rr] @ P[mine]  # (m, k w, 3)
        # U[:, d] += Y_p J_{d,p}^T for the point p of each distance end in this chunk
        for end, J_end in ((ia, Ja), (ib, Jb)):
            pos = np.full(nD, -1)
            pos[mine] = np.arange(len(mine))
            d = np.flatnonzero(pos[end] >= 0)
            if not len(d):
                continue
            m_of = pos[end[d]]
            values = np.einsum("dki,di->dk", Y[m_of], J_end[d])  # (nd, k w)
            target = chunk.cols[rr][m_of].reshape(len(d), -1)
            np.add.at(U, (target, np.broadcast_to(d[:, None], target.shape)), values)
    U = U[:n]
    i3, base = np.arange(3), 3 * np.arange(nD)
    p_rows = np.broadcast_to(base[:, None, None] + i3[None, :, None], P.shape).ravel()
    p_cols = np.broadcast_to(base[:, None, None] + i3[None, None, :], P.shape).ravel()
    Pblock = sp.csr_matrix((P.ravel(), (p_rows, p_cols)), shape=(3 * nD, 3 * nD))
    G = (J @ Pblock @ J.T).toarray()
    q = J @ bP.reshape(-1)
    M = np.eye(r) + G
    L = np.linalg.cholesky(M)
    nz = np.flatnonzero(np.any(U != 0.0, axis=1))
    R = np.linalg.solve(L, U[nz].T)  # (r, w)
    f = np.linalg.solve(L, q - e)
    h = q + G @ e
    growth = float(2 * q @ e + e @ G @ e - h @ np.linalg.solve(M, h))
    return (Coupling(points, J, P, M, e), R, np.broadcast_to(nz, R.shape).copy(), f, float(e @ e), growth)


def distance_columns(point_ids: list[str], dist: Distances, xyz: np.ndarray, tests=None, sigma0: float = 1.0,
                     critical: float = float("nan")) -> dict:
    """The output table distances.csv (docs/file-formats.md) for the adjusted points xyz (n_pt, 3):
    the observation, the adjusted distance ``|X_a - X_b|``, the residual v = adjusted - observed
    (m) and v / sigma; with tests (reliability.measures.DistanceTests of the adjustment) also the
    mean error of the adjusted distance ``sigma0 sqrt(sigma^2 - qvv)`` (m), the redundancy number,
    the normalised residual w, the flag ("suspect" where |w| > critical) and the MDB (m), as
    residuals.csv names them (empty where not tested)."""
    adjusted = np.linalg.norm(xyz[dist.point_from] - xyz[dist.point_to], axis=1)
    v = adjusted - dist.distance
    cols = {"point_from": [point_ids[p] for p in dist.point_from], "point_to": [point_ids[p] for p in dist.point_to],
            "distance": dist.distance, "sigma": dist.sigma, "adjusted": adjusted, "residual": v,
            "residual_sigma": v / dist.sigma}
    r = len(dist)
    if tests is None or len(tests.w) != r:
        nan = np.full(r, np.nan)
        return {**cols, "sigma_adjusted": nan, "redundancy": nan, "w": nan, "flag": [""] * r, "mdb": nan}
    with np.errstate(invalid="ignore"):
        suspect = np.abs(tests.w) > critical
    return {**cols, "sigma_adjusted": sigma0 * np.sqrt(np.maximum(dist.sigma**2 - tests.qvv, 0.0)),
            "redundancy": tests.redundancy, "w": tests.w, "flag": ["suspect" if s else "" for s in suspect],
            "mdb": tests.mdb}


def summary_entry(dist: Distances, xyz: np.ndarray, cols: dict | None = None) -> dict:
    """summary.json "distances": count, rms and largest |v| (m) and largest |v| / sigma; with the
    tested table cols (distance_columns with tests) also the sum of the redundancy numbers, the
    largest |w| and the number flagged suspect (null where not tested)."""
    v = np.linalg.norm(xyz[dist.point_from] - xyz[dist.point_to], axis=1) - dist.distance
    out = {"count": len(dist), "rms_residual_m": float(np.sqrt(np.mean(v**2))),
           "max_abs_residual_m": float(np.max(np.abs(v))), "max_abs_residual_sigma": float(np.max(np.abs(v) / dist.sigma))}
    if cols is not None:
        w = np.abs(np.asarray(cols["w"], dtype=float))
        tested = bool(np.isfinite(np.asarray(cols["redundancy"], dtype=float)).all())
        out.update({"redundancy": float(np.sum(cols["redundancy"])) if tested else None,
                    "max_abs_w": float(np.max(w)) if np.isfinite(w).any() and tested else None,
                    "n_suspect": int(sum(f == "suspect" for f in cols["flag"]))})
    return out


def report_parts(point_ids: list[str], dist: Distances, xyz: np.ndarray, cols: dict | None = None) -> list:
    """The report section's parts (report.py): a paragraph and (header, rows, cls, left) of a table,
    every distance with its residual, mean error, redundancy number and w, largest |w| (else
    |v| / sigma) first. cols: the output table (distance_columns), formed here when not given."""
    cols = distance_columns(point_ids, dist, xyz) if cols is None else cols
    w = np.asarray(cols["w"], dtype=float)
    key = np.where(np.isfinite(w), np.abs(w), np.abs(cols["residual_sigma"]))
    order = np.argsort(-key, kind="stable")
    fmt = lambda x, f: "" if not np.isfinite(x) else format(x, f)  # noqa: E731
    rows = [[html.escape(cols["point_from"][i]), html.escape(cols["point_to"][i]), f"{cols['distance'][i]:.4f}", f"{cols['sigma'][i]:.4g}",
             f"{cols['adjusted'][i]:.4f}", fmt(1000 * cols["sigma_adjusted"][i], ".3g"), f"{1000 * cols['residual'][i]:.2f}",
             fmt(cols["redundancy"][i], ".3f"), fmt(w[i], ".2f"), cols["flag"][i]]
            for i in order]
    text = (f"<p>{len(dist)} observed distances between object points (distances.csv), adjusted with the points; "
            "residual v = adjusted - observed, sigma adj. the mean error of the adjusted distance, r its redundancy "
            "number and w its normalised residual (flagged suspect above the critical value; a distance is flagged, "
            "never rejected; also in the output distances.csv).</p>")
    return [text, (["from", "to", "observed (m)", "sigma (m)", "adjusted (m)", "sigma adj. (mm)", "v (mm)", "r", "w",
                    "flag"], rows, "", 2)]
