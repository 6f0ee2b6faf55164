"""project.toml as the readers see it: :class:`TomlFile` (its path, its parsed tables and its text)
and :func:`toml_line`, the line of a key in it, for messages that name the line."""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple


class TomlFile(NamedTuple):
    """project.toml as read: path (None when the project has none), data (its parsed tables, {}
    without one) and text (for the line of a key in messages)."""

    path: Path | None
    data: dict
    text: str = ""

    def line(self, section: str, key: str) -> int | None:
        """The line of ``key`` in [section] (:func:`toml_line`)."""
        return toml_line(self.text, section, key)


def toml_line(text: str, section: str, key: str) -> int | None:
    """Line of ``key = ...`` inside [section] (section "" = top level), or None if not found."""
    current = ""
    for number, line in enumerate(text.splitlines(), start=1):
        header = re.match(r"\s*\[\s*([^\]]+?)\s*\]", line)
        if header:
            current = header.group(1)
        elif current == section and re.match(rf"\s*\"?{re.escape(key)}\"?\s*=", line):
            return number
    return None
