"""Figures (matplotlib, Agg backend: no display needed). Each function returns PNG bytes so that the
pipeline decides where they go (a file, or embedded in report.html).
"""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def normal_matrix_structure(N: sp.spmatrix, block_starts: np.ndarray, n_photo_blocks: int, title: str = "") -> bytes:
    """The nonzero pattern of the normal matrix (Schmid Fig. 10): one mark per nonzero 6x6 photo
    block (camera columns last), with the block grid for small projects.

    N: (n, n) sparse; block_starts: first column of each photo and camera block (UnknownLayout.
    block_starts); n_photo_blocks: how many of the blocks are photos.
    """
    N = sp.coo_matrix(N)
    n = N.shape[0]
    starts = np.asarray(block_starts, dtype=int)
    block_of = np.zeros(n, dtype=int)
    if len(starts):
        block_of[starts[1:]] = 1
        block_of = np.cumsum(block_of)
    nb = len(starts)
    nz = N.data != 0
    bi, bj = block_of[N.row[nz]], block_of[N.col[nz]]
    pattern = sp.coo_matrix((np.ones(len(bi)), (bi, bj)), shape=(nb, nb)).tocsr()
    pattern.sum_duplicates()
    bandwidth = int(np.max(np.abs(bi - bj), initial=0))
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    rows, cols = pattern.nonzero()
    is_cam = (rows >= n_photo_blocks) | (cols >= n_photo_blocks)
    if nb <= 1500:  # filled cells, as in Schmid's Fig. 10
        image = np.ones((nb, nb, 3))
        image[rows[~is_cam], cols[~is_cam]] = (0.12, 0.31, 0.47)
        image[rows[is_cam], cols[is_cam]] = (0.77, 0.35, 0.07)
        ax.imshow(image, interpolation="nearest")
    else:
        ax.scatter(cols, rows, s=0.5, marker="s", color="#1f4e79", linewidths=0)
    ax.set_xlim(-0.5, nb - 0.5)
    ax.set_ylim(nb - 0.5, -0.5)
    ax.set_aspect("equal")
    if nb <= 40:
        ax.set_xticks(np.arange(nb) - 0.5, minor=True)
        ax.set_yticks(np.arange(nb) - 0.5, minor=True)
        ax.grid(True, which="minor", linewidth=0.4, color="#999999")
        ax.tick_params(labelsize=6)
    ax.set_xlabel("block (photos in order, then cameras in orange)" if is_cam.any() else "photo block")
    ax.set_ylabel("block")
    fill = pattern.nnz / max(nb * nb, 1)
    ax.set_title(title or f"normal matrix: {n} unknowns, {nb} blocks, {fill:.1%} of blocks filled, "
                          f"block bandwidth {bandwidth}", fontsize=9)
    return _png(fig)
