"""The two kinds of failure a user sees: bad input (exit 2) and explained numerical trouble (exit 1)."""

from __future__ import annotations


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
    (datum defect, divergence, a photograph without enough measurements)."""
