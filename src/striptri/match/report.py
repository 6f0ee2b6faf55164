"""The matching report (OUT/match_report.html of ``striptri match``; docs/matching.md): features per
photo, verified matches per pair, the pair graph over the block, the tie points written per photo
and their spread over the format, track lengths, and the time of each stage. One self-contained
HTML file in the look of the adjustment report (report.page.STYLE)."""

from __future__ import annotations

import html

import numpy as np

from ..report import figures as fig
from ..report.page import STYLE, card, figure_html, html_table

MAX_PHOTO_ROWS = 40  # photos listed in the table up to this many; beyond, the 20 with the fewest tie points
MAX_PANELS = 24  # a map of the tie points per photo up to this many photos; beyond, the 12 with the fewest
MAX_PAIR_ROWS = 30  # the weakest verified pairs and every failed one, at most this many rows
CELLS = 3  # the spread: the share of the format's CELLS x CELLS cells that hold a tie point


def match_report(p, project_dir, images_dir) -> str:
    """The report of a run's MatchProducts ``p`` as HTML text."""
    n = len(p.photo_ids)
    rays_per_photo = np.bincount(p.ray_photo, minlength=n)
    spread = _spread(p.ray_photo, p.ray_plate, p.half_format, n)
    verified = p.pair_matches > 0
    total = sum(p.seconds.values())
    cards = "".join([
        card(f"{n}", "photographs"),
        card(f"{p.verified_pairs} / {p.pairs}", "pairs verified / candidates", "bad" if p.verified_pairs < p.pairs else ""),
        card(f"{p.matches:,}", "verified matches"),
        card(f"{p.kept_tracks:,}", "tie points written"),
        card(f"{p.rays:,}", "their rays"),
        card(f"{p.sigma_px:.3f} px", "sigma of an image coordinate"),
        card(f"{int(rays_per_photo.min()) if n else 0}", "fewest tie points in a photo",
             "bad" if n and rays_per_photo.min() < 6 else ""),
        card(f"{total:.1f} s", "time"),
    ])
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>striptri matching report</title><style>{STYLE}</style></head><body><main>",
        "<h1>Automatic tie points: matching report</h1>",
        f"<p class='sub'>Project {html.escape(str(project_dir))} &middot; images {html.escape(str(images_dir))}</p>",
        f"<div class='cards'>{cards}</div>",
        f"<p>The image coordinates' standard deviation, {p.sigma_px:.3f} px, was {html.escape(p.sigma_how)}; it is "
        "the sigma of the automatic rows of image_points.csv. Of the "
        f"{p.tracks:,} tracks, {p.split} were split (two features of one photo) and {p.inconsistent} dropped "
        + ("because their rays, projected onto the terrain with the approximate orientations, do not meet. "
           if p.strips is None else "because their rays break the two-view geometry of a matched pair, the relative "
           "orientation of two successive photos, or, with the orientations from the strips, do not meet. ") +
        "False matches remain among those written: adjust with <code>--blunders robust-snoop</code> (or <code>snoop</code>).</p>",
        (f"<p>Least-squares matching at full resolution refined {p.refined} of the {p.refinable} rays that are not "
         f"their track's reference (median shift {p.refine_shift:.3f} px); the others kept their features' "
         "positions.</p>" if p.refined >= 0 else ""),
        (f"<p>{p.chips} image chips of control and check points, each around the position the approximate "
         "orientations predict (marked), are in chips/ with chips/chips.csv: measure or confirm the points there "
         "and give the measurements in image_points.csv.</p>" if p.chips else ""),
        _fiducial_section(p),
        _strips_section(p),
        "<h2 id='stages'>Time per stage</h2>",
        html_table(["stage", "seconds", "peak memory at its end (MB)"],
                   [[html.escape(k), f"{v:.2f}", f"{p.peak_mb[k]:,.0f}" if k in p.peak_mb else "&ndash;"]
                    for k, v in p.seconds.items()], left=1),
        "<p class='sub'>The peak is this process's (the features and pairs are found in worker processes of "
        "their own); it grows in the stage where it changes.</p>",
        "<h2 id='pairs'>Pairs</h2>",
        figure_html(_pair_graph(p), "pair graph",
                    "The approximate photo centres and the candidate pairs: a line per verified pair, the darker "
                    "the more matches; dashed red: a candidate pair that did not verify."),
        _pair_table(p, verified),
        "<h2 id='photos'>Photos</h2>",
        _photo_table(p, rays_per_photo, spread),
        figure_html(_maps(p, rays_per_photo), "tie points per photo",
                    f"The tie points written on each photo's format, with the {CELLS} &times; {CELLS} cells of the "
                    "thinning" + (f" (the {MAX_PANELS // 2} photos with the fewest)" if n > MAX_PANELS else "") + "."),
        "<h2 id='tracks'>Track lengths</h2>",
        figure_html(_track_lengths(p), "track lengths",
                    "Rays per track: every track of the verified matches, and the tracks written."),
        "<footer>Written by striptri match. The tie points are in image_points.csv beside this file "
        "(source auto).</footer></main></body></html>",
    ]
    return "\n".join(parts)


def _fiducial_section(p) -> str:
    """Film scans: the fiducial marks of each photo, the fit's largest residual and sigma0, and every
    mark that was not found with the reason (the rows with missing marks first)."""
    if not p.fiducials:
        return ""
    found = p.fiducials_found
    order = sorted(range(len(p.fiducials)), key=lambda k: (p.fiducials[k][1] - p.fiducials[k][2], k))
    if len(order) > MAX_PHOTO_ROWS:
        order = order[:MAX_PHOTO_ROWS // 2]
    rows = [[html.escape(pid), f"{m} of {total}", f"{largest:.3f}", "n/a" if not np.isfinite(s0) else f"{s0:.2f}",
             html.escape(missed) or "&ndash;"]
            for pid, m, total, largest, s0, missed in (p.fiducials[k] for k in order)]
    missing = sum(row[2] - row[1] for row in p.fiducials)
    how = ("found in the scans by normalised cross-correlation (written to fiducial_measurements.csv; a mark "
           "not found is left out, never guessed)" if found else "taken from the project's fiducial_measurements.csv")
    return ("<h2 id='fiducials'>Fiducial marks</h2>"
            f"<p>The fiducial marks were {how}. "
            + ("Every mark was found. " if not missing else f"{missing} mark(s) missing in all. ")
            + "Each scan's fiducial "
            "transformation, fitted to its marks, carries the features to the plate.</p>"
            + html_table(["photo", "marks", "largest residual (px)", "sigma0", "not found"], rows, left=1,
                         row_classes=["bad" if p.fiducials[k][1] < p.fiducials[k][2] else "" for k in order]))


def _spread(photo, plate, half, n) -> np.ndarray:
    """(n,) the share of each photo's CELLS x CELLS cells that hold a tie point."""
    if len(photo) == 0:
        return np.zeros(n)
    u = np.clip(((plate / half[photo] + 1.0) / 2.0 * CELLS).astype(int), 0, CELLS - 1)
    occupied = np.zeros((n, CELLS * CELLS), dtype=bool)
    occupied[photo, u[:, 1] * CELLS + u[:, 0]] = True
    return occupied.mean(1)


def _photo_table(p, rays, spread) -> str:
    n = len(p.photo_ids)
    order = np.arange(n) if n <= MAX_PHOTO_ROWS else np.argsort(rays, kind="stable")[:MAX_PHOTO_ROWS // 2]
    rows = [[html.escape(p.photo_ids[k]), f"{p.features[k]:,}", f"{int(rays[k]):,}", f"{spread[k]:.0%}"]
            for k in order]
    note = "" if n <= MAX_PHOTO_ROWS else f"<p class='note'>The {len(order)} photos with the fewest tie points.</p>"
    return note + html_table(["photo", "features", "tie points", "cells covered"], rows, left=1,
                             row_classes=["bad" if rays[k] < 6 or spread[k] < 0.5 else "" for k in order])


def _pair_table(p, verified) -> str:
    if not len(p.pair_list):
        return "<p>No candidate pairs.</p>"
    order = np.argsort(p.pair_matches, kind="stable")[:MAX_PAIR_ROWS]
    rows = [[html.escape(p.photo_ids[a]), html.escape(p.photo_ids[b]), f"{int(m):,}" if m else "not verified"]
            for (a, b), m in zip(p.pair_list[order], p.pair_matches[order])]
    return (f"<p class='note'>Verified matches of the {len(order)} weakest of {len(p.pair_list)} candidate pairs "
            f"(median of the verified: {int(np.median(p.pair_matches[verified])) if verified.any() else 0}).</p>"
            + html_table(["photo", "photo", "verified matches"], rows, left=2,
                         row_classes=["bad" if m == 0 else "" for m in p.pair_matches[order]]))


def _strips_section(p) -> str:
    """Photos without orientations: how each strip was built and placed (sequential.block)."""
    if not p.strips:
        return ""
    rows = [[html.escape(s.strip), f"{s.photos}", f"{s.points}", f"{s.control}", f"{s.dropped}", f"{s.rms_m:.3f}",
             html.escape(", ".join(f"strip {a}" for a in s.after)) or "control only"] for s in p.strips]
    return ("<h2 id='strips'>Orientations from the strips</h2>"
            "<p>photos.csv gives no orientations. Each strip was built photo by photo by the sequential method "
            "(relative orientations and scale transfer) in a frame of its own, then placed by a 3D similarity on "
            "the full control and the points of the strips placed before it, in this order. OUT's photos.csv "
            "carries the orientations found: approximations for the adjustment, which uses every observation.</p>"
            + html_table(["strip", "photos", "points used", "of them control", "left out (trimmed)",
                          "RMS of the fit (m)", "placed through"], rows, left=1))


def _layout(p) -> np.ndarray:
    """(n, 2) where to draw each photo: its approximate centre, else its place in the list."""
    xy = np.asarray(p.centres, dtype=float)
    if np.isfinite(xy).all():
        return xy
    k = np.arange(len(p.photo_ids), dtype=float)
    return np.column_stack([k, np.zeros_like(k)])


def _pair_graph(p) -> bytes:
    from matplotlib import colormaps

    xy = _layout(p)
    figure = fig._figure(figsize=(7.0, 5.0))
    ax = figure.add_subplot()
    if len(p.pair_list):
        m = p.pair_matches
        top = max(int(m.max()), 1)
        cmap = colormaps["Blues"]
        for (a, b), k in zip(p.pair_list, m):  # one line per pair: a drawing, not a hot path
            if k:
                ax.plot(*xy[[a, b]].T, color=cmap(0.3 + 0.7 * k / top), lw=0.6 + 1.6 * k / top, zorder=1)
            else:
                ax.plot(*xy[[a, b]].T, color="#c0392b", lw=1.0, ls="--", zorder=1)
    ax.scatter(*xy.T, s=14, color="#222", zorder=2)
    if len(xy) <= 60:
        for k, name in enumerate(p.photo_ids):
            ax.annotate(name, xy[k], fontsize=6, xytext=(2, 2), textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("X (approximate centres)")
    ax.set_ylabel("Y")
    return fig.png_of(figure)


def _maps(p, rays) -> bytes:
    from matplotlib.patches import Rectangle

    n = len(p.photo_ids)
    shown = np.arange(n) if n <= MAX_PANELS else np.sort(np.argsort(rays, kind="stable")[:MAX_PANELS // 2])
    cols = min(6, max(1, len(shown)))
    rows = max(1, -(-len(shown) // cols))
    figure = fig._figure(figsize=(1.6 * cols, 1.7 * rows))
    for slot, k in enumerate(shown):
        ax = figure.add_subplot(rows, cols, slot + 1)
        hx, hy = p.half_format[k]
        ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, fill=False, lw=0.6, color="#888"))
        for t in range(1, CELLS):
            ax.axvline(-hx + 2 * hx * t / CELLS, lw=0.3, color="#bbb")
            ax.axhline(-hy + 2 * hy * t / CELLS, lw=0.3, color="#bbb")
        mine = p.ray_photo == k
        ax.scatter(*p.ray_plate[mine].T, s=3, color="#1f5fa8")
        ax.set_xlim(-hx * 1.05, hx * 1.05)
        ax.set_ylim(-hy * 1.05, hy * 1.05)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{p.photo_ids[k]}: {int(rays[k])}", fontsize=7)
    return fig.png_of(figure)


def _track_lengths(p) -> bytes:
    figure = fig._figure(figsize=(5.5, 3.0))
    ax = figure.add_subplot()
    every = np.asarray(p.track_lengths)
    top = int(every.max()) if len(every) else 2
    bins = np.arange(1.5, top + 1.5)
    if len(every):
        ax.hist(every, bins=bins, color="#bbb", label="all tracks")
    if len(p.kept_lengths):
        ax.hist(p.kept_lengths, bins=bins, color="#1f5fa8", label="written")
    ax.set_yscale("log")
    ax.set_xlabel("rays per track")
    ax.set_ylabel("tracks")
    ax.legend(fontsize=7)
    return fig.png_of(figure)
