"""The ``striptri`` console script. It puts the signal handling in place before numpy, scipy and
matplotlib are imported, so that SIGINT, SIGTERM or SIGHUP in the first second of a run (while the
command is still loading) also end with one message and no traceback; ``striptri.cli`` takes over
once loaded (cli.reports_errors)."""

from __future__ import annotations

import signal
import sys

from striptri.errors import Interrupted


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def main() -> None:
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _raise_interrupted)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        from striptri.cli import main as command
    except KeyboardInterrupt:
        _stop(signal.SIGINT)
    except Interrupted as exc:
        _stop(exc.signum)
    command()


def _stop(signum: int) -> None:
    sys.stderr.write(f"striptri: error: interrupted ({signal.Signals(signum).name}) while starting; "
                     "nothing was written\n")
    sys.exit(128 + signum)
