"""The cofactor matrix of the unknowns, Qxx = N^-1 (Schmid 53), without forming it.

Everything precision needs is read from here: entries of Qxx for the unknowns of a point group
(``entries``), the 6x6 photo blocks (``photo_blocks``), the diagonal, and the weight coefficient
``f^T Qxx f`` of any function of the unknowns (Schmid 81-84). Underneath is the selected inversion
of ``striptri.selected_inverse`` (banded for strips, supernodal for blocks).

For a free network (datum.FreeNetwork) Qxx is the inverse under the inner constraints,
``Q = S Q_min S^T`` with ``S = I - H K C^T``, ``K = (C^T H)^-1`` and Q_min the inverse of N under
the minimum constraints (held unknowns: zero rows and columns). An entry is then
``Q_min[r, c] - (HK)[r].Y[c] - Y[r].(HK)[c] + (HK)[r] (C^T Y) (HK)[c]^T`` with ``Y = Q_min C``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .selected_inverse import for_layout


class Covariance:
    def __init__(self, N: sp.spmatrix, layout, free_network=None):
        self.layout = layout
        self.n = N.shape[0]
        self.free_network = free_network
        if free_network is None:
            self._inv = for_layout(N, layout)
            return
        N_min, mask = free_network.minimum_constraint_system(N)
        self._inv = for_layout(N_min, layout)
        self._keep = 1.0 - mask
        C, H = free_network.C, free_network.H
        Y = self._inv.solve(C) * self._keep[:, None]
        self._HK = H @ np.linalg.inv(C.T @ H)
        self._Y = Y
        self._CtY = C.T @ Y

    def entries(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Qxx[rows, cols] elementwise (broadcast; index -1, a fixed element, reads zero)."""
        r, c = np.broadcast_arrays(np.asarray(rows, dtype=int), np.asarray(cols, dtype=int))
        q = self._inv.entries(r, c)
        if self.free_network is None:
            return q
        keep = np.append(self._keep, 0.0)
        q = q * keep[r] * keep[c]
        pad = lambda a: np.vstack([a, np.zeros((1, a.shape[1]))])  # noqa: E731  (row -1 reads zeros)
        HK, Y = pad(self._HK), pad(self._Y)
        hr, hc, yr, yc = HK[r], HK[c], Y[r], Y[c]
        return (q - np.einsum("...a,...a->...", hr, yc) - np.einsum("...a,...a->...", yr, hc)
                + np.einsum("...a,ab,...b->...", hr, self._CtY, hc))

    def photo_blocks(self) -> np.ndarray:
        """(n_photos, 6, 6) blocks of Qxx of every photo's elements (fixed elements zero)."""
        cols = self.layout.photo_cols
        if self.free_network is None:
            return self._inv.stack(range(len(cols)))
        return self.entries(cols[:, :, None], cols[:, None, :])

    def diag(self) -> np.ndarray:
        idx = np.arange(self.n)
        return self._inv.diag() if self.free_network is None else self.entries(idx, idx)

    def quadratic_form(self, f: np.ndarray) -> float:
        """f^T Qxx f (Schmid 83), f the gradient of a function of the unknowns."""
        f = np.asarray(f, dtype=float)
        if self.free_network is None:
            return float(self._inv.quadratic_form(f))
        fn = self.free_network
        g = f - fn.C @ (self._HK.T @ f)  # S^T f
        return float(g @ (self._inv.solve(g) * self._keep))

    def dense(self) -> np.ndarray:
        idx = np.arange(self.n)
        return self.entries(idx[:, None], idx[None, :])
