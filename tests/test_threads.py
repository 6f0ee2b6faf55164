"""BLAS threads set by striptri, not by the environment (issue 26; striptri.solvers.threads): one
thread for every BLAS in the process inside a command, the libraries loaded during it included
(scikit-sparse brings Debian's OpenBLAS at the first solve), and the caller's settings back after."""

from __future__ import annotations

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
