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
    # SIGINT too as Interrupted, not KeyboardInterrupt: click would turn one that comes after the
    # command's own handling into "Aborted!" and exit status 1
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, _raise_interrupted)
    try:
        from striptri.cli import main as command
    except KeyboardInterrupt:
        _stop(signal.SIGINT)
    except Interrupted as exc:
        _stop(exc.signum)
    try:
        command()
    except KeyboardInterrupt:  # after the command's own handling ended (cli.reports_errors)
        _stop(signal.SIGINT, starting=False)
    except Interrupted as exc:
        _stop(exc.signum, starting=False)


def _stop(signum: int, starting: bool = True) -> None:
    name = signal.Signals(signum).name
    if starting:
        sys.stderr.write(f"striptri: error: interrupted ({name}) while starting; nothing was written\n")
    else:
        from striptri.io.output import committed_outputs

        written = committed_outputs()
        where = (f"{written[-1]} holds this run's whole result" if written else "no output was left half-written")
        sys.stderr.write(f"striptri: error: interrupted ({name}) as the command ended; {where}\n")
    sys.exit(128 + signum)
