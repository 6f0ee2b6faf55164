"""The two kinds of failure a user sees: bad input (exit 2) and explained numerical trouble (exit 1)."""

from __future__ import annotations

from dataclasses import dataclass


class InputError(Exception):
    """Bad input: names the file, the line (1-based, None when the whole file is meant) and the reason."""

    def __init__(self, path, line: int | None, reason: str):
        self.path = str(path)
        self.line = line
        self.reason = reason
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {reason}")


class NumericalFailure(Exception):
    """An adjustment that cannot be carried out, explained in a photogrammetrist's words
    (datum defect, divergence, a photograph without enough measurements).

    reason: why, as summary.json's "termination" names it (core.result.TERMINATIONS: "diverged",
    "datum_defect", "singular", "not_finite", "iteration_limit"), or "failed" for the failures that
    are none of those (too few observations, an unsuitable option)."""

    def __init__(self, message: str, reason: str = "failed"):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Note:
    """Something in the input that striptri did not use, or used in a way the user may not expect
    (a control point no photo measures, an unknown column, a file it does not read). Never silent:
    the pipeline prints every note on stderr (``striptri: warning: ...``), lists it in report.html
    and in summary.json's ``warnings``.

    path: the file (or folder) concerned; line: 1-based, None for the whole file; text: what was
    ignored and why, in a photogrammetrist's words.
    """

    path: str
    line: int | None
    text: str

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}, line {self.line}"
        return f"{where}: {self.text}"


class Interrupted(BaseException):
    """A termination signal (SIGTERM, SIGHUP) received while a command runs, raised where the
    program is so that every ``finally`` and the output reservation clean up (like
    KeyboardInterrupt for SIGINT). A BaseException: no ``except Exception`` may swallow it."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signum)
