"""photos.csv's optional ``image`` column: which image file is whose photo (docs/file-formats.md)."""

from __future__ import annotations

import csv
import io
from pathlib import Path


def image_column(photos_csv: Path) -> dict[str, tuple[int, str]]:
    """photos.csv's optional ``image`` column: photo_id -> (line, path) where it is not empty."""
    reader = csv.DictReader(io.StringIO(photos_csv.read_text(encoding="utf-8-sig")))
    if "image" not in (reader.fieldnames or []):
        return {}
    return {r["photo_id"].strip(): (k + 2, r["image"].strip()) for k, r in enumerate(reader)
            if (r.get("image") or "").strip()}
