"""What every route of the selected inversion shares: the engine interface.

An engine holds one factorisation of the Jacobi-scaled ``N~`` (the package docstring) and answers
requests for entries of ``N~^-1``: looked up in the pattern it computed, or solved for with its
factor (:meth:`Engine.solved_entries`). :class:`striptri.selected_inverse.SelectedInverse` turns
them back into the units of N. The routes are :mod:`.dense`, :mod:`.banded` and :mod:`.supernodal`.
"""

from __future__ import annotations

import numpy as np

SOLVE_CHUNK = 4_000_000  # entries of the n x q right-hand sides solved at once (32 MB)


class Engine:
    """What the routes share: entries of N~^-1 on request, and solves with the factor."""

    name = "base"
    n = 0
    looks_up = False  # True: lookup() reads entries of the computed pattern without solving

    def __init__(self):
        self.info: dict = {}

    def solve(self, B: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def compute(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def diag(self) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def whole(self) -> np.ndarray | None:
        """The whole N~^-1 (n, n) where the route holds it (dense), else None."""
        return None

    def compute_with_diag(self, rows, cols):
        return self.compute(rows, cols), self.diag()

    def lookup(self, rows: np.ndarray, cols: np.ndarray):  # pragma: no cover - interface
        """(values, found): entries in the computed pattern (0 where fixed, -1, or not found) and
        which were found or are fixed; the others are for solved_entries."""
        raise NotImplementedError

    def solved_entries(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Entries of N~^-1 from whole columns of it, solved for with the factor (columns taken
        from whichever side has fewer distinct indices)."""
        if len(rows) == 0:
            return np.zeros(0)
        if len(np.unique(rows)) < len(np.unique(cols)):
            rows, cols = cols, rows  # symmetric
        want, where = np.unique(cols, return_inverse=True)
        out = np.empty(len(rows))
        chunk = max(1, SOLVE_CHUNK // max(self.n, 1))
        for a in range(0, len(want), chunk):
            E = np.zeros((self.n, min(chunk, len(want) - a)))
            E[want[a: a + chunk], np.arange(E.shape[1])] = 1.0
            X = self.solve(E)
            sel = (where >= a) & (where < a + chunk)
            out[sel] = X[rows[sel], where[sel] - a]
        return out


def not_fixed(rows, cols):
    """Mask of requested entries that are not fixed (-1), and the values array to fill."""
    ok = (rows >= 0) & (cols >= 0)
    return ok, np.zeros(len(rows))


class EmptyInverse(Engine):
    """The route of a 0 x 0 N: nothing to compute."""

    name = "empty"

    def compute(self, rows, cols):
        return np.zeros(len(rows))

    def diag(self):
        return np.zeros(0)

    def solve(self, B):
        return B
