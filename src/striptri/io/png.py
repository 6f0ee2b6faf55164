"""The ``Software`` text of a PNG file: striptri tags the figures it writes as files, so that a
later run recognises a file as its own output before replacing it (io.output), and never replaces
a picture it did not make.

PNG layout (ISO/IEC 15948): an 8-byte signature, then chunks ``length (4, big-endian) | type (4) |
data | CRC-32 of type and data``; a ``tEXt`` chunk's data is ``keyword NUL text`` in Latin-1.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_SCAN = 1 << 16  # text chunks come before the image data; do not read a large foreign file whole


def with_software(png: bytes, software: str) -> bytes:
    """png with a ``tEXt`` chunk ``Software = software`` inserted after IHDR (any earlier
    Software text is dropped)."""
    if not png.startswith(SIGNATURE):
        raise ValueError("not a PNG")
    chunks = list(_chunks(png))
    out = [SIGNATURE]
    for kind, data in chunks:
        if kind == b"tEXt" and data.split(b"\0", 1)[0] == b"Software":
            continue
        out.append(_chunk(kind, data))
        if kind == b"IHDR":
            out.append(_chunk(b"tEXt", b"Software\0" + software.encode("latin-1")))
    return b"".join(out)


def software_of(path: str | Path) -> str | None:
    """The Software text of the PNG file at path (None: not a PNG, unreadable, or no such text)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_MAX_SCAN)
    except OSError:
        return None
    if not head.startswith(SIGNATURE):
        return None
    try:
        for kind, data in _chunks(head, stop_at=b"IDAT"):
            if kind == b"tEXt":
                key, _, text = data.partition(b"\0")
                if key == b"Software":
                    return text.decode("latin-1")
    except ValueError:
        return None
    return None


def _chunks(png: bytes, stop_at: bytes = b""):
    pos = len(SIGNATURE)
    while pos + 8 <= len(png):
        length, kind = struct.unpack(">I4s", png[pos : pos + 8])
        if kind == stop_at:
            return
        end = pos + 8 + length + 4
        if end > len(png):
            raise ValueError("truncated PNG chunk")
        yield kind, png[pos + 8 : pos + 8 + length]
        pos = end


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
