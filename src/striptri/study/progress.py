"""A progress display on stderr for the command line, used as the ``progress(done, total)`` callback
of study.runner: on a terminal, tqdm's bar rewritten in place; in a pipe or a log file, plain lines
("striptri: trials 12/40"), as ``striptri adjust`` writes its progress, at most every
PLAIN_INTERVAL_S seconds and at the end (a carriage-return bar would fill a log with one long line)."""

from __future__ import annotations

import sys
import time

PLAIN_INTERVAL_S = 5.0


class StderrProgress:
    def __init__(self, what: str = "trials", stream=None):
        self.what = what
        self.stream = stream if stream is not None else sys.stderr
        self._bar = None
        self._last = None
        self._tqdm = None
        if _is_terminal(self.stream):
            try:
                import tqdm

                self._tqdm = tqdm
            except ImportError:  # pragma: no cover - tqdm is a dependency
                self._tqdm = None

    def __call__(self, done: int, total: int) -> None:
        if self._tqdm is not None:
            if self._bar is None:
                self._bar = self._tqdm.tqdm(total=total, desc=self.what, file=self.stream)
            self._bar.update(done - self._bar.n)
            return
        now = time.monotonic()
        if done == total or self._last is None or now - self._last >= PLAIN_INTERVAL_S:
            self._last = now
            print(f"striptri: {self.what} {done}/{total}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
