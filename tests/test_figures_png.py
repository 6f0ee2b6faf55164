"""figures.png_of (issue 11): a figure is drawn once and trimmed to its drawn pixels plus PAD_INCHES,
which gives the picture savefig(bbox_inches="tight") gives after two draws; content reaching past
the figure's edge, which trimming cannot bring back, goes through savefig."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from striptri.report import figures

mpl_figure = pytest.importorskip("matplotlib.figure")


def _pixels(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def _savefig_png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=figures.DPI, bbox_inches="tight")
    return buf.getvalue()


def _plot(text_x: float = 0.5):
    fig = figures._figure(figsize=(4.0, 3.0))
    fig.subplots_adjust(left=0.2, bottom=0.2)  # room for the labels inside the figure
    ax = fig.subplots()
    ax.plot([0, 1, 2], [1, 3, 2], "o-")
    ax.set_title("a title")
    ax.set_xlabel("x label")
    ax.set_ylabel("y label")
    ax.text(text_x, 0.5, "some words", transform=ax.transAxes)
    return fig


def _draws(monkeypatch) -> list:
    count = []
    original = mpl_figure.Figure.draw

    def draw(self, renderer):
        count.append(1)
        return original(self, renderer)

    monkeypatch.setattr(mpl_figure.Figure, "draw", draw)
    return count


def test_one_draw_and_the_picture_of_savefig_tight(monkeypatch):
    draws = _draws(monkeypatch)
    ours = _pixels(figures.png_of(_plot()))
    assert len(draws) == 1
    theirs = _pixels(_savefig_png(_plot()))
    # the same content in the same margin: sizes agree to the rounding of the two boxes
    assert abs(ours.shape[0] - theirs.shape[0]) <= 3 and abs(ours.shape[1] - theirs.shape[1]) <= 3
    assert ours.shape[0] < 3.0 * figures.DPI and ours.shape[1] < 4.0 * figures.DPI  # trimmed
    pad = int(round(figures.PAD_INCHES * figures.DPI))
    drawn = (ours != 255).any(axis=2)
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    assert rows[0] == pad and cols[0] == pad
    assert rows[-1] == ours.shape[0] - 1 - pad and cols[-1] == ours.shape[1] - 1 - pad
    # and the same picture: as many dark (ink) pixels, to a percent
    ink_ours, ink_theirs = (int((p.sum(axis=2) < 300).sum()) for p in (ours, theirs))
    assert ink_ours == pytest.approx(ink_theirs, rel=0.01)


def test_content_past_the_edge_goes_through_savefig(monkeypatch):
    """Text placed beyond the right edge of the figure is kept: the picture grows as savefig's."""
    draws = _draws(monkeypatch)
    ours = _pixels(figures.png_of(_plot(text_x=1.1)))
    assert len(draws) > 1  # drawn once, found to touch the edge, drawn again by savefig
    theirs = _pixels(_savefig_png(_plot(text_x=1.1)))
    assert ours.shape == theirs.shape
    assert ours.shape[1] > 4.0 * figures.DPI  # wider than the figure: nothing cut


def test_untrimmed_keeps_the_figure_size():
    png = figures.png_of(_plot(), tight=False)
    assert _pixels(png).shape == (round(3.0 * figures.DPI), round(4.0 * figures.DPI), 3)


def test_every_figure_of_a_strip_report_is_drawn_once(monkeypatch):
    """The report of an aerial strip (error ellipses with their legend beside the axes, labelled
    control points): every figure lies inside its canvas, so each is drawn once (a figure reaching
    past its edge is drawn a second time by savefig: 0.3 s for the error ellipses of 8 photos)."""
    from pathlib import Path

    from striptri import pipeline
    from striptri.core.runs import RunOptions

    draws = _draws(monkeypatch)
    project = pipeline.read_project(Path(__file__).parent.parent / "data" / "synthetic_strips" / "strip8")
    products = pipeline.adjust_products(project, pipeline.options_for(project), RunOptions())
    pngs = products.files["report.html"].count("data:image/png;base64,")
    assert pngs == 5 and len(draws) == pngs


def test_preload_imports_the_figure_modules_in_a_thread_of_its_own():
    """pipeline starts figures.preload before the adjustment: in a fresh interpreter the figure
    modules are not loaded, the call returns at once, and its thread loads them."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from striptri.report import figures as f\n"
        "assert not any(m in sys.modules for m in f.FIGURE_MODULES)\n"
        "f.preload(); f.preload()\n"
        "assert len(f._preloading) == 1 and f._preloading[0] is not __import__('threading').current_thread()\n"
        "f._preloading[0].join()\n"
        "print(all(m in sys.modules for m in f.FIGURE_MODULES))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"


def test_warnings_raised_by_the_figure_packages_are_told_apart():
    """A warning raised by the preloading import while the adjustment records its warnings is not
    a warning of the run (pipeline); the run's own are."""
    import os
    import warnings

    def message(path):
        return warnings.WarningMessage("text", DeprecationWarning, path, 1)

    site = os.path.join(os.sep, "usr", "lib", "python3", "site-packages")
    assert figures.from_figure_packages(message(os.path.join(site, "matplotlib", "axes", "_base.py")))
    assert figures.from_figure_packages(message(os.path.join(site, "PIL", "Image.py")))
    assert not figures.from_figure_packages(message(os.path.join("src", "striptri", "pipeline.py")))
    assert not figures.from_figure_packages(message(os.path.join(site, "numpy", "linalg", "matplotlib.py")))
