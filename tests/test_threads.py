"""BLAS threads set by striptri, not by the environment (issue 26; striptri.solvers.threads): one
thread for every BLAS in the process inside a command, the libraries loaded during it included
(scikit-sparse brings Debian's OpenBLAS at the first solve), and the caller's settings back after."""

from __future__ import annotations

import os

import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

from striptri.solvers import threads  # noqa: E402


def _blas_threads() -> dict:
    return {i["filepath"]: i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"}


def test_one_blas_thread_inside_and_the_callers_settings_after():
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        with threads.single_threaded():
            try:  # a BLAS loaded inside the block (when scikit-sparse is installed)
                from striptri.solvers.sparse_cholesky import cholmod_module

                cholmod_module()
            except Exception:  # noqa: BLE001 - without scikit-sparse: the loaded ones only
                pass
            inside = _blas_threads()
            assert inside and set(inside.values()) == {1}, inside
            with threads.factorisation_threads():
                assert set(_blas_threads().values()) == {1}  # FACTORISATION_THREADS
        after = _blas_threads()
        assert {k: v for k, v in after.items() if k in before} == before


def test_striptri_threads_variable(monkeypatch):
    monkeypatch.setenv(threads.THREADS_VARIABLE, "2")
    assert threads.requested_threads() == 2
    for bad in ("", "0", "-1", "two"):
        monkeypatch.setenv(threads.THREADS_VARIABLE, bad)
        assert threads.requested_threads() is None


def test_the_threads_asked_for_cap_the_factorisation_but_do_not_raise_it(monkeypatch):
    """--threads / STRIPTRI_THREADS are a ceiling: the factorisation keeps its measured one BLAS
    thread (a second made it 2.2-2.4x slower on 2 cores); STRIPTRI_FACTORISATION_THREADS raises it,
    up to the threads asked for and the cores."""
    cores = threads.available_cores()
    monkeypatch.delenv(threads.FACTORISATION_VARIABLE, raising=False)
    monkeypatch.setenv(threads.THREADS_VARIABLE, "2")
    assert threads.factorisation_thread_count() == threads.FACTORISATION_THREADS == 1
    with threads.use_threads(4):
        assert threads.factorisation_thread_count() == 1
    monkeypatch.setenv(threads.FACTORISATION_VARIABLE, "3")
    monkeypatch.delenv(threads.THREADS_VARIABLE)
    assert threads.factorisation_thread_count() == min(3, cores)
    with threads.use_threads(2):
        assert threads.factorisation_thread_count() == min(2, cores)
    with threads.use_threads(1):
        assert threads.factorisation_thread_count() == 1
    monkeypatch.setenv(threads.FACTORISATION_VARIABLE, "many")
    assert threads.factorisation_thread_count() == 1


# --------------------------------------------------------------------------- the chunks on threads
# (issue 29: parallel.map_ordered, solvers.threads.chunk_threads / use_threads, --threads)

import threading  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from striptri import parallel  # noqa: E402
from striptri.parallel import map_ordered  # noqa: E402


def test_map_ordered_keeps_the_order_and_runs_on_threads():
    seen = set()

    def slow_first(i):
        seen.add(threading.current_thread().name)
        time.sleep(0.02 if i % 3 == 0 else 0.0)  # later items finish first
        return i * i

    assert list(map_ordered(slow_first, range(20), 3)) == [i * i for i in range(20)]
    assert len(seen) > 1 and all(name.startswith("striptri-chunk") for name in seen)
    seen.clear()
    assert list(map_ordered(slow_first, range(5), 1)) == [0, 1, 4, 9, 16]
    assert seen == {threading.current_thread().name}  # one thread: in the caller's


def test_map_ordered_holds_few_results_and_stops_with_the_caller():
    started = []

    def task(i):
        started.append(i)
        return i

    results = map_ordered(task, range(1000), 2)
    assert next(results) == 0
    time.sleep(0.05)
    # the one taken and AHEAD_PER_THREAD in the works per thread, all started by now
    assert len(started) == 1 + parallel.AHEAD_PER_THREAD * 2
    results.close()
    n = len(started)
    time.sleep(0.05)
    assert len(started) == n < 10  # nothing more started after the caller stopped


def test_map_ordered_raises_the_tasks_error_and_keeps_the_callers_error_state():
    def fails_at_3(i):
        if i == 3:
            raise ValueError("chunk 3")
        return i

    with pytest.raises(ValueError, match="chunk 3"):
        list(map_ordered(fails_at_3, range(10), 2))

    def overflow(_):
        return np.float64(1e300) * np.float64(1e300)

    with np.errstate(over="raise"):
        with pytest.raises(FloatingPointError):
            list(map_ordered(overflow, range(2), 2))
    with np.errstate(over="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an overflow warning from a thread would fail here
            assert np.isinf(list(map_ordered(overflow, range(2), 2))).all()


def test_threads_option_over_the_variable_and_never_more_than_the_cores(monkeypatch):
    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    monkeypatch.delenv(threads.THREADS_VARIABLE, raising=False)
    assert threads.chunk_threads() == 4  # all cores by default
    monkeypatch.setenv(threads.THREADS_VARIABLE, "3")
    assert threads.chunk_threads() == 3
    with threads.use_threads(1):
        assert threads.chunk_threads() == 1 and threads.requested_threads() == 1
    with threads.use_threads(None):
        assert threads.chunk_threads() == 3
    with threads.use_threads(16):
        assert threads.chunk_threads() == 4
    with pytest.raises(ValueError):
        with threads.use_threads(0):
            pass
    # a small sweep stays in the caller's thread
    assert threads.chunk_threads(threads.PARALLEL_MIN_RAY_PAIRS - 1) == 1
    assert threads.chunk_threads(threads.PARALLEL_MIN_RAY_PAIRS) == 3
    # the size is the ray pairs: 4,095 three-ray points stay, 150 points of 66 rays go on threads
    assert 4095 * 3**2 < threads.PARALLEL_MIN_RAY_PAIRS
    assert 150 * 66**2 >= threads.PARALLEL_MIN_RAY_PAIRS


@pytest.mark.parametrize("method", ["conditions", "bundle"])
def test_the_products_on_threads_equal_those_on_one(monkeypatch, method):
    """Every sweep (assembly, back substitution, residual cofactors of the gross-error test, point
    precision; the bundle's linearised points and costs) over many small chunks on four threads:
    the same numbers, to the last digit, as on one thread (the caller sums the chunks in the same
    order)."""
    from dataclasses import replace
    from pathlib import Path

    from striptri.core.runs import RunOptions
    from striptri.io import read_project
    from striptri.pipeline import adjust_products, options_for

    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    monkeypatch.setattr(threads, "PARALLEL_MIN_RAY_PAIRS", 0)  # threads for this small block too
    project = read_project(Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "block_3x6")
    options = replace(options_for(project), chunk_size=16, method=method)  # several chunks per batch
    files = {}
    for n in (1, 4):
        with threads.use_threads(n):
            products = adjust_products(project, options, RunOptions(blunders="snoop"))
        files[n] = products.files
        assert products.result.converged
    for name in ("photos.csv", "points.csv", "residuals.csv", "cameras.csv"):
        assert files[4][name] == files[1][name], name


def test_threads_option_of_the_commands(tmp_path, monkeypatch):
    """``--threads N`` reaches the chunk threads of the run (and only of the run); 0 is refused as
    bad usage (exit status 2) before anything is computed."""
    from pathlib import Path

    from click.testing import CliRunner

    from striptri.cli import main

    seen = []
    real = threads.chunk_threads
    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    monkeypatch.setattr(threads, "PARALLEL_MIN_RAY_PAIRS", 0)
    monkeypatch.delenv(threads.THREADS_VARIABLE, raising=False)
    monkeypatch.setattr("striptri.equations.linearise.chunk_threads", lambda n=None: seen.append(real(n)) or seen[-1])
    pair = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "pair"
    runner = CliRunner()
    done = runner.invoke(main, ["adjust", str(pair), "--out", str(tmp_path / "o"), "--threads", "1", "--quiet"])
    assert done.exit_code == 0, done.output
    assert seen and set(seen) == {1}
    seen.clear()
    done = runner.invoke(main, ["adjust", str(pair), "--out", str(tmp_path / "o3"), "--quiet"])
    assert done.exit_code == 0, done.output
    assert seen and set(seen) == {4}  # every core by default
    assert not threads._CHOSEN  # the choice ended with the command
    refused = runner.invoke(main, ["adjust", str(pair), "--out", str(tmp_path / "o2"), "--threads", "0"])
    assert refused.exit_code == 2 and not (tmp_path / "o2").exists()
    assert "--threads" in refused.output
    assert "--threads" in runner.invoke(main, ["plan", "--help"]).output


def test_free_memory_of_a_chunk_thread_is_handed_back():
    """What a chunk thread frees stays resident in its malloc arena (glibc), where the next phase
    cannot reuse it and the peak counts it; solvers.memory.give_back_free_memory hands it back.
    In a fresh interpreter: 190 MB of 96 kB arrays made and freed in a thread."""
    import subprocess
    import sys

    from striptri.solvers import memory

    if memory._malloc_trim() is None or not os.path.exists("/proc/self/status"):
        pytest.skip("glibc's malloc_trim and /proc are needed")
    code = (
        "import threading\n"
        "import numpy as np\n"
        "from striptri.solvers.memory import give_back_free_memory\n"
        "def rss():\n"
        "    with open('/proc/self/status') as f:\n"
        "        return next(int(l.split()[1]) for l in f if l.startswith('VmRSS')) // 1024\n"
        "kept = []\n"
        "def work():\n"
        "    arrays = [np.ones(12_000) for _ in range(2_000)]\n"
        "    kept.append(np.ones(4_000))\n"
        "    del arrays\n"
        "base = rss()\n"
        "t = threading.Thread(target=work); t.start(); t.join()\n"
        "held = rss()\n"
        "give_back_free_memory()\n"
        "print(base, held, rss())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    base, held, after = (int(x) for x in out.stdout.split())
    assert held - base > 150  # MB: freed, still resident
    assert after - base < 30  # handed back


@pytest.mark.parametrize("keeping", [False, True])
def test_the_conditions_method_trims_between_assemblies_from_trim_from_measurements(monkeypatch, keeping):
    """conditions_method.adjust: free memory handed back before and after every assembly from
    TRIM_FROM plate measurements on (the factorisation's peak), not below (each sweep would get the
    pages anew), and at no size in a process that keeps its freed pages (keep_freed_memory: the
    command); the adjustment is the same either way."""
    from pathlib import Path

    from striptri.conditions_method import adjust as conditions
    from striptri.core.options import AdjustmentOptions
    from striptri.adjustment import adjust
    from striptri.io import read_project

    project = read_project(Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "block_3x6")
    trims = []
    monkeypatch.setattr(conditions, "give_back_free_memory", lambda: trims.append(1))
    monkeypatch.setattr(conditions, "keeps_freed_memory", lambda: keeping)
    results, counts = [], []
    for limit in (len(project.image_points) + 1, len(project.image_points)):
        monkeypatch.setattr(conditions, "TRIM_FROM", limit)
        trims.clear()
        results.append(adjust(project, AdjustmentOptions(method="conditions")))
        counts.append(len(trims))
    below, at = results
    assert counts[0] == 0
    if keeping:
        assert counts[1] == 0
    else:
        assert counts[1] >= 2 * at.iterations  # before and after each assembly (and the final checks')
    assert at.iterations == below.iterations
    np.testing.assert_array_equal(at.state.xyz0, below.state.xyz0)


@pytest.mark.parametrize("keeping", [False, True])
def test_the_selected_inversion_trims_unless_the_freed_pages_are_kept(monkeypatch, keeping):
    """selected_inverse hands the free pages back before it factorises (the factor and the inverse
    are often a run's largest arrays), except in a process that keeps them (the command): there the
    iterations' freed arrays hold the inverse's (docs/decisions.md "The largest arrays from the
    heap too"). The inverse is the same either way."""
    import scipy.sparse as sp

    import striptri.selected_inverse as si

    rng = np.random.default_rng(5)
    B = sp.random(40, 40, density=0.1, random_state=rng) + sp.eye(40)
    N = (B @ B.T + 40 * sp.eye(40)).tocsr()
    trims = []
    monkeypatch.setattr(si, "give_back_free_memory", lambda: trims.append(1))
    monkeypatch.setattr(si, "keeps_freed_memory", lambda: keeping)
    inverse = si.selected_inverse(N, method="sparse")
    assert len(trims) == (0 if keeping else 1)
    np.testing.assert_allclose(inverse.diag(), np.diag(np.linalg.inv(N.toarray())), rtol=1e-12)


def test_keeps_freed_memory_says_whether_the_thresholds_are_set():
    """solvers.memory.keeps_freed_memory: False in a fresh process, True once keep_freed_memory has
    set glibc's thresholds, and False when the environment holds the user's own."""
    import subprocess
    import sys

    if not _glibc():
        pytest.skip("glibc's mallopt")
    code = ("from striptri.solvers import memory; a = memory.keeps_freed_memory(); "
            "b = memory.keep_freed_memory(); print(a, b, memory.keeps_freed_memory())")
    fresh = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert fresh.stdout.split() == ["False", "True", "True"], fresh.stderr
    env = {k: v for k, v in os.environ.items() if k not in ("MALLOC_MMAP_THRESHOLD_", "GLIBC_TUNABLES")}
    for name, value in (("MALLOC_TRIM_THRESHOLD_", "1000000"), ("MALLOC_MMAP_MAX_", "65536")):
        user = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                              env={**env, name: value})
        assert user.stdout.split() == ["False", "False", "False"], (name, user.stderr)


@pytest.mark.parametrize("point_precision", ["schmid90", "joint92"])
def test_the_precision_passes_give_the_same_numbers_in_smaller_chunks(monkeypatch, point_precision):
    """The precision passes take fewer groups at once than the assembly (linearise.PRECISION_CHUNK:
    residual cofactors, separability, Schmid's (92)) and the point precision fewer points with the
    orientation part (triangulation.ORIENTATION_CHUNK): memory, not results. A snooping run with
    chunks of a few groups writes the same files, byte for byte, as one with every batch whole."""
    from dataclasses import replace
    from pathlib import Path

    from striptri.core.runs import RunOptions
    from striptri.equations import linearise, triangulation
    from striptri.io import read_project
    from striptri.pipeline import adjust_products, options_for

    project = read_project(Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "block_3x6")
    options = replace(options_for(project), chunk_size=1_000_000)  # the assembly in whole batches
    files = {}
    for precision, orientation in ((1_000_000, 1_000_000), (7, 5)):
        monkeypatch.setattr(linearise, "PRECISION_CHUNK", precision)
        monkeypatch.setattr(triangulation, "ORIENTATION_CHUNK", orientation)
        products = adjust_products(project, options, RunOptions(blunders="snoop", point_precision=point_precision))
        assert products.result.converged
        files[precision] = products.files
    for name in ("photos.csv", "points.csv", "residuals.csv"):
        assert files[7][name] == files[1_000_000][name], name


ARENA_SCRIPT = """
import ctypes, sys, threading
if sys.argv[1] == "one":
    from striptri._entry import one_malloc_arena
    assert one_malloc_arena()
import numpy as np
keep = []
together = threading.Barrier(3)  # all three alive at once: an ended thread's arena is reused
def work():
    for _ in range(200):
        keep.append(np.ones(5000))  # 40 kB: below glibc's mmap threshold, from the thread's arena
    together.wait()
threads = [threading.Thread(target=work) for _ in range(3)]
for t in threads:
    t.start()
for t in threads:
    t.join()
ctypes.CDLL("libc.so.6").malloc_stats()  # one "Arena i:" block per arena, on stderr
"""


def test_the_command_keeps_its_threads_in_one_malloc_arena(tmp_path):
    """_entry.one_malloc_arena (called by the console script before anything starts a thread): three
    threads that allocate arrays below the mmap threshold share the main arena, where by default
    each takes one of its own (4 arenas while all three live); a MALLOC_ARENA_MAX of the user is left
    alone."""
    import subprocess
    import sys

    if not _glibc():
        pytest.skip("glibc's mallopt and malloc_stats are needed")
    script = tmp_path / "arenas.py"
    script.write_text(ARENA_SCRIPT)
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}

    def arenas(mode: str, extra: dict | None = None) -> int:
        proc = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, timeout=120,
                              env={**env, **(extra or {})})
        assert proc.returncode == 0, proc.stderr
        return sum(line.startswith("Arena ") for line in proc.stderr.splitlines())

    assert arenas("default") > 1  # the main arena and one per thread (4 here): the test tells them apart
    assert arenas("one") == 1
    user = subprocess.run([sys.executable, "-c", "from striptri._entry import one_malloc_arena; "
                           "print(one_malloc_arena())"], capture_output=True, text=True, timeout=60,
                          env={**env, "MALLOC_ARENA_MAX": "4"})
    assert user.stdout.strip() == "False"


FAULTS_SCRIPT = """
import resource, sys
import numpy as np
np._core.multiarray._set_madvise_hugepage(False)  # pages of 4 kB, whatever the kernel's huge pages
if sys.argv[1] == "kept":
    from striptri.solvers.memory import keep_freed_memory
    assert keep_freed_memory()
size = 512 * 1024 if sys.argv[2] == "small" else 6 * 2**20
def sweep():  # ten 4 MB temporaries alive together, then all freed (a sweep's chunks); or ten of 48 MB
    arrays = [np.ones(size) for _ in range(10)]
    del arrays
sweep()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    sweep()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def test_a_small_run_keeps_the_pages_it_frees(tmp_path):
    """solvers.memory.keep_freed_memory: twenty sweeps of ten 4 MB temporaries. With glibc's own
    thresholds the freed top of the heap goes back to the system after each sweep and the next
    one takes its 10,240 pages again, zeroed (page faults); kept, the sweeps after the first take
    none. A threshold the user set in the environment is left alone."""
    import subprocess
    import sys

    if not _glibc():
        pytest.skip("glibc's mallopt is needed")
    env = _without_malloc_settings()

    def faults(mode: str, size: str = "small") -> int:
        return _faults_of(tmp_path, FAULTS_SCRIPT, mode, size)

    assert faults("default") >= 20 * 5000  # half of each sweep's pages at least
    assert faults("kept") < 1000
    # arrays beyond the largest mmap threshold (32 MB): glibc maps each anew (12,288 pages); kept, the
    # heap serves them too (docs/decisions.md "The largest arrays from the heap too")
    assert faults("default", "large") >= 20 * 10 * 10_000
    assert faults("kept", "large") < 1000
    user = subprocess.run([sys.executable, "-c", "from striptri.solvers.memory import keep_freed_memory; "
                           "print(keep_freed_memory())"], capture_output=True, text=True, timeout=60,
                          env={**env, "GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1000000"})
    assert user.stdout.strip() == "False"


WARM_SCRIPT = """
import resource, sys
import numpy as np
from striptri.solvers import memory
np._core.multiarray._set_madvise_hugepage(False)  # pages of 4 kB, whatever the kernel's huge pages
assert memory.warm_heap(64 * 2**20) == 0  # a process that does not keep its freed pages: nothing
assert memory.keep_freed_memory()
assert memory.warm_heap(64 * 2**20, stop=lambda: True) == 0
assert memory.warm_heap(2**62) == 0  # more than any address space: nothing, and no MemoryError
if sys.argv[1] == "warm":
    assert memory.warm_heap(64 * 2**20) == 64 * 2**20
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
arrays = [np.ones(2**20) for _ in range(6)]  # 48 MB: a run's first arrays
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def test_a_warmed_heap_serves_the_first_arrays_without_faults(tmp_path):
    """solvers.memory.warm_heap (docs/decisions.md "The heap warmed while the project is read"):
    64 MB of heap touched and freed in a process that keeps its freed pages; the run's first 48 MB
    of arrays then take none of the 12,288 page faults they take in a cold heap. Nothing is
    touched in a process that does not keep its pages, nor once ``stop`` says so."""
    if not _glibc():
        pytest.skip("glibc's mallopt is needed")
    assert _faults_of(tmp_path, WARM_SCRIPT, "cold") >= 12_000
    assert _faults_of(tmp_path, WARM_SCRIPT, "warm") < 500


def _without_malloc_settings() -> dict:
    """The environment without the user's glibc malloc settings (which keep_freed_memory leaves alone)."""
    return {k: v for k, v in os.environ.items()
            if k not in ("GLIBC_TUNABLES", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_")}


def _faults_of(tmp_path, script_text: str, *args: str) -> int:
    """The page faults a script prints, run in a fresh interpreter without the user's malloc settings."""
    import subprocess
    import sys

    script = tmp_path / "faults.py"
    script.write_text(script_text)
    proc = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=120,
                          env=_without_malloc_settings())
    assert proc.returncode == 0, proc.stderr
    return int(proc.stdout)


def test_the_command_keeps_freed_pages_at_every_size(monkeypatch, tmp_path):
    """pipeline.run_adjust keeps the freed pages (keep_freed_memory) in every run, small or not
    (docs/decisions.md "Freed pages kept at every size"): with them kept, the conditions method does
    not trim around its assemblies (keeps_freed_memory)."""
    from pathlib import Path

    from striptri import pipeline

    project_dir = Path(__file__).resolve().parents[1] / "data" / "synthetic_strips" / "block_3x6"
    calls = []
    monkeypatch.setattr(pipeline, "keep_freed_memory", lambda: calls.append(1) or True)
    pipeline.run_adjust(project_dir, tmp_path / "out")
    assert len(calls) == 1


def _glibc() -> bool:
    import platform

    return platform.libc_ver()[0] == "glibc"


DEFER_SCRIPT = """
import sys
from striptri._entry import defer_unused_numpy_modules
deferred = defer_unused_numpy_modules() if sys.argv[1] == "deferred" else []
import scipy.linalg, scipy.sparse  # scipy's array API layer reads every name of numpy
loaded = sorted(m for m in ("numpy.f2py.crackfortran", "charset_normalizer", "numpy.testing._private.utils")
                if m in sys.modules)
import numpy as np
np.testing.assert_allclose([1.0], [1.0])  # still there, loaded on first use
assert callable(np.f2py.get_include)
print(",".join(deferred) + "|" + ",".join(loaded) + "|" + str("numpy.testing._private.utils" in sys.modules))
"""


def test_the_command_defers_numpys_unused_modules(tmp_path):
    """_entry.defer_unused_numpy_modules (the console script, before striptri imports numpy):
    numpy.f2py and numpy.testing are not executed by scipy's import, and load in full when used."""
    import subprocess
    import sys

    script = tmp_path / "defer.py"
    script.write_text(DEFER_SCRIPT)

    def run(mode):
        proc = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip().split("|")

    deferred, loaded, used = run("deferred")
    assert deferred == "numpy.f2py,numpy.testing" and loaded == "" and used == "True"
    _, loaded, _ = run("plain")  # what scipy's import does without it (if this scipy does it at all)
    assert set(loaded.split(",")) <= {"numpy.f2py.crackfortran", "charset_normalizer", "numpy.testing._private.utils"}


LEAVE_SCRIPT = """
import atexit, sys
from striptri._entry import leave
atexit.register(lambda: sys.stdout.write("exit handler ran\\n"))
sys.stdout.write("buffered line")  # no newline: still in the buffer when leave() is called
code = {"none": None, "three": 3, "big": 258, "text": "a message"}[sys.argv[1]]
leave(code)
sys.stdout.write("never reached\\n")
"""


@pytest.mark.parametrize(("code", "status"), [("none", 0), ("three", 3), ("big", 2), ("text", 1)])
def test_the_console_script_leaves_as_sys_exit_would(tmp_path, code, status):
    """_entry.leave (the console script's end, without the interpreter's teardown): the exit status
    of sys.exit(code), the exit handlers run, the buffered output flushed, a message to stderr."""
    import subprocess
    import sys

    script = tmp_path / "leave.py"
    script.write_text(LEAVE_SCRIPT)
    proc = subprocess.run([sys.executable, str(script), code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == status
    assert proc.stdout == "buffered lineexit handler ran\n"
    assert proc.stderr == ("a message\n" if code == "text" else "")


def test_a_profiled_command_exits_as_python_does(tmp_path):
    """Under a profiler (or a tracer such as coverage) the console script exits normally, so that
    the profiler writes its data (cProfile's own main then sets the status: it ignores SystemExit)."""
    import subprocess
    import sys

    stats = tmp_path / "profile.out"
    proc = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(stats), "-m", "striptri", "--version"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "striptri" in proc.stdout
    assert stats.exists() and stats.stat().st_size > 0
