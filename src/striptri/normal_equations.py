"""Step-by-step formation of the normal equations (Schmid 36-38, 46-50; DESIGN section 4).

Each group is whitened with the Cholesky factor of ``M = A Q A^T`` (``M = L L^T``):
``B~ = L^-1 B``, ``w~ = L^-1 w`` are Schmid's pseudo-observations with their cross-weights folded
in, and the group adds ``B~^T B~`` to N and ``B~^T w~`` to u. Contributions are scattered into the
global matrix chunk by chunk, so memory does not grow with the number of points.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .linearise import GroupSystem


def whiten(system: GroupSystem):
    """L^-1 B, L^-1 w, L^-1 g and L for each group (M = A Q A^T = L L^T). Batched."""
    M = np.einsum("mco,mo,mdo->mcd", system.A, system.Q, system.A)
    L = np.linalg.cholesky(M)
    Bw = np.linalg.solve(L, system.B)
    wg = np.linalg.solve(L, np.stack([system.w, system.g], -1))
    return Bw, wg[..., 0], wg[..., 1], L


class NormalAccumulator:
    """Sums ``B~^T B~`` and ``B~^T w~`` of group chunks into a sparse N and a dense u."""

    def __init__(self, n_unknowns: int):
        self.n = n_unknowns
        self.N = sp.csr_matrix((n_unknowns, n_unknowns))
        self.u = np.zeros(n_unknowns)
        self.wPw = 0.0  # sum of w~^T w~ (Schmid 59: [LL])
        # sum B~^T g~ and g~^T g~ of the misclosures at l^ (used by the datum diagnosis: the tie
        # conditions are homogeneous of degree one in the scale of the block, so B h_scale = g)
        self.ug = np.zeros(n_unknowns)
        self.gPg = 0.0

    def add(self, Bw: np.ndarray, ww: np.ndarray, cols: np.ndarray, gw: np.ndarray | None = None) -> None:
        """Bw: (m, nc, nu) whitened B; ww, gw: (m, nc) whitened w and g; cols: (m, nu) global
        columns, -1 = fixed."""
        self.wPw += float(np.sum(ww * ww))
        gw = ww if gw is None else gw
        self.gPg += float(np.sum(gw * gw))
        if Bw.shape[-1] == 0 or self.n == 0:
            return
        Nloc = np.einsum("mca,mcb->mab", Bw, Bw)
        uloc = np.einsum("mca,mc->ma", Bw, ww)
        valid = cols >= 0
        self.u += np.bincount(cols[valid], weights=uloc[valid], minlength=self.n)
        uglo = np.einsum("mca,mc->ma", Bw, gw)
        self.ug += np.bincount(cols[valid], weights=uglo[valid], minlength=self.n)
        pair = valid[:, :, None] & valid[:, None, :]
        rows = np.broadcast_to(cols[:, :, None], Nloc.shape)[pair]
        cc = np.broadcast_to(cols[:, None, :], Nloc.shape)[pair]
        chunk = sp.coo_matrix((Nloc[pair], (rows, cc)), shape=(self.n, self.n)).tocsr()
        self.N = self.N + chunk

    def add_rows(self, grad: np.ndarray, cols: np.ndarray, misclosure: np.ndarray, sigma: np.ndarray) -> None:
        """Parameter observations: one condition each, B = -grad, w = misclosure, M = sigma^2."""
        Bw = (-grad / sigma[:, None])[:, None, :]
        ww = (misclosure / sigma)[:, None]
        self.add(Bw, ww, cols, np.zeros_like(ww))
