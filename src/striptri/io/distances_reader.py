"""distances.csv: observed distances between object points (scale bars, taped distances), for
the methods conditions and bundle (striptri.equations.joint_groups, striptri.bundle.distances;
docs/file-formats.md).

Columns point_from, point_to (point ids of image_points.csv or control.csv), distance (m, > 0),
sigma (m, > 0: a distance is always an observation; a very small sigma nearly enforces it).
"""

from __future__ import annotations

import numpy as np

from striptri import model
from striptri.io import plausibility as limits
from striptri.model import Distances
from striptri.io.csvtable import CsvTable

FILE_NAME = "distances.csv"


def read_distances(table: CsvTable, points: model.ObjectPoints) -> Distances:
    """The rows of distances.csv (module doc); InputError naming the line and the reason for an
    unknown point, a distance from a point to itself, a repeated pair, a distance or sigma not
    positive."""
    table.require("point_from", "point_to", "distance", "sigma")
    point_of = {pid: k for k, pid in enumerate(points.ids)}
    index = table.id_indices(("point_from", "point_to"), point_of, "image_points.csv or control.csv")
    first_line: dict[tuple[int, int], int] = {}
    for i, (a, b) in enumerate(zip(index["point_from"], index["point_to"])):
        if a == b:
            raise table.error(i, "point_from and point_to are the same point")
        key = (int(min(a, b)), int(max(a, b)))
        if key in first_line:
            raise table.error(i, f"duplicate distance between these two points (first on line {first_line[key]})")
        first_line[key] = table.lines[i]
    distance = table.floats("distance")
    for i in np.flatnonzero(~(distance > 0)):
        raise table.error(i, f"column 'distance': a distance must be positive (got {table.text(i, 'distance')})")
    for i in np.flatnonzero(distance > limits.GROUND_LIMIT_M):
        raise table.error(i, f"column 'distance': {table.text(i, 'distance')} m is beyond the plausible "
                             f"{limits.number_text(limits.GROUND_LIMIT_M)} m")
    sigma = table.floats("sigma")
    for i in np.flatnonzero(~(sigma > 0)):
        raise table.error(i, "column 'sigma': a distance's standard deviation must be positive "
                             f"(got {table.text(i, 'sigma')}); give a small one to nearly enforce it")
    i = limits.first_sigma_out_of_range(sigma)
    if i is not None:
        raise table.error(i, f"column 'sigma': a standard deviation of {table.text(i, 'sigma')} is outside the "
                             f"plausible range [{limits.number_text(limits.SIGMA_MIN)}, "
                             f"{limits.number_text(limits.SIGMA_MAX)}]")
    return Distances(index["point_from"], index["point_to"], distance, sigma, np.asarray(table.lines))
