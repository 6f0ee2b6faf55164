"""report.drawing (issue 29): the report's figures drawn by a second process while the run goes on.
The report is the same byte for byte (but the footer's seconds) whichever process draws; a figure the
worker cannot draw, or a worker that dies, leaves the figure to the command's process; the worker
ends with the run, also when the run is interrupted, and never outlives the command."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from striptri.core.options import AdjustmentOptions
from striptri.core.runs import RunOptions
from striptri.errors import NumericalFailure
from striptri.io import read_project
from striptri.pipeline import adjust_products
from striptri.report import drawing

import drawing_helpers

TESTS = Path(__file__).resolve().parent
DATA = TESTS.parents[0] / "data" / "synthetic_strips"
sys.path.insert(0, str(TESTS.parents[0] / "scripts" / "bench"))
import close_range  # noqa: E402


@pytest.fixture
def helpers_importable(monkeypatch):
    """The worker (a fresh interpreter) can import drawing_helpers; it knows this process's pid."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv(drawing_helpers.PARENT, str(os.getpid()))


def _drawn_by(text: str) -> int:
    return int(re.search(r"drawn by (\d+)", text).group(1))


def _figures_and_text(report: str) -> tuple[list[str], str]:
    """The report's images (alt text and PNG bytes, base64) in order, and its text without them,
    with digits as 0 and without the footer (the time it started and the seconds it took differ
    between two runs)."""
    images = re.findall(r"<img alt='([^']*)' src='data:image/png;base64,([^']*)'>", report)
    text = re.sub(r"<img [^>]*>", "<img>", re.sub(r"<footer>.*?</footer>", "", report, flags=re.S))
    return images, re.sub(r"\d", "0", text)


@pytest.fixture(scope="module")
def with_a_gross_error(tmp_path_factory):
    """block_3x6 with 0.1 mm added to one plate coordinate: snooping rejects it and adjusts again."""
    folder = tmp_path_factory.mktemp("gross") / "block_3x6"
    shutil.copytree(DATA / "block_3x6", folder)
    table = folder / "image_points.csv"
    lines = table.read_text().splitlines()
    fields = lines[40].split(",")
    fields[2] = repr(float(fields[2]) + 0.1)
    lines[40] = ",".join(fields)
    table.write_text("\n".join(lines) + "\n")
    return folder


@pytest.mark.parametrize("when", ["now", "later"])
@pytest.mark.parametrize("gross", [False, True], ids=["tests keep the adjustment", "snooping adjusts again"])
def test_the_report_drawn_by_a_worker_is_the_report_drawn_here(monkeypatch, with_a_gross_error, when, gross):
    """The figures of the first adjustment asked for early ("now") serve the report only when the
    tests keep its result; after a rejection they are drawn anew."""
    project = read_project(with_a_gross_error if gross else DATA / "block_3x6")
    run = RunOptions(blunders="snoop" if gross else "off")
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: None)
    here = adjust_products(project, AdjustmentOptions(), run)
    assert (here.summary.blunders["rejected"] > 0) == gross
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: when)
    asked: list[str] = []
    draw = drawing.draw

    def counted(function, *args, **kwargs):
        asked.append(function.__name__)
        return draw(function, *args, **kwargs)

    monkeypatch.setattr(drawing, "draw", counted)
    elsewhere = adjust_products(project, AdjustmentOptions(), run)
    # drawn once each, but for the adjustment's own figures asked for early ("now") and drawn anew
    # after the rejection
    twice = {"structure_figure", "convergence"} if when == "now" and gross else set()
    assert sorted(asked) == sorted(["structure_figure", "convergence", "plate_residuals_per_photo",
                                    "plate_residuals_stacked", "error_ellipses", *twice])
    footer = re.search(r"<footer>.*?</footer>", elsewhere.files["report.html"], flags=re.S).group(0)
    assert "drawn by the second process" in footer  # the worker drew them
    assert drawing.MARK not in elsewhere.files["report.html"]  # every placeholder filled
    # convergence, residuals per photo and over one format, error ellipses, structure of N
    assert elsewhere.files["report.html"].count("data:image/png;base64,") == 5
    images, text = _figures_and_text(elsewhere.files["report.html"])
    assert len(images) == 5 and (images, text) == _figures_and_text(here.files["report.html"])  # the same pixels
    for name in ("photos.csv", "points.csv", "residuals.csv"):
        assert elsewhere.files[name] == here.files[name]
    assert not drawing.drawing_elsewhere()  # ended with the run


def test_the_worker_draws_and_a_figure_it_cannot_draw_is_drawn_here(helpers_importable):
    with drawing.worker_for(True) as worker:
        assert worker is not None and drawing.drawing_elsewhere()
        there = drawing.draw(drawing_helpers.anywhere, b"a")
        failed = drawing.draw(drawing_helpers.only_in_the_parent, b"b")
        assert isinstance(there, drawing.Pending) and isinstance(failed, drawing.Pending)
        text = drawing.html_of(there, bytes.decode) + " | " + drawing.html_of(failed, bytes.decode)
        assert drawing.MARK in text
        text = drawing.fill(text)
    first, second = text.split(" | ")
    assert first.startswith("a ") and _drawn_by(first) == worker.process.pid != os.getpid()
    assert second.startswith("b ") and _drawn_by(second) == os.getpid()
    assert worker.process.poll() is not None  # ended with the block


@pytest.mark.parametrize("drawers", [1, 2])
def test_a_worker_that_dies_leaves_its_figures_to_this_process(helpers_importable, drawers):
    with drawing.worker_for(True, drawers) as worker:  # killed before it has imported matplotlib (and forked)
        worker.process.kill()
        worker.process.wait()
        text = drawing.fill(drawing.html_of(drawing.draw(drawing_helpers.anywhere, b"c"), bytes.decode))
    assert _drawn_by(text) == os.getpid()


def _running(pid: int) -> bool:
    """Whether the process runs (neither gone nor a zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in "ZX"
    except OSError:
        return False


def _both_ready(worker, seconds: float = 60.0) -> set[int]:
    deadline = time.monotonic() + seconds
    while len(worker.pids) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    return set(worker.pids)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_two_drawers_share_the_figures_and_end_with_the_block(helpers_importable):
    """Figures asked for together are drawn two at a time, by the worker and its twin (a fork of
    it), in the report's order; both end with the block."""
    with drawing.worker_for(True, drawers=2) as worker:
        pids = _both_ready(worker)
        figures = [drawing.draw(drawing_helpers.slowly, str(i).encode(), 0.3) for i in range(4)]
        text = drawing.fill(" | ".join(drawing.html_of(f, bytes.decode) for f in figures))
    drawn = text.split(" | ")
    assert [t.split()[0] for t in drawn] == ["0", "1", "2", "3"]
    assert len(pids) == 2 and worker.process.pid in pids and os.getpid() not in pids
    assert {_drawn_by(t) for t in drawn} == pids
    deadline = time.monotonic() + 5  # the twin is the worker's child: the system reaps it
    while any(_running(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_running(pid) for pid in pids)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_twin_that_dies_leaves_its_figures_to_the_other_drawer(helpers_importable):
    with drawing.worker_for(True, drawers=2) as worker:
        pids = _both_ready(worker)
        (twin,) = pids - {worker.process.pid}
        os.kill(twin, signal.SIGKILL)
        deadline = time.monotonic() + 5
        while _running(twin) and time.monotonic() < deadline:
            time.sleep(0.01)
        figures = [drawing.draw(drawing_helpers.anywhere, str(i).encode()) for i in range(3)]
        text = drawing.fill(" | ".join(drawing.html_of(f, bytes.decode) for f in figures))
    assert [_drawn_by(t) for t in text.split(" | ")] == [worker.process.pid] * 3


def test_arguments_that_do_not_pickle_are_drawn_here(helpers_importable):
    with drawing.worker_for(True):
        figure = drawing.draw(drawing_helpers.anywhere, b"d", **{})
        unpicklable = drawing.draw(lambda v: drawing_helpers.anywhere(v()), lambda: b"e")
        text = drawing.fill(drawing.html_of(figure, bytes.decode) + "|" + drawing.html_of(unpicklable, bytes.decode))
    there, here = text.split("|")
    assert _drawn_by(there) != os.getpid() and _drawn_by(here) == os.getpid()


def test_the_worker_ends_when_the_run_fails(helpers_importable):
    with pytest.raises(ValueError, match="the run failed"):
        with drawing.worker_for(True) as worker:
            drawing.draw(drawing_helpers.anywhere, b"f")
            raise ValueError("the run failed")
    assert worker.process.poll() is not None
    assert not drawing.drawing_elsewhere()


def test_without_a_worker_figures_are_drawn_at_once():
    with drawing.worker_for(False) as worker:
        assert worker is None
        assert drawing.draw(drawing_helpers.anywhere, b"g").startswith(b"g drawn by")


def _workers_of(mark: str) -> list[int]:
    """The processes (pids) whose environment holds the mark: the command and its worker."""
    found = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                with open(f"/proc/{entry.name}/environ", "rb") as f:
                    if mark.encode() in f.read():
                        with open(f"/proc/{entry.name}/cmdline", "rb") as g:
                            if b"striptri.report.drawing" in g.read():
                                found.append(int(entry.name))
            except OSError:
                continue
    return found


@pytest.fixture
def long_tracks(tmp_path):
    """50 photos, 60 targets of 12 to 45 rays: large enough for two threads (and a worker)."""
    return close_range.write_close_range(tmp_path / "p", close_range.make_close_range(50, 60, seed=3))


def _command_draws_in_a_worker_and_leaves_none(project, tmp_path) -> None:
    """``striptri adjust PROJECT`` (bundle method, two threads) ends well, its report's five figures
    drawn by the second process, and leaves no worker behind."""
    mark = f"STRIPTRI_TEST_MARK={uuid.uuid4().hex}"
    env = {**os.environ, "STRIPTRI_THREADS": "2", mark.split("=")[0]: mark.split("=")[1]}
    proc = subprocess.run([sys.executable, "-m", "striptri", "adjust", str(project), "--out", str(tmp_path / "o"),
                           "--method", "bundle"], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    report = (tmp_path / "o" / "report.html").read_text()
    assert "drawn by the second process" in report and drawing.MARK not in report
    assert report.count("data:image/png;base64,") == 5
    assert not _workers_of(mark)


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_the_command_draws_in_a_worker_and_leaves_none_behind(tmp_path, long_tracks):
    _command_draws_in_a_worker_and_leaves_none(long_tracks, tmp_path)


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", (signal.SIGINT, signal.SIGTERM), ids=lambda s: signal.Signals(s).name)
def test_an_interrupted_command_ends_its_worker(tmp_path, long_tracks, sig):
    mark = f"STRIPTRI_TEST_MARK={uuid.uuid4().hex}"
    env = {**os.environ, "STRIPTRI_THREADS": "2", mark.split("=")[0]: mark.split("=")[1]}
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "striptri", "adjust", str(long_tracks), "--out", str(out),
                             "--method", "bundle"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 60
    while not _workers_of(mark) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _workers_of(mark), "the worker did not start"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err
    assert not out.exists()  # no partial output
    deadline = time.monotonic() + 5
    while _workers_of(mark) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _workers_of(mark)


def test_when_the_worker_starts(monkeypatch):
    """None for a run too small for two threads, for --threads 1 and on one core; "now" for a
    small run that is large enough, "later" (after the gross-error tests) from LATER_FROM
    measurements."""
    from striptri.solvers import threads

    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    long_tracks = [40] * 60  # 96,000 ray pairs, 2,400 measurements
    many = [4] * (drawing.LATER_FROM // 4)  # LATER_FROM measurements of four-ray points
    assert drawing.when_to_start([3] * 50) is None  # 450 ray pairs: one thread
    assert drawing.when_to_start(long_tracks) == "now"
    assert drawing.when_to_start(many) == "later"
    assert drawing.when_to_start(many[:-1]) == "now"
    with threads.use_threads(1):
        assert drawing.when_to_start(many) is None
    monkeypatch.setattr(threads, "available_cores", lambda: 1)
    assert drawing.when_to_start(many) is None


def test_a_worker_that_does_not_answer_is_killed_and_its_figure_drawn_here(helpers_importable, monkeypatch):
    monkeypatch.setattr(drawing, "WAIT_SECONDS", 1.0)
    with drawing.worker_for(True) as worker:
        os.kill(worker.process.pid, signal.SIGSTOP)  # alive, but draws nothing
        try:
            text = drawing.fill(drawing.html_of(drawing.draw(drawing_helpers.anywhere, b"h"), bytes.decode))
        finally:
            if worker.process.poll() is None:
                os.kill(worker.process.pid, signal.SIGCONT)
    assert _drawn_by(text) == os.getpid()
    assert worker.process.poll() is not None  # killed


class _Stand_in:
    """In place of drawing.Worker where only the decision to start one is tested."""

    made: list = []

    def __init__(self, drawers: int = 1):
        self.threads = [None] * drawers
        self.process = type("P", (), {"poll": staticmethod(lambda: None)})()
        self.stopped = False
        _Stand_in.made.append(self)

    def stop(self):
        self.stopped = True


def test_which_commands_start_their_worker_early(monkeypatch, tmp_path):
    """early_worker starts a worker (with DRAWERS_NOW drawers) only for a project folder whose
    image_points.csv has EARLY_BYTES and a run with two threads for its chunks; it stops whatever
    the pipeline did not take."""
    from striptri.solvers import threads

    monkeypatch.setattr(drawing, "Worker", _Stand_in)
    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    _Stand_in.made = []
    low, high = drawing.EARLY_BYTES
    for size, started in ((low - 1, False), (low, True), (high, True), (high + 1, False)):
        folder = tmp_path / str(size)
        folder.mkdir()
        (folder / "image_points.csv").write_bytes(b"x" * size)
        with drawing.early_worker(folder):
            assert bool(drawing._early) == started, size
            early = list(drawing._early)
        assert not drawing._early and all(w.stopped for w in early)
        assert all(len(w.threads) == drawing.DRAWERS_NOW for w in early)
    with drawing.early_worker(tmp_path / "nowhere"):
        assert not drawing._early
    with threads.use_threads(1), drawing.early_worker(tmp_path / str(low)):
        assert not drawing._early
    assert len(_Stand_in.made) == 2


@pytest.mark.parametrize("when", ["now", "later", None])
def test_the_run_takes_the_early_worker_or_stops_it(monkeypatch, when):
    """A run that decides "now" takes the worker started early (no second one; its figures are drawn
    there); "later" and no worker stop it (and "later" starts its own after the tests)."""
    made, stopped = [], []
    real_init, real_stop = drawing.Worker.__init__, drawing.Worker.stop
    monkeypatch.setattr(drawing.Worker, "__init__", lambda self, *a: made.append(self) or real_init(self, *a))
    monkeypatch.setattr(drawing.Worker, "stop", lambda self: stopped.append(self) or real_stop(self))
    monkeypatch.setattr(drawing, "EARLY_BYTES", (0, 10**9))
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: when)
    from striptri.solvers import threads

    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    project = read_project(DATA / "block_3x6")
    with drawing.early_worker(DATA / "block_3x6"):
        early = made[0]
        products = adjust_products(project, AdjustmentOptions(), RunOptions())
        assert early in stopped  # taken and stopped with the run, or stopped at its decision
    footer = re.search(r"<footer>.*?</footer>", products.files["report.html"], flags=re.S).group(0)
    assert ("drawn by the second process" in footer) == (when is not None)
    assert len(made) == {"now": 1, "later": 2, None: 1}[when]
    assert set(made) == set(stopped) and early.process.poll() is not None
    assert not drawing._early and not drawing.drawing_elsewhere()


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_a_command_with_an_early_worker_draws_there_and_leaves_none_behind(tmp_path):
    """100 photos, 100 targets: image_points.csv within EARLY_BYTES, so the command starts its worker
    before reading the project; the report is complete and no worker is left."""
    project = close_range.write_close_range(tmp_path / "p", close_range.make_close_range(100, 100, seed=3))
    size = (Path(project) / "image_points.csv").stat().st_size
    assert drawing.EARLY_BYTES[0] <= size <= drawing.EARLY_BYTES[1]
    _command_draws_in_a_worker_and_leaves_none(project, tmp_path)


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc")
def test_a_parked_worker_imports_matplotlib_only_when_taken(helpers_importable):
    """park_worker starts the drawer without its import of matplotlib; worker_for takes it, and it
    imports and draws then."""
    drawing.park_worker()
    parked = drawing._early[0]
    try:
        assert parked.parked
        time.sleep(1.0)  # an unparked drawer has imported matplotlib's extensions by now
        assert parked.process.poll() is None
        assert "matplotlib" not in Path(f"/proc/{parked.process.pid}/maps").read_text()
        with drawing.worker_for(True) as worker:
            assert worker is parked and not worker.parked and not drawing._early
            text = drawing.fill(drawing.html_of(drawing.draw(drawing_helpers.anywhere, b"p"), bytes.decode))
            assert _drawn_by(text) == worker.process.pid
            assert "matplotlib" in Path(f"/proc/{worker.process.pid}/maps").read_text()
        assert worker.process.poll() is not None
    finally:
        drawing.discard_early_worker()


def test_the_worker_imports_matplotlib_without_its_3d_projection(helpers_importable):
    """The drawer's import leaves mplot3d out (figures.import_figure_modules' without_axes3d): no
    figure draws in 3D, and the report's figures are the same bytes as this process draws them
    (test_the_report_drawn_by_a_worker_is_the_report_drawn_here)."""
    with drawing.worker_for(True):
        text = drawing.fill(drawing.html_of(drawing.draw(drawing_helpers.projections, b"p"), bytes.decode))
    assert text == "p mplot3d False 3d False"


def test_the_stand_in_for_mplot3d_is_gone_after_the_import():
    """In an interpreter of its own: after import_figure_modules(without_axes3d=True) the real
    mplot3d imports as ever."""
    code = ("import sys; from striptri.report.figures import import_figure_modules as i; i(without_axes3d=True); "
            "import matplotlib.projections as p; assert '3d' not in p.get_projection_names(); "
            "assert 'mpl_toolkits.mplot3d' not in sys.modules; from mpl_toolkits.mplot3d import Axes3D; "
            "assert Axes3D.name == '3d'; print('ok')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"


@pytest.mark.parametrize("method", ["bundle", "conditions"])
def test_a_later_bundle_run_parks_its_drawer(monkeypatch, method):
    """A "later" run of the bundle method starts its drawer parked with the run and takes it after the
    tests (one drawer made, the same report as drawn here); the method of conditions, whose point
    precision hides a drawer's start, starts it after the tests. None is left."""
    project = read_project(DATA / "block_3x6")
    options = AdjustmentOptions(method=method)
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: None)
    here = adjust_products(project, options, RunOptions())
    made = []
    real_init = drawing.Worker.__init__
    monkeypatch.setattr(drawing.Worker, "__init__",
                        lambda self, *a, **k: made.append((self, k.get("parked", False))) or real_init(self, *a, **k))
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: "later")
    elsewhere = adjust_products(project, options, RunOptions())
    assert [parked for _, parked in made] == [method == "bundle"]
    footer = re.search(r"<footer>.*?</footer>", elsewhere.files["report.html"], flags=re.S).group(0)
    assert "drawn by the second process" in footer
    assert _figures_and_text(elsewhere.files["report.html"]) == _figures_and_text(here.files["report.html"])
    assert made[0][0].process.poll() is not None and not drawing._early and not drawing.drawing_elsewhere()


def test_a_parked_drawer_is_stopped_when_the_run_fails(monkeypatch):
    """The run ends before its tests (a datum defect): the parked drawer is stopped with it."""
    project = read_project(DATA / "block_3x6")
    made = []
    real_init = drawing.Worker.__init__
    monkeypatch.setattr(drawing.Worker, "__init__", lambda self, *a, **k: made.append(self) or real_init(self, *a, **k))
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: "later")
    import striptri.pipeline as pipeline

    def fails(*args, **kwargs):
        raise NumericalFailure("no datum", reason="datum_defect")

    monkeypatch.setattr(pipeline, "adjust", fails)
    with pytest.raises(NumericalFailure):
        adjust_products(project, AdjustmentOptions(method="bundle"), RunOptions())
    assert len(made) == 1 and made[0].process.wait(timeout=30) is not None and not drawing._early


def test_a_later_run_asks_for_its_figures_before_the_point_precision(monkeypatch):
    """A "later" run (conditions) asks its worker for every figure that needs no points as soon as
    the worker starts, so that they are drawn beside the point precision; the point precision then
    reads the blocks of Qxx the tests read, with the inverse let go before it (its memory is not
    beside the worker's) and not made again."""
    import striptri.pipeline as pipeline

    project = read_project(DATA / "block_3x6")
    monkeypatch.setattr(drawing, "when_to_start", lambda rays: "later")
    asked: list[str] = []
    draw, triangulate = drawing.draw, pipeline.triangulate_result

    def counted(function, *args, **kwargs):
        asked.append(function.__name__)
        return draw(function, *args, **kwargs)

    def points(adjusted, result):
        engine = result.covariance._inv._engine
        assert type(engine).__name__ == "_Rebuilt" and not engine.rebuilt  # let go before
        out = triangulate(adjusted, result)
        assert not engine.rebuilt  # and not needed
        asked.append("(point precision)")
        return out

    monkeypatch.setattr(drawing, "draw", counted)
    monkeypatch.setattr(pipeline, "triangulate_result", points)
    products = adjust_products(project, AdjustmentOptions(), RunOptions())
    assert asked.index("(point precision)") == 4 and asked[-1] == "error_ellipses"
    assert sorted(asked[:4]) == ["convergence", "plate_residuals_per_photo", "plate_residuals_stacked",
                                 "structure_figure"]
    assert "drawn by the second process" in products.files["report.html"]
