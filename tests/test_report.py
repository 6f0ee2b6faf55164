"""report.html: one self-contained file (no scripts, no network, no external files), every section
present, every figure a valid PNG, the numbers agree with summary.json and residuals.csv, and a
real browser (headless Chromium) renders it."""

from __future__ import annotations

import base64
import csv
import functools
import io
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from striptri import pipeline
from striptri.report import html as report
from striptri.report import page
from striptri.io.project_reader import read_project

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
HEADINGS = [  # what a reader must find (DESIGN section 10 and the report brief)
    "Summary",
    "Checks after convergence",
    "Convergence",
    "Residuals on the photographs",
    "Precision of the ground points",
    "Check points",
    "Flagged measurements",
    "Photographs",
    "Structure of the normal matrix",
]


@functools.lru_cache(maxsize=None)
def _products(name: str):
    project = read_project(DATA / name)
    return pipeline.adjust_products(project, pipeline.options_for(project))


@functools.lru_cache(maxsize=None)
def _normalised(name: str) -> np.ndarray:
    """The normalised residuals w that adjust_products gave the report (it does not keep them)."""
    from striptri.precision.residuals import normalised_residuals, residual_cofactors

    products = _products(name)
    cof = residual_cofactors(products.project, products.result, pipeline.options_for(products.project))
    return normalised_residuals(products.result.plate_residuals, cof.plate)


@pytest.fixture(params=["strip8", "block_3x6"])
def name(request):
    return request.param


@pytest.fixture
def products(name):
    return _products(name)


class _Sections(HTMLParser):
    """Collects, per <h2 id=...> section, the tables as rows of (text, attrs) cells, and every
    src and href attribute of the document."""

    def __init__(self):
        super().__init__()
        self.section = None
        self.tables: dict[str, list] = {}
        self.headings: list[str] = []
        self.urls: list[tuple[str, str, str]] = []  # (tag, attribute, value)
        self._cell = None
        self._in_h2 = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for name in ("src", "href", "action", "srcset", "poster", "data"):
            if name in a:
                self.urls.append((tag, name, a[name] or ""))
        if tag == "h2":
            self.section = a.get("id")
            self._in_h2 = True
            self.headings.append("")
        elif tag == "table":
            self.tables.setdefault(self.section, []).append([])
        elif tag == "tr":
            self.tables[self.section][-1].append([])
        elif tag in ("td", "th"):
            self._cell = ["", a]

    def handle_endtag(self, tag):
        if tag == "h2":
            self._in_h2 = False
        elif tag in ("td", "th") and self._cell is not None:
            self.tables[self.section][-1][-1].append((self._cell[0].strip(), self._cell[1]))
            self._cell = None

    def handle_data(self, data):
        if self._in_h2:
            self.headings[-1] += data
        if self._cell is not None:
            self._cell[0] += data


def _parse(text: str) -> _Sections:
    p = _Sections()
    p.feed(text)
    p.close()
    return p


def _residuals_csv(products) -> list[dict]:
    return list(csv.DictReader(io.StringIO(products.files["residuals.csv"])))


def test_report_is_self_contained(products):
    text = products.files["report.html"]
    low = text.lower()
    assert low.startswith("<!doctype html>") and low.rstrip().endswith("</html>")
    assert "http:" not in low and "https:" not in low and "//" not in re.sub(r"data:[^'\"]*", "", low)
    assert "<script" not in low and "<link" not in low and "<iframe" not in low and "@import" not in low
    assert "url(" not in low
    parsed = _parse(text)
    for tag, attr, value in parsed.urls:
        if attr == "src":
            assert value.startswith("data:image/png;base64,"), (tag, value[:60])
        else:
            assert attr == "href" and value.startswith("#") and len(value) > 1, (tag, attr, value)
    # every internal link points at a section that exists
    ids = set(re.findall(r"id='([^']+)'", text))
    assert {v[1:] for _, a, v in parsed.urls if a == "href"} <= ids


def test_report_has_every_section(products):
    headings = [h.strip() for h in _parse(products.files["report.html"]).headings]
    for h in HEADINGS:
        assert h in headings, h


def test_every_embedded_image_is_a_png(products):
    from PIL import Image  # matplotlib depends on Pillow

    text = products.files["report.html"]
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", text)
    # convergence, residuals per photo, residuals over one format, error ellipses, normal matrix
    assert len(images) == len(re.findall(r"<img", text)) >= 5
    for data in images:
        png = base64.b64decode(data, validate=True)
        assert png[:8] == PNG_SIGNATURE
        with Image.open(io.BytesIO(png)) as im:
            im.verify()
            assert im.format == "PNG" and im.size[0] > 100 and im.size[1] > 100


def test_check_point_rms_equals_summary(products):
    summary = json.loads(products.files["summary.json"])
    cp = summary["check_points"]
    assert cp["n"] > 0
    table = _parse(products.files["report.html"]).tables["check-points"][0]
    points = [row for row in table[1:] if row[0][0] not in ("mean", "RMS")]
    assert len(points) == cp["n"]
    (rms_row,) = [row for row in table if row[0][0] == "RMS"]
    for axis, (text, attrs) in zip("XYZ", rms_row[1:4]):
        assert float(attrs["title"]) == cp[f"rms_{axis}"]  # the full value, on hover
        assert text == f"{cp[f'rms_{axis}']:.3f}"
    # and the table's own differences give that RMS
    d = np.array([[float(c[0]) for c in row[1:4]] for row in points])
    assert np.allclose(np.sqrt(np.mean(d**2, axis=0)), [cp["rms_X"], cp["rms_Y"], cp["rms_Z"]], atol=1e-3)


def _flagged_pairs(text: str) -> set:
    tables = _parse(text).tables.get("flagged", [])
    return {(row[0][0], row[1][0]) for t in tables for row in t[1:]}


def test_given_flags_fill_the_flagged_table(name, products):
    rows = _residuals_csv(products)
    flags = np.zeros(len(rows), dtype=bool)
    chosen = [0, len(rows) // 2, len(rows) - 1]
    flags[chosen] = True
    text = report.html_report(products.project, products.result, products.summary, _normalised(name),
                              points=products.points, flags=flags)
    assert _flagged_pairs(text) == {(rows[i]["photo_id"], rows[i]["point_id"]) for i in chosen}
    assert "3 measurements flagged" in text


def test_flagged_table_matches_residuals_csv(name, products):
    rows = _residuals_csv(products)
    suspect = {(r["photo_id"], r["point_id"]) for r in rows if r["flag"]}
    assert _flagged_pairs(products.files["report.html"]) == suspect
    if not suspect:
        assert "No measurement is flagged" in products.files["report.html"]
    # without flags the report applies residuals.csv's rule itself
    text = report.html_report(products.project, products.result, products.summary, _normalised(name),
                              points=products.points)
    assert _flagged_pairs(text) == suspect


def test_large_projects_show_a_selection(name, products, monkeypatch):
    """Beyond the caps: a few photos get a panel, the photos table lists the first and worst, with a note."""
    monkeypatch.setattr(page, "MAX_PHOTO_PANELS", 3)
    monkeypatch.setattr(page, "WORST_PANELS", 2)
    monkeypatch.setattr(page, "MAX_PHOTO_ROWS", 4)
    monkeypatch.setattr(page, "PHOTO_ROWS_EACH", 2)
    text = report.html_report(products.project, products.result, products.summary, _normalised(name),
                              points=products.points)
    photos = _parse(text).tables["photos"][0]
    assert len(photos) == 1 + 4
    ids = [row[0][0] for row in photos[1:]]
    assert ids[:2] == products.project.photos.ids[:2] and len(set(ids)) == 4
    n = len(products.project.photos)
    assert f"of {n}; photos.csv lists all" in text
    assert "the 2 photographs with the most flagged measurements" in text


def _large_mode(monkeypatch):
    """The drawing of large projects on a small one: rasters and the worst, not every vector and ellipse."""
    monkeypatch.setattr(page, "MAX_VECTORS", 50)
    monkeypatch.setattr(page, "WORST_VECTORS", 7)
    monkeypatch.setattr(page, "MAX_ELLIPSES", 20)
    monkeypatch.setattr(page, "WORST_ELLIPSES", 5)
    monkeypatch.setattr(page, "WORST_POINT_ROWS", 4)


def test_large_projects_are_drawn_as_rasters_with_the_worst_on_top(name, products, monkeypatch):
    """Beyond MAX_VECTORS measurements and MAX_ELLIPSES points: the residual field and the precision
    map are rasters with the worst on top, a table lists the points with the largest mean error
    (the largest first, with points.csv's sigmas), every figure is a valid PNG and every section
    is timed."""
    from PIL import Image

    _large_mode(monkeypatch)
    timings = {}
    text = report.html_report(products.project, products.result, products.summary, _normalised(name),
                              points=products.points, flags=products.blunders.flag[products.blunders.rows],
                              parts=report.ReportParts(timings=timings))
    m = len(products.project.image_points)
    assert f"the RMS length of the residuals of all {m} measurements in each cell" in text
    assert "the 7 with the largest normalised residual |w|" in text
    assert "alt='precision of the ground points over the block'" in text
    assert "alt='error ellipses of the ground points'" not in text
    assert "the 5 points with the largest, magnified" in text
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", text)
    assert len(images) == len(re.findall(r"<img", text)) >= 4
    for data in images:
        with Image.open(io.BytesIO(base64.b64decode(data, validate=True))) as im:
            im.verify()
            assert im.format == "PNG" and im.size[0] > 100 and im.size[1] > 100
    # the worst points: the largest sqrt(sX^2 + sY^2 + sZ^2) of points.csv, largest first
    tables = _parse(text).tables["points"]
    worst = tables[-1]
    assert [c[0] for c in worst[0]][:3] == ["point", "kind", "rays"] and len(worst) == 1 + 4
    rows = {r["point_id"]: r for r in csv.DictReader(io.StringIO(products.files["points.csv"]))}
    total = {pid: np.sqrt(sum(float(r[f"sigma_{a}"]) ** 2 for a in "XYZ")) for pid, r in rows.items()
             if r["sigma_X"] != ""}
    expected = sorted(total, key=lambda pid: -total[pid])[:4]
    assert [row[0][0] for row in worst[1:]] == expected
    for row in worst[1:]:
        for a, (cell, _) in zip("XYZ", row[6:9]):
            assert cell == f"{float(rows[row[0][0]][f'sigma_{a}']):.3f}"
    assert set(timings) >= {"summary", "convergence", "residuals", "points", "photos", "total"}
    assert all(v >= 0 for v in timings.values())


def test_chi2_quantile_equals_scipy_stats():
    """The global test's range without scipy.stats: the same quantiles as scipy.stats.chi2.ppf."""
    from scipy.stats import chi2

    p = np.array([0.025, 0.5, 0.975])
    for dof in (1, 2, 7, 150, 12345, 3_000_000):
        np.testing.assert_allclose(report.chi2_quantile(p, dof), chi2.ppf(p, dof), rtol=1e-14)


def test_large_normal_matrix_is_drawn_as_an_image(monkeypatch):
    """Beyond STRUCTURE_CELLS blocks the pattern is an image of STRUCTURE_PIXELS a side (a valid PNG)."""
    from PIL import Image

    from striptri.report import figures

    products = _products("block_3x6")
    n_photos = len(products.project.photos)
    monkeypatch.setattr(figures, "STRUCTURE_CELLS", 4)
    monkeypatch.setattr(figures, "STRUCTURE_PIXELS", 5)
    png = figures.normal_matrix_structure(products.result.N, products.result.layout.block_starts(), n_photos)
    with Image.open(io.BytesIO(png)) as im:
        im.verify()
        assert im.format == "PNG"


def test_block_pattern_equals_a_dense_computation():
    """The blocks of the normal matrix's figure: a block is marked exactly when it holds a nonzero
    (explicit zeros do not count), for the normal matrix of block_3x6 and random matrices."""
    import scipy.sparse as sp

    from striptri.report.figures import block_pattern

    def dense(N, starts):
        A = np.abs(N.toarray()) > 0
        edges = list(starts) + [N.shape[0]]
        nb = len(starts)
        return np.array([[A[edges[i]:edges[i + 1], edges[j]:edges[j + 1]].any() for j in range(nb)]
                         for i in range(nb)])

    products = _products("block_3x6")
    cases = [(products.result.N, products.result.layout.block_starts())]
    rng = np.random.default_rng(5)
    for _ in range(20):
        n = int(rng.integers(1, 40))
        N = sp.random(n, n, density=float(rng.uniform(0.01, 0.3)), random_state=rng, format="csr")
        N.data[rng.random(len(N.data)) < 0.2] = 0.0  # explicit zeros
        starts = np.unique(np.concatenate([[0], rng.integers(0, n, int(rng.integers(0, n)))]))
        cases.append((N, starts))
    for N, starts in cases:
        got = block_pattern(N, starts).toarray() != 0
        np.testing.assert_array_equal(got, dense(sp.csr_matrix(N), starts))


CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (apt-get install chromium)")
@pytest.mark.parametrize("large", [False, True], ids=["full", "large-project drawing"])
def test_headless_chromium_renders_the_report(tmp_path, monkeypatch, large):
    from PIL import Image

    products = _products("block_3x6")
    page = tmp_path / "report.html"
    text = products.files["report.html"]
    if large:
        _large_mode(monkeypatch)
        text = report.html_report(products.project, products.result, products.summary, _normalised("block_3x6"),
                                  points=products.points)
    page.write_text(text, encoding="utf-8")
    shot = tmp_path / "shot.png"
    width, height = 1200, 1600
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
           f"--window-size={width},{height}", page.as_uri()]
    subprocess.run(cmd, capture_output=True, timeout=60, check=False)
    assert shot.exists(), "chromium wrote no screenshot"
    data = shot.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    with Image.open(shot) as im:
        assert im.size == (width, height)
        rgb = np.asarray(im.convert("RGB"))
    colours = np.unique(rgb.reshape(-1, 3), axis=0)
    assert len(colours) > 20, "the screenshot is blank"
    # the page itself was drawn, not an error page: the heading rules are in the report's accent colour
    accent = np.all(rgb == (0x1F, 0x4E, 0x79), axis=-1).sum()
    assert accent > 500, accent
