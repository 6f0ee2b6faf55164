"""Figures (matplotlib, Agg backend: no display needed). Each function returns PNG bytes so that the
pipeline decides where they go (a file, or embedded in report.html).

matplotlib is imported when the first figure is drawn, not with this module (it takes a third of a
second): a run that fails on its input, or never draws, does not pay for it. The pipeline imports
it ahead, in a thread of its own, while the adjustment computes (``preload``). The figures are
``matplotlib.figure.Figure`` objects without pyplot's global state; ``figures.plt`` (pyplot, Agg)
is still there for the study's figures.
"""

from __future__ import annotations

import io
import os
import sys
import threading
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

DPI = 110

# what the report's figures import (preload); a warning raised from these packages' files during the
# adjustment can only come from the preloading import (the adjustment draws nothing)
FIGURE_MODULES = ("matplotlib.figure", "matplotlib.backends.backend_agg", "PIL.Image")
FIGURE_PACKAGES = ("matplotlib", "mpl_toolkits", "PIL", "pyparsing", "fontTools", "kiwisolver", "cycler",
                   "dateutil", "contourpy")
_preloading: list[threading.Thread] = []


def preload() -> None:
    """Import what the figures need (FIGURE_MODULES: matplotlib, its Agg canvas, PIL) in a thread
    of its own while the caller computes, once per process. The pipeline starts it before the
    adjustment: the import is pure Python (about 0.8 s), the adjustment's numpy and BLAS work
    leaves the interpreter free for much of its time, and the second core takes the import there.
    The report's own imports then find the modules loaded (or wait for the thread to finish them:
    Python's import locks). The thread is not a daemon: an interpreter that exits meanwhile lets it
    finish its import first."""
    if _preloading or all(name in sys.modules for name in FIGURE_MODULES):
        return
    thread = threading.Thread(target=import_figure_modules, name="striptri-figure-imports")
    _preloading.append(thread)
    thread.start()


AXES3D_MODULE = "mpl_toolkits.mplot3d"


def import_figure_modules(without_axes3d: bool = False) -> None:
    """Import FIGURE_MODULES (preload's thread; the drawing worker, report.drawing, at its start).

    without_axes3d: for the drawing worker's own interpreter, where no caller's code runs.
    matplotlib's registry of projections imports mpl_toolkits.mplot3d for its 3D projection, which
    no figure of striptri draws: 0.04 s of the worker's 0.3 s import (six alternating runs, medians
    0.320 -> 0.273 s). A stand-in module without Axes3D takes its place during the import
    (matplotlib then leaves the projection out, as it does when mplot3d cannot be imported) and is
    removed after it."""
    import importlib
    import types

    stand_in = None
    if without_axes3d and AXES3D_MODULE not in sys.modules:
        stand_in = sys.modules[AXES3D_MODULE] = types.ModuleType(AXES3D_MODULE)
        stand_in.Axes3D = None
    try:
        for name in FIGURE_MODULES:
            try:
                importlib.import_module(name)
            except ImportError:  # the figures' own import says what is missing
                return
    finally:
        if stand_in is not None and sys.modules.get(AXES3D_MODULE) is stand_in:
            del sys.modules[AXES3D_MODULE]


def from_figure_packages(message: warnings.WarningMessage) -> bool:
    """Whether a recorded warning was raised in a file of FIGURE_PACKAGES (the pipeline leaves such
    warnings of its adjustment phase out of the run's warnings: only the preload can raise them)."""
    parts = os.path.normpath(str(message.filename)).split(os.sep)
    return any(p in FIGURE_PACKAGES for p in parts[:-1])


def __getattr__(name: str):
    """``plt``: matplotlib.pyplot with the Agg backend, imported on first use."""
    if name == "plt":
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        return plt
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _figure(**kwargs):
    """A matplotlib Figure outside pyplot (nothing to close, nothing global), at DPI."""
    from matplotlib.figure import Figure

    return Figure(dpi=DPI, **kwargs)


PNG_COMPRESSION = 3  # zlib level: 6 (PIL's default) makes the report's PNGs 5 % smaller in 40 % more time
PAD_INCHES = 0.1  # margin kept about the drawn content when a figure is trimmed (savefig's pad_inches)


def png_of(fig, tight: bool = True) -> bytes:
    """The figure as PNG bytes (DPI dots per inch; trimmed to its content plus PAD_INCHES when
    ``tight``). A pyplot figure (the study's) is closed afterwards.

    A figure of ``_figure`` is drawn once and trimmed to the pixels that are not background
    (savefig's ``bbox_inches="tight"`` draws it twice, the first time only to find the extent of its
    artists). Content that touches the figure's edge may reach past it, which trimming cannot bring
    back: such a figure is drawn by savefig instead."""
    if getattr(fig.canvas, "manager", None) is not None or fig.dpi != DPI:
        return _png_savefig(fig, tight)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    if tight:
        background = np.array([*_background(fig), 255], dtype=np.uint8).view(np.uint32)[0]
        drawn = rgba.view(np.uint32)[:, :, 0] != background  # (height, width): a pixel not of the background
        rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
        if len(rows):
            height, width = drawn.shape
            if rows[0] == 0 or cols[0] == 0 or rows[-1] == height - 1 or cols[-1] == width - 1:
                return _png_savefig(fig, tight)
            pad = int(round(PAD_INCHES * DPI))
            rgba = rgba[max(rows[0] - pad, 0):rows[-1] + 1 + pad, max(cols[0] - pad, 0):cols[-1] + 1 + pad]
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba[:, :, :3])).save(buf, format="png", compress_level=PNG_COMPRESSION)
    return buf.getvalue()


def _background(fig) -> tuple:
    """The figure's face colour as 8-bit RGB."""
    from matplotlib.colors import to_rgb

    return tuple(int(round(255 * c)) for c in to_rgb(fig.get_facecolor()))


def _png_savefig(fig, tight: bool) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight" if tight else None)
    if getattr(fig.canvas, "manager", None) is not None:
        import matplotlib.pyplot as plt

        plt.close(fig)
    return buf.getvalue()


STRUCTURE_PHOTO, STRUCTURE_CAMERA = (0.12, 0.31, 0.47), (0.77, 0.35, 0.07)  # the colours of the blocks
# The square axes of the figure are about 465 pixels across at DPI: an image of more pixels (or more
# cells) would only be resampled down, dropping marks, in an array of 32 bytes per pixel (150 MB for
# 1,500 x 1,500 cells). Up to STRUCTURE_CELLS blocks one cell each; beyond, one pixel per group.
STRUCTURE_CELLS = 450
STRUCTURE_PIXELS = 450


def normal_matrix_structure(N, block_starts: np.ndarray, n_photo_blocks: int, title: str = "",
                            labels=None) -> bytes:
    """:func:`structure_figure` of N (its arguments there)."""
    return structure_figure(*structure_parts(N, block_starts), n_photo_blocks, title, labels)


class BlockStructure(NamedTuple):
    """The nonzero blocks of a normal matrix (block_pattern's), rows compressed: indptr (nb + 1,)
    and indices (nnz,). Plain arrays: a drawing worker (report.drawing) gets them without scipy."""

    indptr: np.ndarray
    indices: np.ndarray


def structure_parts(N, block_starts: np.ndarray) -> tuple:
    """(the nonzero blocks of N (BlockStructure; None when N is empty), N's size): what
    :func:`structure_figure` draws, small where N is large."""
    n = N.shape[0]
    if not n:
        return None, 0
    pattern = block_pattern(N, block_starts)
    return BlockStructure(pattern.indptr, pattern.indices), n


def structure_figure(pattern, n: int, n_photo_blocks: int, title: str = "", labels=None) -> bytes:
    """The nonzero pattern of the normal matrix (Schmid Fig. 10): one mark per nonzero 6x6 photo
    block (camera columns last), with the block grid for small projects. Beyond STRUCTURE_CELLS
    blocks the pattern is drawn as an image of STRUCTURE_PIXELS pixels a side, a pixel coloured when
    any block it covers is nonzero (camera blocks on top).

    pattern: the nonzero blocks of the normal matrix N (BlockStructure: structure_parts of N and
    the first column of each photo and camera block, UnknownLayout.block_starts); n: N's size;
    n_photo_blocks: how many of the blocks are photos; labels: the ids of the blocks
    (photo ids, then camera ids), shown on the axes where they fit (at most STRUCTURE_LABELS blocks;
    beyond, the axes count the blocks from 1).
    """
    if n == 0:
        return _empty_normal_matrix(title)
    nb = len(pattern.indptr) - 1
    rows = np.repeat(np.arange(nb), np.diff(pattern.indptr))
    cols = np.asarray(pattern.indices)
    bandwidth = int(np.max(np.abs(rows - cols), initial=0))
    fig = _figure(figsize=(6.4, 5.5))  # room for the title beside the square axes
    ax = fig.subplots()
    is_cam = (rows >= n_photo_blocks) | (cols >= n_photo_blocks)
    # 8-bit colours: an image of floats would take 8 times the memory (and matplotlib copies it)
    photo, camera = (np.round(255 * np.array(c)).astype(np.uint8) for c in (STRUCTURE_PHOTO, STRUCTURE_CAMERA))
    if nb <= STRUCTURE_CELLS:  # filled cells, as in Schmid's Fig. 10
        image = np.full((nb, nb, 3), 255, dtype=np.uint8)
        image[rows[~is_cam], cols[~is_cam]] = photo
        image[rows[is_cam], cols[is_cam]] = camera
        ax.imshow(image, interpolation="nearest")
    else:  # one pixel per group of blocks
        px = STRUCTURE_PIXELS
        image = np.full((px, px, 3), 255, dtype=np.uint8)
        pr, pc = rows * px // nb, cols * px // nb
        image[pr[~is_cam], pc[~is_cam]] = photo
        image[pr[is_cam], pc[is_cam]] = camera
        ax.imshow(image, interpolation="nearest", extent=(-0.5, nb - 0.5, nb - 0.5, -0.5))
    ax.set_xlim(-0.5, nb - 0.5)
    ax.set_ylim(nb - 0.5, -0.5)
    ax.set_aspect("equal")
    if nb <= 40:
        ax.set_xticks(np.arange(nb) - 0.5, minor=True)
        ax.set_yticks(np.arange(nb) - 0.5, minor=True)
        ax.grid(True, which="minor", linewidth=0.4, color="#999999")
        ax.tick_params(labelsize=6)
    if labels is not None and len(labels) == nb and nb <= STRUCTURE_LABELS:
        ax.set_xticks(np.arange(nb), [str(x) for x in labels], rotation=90)
        ax.set_yticks(np.arange(nb), [str(x) for x in labels])
        ax.tick_params(labelsize=6 if nb <= 20 else 4.5)
        what = "photo id"
    else:  # too many to name: the blocks counted from 1, as a user counts photos
        ax.xaxis.set_major_formatter(_count_from_one)
        ax.yaxis.set_major_formatter(_count_from_one)
        what = "photo number"
    ax.set_xlabel(f"{what} (photos in order, then cameras in orange)" if is_cam.any() else what)
    ax.set_ylabel(what)
    fill = len(cols) / max(nb * nb, 1)
    ax.set_title(title or f"normal matrix: {n} unknowns, {nb} blocks, {fill:.1%} of blocks filled, "
                          f"block bandwidth {bandwidth}", fontsize=9)
    return png_of(fig)


STRUCTURE_LABELS = 40  # photo ids on the axes of the normal matrix's structure up to this many blocks


def _count_from_one(value, position) -> str:
    return f"{int(round(value)) + 1}" if abs(value - round(value)) < 1e-9 and value >= 0 else ""


def block_pattern(N, block_starts: np.ndarray):
    """(nb, nb) CSR matrix with a 1 for every block (rows and columns grouped at block_starts, the
    first unknown of each block) that holds a nonzero of the sparse (n, n) matrix N.

    The rows of a block being contiguous, the stored entries of N are grouped by block row through
    N's own row pointers and only their columns are mapped to blocks: no coordinate list of N."""
    import scipy.sparse as sp

    N = sp.csr_matrix(N)
    n = N.shape[0]
    starts = np.asarray(block_starts, dtype=int)
    block_of = np.zeros(n, dtype=int)
    if len(starts):
        block_of[starts[1:]] = 1
        block_of = np.cumsum(block_of)
    nb = len(starts)
    if nb and starts[0] == 0 and np.all(np.diff(starts) > 0):
        indptr = N.indptr[np.append(starts, n)]
        data = (N.data != 0).astype(np.float64)
        pattern = sp.csr_matrix((data, block_of[N.indices], indptr - indptr[0]), shape=(nb, nb))
    else:  # blocks as block_of says, whatever their order
        N = N.tocoo()
        nz = N.data != 0
        pattern = sp.csr_matrix((np.ones(int(nz.sum())), (block_of[N.row[nz]], block_of[N.col[nz]])), shape=(nb, nb))
    pattern.sum_duplicates()
    pattern.eliminate_zeros()
    pattern.data[:] = 1.0
    return pattern


def _empty_normal_matrix(title: str = "") -> bytes:
    """The figure of a normal matrix without unknowns: every orientation and camera element held
    fixed (a pure forward intersection), so there is no structure to draw; it says so."""
    fig = _figure(figsize=(5.5, 2.0))
    ax = fig.subplots()
    ax.axis("off")
    ax.text(0.5, 0.5, "The normal matrix is empty (0 unknowns):\nevery orientation and camera element is held "
            "fixed,\nso the adjustment only intersects the points.", ha="center", va="center", fontsize=9,
            transform=ax.transAxes)
    ax.set_title(title or "normal matrix: 0 unknowns", fontsize=9)
    return png_of(fig)


# Colours shared by the figures and the report's legend text.
RESIDUAL_COLOUR = "#1f4e79"


class ScaleBar(NamedTuple):
    """Vectors or ellipses drawn magnified by ``magnification``, with a scale bar of ``length`` (in
    the units of what is drawn: plate units for residuals, m for errors on the ground) labelled
    ``label``."""

    magnification: float
    length: float
    label: str


@dataclass(frozen=True)
class VectorStyle:
    """How residual vectors are drawn: line width, opacity, rasterised (many vectors), a dot at the
    measured point, colour (flagged ones always in FLAG_COLOUR, opaque and on top)."""

    width: float = 0.6
    alpha: float = 1.0
    rasterized: bool = False
    dots: bool = True
    colour: str = RESIDUAL_COLOUR
FLAG_COLOUR = "#c0392b"
KIND_STYLE = {  # kind name -> (marker, colour, label)
    "tie": (".", "#4c72b0", "tie point"),
    "XYZ": ("^", "#c0392b", "full control (XYZ)"),
    "XY": ("^", "#e67e22", "plan control (XY)"),
    "Z": ("v", "#27ae60", "height control (Z)"),
    "check": ("D", "#8e44ad", "check point"),
}
FIELD_COLOURS = "YlGnBu"  # colour map of the rasters (residual field, precision map): light = small


def nice_number(x: float) -> float:
    """The largest of 1, 2, 5 times a power of ten not above x (x > 0)."""
    if not np.isfinite(x) or x <= 0:
        return 1.0
    e = np.floor(np.log10(x))
    for m in (5.0, 2.0, 1.0):
        if m * 10**e <= x * (1 + 1e-12):
            return float(m * 10**e)
    return float(10**e)


def _positive(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


def _power_label(y, _pos) -> str:
    """1e-05 -> "1e-5": short plain labels for log axes."""
    return f"{y:.0e}".replace("e+0", "e").replace("e-0", "e-")


def convergence(vtpv, max_correction, inner_iterations=None) -> bytes:
    """Convergence history on log axes: v^T P v and the largest correction (in units of its
    standard deviation) per iteration; a third panel with the inner iterations of an iterative
    solver when given. All arrays (n_iter,)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullLocator

    it = np.arange(1, len(vtpv) + 1)
    n_panels = 3 if inner_iterations is not None else 2
    fig = _figure(figsize=(3.3 * n_panels, 2.6))
    axes = fig.subplots(1, n_panels)
    for ax, values, label in ((axes[0], vtpv, "vᵀP v"), (axes[1], max_correction, "largest |dx| / its σ")):
        ax.semilogy(it, _positive(values), "o-", color=RESIDUAL_COLOUR, markersize=4)
        # plain labels and no minor ticks: mathtext labels and minor gridlines cost most of the time
        ax.yaxis.set_major_locator(LogLocator(numticks=7))
        ax.yaxis.set_minor_locator(NullLocator())
        ax.yaxis.set_major_formatter(FuncFormatter(_power_label))
        ax.set_xlabel("iteration", fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.grid(True, linewidth=0.3, alpha=0.6)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    if inner_iterations is not None:
        ax = axes[2]
        ax.bar(it, np.nan_to_num(np.asarray(inner_iterations, dtype=float)), color="#7f8c8d")
        ax.set_xlabel("iteration", fontsize=8)
        ax.set_title("inner iterations of the solver", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    # fixed margins (the PNG is trimmed to its content): tight_layout would lay out every label once more
    fig.subplots_adjust(left=0.6 / fig.get_figwidth(), right=0.99, bottom=0.17, top=0.9, wspace=0.28)
    return png_of(fig)


def _format_frame(ax, half_format: float) -> None:
    h = half_format
    ax.plot([-h, h, h, -h, -h], [-h, -h, h, h, -h], color="#888888", linewidth=0.6)
    ax.plot([-0.03 * h, 0.03 * h], [0, 0], color="#888888", linewidth=0.5)
    ax.plot([0, 0], [-0.03 * h, 0.03 * h], color="#888888", linewidth=0.5)
    ax.set_xlim(-1.04 * h, 1.04 * h)
    ax.set_ylim(-1.04 * h, 1.04 * h)
    ax.set_aspect("equal")
    for s in ax.spines.values():
        s.set_visible(False)


def _vectors(ax, xy, v, flagged, magnification, style: VectorStyle = VectorStyle()) -> None:
    """Residual vectors as line segments from the measured point to point + magnification v;
    flagged ones on top in FLAG_COLOUR, opaque."""
    from matplotlib.collections import LineCollection

    width, alpha, rasterized, dots, colour = style.width, style.alpha, style.rasterized, style.dots, style.colour
    styles = ((~flagged, colour, width, alpha, 2, 3), (flagged, FLAG_COLOUR, 2.0 * max(width, 0.6), 1.0, 4, 5))
    for sel, c, lw, al, z_line, z_dot in styles:
        if not sel.any():
            continue
        seg = np.stack([xy[sel], xy[sel] + magnification * v[sel]], axis=1)
        ax.add_collection(LineCollection(seg, colors=c, linewidths=lw, alpha=al, rasterized=rasterized,
                                         zorder=z_line))
        if dots or c == FLAG_COLOUR:
            ax.scatter(xy[sel, 0], xy[sel, 1], s=2 if c != FLAG_COLOUR else 6, color=c,
                       linewidths=0, alpha=al, rasterized=rasterized, zorder=z_dot)


def _scale_bar(ax, length_plot: float, label: str, half_format: float) -> None:
    """A bar of length_plot (plot units) in the lower left corner of the format."""
    x0, y0 = -0.92 * half_format, -0.9 * half_format
    ax.plot([x0, x0 + length_plot], [y0, y0], color="black", linewidth=1.6, solid_capstyle="butt")
    ax.text(x0, y0 + 0.05 * half_format, label, fontsize=6.5, va="bottom", ha="left")


def plate_residuals_per_photo(xy_plate, v_plate, flagged, groups, titles, half_format: float, scale: ScaleBar,
                              ncols: int = 6) -> bytes:
    """Small multiples: the residual vectors of one photo per panel, drawn on the format.

    xy_plate, v_plate: (m, 2) measured plate coordinates and residuals (plate units); flagged: (m,)
    bool; groups: list of index arrays into the rows, one per panel; titles: one per panel;
    half_format: half the side of the drawn frame; scale: the magnification of the vectors and the
    scale bar (a residual in plate units).

    All panels share one axes (each shifted to its place in the grid): one collection per colour
    instead of one axes per photo keeps this fast for many panels.
    """
    from matplotlib.collections import LineCollection

    magnification, bar_length, bar_label = scale
    n = len(groups)
    ncols = max(1, min(ncols, n))
    nrows = int(np.ceil(n / ncols))
    h = half_format
    pitch_x, pitch_y = 2.25 * h, 2.5 * h  # room for the title above each frame
    fig = _figure(figsize=(1.9 * ncols, 2.1 * nrows))
    ax = fig.add_axes((0, 0, 1, 1))
    shift = np.array([[(k % ncols) * pitch_x, -(k // ncols) * pitch_y] for k in range(n)]).reshape(-1, 2)
    rows = np.concatenate(groups) if n else np.zeros(0, dtype=int)
    panel = np.repeat(np.arange(n), [len(g) for g in groups])
    xy = xy_plate[rows] + shift[panel]
    frame = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]])
    ax.add_collection(LineCollection([frame + s for s in shift], colors="#888888", linewidths=0.6))
    cross = [np.array([[-0.03 * h, 0], [0.03 * h, 0]]), np.array([[0, -0.03 * h], [0, 0.03 * h]])]
    ax.add_collection(LineCollection([c + s for s in shift for c in cross], colors="#888888", linewidths=0.5))
    _vectors(ax, xy, v_plate[rows], flagged[rows], magnification)
    for k in range(n):
        ax.text(shift[k, 0], shift[k, 1] + 1.06 * h, titles[k], fontsize=7, ha="center", va="bottom")
    if n:
        x0, y0 = shift[0] + (-0.92 * h, -0.9 * h)
        ax.plot([x0, x0 + bar_length * magnification], [y0, y0], color="black", linewidth=1.6, solid_capstyle="butt")
        ax.text(x0, y0 + 0.05 * h, bar_label, fontsize=6.5, va="bottom", ha="left")
    ax.set_xlim(-1.1 * h, (ncols - 1) * pitch_x + 1.1 * h)
    ax.set_ylim(-(nrows - 1) * pitch_y - 1.1 * h, 1.4 * h)
    ax.set_aspect("equal")
    ax.axis("off")
    return png_of(fig)


def plate_residuals_stacked(xy_plate, v_plate, flagged, half_format: float, scale: ScaleBar, cell_means=None,
                            field=None, plate_unit: str = "mm") -> bytes:
    """All residual vectors of all photos over one format (systematic image errors show as a
    pattern), drawn as ``scale`` says, and, when cell_means = (centres (k, 2), means (k, 2), counts
    (k,), ScaleBar) is given, the mean residual of each cell of a grid in a second panel.

    field = (rms (g, g), unit_label, n_all), for many measurements: the left panel shows instead the
    RMS residual length of each cell of a g x g grid over the format (rms in the plate units of
    the vectors, row 0 at -half_format; nan where no measurement falls) as a raster, and on top only
    the vectors given (the caller passes the worst), out of n_all measurements. plate_unit: the
    unit of the plate coordinates on the axes ("mm" or "px", model.PLATE_UNITS).
    """
    from matplotlib.collections import LineCollection

    magnification, bar_length, bar_label = scale
    n_panels = 2 if cell_means is not None else 1
    fig = _figure(figsize=(4.6 * n_panels + (0.6 if field is not None else 0.0), 4.6))
    axes = fig.subplots(1, n_panels, squeeze=False)
    ax = axes[0, 0]
    _format_frame(ax, half_format)
    if field is None:
        many = len(xy_plate) > 3000
        _vectors(ax, xy_plate, v_plate, flagged, magnification,
                 VectorStyle(width=0.3 if many else 0.5, alpha=0.35 if many else 1.0, rasterized=many, dots=not many))
        ax.set_title(f"all {len(xy_plate)} measurements, vectors x{magnification:g}", fontsize=9)
    else:
        rms, unit_label, n_all = field
        h = half_format
        top = float(np.nanpercentile(rms, 99)) if np.isfinite(rms).any() else 1.0
        image = ax.imshow(np.ma.masked_invalid(rms), origin="lower", extent=(-h, h, -h, h), cmap=FIELD_COLOURS,
                          vmin=0.0, vmax=top if top > 0 else 1.0, interpolation="nearest", zorder=1)
        bar = fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03, extend="max")
        bar.set_label(f"RMS residual per cell ({unit_label})", fontsize=7)
        bar.ax.tick_params(labelsize=6.5)
        _vectors(ax, xy_plate, v_plate, flagged, magnification, VectorStyle(width=0.8, colour="#2c3e50"))
        ax.set_title(f"{n_all} measurements: RMS per cell; the {len(xy_plate)} largest |w| drawn x{magnification:g}",
                     fontsize=8.5)
    _scale_bar(ax, bar_length * magnification, bar_label, half_format)
    ax.tick_params(labelsize=7)
    ax.set_xlabel(f"x ({plate_unit})", fontsize=8)
    ax.set_ylabel(f"y ({plate_unit})", fontsize=8)
    if cell_means is not None:
        centres, means, counts, (mag2, bar2, label2) = cell_means
        ax = axes[0, 1]
        _format_frame(ax, half_format)
        ok = counts > 0
        seg = np.stack([centres[ok], centres[ok] + mag2 * means[ok]], axis=1)
        ax.add_collection(LineCollection(seg, colors="#d35400", linewidths=1.6))
        ax.scatter(centres[ok, 0], centres[ok, 1], s=8, color="#d35400", zorder=3)
        _scale_bar(ax, bar2 * mag2, label2, half_format)
        ax.set_title(f"mean residual per cell, vectors x{mag2:g}", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_xlabel(f"x ({plate_unit})", fontsize=8)
    width = fig.get_figwidth()  # fixed margins in inches, as convergence's
    fig.subplots_adjust(left=0.65 / width, right=1 - 0.15 / width, bottom=0.1, top=0.93, wspace=0.18)
    return png_of(fig)
