"""What the diagnoses share (core.diagnosis, core.orientations, core.photo_groups): how they name many
things (at most LIST_MAX, then "and N more"), a robust quantile per group of values, and the
spread of the projection centres with the factor FAR beyond which a value is implausible."""

from __future__ import annotations

import numpy as np

FAR = 1000.0  # a value this many times farther out than the typical one is a typo or another unit
LIST_MAX = 8  # photos, points or groups named in one message before "and N more"


def more(n: int) -> str:
    return f" and {n - LIST_MAX} more" if n > LIST_MAX else ""


def group_quantile(groups: np.ndarray, values: np.ndarray, n_groups: int, q: float) -> np.ndarray:
    """(n_groups,) the q-quantile (lower, by rank) of the finite values of each group; nan where none."""
    ok = np.isfinite(values)
    g, v = groups[ok], values[ok]
    order = np.lexsort((v, g))
    g, v = g[order], v[order]
    counts = np.bincount(g, minlength=n_groups)
    starts = np.cumsum(counts) - counts
    out = np.full(n_groups, np.nan)
    has = counts > 0
    if q == 0.5:
        lo = starts + (counts - 1) // 2
        hi = starts + counts // 2
        out[has] = 0.5 * (v[lo[has]] + v[hi[has]])
    else:
        idx = starts + np.floor(q * (counts - 1)).astype(int)
        out[has] = v[idx[has]]
    return out


def centre_spread(O: np.ndarray):
    """The median centre, every centre's distance from it (max norm, no overflow) and the typical
    distance (their median, at least 1 m)."""
    middle = np.median(O, axis=0) if len(O) else np.zeros(3)
    d = np.max(np.abs(O - middle), axis=1)
    return middle, d, max(float(np.median(d)) if len(d) else 0.0, 1.0)
