"""project.toml's [coordinates] (docs/file-formats.md): validated into model.CoordinateSettings.

::

    [coordinates]
    crs = "EPSG:32633"            # or WKT; a projected CRS with axes in metres
    heights = "orthometric"       # or "ellipsoidal" (required)
    geoid_undulation = 47.3       # orthometric only: N in metres, h = H + N ...
    # geoid_grid = "geoid.gtx"    # ... or a PROJ grid file, relative to the project folder

Decisions (docs/decisions.md, "Map coordinates"): a geographic, geocentric or compound CRS is
refused (the files hold metres of a map projection; the height kind is the separate key);
``heights`` has no default (a geoid undulation is tens of metres: guessing is not safe);
geoid keys with ellipsoidal heights are refused as contradictory.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from striptri.crs.frame import geoid_pipeline, parse_crs
from striptri.model import HEIGHT_KINDS, CoordinateSettings

KEYS = ("crs", "heights", "geoid_undulation", "geoid_grid")
GEOID_LIMIT_M = 200.0  # |N| on the Earth stays below 110 m


def parse_coordinates(section: dict, folder: Path, fail: Callable[[str, str], Exception],
                      line: int | None) -> CoordinateSettings:
    """CoordinateSettings from the [coordinates] table ``section``; folder: the project's (geoid_grid
    is relative to it); fail(key, reason) -> the InputError to raise (naming project.toml and the
    key's line); line: of the section header."""
    if "crs" not in section:
        raise fail("crs", "missing: give the projected CRS of the ground coordinates (crs = \"EPSG:...\" or WKT)")
    text = section["crs"]
    if not isinstance(text, str) or not text.strip():
        raise fail("crs", f"{text!r} is not a CRS (an EPSG code such as \"EPSG:32633\" or WKT)")
    try:
        parse_crs(text)
    except ValueError as exc:
        raise fail("crs", str(exc)) from None
    heights = section.get("heights")
    if heights is None:
        raise fail("crs", "[coordinates] needs heights = \"ellipsoidal\" or \"orthometric\" (the kind of every Z of "
                          "the project)")
    if heights not in HEIGHT_KINDS:
        raise fail("heights", f"{heights!r} is not one of {', '.join(repr(h) for h in HEIGHT_KINDS)}")
    undulation, grid = section.get("geoid_undulation"), section.get("geoid_grid")
    if heights == "ellipsoidal":
        for key in ("geoid_undulation", "geoid_grid"):
            if key in section:
                raise fail(key, "a geoid is given but heights = \"ellipsoidal\": say heights = \"orthometric\" or "
                                "remove the geoid")
        return CoordinateSettings(crs=text, heights=heights, line=line)
    if undulation is not None and grid is not None:
        raise fail("geoid_grid", "give either geoid_undulation or geoid_grid, not both")
    if undulation is None and grid is None:
        raise fail("heights", "orthometric heights need the geoid undulation N (h = H + N): give geoid_undulation = "
                              "<metres> or geoid_grid = \"<PROJ grid file>\"")
    if undulation is not None:
        if isinstance(undulation, bool) or not isinstance(undulation, (int, float)) or not (
                math.isfinite(undulation) and abs(undulation) <= GEOID_LIMIT_M):
            raise fail("geoid_undulation", f"{undulation!r} is not a geoid undulation in metres (|N| <= "
                                           f"{GEOID_LIMIT_M:g})")
        return CoordinateSettings(crs=text, heights=heights, geoid_undulation=float(undulation), line=line)
    if not isinstance(grid, str) or not grid:
        raise fail("geoid_grid", f"{grid!r} is not a file name")
    path = (folder / grid).resolve()
    if not path.is_file():
        raise fail("geoid_grid", f"the grid file {str(path)!r} is not found (geoid_grid is relative to the project "
                                 "folder)")
    try:
        geoid_pipeline(path)
    except ValueError as exc:
        raise fail("geoid_grid", str(exc)) from None
    return CoordinateSettings(crs=text, heights=heights, geoid_grid=path, line=line)
