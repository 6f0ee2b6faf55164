"""The reports as a person sees them (issue 26): headless Chromium lays out report.html of the
strip8, scanned-film and close-range examples at 1,000 and 1,400 px, and the page itself measures
every table (a script added to a copy of the report, read back from the DOM Chromium dumps): no
table may reach past the page's width. Before, the "Adjustment" table ran off a 1,400 px page (a
no-wrap BLAS line with the library's full path). Runs where Chromium is installed (.ci/run
installs it); a screenshot of each is kept for the eye (STRIPTRI_SCREENSHOTS=DIR)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from striptri.core.runs import RunOptions
from striptri.pipeline import run_adjust

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)
CASES = {
    "strip8": (REPO / "data" / "synthetic_strips" / "strip8", {}),
    "film": (REPO / "data" / "film_strip", {}),
    "close_range": (REPO / "data" / "close_range", {"method": "bundle"}),
}
MEASURE = """<script>
(function () {
  var w = document.documentElement.clientWidth, bad = [];
  document.querySelectorAll('table').forEach(function (t, i) {
    var right = t.getBoundingClientRect().left + t.scrollWidth;
    if (right > w + 0.5) bad.push(i + ':' + Math.round(right));
  });
  document.body.setAttribute('data-page-width', String(w));
  document.body.setAttribute('data-too-wide', bad.length ? bad.join(' ') : 'none');
})();
</script>"""


def _chromium(tmp_path: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                           "--disable-background-networking", "--disable-component-update", "--disable-sync",
                           "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}", *args],
                          capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (apt-get install chromium)")
@pytest.mark.parametrize("case", sorted(CASES))
def test_no_table_is_wider_than_the_page(tmp_path, case):
    folder, options = CASES[case]
    products = run_adjust(folder, tmp_path / "out", RunOptions(**options))
    page = tmp_path / "measured.html"
    page.write_text(products.files["report.html"].replace("</body>", MEASURE + "</body>"), encoding="utf-8")
    for width in (1000, 1400):
        dom = _chromium(tmp_path, f"--window-size={width},900", "--virtual-time-budget=3000", "--dump-dom",
                        page.as_uri()).stdout
        found = re.search(r'data-page-width="(\d+)" data-too-wide="([^"]*)"', dom)
        assert found, "the measuring script did not run"
        assert int(found.group(1)) == width
        assert found.group(2) == "none", f"{case} at {width} px: tables (index:right edge) {found.group(2)}"
    shots = Path(os.environ.get("STRIPTRI_SCREENSHOTS", tmp_path))
    shots.mkdir(parents=True, exist_ok=True)
    shot = shots / f"report_{case}.png"
    _chromium(tmp_path, "--window-size=1400,1800", f"--screenshot={shot}", (tmp_path / "out" / "report.html").as_uri())
    assert shot.exists() and shot.stat().st_size > 20_000  # drawn, not an empty page
