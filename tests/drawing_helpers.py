"""Figure functions for tests/test_drawing.py that the drawing worker imports (PYTHONPATH): each
says which process drew it."""

from __future__ import annotations

import os

PARENT = "STRIPTRI_TEST_PARENT"  # the test process's pid


def anywhere(value: bytes) -> bytes:
    return value + b" drawn by " + str(os.getpid()).encode()


def only_in_the_parent(value: bytes) -> bytes:
    if str(os.getpid()) != os.environ[PARENT]:
        raise RuntimeError("this figure fails in the worker")
    return anywhere(value)


def slowly(value: bytes, seconds: float) -> bytes:
    """A figure that takes ``seconds`` to draw."""
    import time

    time.sleep(seconds)
    return anywhere(value)
