"""Synthetic photogrammetric projects: truth apart from noise (cf. COLMAP's SyntheticDatasetOptions /
SyntheticNoiseOptions).

* :mod:`.design` -- what to fly: camera, flight line, terrain, pass points, control layout;
* :mod:`.truth` -- ``make_truth(design, rng)``: true photos, points and exact plate coordinates;
* :mod:`.noise` -- ``perturb(truth, noise, rng)``: the :class:`striptri.model.Project` an
  adjustment is given;
* :mod:`.pipeline` -- ``simulate_project(kind, options, seed)`` and the truth tables.
"""

from striptri.simulate.design import (
    LAYOUTS,
    PAIR_LAYOUTS,
    STRIP_LAYOUTS,
    CameraDesign,
    ControlDesign,
    FlightDesign,
    PointDesign,
    SyntheticDesign,
    TerrainDesign,
)
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.pipeline import KINDS, SimulateOptions, simulate_project, truth_tables
from striptri.simulate.terrain import Terrain
from striptri.simulate.truth import Truth, make_truth

__all__ = [
    "KINDS",
    "LAYOUTS",
    "PAIR_LAYOUTS",
    "STRIP_LAYOUTS",
    "CameraDesign",
    "ControlDesign",
    "FlightDesign",
    "NoiseOptions",
    "PointDesign",
    "SimulateOptions",
    "SyntheticDesign",
    "Terrain",
    "TerrainDesign",
    "Truth",
    "make_truth",
    "perturb",
    "simulate_project",
    "truth_tables",
]
