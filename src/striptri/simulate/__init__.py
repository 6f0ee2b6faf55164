"""Synthetic photogrammetric projects: truth apart from noise (cf. COLMAP's SyntheticDatasetOptions /
SyntheticNoiseOptions).

* :mod:`.design` -- what to fly: camera, strips (a block), terrain, pass points, control layout;
* :mod:`.control` -- control layouts on the grid of pass points of a strip or block;
* :mod:`.schmid_fig8` -- Schmid's worked strip of five photographs (BRL 961, Fig. 8);
* :mod:`.truth` -- ``make_truth(design, rng)``: true photos, points and exact plate coordinates;
* :mod:`.noise` -- ``perturb(truth, noise, rng)``: the :class:`striptri.model.Project` an
  adjustment is given;
* :mod:`.pipeline` -- ``simulate_project(kind, options, seed)`` and the truth tables.
* :mod:`.render` -- the photos rendered from a textured terrain (``striptri simulate ... --images``).
"""

from striptri.simulate.design import (
    BLOCK_LAYOUTS,
    LAYOUTS,
    PAIR_LAYOUTS,
    SCHMID_FIG8,
    STRIP_LAYOUTS,
    CameraDesign,
    ControlDesign,
    FlightDesign,
    PointDesign,
    SyntheticDesign,
    TerrainDesign,
)
from striptri.simulate.gnss import GnssOptions, add_gnss
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.pipeline import (
    KINDS, SimulateOptions, images_rng, simulate_project, simulate_with_truth, truth_tables,
)
from striptri.simulate.terrain import Terrain
from striptri.simulate.truth import Truth, make_truth

__all__ = [
    "GnssOptions",
    "add_gnss",
    "BLOCK_LAYOUTS",
    "KINDS",
    "LAYOUTS",
    "PAIR_LAYOUTS",
    "SCHMID_FIG8",
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
    "images_rng",
    "simulate_project",
    "simulate_with_truth",
    "truth_tables",
]
