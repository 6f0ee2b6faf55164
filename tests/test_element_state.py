"""One element state (issue 27): every element of the model is held, observed or free
(model.ElementState). The tables keep their files' sigma conventions and translate them once into
their *_state arrays; nothing below the readers reads a sentinel of those sigmas."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from striptri.model import (
    CHECK,
    FREE,
    FULL,
    HELD,
    HEIGHT,
    OBSERVED,
    TIE,
    Cameras,
    ObjectPoints,
    Photos,
    default_gnss,
    element_states,
)

nan, inf = np.nan, np.inf


def test_each_table_translates_its_own_convention():
    cams = Cameras(["C"], [[150.0, 0.0, 0.0]], [[nan, 0.0, 0.01]])
    assert cams.interior_state[0, :3].tolist() == [HELD, HELD, OBSERVED]
    assert (cams.interior_state[0, 3:] == HELD).all()  # padded elements: held
    cams = Cameras(["C"], [[150.0, 0.0, 0.0]], [[inf, 0.0, 0.01]])
    assert cams.interior_state[0, 0] == FREE

    photos = Photos(["1"], np.zeros(1, dtype=int), [""], np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)),
                    np.array([[nan, 0.0, 0.05]]), np.array([[0.001, nan, 0.0]]))
    assert photos.centre_state.tolist() == [[FREE, HELD, OBSERVED]]  # an empty photo sigma leaves it free
    assert photos.angle_state.tolist() == [[OBSERVED, FREE, HELD]]

    given = np.array([[1.0, 2.0, 3.0], [nan, nan, 5.0], [nan] * 3, [1.0, 2.0, 3.0]])
    points = ObjectPoints(["A", "B", "T", "K"], np.array([FULL, HEIGHT, TIE, CHECK]), given,
                          np.array([[nan, 0.02, 0.0], [nan, nan, 0.05], [nan] * 3, [0.1] * 3]))
    assert points.given_state.tolist() == [[HELD, OBSERVED, HELD],  # an empty control sigma holds it
                                           [FREE, FREE, OBSERVED],  # a Z point: X and Y are unknowns
                                           [FREE] * 3,  # a tie point
                                           [FREE] * 3]  # a check point is withheld: its sigma plays no part

    gnss = default_gnss(1, [""])
    assert (gnss.lever_state == HELD).all() and not gnss.in_play
    gnss = replace(gnss, sigma_lever=np.array([[inf, 0.05, nan]]))
    assert gnss.lever_state.tolist() == [[FREE, OBSERVED, HELD]] and gnss.in_play


def test_the_state_follows_the_sigma():
    """The state is read off the sigma each time, so neither a replace() of a table nor an edit of
    its sigma array in place can leave it stale."""
    photos = Photos(["1"], np.zeros(1, dtype=int), [""], np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)),
                    np.full((1, 3), nan), np.full((1, 3), nan))
    held = replace(photos, sigma_xyz0=np.zeros((1, 3)))
    assert (photos.centre_state == FREE).all() and (held.centre_state == HELD).all()
    photos.sigma_xyz0[0, 2] = 0.05
    assert photos.centre_state.tolist() == [[FREE, FREE, OBSERVED]]


def test_element_states_codes():
    assert element_states(np.array([nan, 0.0, 2.0, inf]), FREE).tolist() == [FREE, HELD, OBSERVED, FREE]
    assert element_states(np.array([nan, 0.0, 2.0, inf]), HELD).tolist() == [HELD, HELD, OBSERVED, FREE]


ELEMENTS = r"sigma_(interior|xyz0|angles|given|lever|boresight)"
# a test of a sigma's value against its file convention: isnan / isinf / isfinite of it, or a
# comparison of it (also through nan_to_num) with 0; reading an observed sigma under a state mask is fine
SENTINEL = re.compile(rf"(isnan|isinf|isfinite)\([^)]*{ELEMENTS}|nan_to_num\([^)]*{ELEMENTS}[^)]*\) *(==|>|>=|<|!=)"
                      rf"|{ELEMENTS}\b[^ ,)]* *(==|>|>=|<|!=) *0")
EDGE = ("io", "formats", "simulate")  # the readers, the converters and the simulator write the conventions


def test_nothing_below_the_readers_reads_a_sigma_sentinel():
    src = Path(__file__).resolve().parents[1] / "src" / "striptri"
    found = [f"{p.relative_to(src)}:{i}: {line.strip()}"
             for p in src.rglob("*.py") if p.relative_to(src).parts[0] not in EDGE and p.name != "model.py"
             for i, line in enumerate(p.read_text().splitlines(), 1)
             if SENTINEL.search(line) and "_state" not in line]
    assert not found, "\n".join(found)
