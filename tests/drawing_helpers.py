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


def projections(value: bytes) -> bytes:
    """Whether this process holds mpl_toolkits.mplot3d and matplotlib's 3D projection (the drawing
    worker imports neither: figures.import_figure_modules' without_axes3d)."""
    import sys

    import matplotlib.projections

    names = matplotlib.projections.get_projection_names()
    return value + f" mplot3d {'mpl_toolkits.mplot3d' in sys.modules} 3d {'3d' in names}".encode()
