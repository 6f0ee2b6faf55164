"""Fiducial marks found in a film scan automatically (issue 28), for fiducial_measurements.csv.

Each mark is searched in a window around its position predicted from the calibrated fiducial
coordinates: the plate origin at the scan's centre, x to the right and y up, ``px_per_mm`` scan
pixels per plate millimetre (the scan resolution: 15 um -> 66.7 px/mm), so that the window's
half-width ``search_mm`` absorbs where the film lay on the scanner. In the window the template (one
example mark cut from a scan, or a synthetic cross or dot, :func:`synthetic_mark`) is found by
normalised cross-correlation (OpenCV's TM_CCOEFF_NORMED), and the peak to subpixel by a quadratic
through the 3 x 3 correlations around it. A mark whose correlation stays below ``min_correlation``,
or whose second-best peak (away from the best) is nearly as high (``ambiguity``: a look-alike, a
scratch, another mark in the window), is listed as not found with the reason, never guessed.

Pixel coordinates as everywhere in striptri: origin at the scan's top-left corner, the centre of
the top-left pixel at (0.5, 0.5), col to the right and row down (docs/file-formats.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features import cv2_module

MIN_CORRELATION = 0.6  # a mark must correlate at least this well with the template
AMBIGUITY = 0.9  # a second peak above this fraction of the best makes the mark ambiguous
SUPPRESS_PX = 3  # the second peak is sought this far (template half-sizes + this) from the best


@dataclass(frozen=True)
class FoundMark:
    """One fiducial of one scan: col, row (scan px, nan when not found), correlation at the peak,
    and ``reason`` (empty when found)."""

    fiducial_id: str
    col: float
    row: float
    correlation: float
    reason: str = ""

    @property
    def found(self) -> bool:
        return not self.reason


def synthetic_mark(kind: str, size_px: int, line_px: float = 3.0, bright: bool = True) -> np.ndarray:
    """A template (size_px x size_px, float) of a ``cross`` (arms line_px wide) or a ``dot``
    (diameter line_px) centred in it; bright on dark unless ``bright`` is False."""
    if kind not in ("cross", "dot"):
        raise ValueError(f"synthetic mark {kind!r}: 'cross' or 'dot'")
    c = np.arange(size_px) + 0.5 - size_px / 2.0
    x, y = np.meshgrid(c, c)
    if kind == "cross":
        mark = (np.abs(x) <= line_px / 2) | (np.abs(y) <= line_px / 2)
    else:
        mark = np.hypot(x, y) <= line_px / 2
    t = mark.astype(np.float32)
    return t if bright else 1.0 - t


def find_marks(scan: np.ndarray, fiducials: dict[str, tuple[float, float]], template: np.ndarray,
               px_per_mm: float, search_mm: float = 3.0, min_correlation: float = MIN_CORRELATION,
               ambiguity: float = AMBIGUITY, predicted: dict | None = None) -> list[FoundMark]:
    """The fiducial marks of one scan (module doc). scan: (H, W) grey; fiducials: id -> calibrated
    (x, y) plate mm; template: (h, w) the mark, its centre the template's centre; predicted:
    id -> (col, row) where to centre a mark's window instead of the prediction from the scan's
    centre (find_marks_turned)."""
    cv2 = cv2_module()
    scan = np.asarray(scan, dtype=np.float32)
    template = np.asarray(template, dtype=np.float32)
    H, W = scan.shape
    th, tw = template.shape
    half = search_mm * px_per_mm
    out = []
    for fid, (x, y) in fiducials.items():
        col0, row0 = (W / 2.0 + x * px_per_mm, H / 2.0 - y * px_per_mm) if predicted is None else predicted[fid]
        c0, c1 = int(np.floor(col0 - half - tw / 2)), int(np.ceil(col0 + half + tw / 2))
        r0, r1 = int(np.floor(row0 - half - th / 2)), int(np.ceil(row0 + half + th / 2))
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, W), min(r1, H)
        if c1 - c0 < tw + 2 or r1 - r0 < th + 2:
            out.append(FoundMark(fid, np.nan, np.nan, np.nan, "its search window lies outside the scan"))
            continue
        window = scan[r0:r1, c0:c1]
        if float(window.std()) == 0.0:
            out.append(FoundMark(fid, np.nan, np.nan, np.nan, "the search window is blank"))
            continue
        ncc = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
        v, u = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
        best = float(ncc[v, u])
        away = ncc.copy()
        reach_v, reach_u = th // 2 + SUPPRESS_PX, tw // 2 + SUPPRESS_PX
        away[max(v - reach_v, 0):v + reach_v + 1, max(u - reach_u, 0):u + reach_u + 1] = -1.0
        second = float(away.max()) if away.size else -1.0
        if best < min_correlation:
            out.append(FoundMark(fid, np.nan, np.nan, best, f"no mark: best correlation {best:.2f} "
                                                            f"below {min_correlation:g}"))
            continue
        if second > ambiguity * best:
            out.append(FoundMark(fid, np.nan, np.nan, best, f"ambiguous: two peaks {best:.2f} and {second:.2f}"))
            continue
        # the template's top-left pixel at index (u, v) of the window: its centre, in corner-origin
        # pixels of the scan, at window origin + (u + tw/2, v + th/2); refined on an upsampled patch
        col, row = _refined(cv2, window, template, u, v)
        out.append(FoundMark(fid, c0 + col, r0 + row, best))
    return out


def find_marks_turned(scan: np.ndarray, fiducials: dict[str, tuple[float, float]], template: np.ndarray,
                      px_per_mm: float, wide_mm: float = 15.0, narrow_mm: float = 1.5) -> list[FoundMark]:
    """The marks of a scan that may lie turned (a few degrees) and shifted (a few mm) on the
    scanner, in two passes: every mark in a wide window about its position predicted from the
    scan's centre (wide_mm: a 2 degree turn moves a corner mark 150 mm from the centre by 5 mm);
    a similarity transformation fitted to the marks found (two or more) predicts them all again,
    and each is searched once more in a narrow window there. The second pass decides: a mark
    found in the wide window but not in the narrow one (a look-alike in the wide window) is listed
    as not found, as is every mark when fewer than two were found in the first pass."""
    first = find_marks(scan, fiducials, template, px_per_mm, wide_mm)
    ok = [m for m in first if m.found]
    if len(ok) < 2:
        return first
    xy = np.array([fiducials[m.fiducial_id] for m in ok], dtype=float)
    cr = np.array([(m.col, m.row) for m in ok])
    # col = a x - b y + c, row = -(b x + a y) + d: a similarity from the plate (y up) to pixels (row down)
    A = np.zeros((2 * len(ok), 4))
    A[0::2] = np.column_stack([xy[:, 0], -xy[:, 1], np.ones(len(ok)), np.zeros(len(ok))])
    A[1::2] = np.column_stack([-xy[:, 1], -xy[:, 0], np.zeros(len(ok)), np.ones(len(ok))])
    a, b, c, d = np.linalg.lstsq(A, cr.ravel(), rcond=None)[0]
    predicted = {fid: (a * x - b * y + c, -(b * x + a * y) + d) for fid, (x, y) in fiducials.items()}
    return find_marks(scan, fiducials, template, px_per_mm, narrow_mm, predicted=predicted)


UPSAMPLE = 4  # the refinement correlates the window and the template upsampled this many times
REFINE_PX = 2  # ... over the integer peak +- this many pixels
BLUR_PX = 1.0  # ... after smoothing both by a Gaussian of this sigma (scan pixels)


def _refined(cv2, window: np.ndarray, template: np.ndarray, u: int, v: int) -> tuple[float, float]:
    """The template's centre (col, row) in the window's corner-origin pixels, near the integer
    peak (u, v): the correlation of window and template upsampled UPSAMPLE times (bicubic; corner
    origin scales exactly), its peak to subpixel by :func:`_subpixel` (a 3-point fit on the
    integer correlations alone is pulled towards the pixel by up to 0.1 px on rendered marks)."""
    th, tw = template.shape
    f = UPSAMPLE
    a0, b0 = max(u - REFINE_PX, 0), max(v - REFINE_PX, 0)
    a1, b1 = min(u + REFINE_PX + tw, window.shape[1]), min(v + REFINE_PX + th, window.shape[0])
    patch = window[b0:b1, a0:a1]
    up = cv2.resize(patch, (patch.shape[1] * f, patch.shape[0] * f), interpolation=cv2.INTER_CUBIC)
    tup = cv2.resize(template, (tw * f, th * f), interpolation=cv2.INTER_CUBIC)
    # both smoothed alike (a Gaussian of BLUR_PX): the correlation peak of sharp edges is a cone,
    # which no 3-point fit locates without bias; smoothed, it is round
    up = cv2.GaussianBlur(up, (0, 0), BLUR_PX * f)
    tup = cv2.GaussianBlur(tup, (0, 0), BLUR_PX * f)
    ncc = cv2.matchTemplate(up, tup, cv2.TM_CCOEFF_NORMED)
    vv, uu = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    du, dv = _subpixel(ncc, uu, vv)
    return a0 + (uu + du + tw * f / 2.0) / f, b0 + (vv + dv + th * f / 2.0) / f


def _subpixel(ncc: np.ndarray, u: int, v: int) -> tuple[float, float]:
    """The peak's offset from (u, v), in [-0.5, 0.5] each way, by a Gaussian through the 3
    correlations along each axis (a parabola through their logarithms; a parabola through the
    correlations themselves pulls the peak towards the pixel, by up to 0.1 px on rendered marks);
    0 at the border of the correlation map or where a correlation is not positive."""
    def vertex(m, c, p):
        if min(m, c, p) <= 0:
            return 0.0
        lm, lc, lp = np.log(m), np.log(c), np.log(p)
        d = lm - 2 * lc + lp
        return float(np.clip(0.5 * (lm - lp) / d, -0.5, 0.5)) if d < 0 else 0.0

    h, w = ncc.shape
    du = vertex(ncc[v, u - 1], ncc[v, u], ncc[v, u + 1]) if 0 < u < w - 1 else 0.0
    dv = vertex(ncc[v - 1, u], ncc[v, u], ncc[v + 1, u]) if 0 < v < h - 1 else 0.0
    return du, dv
