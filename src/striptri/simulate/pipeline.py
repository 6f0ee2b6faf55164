"""One call from options and a seed to a project and its truth tables (what ``striptri simulate`` runs)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from striptri import model
from striptri.geometry.rotations import opk_from_R
from striptri.simulate.design import PAIR_LAYOUTS, SCHMID_FIG8, SyntheticDesign
from striptri.simulate.gnss import GnssOptions, add_gnss, gnss_truth_tables
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.truth import Truth, make_truth

KINDS = ("pair", "strip", "block")


@dataclass(frozen=True)
class SimulateOptions:
    design: SyntheticDesign = field(default_factory=SyntheticDesign)
    noise: NoiseOptions = field(default_factory=NoiseOptions)
    gnss: GnssOptions | None = None  # a GNSS-supported block (simulate.gnss); None: plain


def simulate_project(
    kind: str, options: SimulateOptions, seed: int | None
) -> tuple[model.Project, dict[str, dict[str, Sequence]]]:
    """Simulate a ``kind`` ("pair", "strip" or "block") project. -> (project, truth tables).
    A pair and a strip are one strip; a block has two strips or more.

    The seed feeds independent streams (numpy SeedSequence.spawn): one for the truth, one for the
    noise, so that the same seed with other noise options gives the same true flight.
    truth tables: file name -> columns, for io.project_writer.write_project (see truth_tables).
    """
    project, tables, _ = simulate_with_truth(kind, options, seed)
    return project, tables


def simulate_with_truth(
    kind: str, options: SimulateOptions, seed: int | None
) -> tuple[model.Project, dict[str, dict[str, Sequence]], Truth]:
    """simulate_project, and the Truth it was made from (for rendering its photos)."""
    _check_kind(kind, options.design)
    # a third stream for the GNSS block (spawn(3)[:2] are spawn(2)'s streams: the same flight and noise)
    streams = np.random.SeedSequence(seed).spawn(2 if options.gnss is None else 3)
    truth = make_truth(options.design, np.random.default_rng(streams[0]))
    project = perturb(truth, options.noise, np.random.default_rng(streams[1]))
    tables = truth_tables(truth)
    if options.gnss is not None:
        project, gnss_truth = add_gnss(project, truth, options.gnss, np.random.default_rng(streams[2]))
        tables.update(gnss_truth_tables(gnss_truth, project.cameras.ids))
    return project, tables, truth


def images_rng(seed: int | None) -> np.random.Generator:
    """The fourth stream of the seed: the rendered images' texture and noise (simulate.render),
    independent of the truth, the noise and GNSS."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[3])


def truth_tables(truth: Truth) -> dict[str, dict[str, Sequence]]:
    """photos.csv: photo_id, X0, Y0, Z0, omega, phi, kappa (degrees);
    points.csv: point_id, kind (tie, Z, XY, XYZ, check), X, Y, Z."""
    opk = np.degrees(opk_from_R(truth.R_ground_from_cam))
    photos = {"photo_id": list(truth.photo_ids)}
    photos.update({name: truth.xyz0[:, j] for j, name in enumerate(("X0", "Y0", "Z0"))})
    photos.update({name: opk[:, j] for j, name in enumerate(("omega", "phi", "kappa"))})
    points = {"point_id": list(truth.point_ids), "kind": [model.KIND_NAMES[int(k)] for k in truth.kind]}
    points.update({name: truth.xyz_ground[:, j] for j, name in enumerate("XYZ")})
    return {"photos.csv": photos, "points.csv": points}


def _check_kind(kind: str, design: SyntheticDesign) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r} (one of {', '.join(KINDS)})")
    n, n_strips, layout = design.flight.n_photos, design.flight.n_strips, design.control.layout
    if kind == "pair" and n != 2:
        raise ValueError(f"a pair has 2 photos, not {n}")
    if kind in ("pair", "strip") and n_strips != 1:
        raise ValueError(f"a {kind} is one strip, not {n_strips}; simulate a block")
    if kind == "block" and n_strips < 2:
        raise ValueError(f"a block has 2 strips or more, not {n_strips}")
    if kind != "pair" and layout in PAIR_LAYOUTS:
        raise ValueError(f"control layout {layout!r} is for a pair")
    if kind != "strip" and layout == SCHMID_FIG8:
        raise ValueError(f"control layout {layout!r} is Schmid's strip: simulate a strip")
