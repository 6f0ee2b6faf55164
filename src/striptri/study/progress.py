"""A progress display on stderr for the command line: tqdm when it is installed, otherwise a plain
counter ("trials 12/40"). Used as the ``progress(done, total)`` callback of study.runner."""

from __future__ import annotations

import sys


class StderrProgress:
    def __init__(self, what: str = "trials"):
        self.what = what
        self._bar = None
        try:
            import tqdm  # noqa: F401
            self._tqdm = tqdm
        except ImportError:
            self._tqdm = None

    def __call__(self, done: int, total: int) -> None:
        if self._tqdm is not None:
            if self._bar is None:
                self._bar = self._tqdm.tqdm(total=total, desc=self.what, file=sys.stderr)
            self._bar.update(done - self._bar.n)
        else:
            end = "\n" if done == total else ""
            print(f"\r{self.what} {done}/{total}", end=end, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
