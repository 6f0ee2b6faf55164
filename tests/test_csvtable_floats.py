"""The compiled float conversion of large CSV columns (csvtable._compiled_floats, fastnumbers) gives
float's doubles or leaves the column to float's path: never a different number, never a value float
refuses, and the same table and errors as without it."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from striptri.errors import InputError
from striptri.io import csvtable
from striptri.io.csvtable import FAST_FLOATS_MIN, parse_csv

N = FAST_FLOATS_MIN  # a column long enough for the compiled conversion


def _float_or_none(text: str):
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _same_double(a: float, b: float) -> bool:
    return np.float64(a).view(np.int64) == np.float64(b).view(np.int64)


def _check(text: str) -> None:
    """A column of ``text``: the compiled conversion takes it only where float gives a finite number,
    and then gives that double (the sign of zero too)."""
    got = csvtable._compiled_floats([text] * N)
    expected = _float_or_none(text)
    if got is None:
        return
    assert expected is not None, f"{text!r}: float refuses it or gives a non-finite number, fastnumbers gave {got[0]!r}"
    assert got.shape == (N,) and got.dtype == np.float64
    assert all(_same_double(g, expected) for g in got[:3].tolist()), (text, got[0], expected)


def test_compiled_conversion_is_used_for_plain_numbers():
    """The path under test runs: a long column of plain numbers is converted by it, a short one is not."""
    values = [repr(v) for v in np.random.default_rng(1).normal(size=N).tolist()]
    got = csvtable._compiled_floats(values)
    assert got is not None
    assert all(_same_double(g, float(v)) for g, v in zip(got.tolist(), values))
    assert csvtable._compiled_floats(values[:-1]) is None
    assert csvtable._compiled_floats(values[:-1] + [""]) is None  # an empty field: float's path ('' -> nan)


@pytest.mark.parametrize("text", [
    "1_0", "nan(123)", "nan", "-inf", "Infinity", "1e400", "-1e400", "0x1p3", "1e", "e1", ".", "-", "+-1", "1,5",
    "\u0661\u0662", "\u0663.\u0665", "\uff11\uff12", "1.5\u2003", "\u00a01.5", "1j", "0b1", "1__0", "_1", "1_",
    "4.9e-324", "2.4703282292062328e-324", "2.4703282292062327e-324", "1.7976931348623157e308",
    "1.7976931348623158e308", "1.7976931348623159e308", "-0", "-0.0", "+.5", "5.", "00012", "1E+05",
    "9" * 400, "0." + "0" * 400 + "1", "0.1000000000000000055511151231257827021181583404541015625",
    "0.1000000000000000055511151231257827021181583404541015624",
])
def test_edge_texts_give_floats_double_or_none(text):
    _check(text)


@settings(max_examples=400, deadline=None)
@given(st.text(alphabet="0123456789.eE+-_ infatyINFATY", max_size=30))
def test_random_texts_give_floats_double_or_none(text):
    _check(text)


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["repr", "%.17e", "%.25g", "%.3f", "%.40f"]))
def test_doubles_written_every_way_read_back_as_float_reads_them(value, form):
    text = repr(value) if form == "repr" else form % value
    _check(text)


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="0123456789", min_size=1, max_size=40), st.integers(-340, 320), st.booleans())
def test_long_mantissas_near_the_ends_of_the_range_round_as_float_rounds(digits, exponent, point):
    """Mantissas longer than a double holds, with exponents down to the subnormals and up to overflow:
    the halfway cases that a conversion not correctly rounded gets wrong."""
    text = (digits[:1] + "." + digits[1:] if point else digits) + f"e{exponent}"
    _check(text)


def test_tables_and_errors_are_those_of_floats_path(monkeypatch):
    """A long column through parse_csv: the same array with and without fastnumbers, and a bad value
    (one fastnumbers takes, one it refuses, one neither takes) named at its line as before."""
    rng = np.random.default_rng(5)
    values = [repr(v) for v in (rng.normal(size=3 * N) * 1e3).tolist()]
    text = "a,b\n" + "".join(f"{i},{v}\n" for i, v in enumerate(values))
    with_it = parse_csv("t.csv", text).floats("b")
    monkeypatch.setattr(csvtable, "_fastnumbers", None)
    without = parse_csv("t.csv", text).floats("b")
    assert with_it.tobytes() == without.tobytes()
    monkeypatch.undo()
    for bad, reason in (("nan(1)", "'nan(1)' is not a number"), ("inf", "'inf' is not a finite number"),
                        ("1.2.3", "'1.2.3' is not a number")):
        broken = list(values)
        broken[N + 7] = bad
        text = "a,b\n" + "".join(f"{i},{v}\n" for i, v in enumerate(broken))
        with pytest.raises(InputError) as info:
            parse_csv("t.csv", text).floats("b")
        assert info.value.line == N + 9 and info.value.reason == f"column 'b': {reason}"
    broken = list(values)
    broken[N] = "1_000"  # float takes it; fastnumbers refuses it, so float's path reads the column
    got = parse_csv("t.csv", "a,b\n" + "".join(f"{i},{v}\n" for i, v in enumerate(broken))).floats("b")
    assert got[N] == 1000.0 and got[0] == float(values[0])
