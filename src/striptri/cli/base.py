"""The ``striptri`` command group and what every command shares: errors and signals reach the
user through :func:`reports_errors`:

* :class:`striptri.errors.InputError` -> ``striptri: error: <message>`` on stderr, exit status 2;
* :class:`striptri.errors.NumericalFailure` -> the same message form, exit status 1;

and the option types of several commands (finite numbers, fractions, repeatable lists).
"""

from __future__ import annotations

import functools
import math
import os
import signal
import sys

import click

from striptri import __version__
from striptri.solvers import threads
from striptri.errors import InputError, Interrupted, NumericalFailure, deferred_while_importing, send_again_later
from striptri.io.output import committed_outputs

EXIT_INPUT, EXIT_NUMERICAL = 2, 1
TERMINATION_SIGNALS = (signal.SIGTERM, signal.SIGHUP)  # raised as errors.Interrupted; SIGINT: KeyboardInterrupt


def threads_option(command):
    """``--threads N`` for a command that adjusts: the cores striptri uses (solvers.threads.use_threads;
    STRIPTRI_THREADS when not given, else all of them). reports_errors applies it."""
    return click.option("--threads", "threads", type=click.IntRange(min=1), default=None,
                        help="Cores to use: the chunks of each sweep (linearisation, whitening, residual "
                             "cofactors) run on this many threads, at most [STRIPTRI_THREADS, else all cores].")(command)


def reports_errors(command):
    """Decorate a command so that every way it can end is one message and an exit status, never a
    traceback (README "Safety"):

    * InputError (bad input, an unusable output location) -> exit status 2;
    * NumericalFailure (a datum defect, divergence, no convergence) -> exit status 1;
    * MemoryError -> exit status 1, saying so;
    * SIGINT, SIGTERM, SIGHUP -> the output reservation cleans up, then exit 128 + the signal's
      number, as a shell reports a killed program (also when compiled code that called back into
      Python turned the interruption into an error of its own);
    * anything else is a defect of striptri: one line naming it, exit status 1 (the traceback only
      with STRIPTRI_DEBUG=1).
    """

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        previous = _raise_on_signals()
        chosen = kwargs.pop("threads", None)  # threads_option
        try:
            with threads.single_threaded(), threads.use_threads(chosen):  # threads set here, not by the environment
                return command(*args, **kwargs)
        except InputError as exc:
            _fail(exc, EXIT_INPUT)
        except NumericalFailure as exc:
            reason = "" if exc.reason == "failed" else f"\n(termination: {exc.reason}; nothing was written)"
            _fail(f"{exc}{reason}", EXIT_NUMERICAL)
        except MemoryError:
            _fail("not enough memory for this project on this machine (the arrays of the adjustment did not fit); "
                  "nothing was written", EXIT_NUMERICAL)
        except KeyboardInterrupt:
            _interrupted(signal.SIGINT)
        except Interrupted as exc:
            _interrupted(exc.signum)
        except BrokenPipeError:
            _quiet_broken_pipe()
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise  # click's own usage errors (exit status 2) and exits
        except Exception as exc:  # noqa: BLE001 - the last line of defence: one message, no traceback
            signum = _interrupted_inside_an_extension()
            if signum is not None:  # the interruption, turned into another error by compiled code
                _interrupted(signum)
            if os.environ.get("STRIPTRI_DEBUG"):
                raise
            _fail(f"internal error ({type(exc).__name__}: {exc}). This is a defect of striptri; please report it "
                  "with the command that caused it (STRIPTRI_DEBUG=1 shows the traceback).", EXIT_NUMERICAL)
        finally:
            _restore_signals(previous)

    return wrapper


_RECEIVED: list[int] = []  # the termination signals received while the command runs


def _interrupted(signum: int):
    """Exit 128 + signum with a message that says what state the output is in."""
    name = signal.Signals(signum).name
    written = committed_outputs()
    if written:
        _fail(f"interrupted ({name}) after the output was complete: {written[-1]} holds this run's whole "
              "result", 128 + signum)
    _fail(f"interrupted ({name}); no output was left half-written", 128 + signum)


def _raise_interrupted(signum, frame):
    if deferred_while_importing(signum, frame):  # raised once the import has ended
        return
    _RECEIVED.append(signum)
    raise Interrupted(signum)


def _raise_keyboard_interrupt(signum, frame):
    if deferred_while_importing(signum, frame):
        return
    _RECEIVED.append(signum)
    raise KeyboardInterrupt


def _interrupted_inside_an_extension() -> int | None:
    """The signal, when one was received during the command: a compiled extension that calls back
    into Python (matplotlib's Agg renderer) may turn the Interrupted or KeyboardInterrupt its
    callback raised into an error of its own ("ValueError: Invalid bounding box"); the run was
    interrupted all the same."""
    return _RECEIVED[-1] if _RECEIVED else None


def _raise_on_signals() -> dict:
    """Turn SIGTERM and SIGHUP into Interrupted, and SIGINT into KeyboardInterrupt (even when the
    shell started striptri with SIGINT ignored), while the command runs (main thread only).

    A Python signal handler runs at the next bytecode boundary, which may lie in a finaliser or a
    weakref callback (a garbage collection); Python ignores an exception raised there, prints
    "Exception ignored in ..." with a traceback and goes on. :func:`_redeliver_swallowed_signals`
    (sys.unraisablehook while the command runs) catches exactly that case, prints nothing and sends
    the signal again a moment later, when the main thread is back in ordinary code."""
    previous = {}
    _RECEIVED.clear()
    handlers = {**{sig: _raise_interrupted for sig in TERMINATION_SIGNALS}, signal.SIGINT: _raise_keyboard_interrupt}
    for sig, handler in handlers.items():
        try:
            previous[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread: leave the signals as they are
            break
    if previous:
        previous["unraisablehook"] = sys.unraisablehook
        sys.unraisablehook = functools.partial(_redeliver_swallowed_signals, previous["unraisablehook"])
    return previous


def _redeliver_swallowed_signals(hook, unraisable) -> None:
    """sys.unraisablehook: an Interrupted or KeyboardInterrupt that Python had to ignore (raised by
    a signal handler inside a finaliser or weakref callback) is sent again as its signal from a
    timer thread, so that it interrupts the command where it can; anything else goes to ``hook``."""
    exc = unraisable.exc_value
    if isinstance(exc, Interrupted):
        signum = exc.signum
    elif isinstance(exc, KeyboardInterrupt):
        signum = signal.SIGINT
    else:
        hook(unraisable)
        return
    send_again_later(signum)


def _restore_signals(previous: dict) -> None:
    for sig, handler in previous.items():
        if sig == "unraisablehook":
            sys.unraisablehook = handler
        else:
            signal.signal(sig, handler)


def _quiet_broken_pipe():
    """stdout was closed by the reader (``striptri ... | head``): stop without a message."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    sys.exit(EXIT_NUMERICAL)


def _warn(message: str) -> None:
    click.echo(f"striptri: warning: {message}", err=True)


def _fail(exc, status: int):
    click.echo(f"striptri: error: {exc}", err=True)
    sys.exit(status)


@click.group()
@click.version_option(__version__, prog_name="striptri")
def main():
    """striptri: analytical aerial triangulation after H. H. Schmid (BRL Report 961, 1955)."""



class _Finite(click.FloatRange):
    """A finite number (nan and inf are refused) within the given range."""

    name = "float"

    def _describe_range(self) -> str:
        """The range for --help ("x>=0"); nothing without bounds (click would print "x<=None")."""
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


class _Fraction(click.ParamType):
    """A number given as a decimal (0.6) or as a fraction (2/3)."""

    name = "fraction"

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            return value
        try:
            num, _, den = str(value).partition("/")
            number = float(num) / float(den) if den else float(num)
        except (ValueError, ZeroDivisionError):
            self.fail(f"{value!r} is not a number or a fraction such as 2/3", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number



class _ManyValues(click.Option):
    """An option with multiple=True that also takes several values after one flag:
    ``--photos 4 8 16`` as well as ``--photos 4 --photos 8``. The values run to the next option."""

    def add_to_parser(self, parser, ctx):
        result = super().add_to_parser(parser, ctx)
        for name in self.opts:
            option = parser._long_opt.get(name) or parser._short_opt.get(name)
            if option is not None:
                previous = option.process

                def process(value, state, previous=previous, prefixes=option.prefixes):
                    previous(value, state)
                    while state.rargs and not any(state.rargs[0].startswith(p) for p in prefixes):
                        previous(state.rargs.pop(0), state)

                option.process = process
        return result
