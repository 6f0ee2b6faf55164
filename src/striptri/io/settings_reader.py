"""project.toml: the settings of a project (docs/file-formats.md), checked key by key with the file
and line of every problem (io.project_reader reads the rest of the folder)."""

from __future__ import annotations

import math
import re
from pathlib import Path


from striptri import model
from striptri.errors import InputError
from striptri.core.options import DATUMS, METHODS
from striptri.crs.settings import KEYS, parse_coordinates
from striptri.io import plausibility as limits
from striptri.io.csvtable import decode_text, input_present, read_input_bytes
from striptri.io.toml_file import toml_line
from striptri.io.film_reader import TOML_KEYS as FILM_TOML_KEYS
from striptri.io.gnss_reader import TOML_KEYS as GNSS_TOML_KEYS, TOML_SECTION as GNSS_SECTION
from striptri.equations.plate_corrections import EARTH_RADIUS_RANGE_M

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the tomli backport
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None

# Keys project.toml may hold, per section.
TOML_KEYS = {
    "units": ("angles", "rotation", "plate"),
    "defaults": ("sigma_image",),
    "adjustment": ("method", "solver", "max_iterations", "cost_tolerance"),
    "datum": ("mode", "points"),
    "corrections": ("earth_curvature", "refraction", "earth_radius"),
    GNSS_SECTION: GNSS_TOML_KEYS,  # GNSS shift and drift (io.gnss_reader)
    "coordinates": KEYS,  # striptri.crs.settings
    "plan": ("format", "terrain_height"),  # striptri plan only (striptri.plan.vongruber)
    "film": FILM_TOML_KEYS,  # scanned film (striptri.film.data)
}



def read_settings(path: str | Path) -> model.ProjectSettings:
    """ProjectSettings from project.toml; defaults when the file is absent (a link to nothing, a
    folder or a FIFO is an InputError). Unknown sections, keys or values -> InputError naming
    project.toml and, where it can be found, the line."""
    path = Path(path)
    if not input_present(path):
        return model.ProjectSettings()
    return parse_settings(path, read_input_bytes(path))


def parse_settings(path: str | Path, content: str | bytes) -> model.ProjectSettings:
    """ProjectSettings from the content of project.toml (UTF-8, a byte-order mark accepted); path
    names it in messages. Rules of read_settings."""
    path = Path(path)
    text = decode_text(path, content)
    data = _parse_toml(path, text)
    defaults = model.ProjectSettings()
    _check_toml_keys(path, text, data)

    def get(section: str, key: str, default):
        return data.get(section, {}).get(key, default)

    def fail(section: str, key: str, reason: str) -> InputError:
        return InputError(path, toml_line(text, section, key), f"[{section}] {key}: {reason}")

    def choice(section: str, key: str, allowed: tuple[str, ...], default: str, meaning: str = "") -> str:
        value = get(section, key, default)
        if not isinstance(value, str) or value not in allowed:
            raise fail(section, key, f"{value!r} is not one of {', '.join(repr(a) for a in allowed)}{meaning}")
        return value

    sigma_image = get("defaults", "sigma_image", defaults.sigma_image)
    if isinstance(sigma_image, bool) or not isinstance(sigma_image, (int, float)) or not (
        math.isfinite(sigma_image) and sigma_image > 0
    ):
        raise fail("defaults", "sigma_image", f"{sigma_image!r} is not a positive number (plate units)")
    if not limits.SIGMA_MIN <= sigma_image <= limits.SIGMA_MAX:
        raise fail("defaults", "sigma_image", f"{sigma_image!r} is outside the plausible range "
                                              f"[{limits.number_text(limits.SIGMA_MIN)}, {limits.number_text(limits.SIGMA_MAX)}] of a standard deviation")
    max_iterations = get("adjustment", "max_iterations", defaults.max_iterations)
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise fail("adjustment", "max_iterations", f"{max_iterations!r} is not a positive integer")
    cost_tolerance = get("adjustment", "cost_tolerance", defaults.cost_tolerance)
    if isinstance(cost_tolerance, bool) or not isinstance(cost_tolerance, (int, float)) or not (
        math.isfinite(cost_tolerance) and 0 <= cost_tolerance < 1
    ):
        raise fail("adjustment", "cost_tolerance", f"{cost_tolerance!r} is not a number in [0, 1)")
    switches = {key: get("corrections", key, getattr(defaults, key)) for key in ("earth_curvature", "refraction")}
    for key, value in switches.items():
        if not isinstance(value, bool):
            raise fail("corrections", key, f"{value!r} is not true or false")
    earth_radius = get("corrections", "earth_radius", defaults.earth_radius)
    low, high = EARTH_RADIUS_RANGE_M
    if isinstance(earth_radius, bool) or not isinstance(earth_radius, (int, float)) or not low <= earth_radius <= high:
        raise fail("corrections", "earth_radius", f"{earth_radius!r} is not a radius of the Earth in metres "
                                                  f"(accepted: {low:.0f} to {high:.0f})")
    datum = choice("datum", "mode", DATUMS, defaults.datum)
    datum_points = get("datum", "points", [])
    if not isinstance(datum_points, list) or not all(isinstance(p, str) for p in datum_points):
        raise fail("datum", "points", f"{datum_points!r} is not a list of point ids (strings)")
    if datum_points and datum != "inner-points":
        raise fail("datum", "points", "datum points are for mode = \"inner-points\" (the point datum)")
    if datum_points and len(datum_points) < 3:
        raise fail("datum", "points", f"{len(datum_points)} datum point(s): the point datum needs at least three")
    if len(set(datum_points)) != len(datum_points):
        raise fail("datum", "points", "a point is given twice")
    coordinates = None
    if "coordinates" in data:
        coordinates = parse_coordinates(data["coordinates"], path.parent, lambda key, reason: fail("coordinates", key, reason),
                                        _toml_section_line(text, "coordinates"))
    if coordinates is not None and switches["earth_curvature"]:
        raise fail("corrections", "earth_curvature", "true with [coordinates] crs: the project is adjusted in a local "
                   "Cartesian frame, where the Earth's curvature is in the coordinates themselves; the correction "
                   "would count it twice (docs/decisions.md)")
    return model.ProjectSettings(
        earth_curvature=switches["earth_curvature"],
        refraction=switches["refraction"],
        earth_radius=float(earth_radius),
        coordinates=coordinates,
        angle_unit=choice("units", "angles", model.ANGLE_UNITS, defaults.angle_unit),
        rotation=choice("units", "rotation", model.ROTATION_CONVENTIONS, defaults.rotation),
        sigma_image=float(sigma_image),
        method=choice("adjustment", "method", METHODS, defaults.method),
        solver=choice("adjustment", "solver", model.SOLVERS, defaults.solver),
        max_iterations=max_iterations,
        datum=datum,
        datum_points=tuple(datum_points),
        cost_tolerance=float(cost_tolerance),
        plate_unit=choice("units", "plate", model.PLATE_UNITS, defaults.plate_unit,
                          " (the unit of c and of the plate coordinates: mm of the film or sensor, px for the "
                          "pixels of the image)"),
    )


def _check_datum_points(files, settings: model.ProjectSettings, points: model.ObjectPoints) -> None:
    """[datum] points must name object points of the project (InputError at the key's line)."""
    known = set(map(str, points.ids))
    unknown = [p for p in settings.datum_points if p not in known]
    if unknown:
        path = files.path("project.toml")
        text = decode_text(path, files.content("project.toml"))
        raise InputError(path, toml_line(text, "datum", "points"),
                         f"[datum] points: {', '.join(unknown)} not among the object points of the project")


def _parse_toml(path: Path, text: str) -> dict:
    """tomllib.loads with its error turned into an InputError (line taken from the message)."""
    if tomllib is None:  # pragma: no cover
        raise InputError(path, None, "reading project.toml needs Python >= 3.11 or the 'tomli' package")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise InputError(path, int(match.group(1)) if match else None, f"not valid TOML: {exc}") from None


def _check_toml_keys(path: Path, text: str, data: dict) -> None:
    """Only the sections and keys of TOML_KEYS are allowed (a misspelt key must not be ignored)."""
    for section, table in data.items():
        if section not in TOML_KEYS:
            known = ", ".join(f"[{s}]" for s in TOML_KEYS)
            reason = f"unknown section [{section}] (known: {known})"
            raise InputError(path, _toml_section_line(text, section), reason)
        if not isinstance(table, dict):
            raise InputError(path, toml_line(text, "", section), f"'{section}' must be a section [{section}]")
        for key in table:
            if key not in TOML_KEYS[section]:
                known = ", ".join(TOML_KEYS[section])
                raise InputError(
                    path, toml_line(text, section, key), f"unknown key '{key}' in [{section}] (known: {known})"
                )


def _toml_section_line(text: str, section: str) -> int | None:
    """Line of the header [section], or None."""
    for number, line in enumerate(text.splitlines(), start=1):
        if re.match(rf"\s*\[\s*{re.escape(section)}\s*\]", line):
            return number
    return None


# ---------------------------------------------------------------------------------------------
# cameras.csv
