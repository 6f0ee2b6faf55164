"""Plan views of the block (matplotlib, as report.figures): the error ellipses of the ground points
over the projection centres and their flight lines, and for large blocks the precision map (rasters
of the RMS error per cell with the worst points on top). Each function returns PNG bytes."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .figures import FIELD_COLOURS, KIND_STYLE, ScaleBar, _figure, png_of

WORST_COLOUR = "#c0392b"
MAP_FLIGHT_LINES = 30  # the precision map draws the flight lines of at most this many strips (more hide the raster)
LEGEND_INCHES = 2.4  # room right of the error ellipses' axes for their legend
NADIR_DEGREES = 30.0  # photos whose axes are this close to the vertical (median) fly strips: flight lines are drawn


class BlockPlan(NamedTuple):
    """What a plan view of the block draws: xy_centres (n_ph, 2) ground X, Y of the projection
    centres, in flight order within a strip; strip_of_photo (n_ph,) strip labels; xy_points
    (n_pt, 2); kind_names (n_pt,) names of KIND_STYLE; flight_lines: join the centres of each
    strip (False for convergent close range, whose stations fly no line)."""

    xy_centres: np.ndarray
    strip_of_photo: np.ndarray
    xy_points: np.ndarray
    kind_names: np.ndarray
    flight_lines: bool = True


def flies_strips(R_ground_from_cam: np.ndarray) -> bool:
    """Whether the photos look down like an aerial block (the median angle between the camera axis
    and the plumb line below NADIR_DEGREES), so that joining their centres strip by strip draws
    flight lines; convergent close-range stations fly none."""
    if not len(R_ground_from_cam):
        return True
    axis = -np.asarray(R_ground_from_cam)[:, :, 2]  # the viewing direction (-z of the camera) on the ground
    cos = np.clip(-axis[:, 2] / np.maximum(np.linalg.norm(axis, axis=1), 1e-300), -1.0, 1.0)
    return bool(np.degrees(np.median(np.arccos(cos))) < NADIR_DEGREES)


def _block_axes_size(xy_centres, xy_points) -> float:
    """Height / width of a plan view of the block (0.3 to 1)."""
    every = np.concatenate([xy_centres, xy_points[np.isfinite(xy_points).all(axis=1)]])
    dx, dy = np.ptp(every, axis=0) if len(every) else (1.0, 1.0)
    return float(np.clip((dy + 0.1 * max(dx, dy)) / max(dx, 1e-9), 0.3, 1.0))


def _flight_lines(ax, xy_centres, strip_of_photo, arrows: bool = True) -> None:
    """The projection centres of each strip joined in flight order, an arrow at the end."""
    from matplotlib.collections import LineCollection

    strips = np.asarray(strip_of_photo)
    lines = [xy_centres[strips == s] for s in dict.fromkeys(strips.tolist())]
    ax.add_collection(LineCollection(lines, colors="#95a5a6", linewidths=0.8, zorder=1))
    if arrows:
        for c in lines:
            if len(c) > 1:
                ax.annotate("", xy=c[-1], xytext=c[-2], arrowprops=dict(arrowstyle="-|>", color="#95a5a6",
                                                                        linewidth=0.8))


def _ellipse_collection(ax, xy, cov_xy, magnification, colours, linewidths=0.7, rasterized=False, zorder=3):
    """The horizontal standard error ellipses (semi-axes sqrt of the eigenvalues of cov_xy, (n, 2, 2))
    of the points xy (n, 2), magnified; points without a finite, nonzero ellipse are skipped."""
    from matplotlib.collections import EllipseCollection

    cov = np.asarray(cov_xy, dtype=float)
    ok = np.isfinite(cov).all(axis=(1, 2)) & np.isfinite(xy).all(axis=1)
    eigval, eigvec = np.linalg.eigh(np.where(ok[:, None, None], cov, np.eye(2)))
    a = np.sqrt(np.maximum(eigval[:, 1], 0.0))
    b = np.sqrt(np.maximum(eigval[:, 0], 0.0))
    angle = np.degrees(np.arctan2(eigvec[:, 1, 1], eigvec[:, 0, 1]))
    ok &= a > 0
    if ok.any():
        ax.add_collection(EllipseCollection(
            2 * a[ok] * magnification, 2 * b[ok] * magnification, angle[ok], units="xy",
            offsets=xy[ok], offset_transform=ax.transData, facecolors="none",
            edgecolors=np.asarray(colours)[ok] if np.ndim(colours) else colours, linewidths=linewidths,
            zorder=zorder, rasterized=rasterized))


def _plan_frame(ax, bar_length: float, magnification: float, bar_label: str, bar: bool = True) -> None:
    """Equal scales, a margin, a scale bar (bar_length m, drawn magnified; when ``bar``) in the lower
    left corner, plain tick labels in metres."""
    ax.set_aspect("equal")
    ax.autoscale_view()
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    pad = 0.04 * max(x1 - x0, y1 - y0)
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - 2.5 * pad, y1 + pad)
    if bar:
        bx, by = x0 - 0.5 * pad, y0 - 1.8 * pad
        ax.plot([bx, bx + bar_length * magnification], [by, by], color="black", linewidth=2, solid_capstyle="butt")
        ax.text(bx, by + 0.25 * pad, f"{bar_label} (ellipses x{magnification:g})", fontsize=7, va="bottom")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("X (m)", fontsize=8)
    ax.grid(True, linewidth=0.3, alpha=0.5)


def error_ellipses(plan: BlockPlan, cov_xy, scale: ScaleBar, labels=None) -> bytes:
    """Plan view of the block (``plan``): projection centres joined along their strips, the ground
    points coloured by kind (control as triangles) and the horizontal standard error ellipse of each
    point magnified as ``scale`` says, with its scale bar (m).

    cov_xy: (n_pt, 2, 2) covariance of X, Y in m^2 (nan where undetermined); labels: optional
    (n_pt,) strings, drawn beside control and check points.
    """
    xy_centres, strip_of_photo, xy_points, kind_names, flight_lines = plan
    magnification, bar_length, bar_label = scale
    kind_names = np.asarray(kind_names)
    many = len(xy_points) > 2000
    # the axes of an 8.6 in wide figure (matplotlib's default margins), with LEGEND_INCHES more on the
    # right for the legend beside them: everything inside the figure, so that it is drawn once
    # (figures.png_of trims it; a legend past the edge would need savefig's second drawing)
    width = 8.6 + LEGEND_INCHES
    fig = _figure(figsize=(width, 0.9 + 6.3 * _block_axes_size(xy_centres, xy_points)))
    fig.subplots_adjust(left=0.125 * 8.6 / width, right=0.9 * 8.6 / width)
    ax = fig.subplots()
    if flight_lines:
        _flight_lines(ax, xy_centres, strip_of_photo)
    ax.scatter(xy_centres[:, 0], xy_centres[:, 1], marker="+", s=18, color="#2c3e50", linewidths=0.7,
               zorder=2, label="projection centre" if flight_lines else "camera station",
               rasterized=len(xy_centres) > 2000)
    colours = np.array([KIND_STYLE.get(k, KIND_STYLE["tie"])[1] for k in kind_names] or ["#000000"])[:len(kind_names)]
    _ellipse_collection(ax, xy_points, cov_xy, magnification, colours, rasterized=many)
    _kind_markers(ax, xy_points, kind_names, rasterized=many)
    if labels is not None:
        named = np.flatnonzero(kind_names != "tie")
        if len(named) <= 60:
            for i in named:
                ax.annotate(str(labels[i]), xy_points[i], xytext=(3, 3), textcoords="offset points",
                            fontsize=5.5, color="#34495e", zorder=5)
    _plan_frame(ax, bar_length, magnification, bar_label)
    ax.set_ylabel("Y (m)", fontsize=8)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return png_of(fig)


def _kind_markers(ax, xy_points, kind_names, rasterized=False, kinds=None, small: bool = False) -> None:
    """The ground points of each kind of KIND_STYLE (all, or those in ``kinds``) as markers (small
    ones without an outline when ``small``)."""
    for name, (marker, colour, label) in KIND_STYLE.items():
        if kinds is not None and name not in kinds:
            continue
        sel = kind_names == name
        if not sel.any():
            continue
        size = 5 if small else 10 if name == "tie" else 30
        ax.scatter(xy_points[sel, 0], xy_points[sel, 1], marker=marker, s=size, color=colour,
                   edgecolors="white" if name != "tie" and not small else "none", linewidths=0.4, zorder=4,
                   label=f"{label} ({int(sel.sum())})", rasterized=rasterized)


def precision_map(plan: BlockPlan, extent, grids, worst, cov_xy, scale: ScaleBar) -> bytes:
    """Plan view of a large block as two rasters side by side: the RMS of the points' horizontal
    standard error (semi-major axis of the ellipse) and of their sigma Z, per cell of a grid over
    the block, with the flight lines (up to MAP_FLIGHT_LINES strips), the control points (small
    markers in the colours of KIND_STYLE) and the worst points on top (left: their ellipses
    magnified by ``magnification``; right: circled).

    extent: (x0, x1, y0, y1) of the grid in m; grids: ((ny, nx) horizontal, (ny, nx) vertical,
    unit_label, scale) with the RMS values in m (nan: no point in the cell), shown multiplied by
    scale in unit_label; worst: (horizontal indices, vertical indices) into the points; cov_xy:
    (n_pt, 2, 2) covariance of X, Y in m^2. plan, scale as for error_ellipses.
    """
    xy_centres, strip_of_photo, xy_points, kind_names, flight_lines = plan
    magnification, bar_length, bar_label = scale
    kind_names = np.asarray(kind_names)
    grid_h, grid_z, unit_label, scale = grids
    worst_h, worst_z = (np.asarray(w, dtype=int) for w in worst)
    aspect = _block_axes_size(xy_centres, xy_points)
    fig = _figure(figsize=(11.5, 1.4 + 5.0 * aspect))
    axes = fig.subplots(1, 2)
    control = [k for k in KIND_STYLE if k != "tie"]
    for ax, grid, title in ((axes[0], grid_h, "horizontal: semi-major axis of the error ellipse"),
                            (axes[1], grid_z, "height: σZ")):
        finite = grid[np.isfinite(grid)] * scale
        low, top = (float(v) for v in np.percentile(finite, [1, 99])) if len(finite) else (0.0, 1.0)
        image = ax.imshow(np.ma.masked_invalid(grid * scale), origin="lower", extent=extent, cmap=FIELD_COLOURS,
                          vmin=low, vmax=top if top > low else low + 1.0, interpolation="nearest", zorder=0)
        bar = fig.colorbar(image, ax=ax, orientation="horizontal", fraction=0.05, pad=0.1, extend="both")
        bar.set_label(f"RMS per cell ({unit_label})", fontsize=7)
        bar.ax.tick_params(labelsize=6.5)
        if flight_lines and len(set(np.asarray(strip_of_photo).tolist())) <= MAP_FLIGHT_LINES:
            _flight_lines(ax, xy_centres, strip_of_photo, arrows=False)
        _kind_markers(ax, xy_points, kind_names, kinds=control, small=True)
        ax.set_title(title, fontsize=9)
    _ellipse_collection(axes[0], xy_points[worst_h], np.asarray(cov_xy)[worst_h], magnification, WORST_COLOUR,
                        linewidths=1.0, zorder=5)
    axes[1].scatter(xy_points[worst_z, 0], xy_points[worst_z, 1], s=40, facecolors="none", edgecolors=WORST_COLOUR,
                    linewidths=1.0, zorder=5)
    _plan_frame(axes[0], bar_length, magnification, bar_label)
    _plan_frame(axes[1], bar_length, magnification, bar_label, bar=False)
    axes[0].set_ylabel("Y (m)", fontsize=8)
    return png_of(fig)
