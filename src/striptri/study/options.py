"""What a method-comparison study runs (DESIGN section 9): methods x configurations x trials.

A *configuration* is one synthetic strip: number of photos, control layout, plate noise. A *task* is
one (configuration, trial): one true strip and one noise realisation, adjusted by every method of the
study. Its seed comes from (study seed, configuration, trial) alone (numpy SeedSequence with a spawn
key), never from the worker or from the other configurations of the study, so that a study gives the
same numbers whatever runs it and a configuration gives the same trials in any study.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

# Method labels -> (method, procedure, direction) of AdjustmentOptions.
METHOD_SPECS = {
    "seq1-forward": ("sequential", 1, "forward"),
    "seq1-backward": ("sequential", 1, "backward"),
    "seq2-forward": ("sequential", 2, "forward"),
    "seq2-backward": ("sequential", 2, "backward"),
    "conditions": ("conditions", None, None),
    "bundle": ("bundle", None, None),
}
METHOD_LABELS = tuple(METHOD_SPECS)
SIMULTANEOUS = ("conditions", "bundle")
# cantilever: control only in the first model; ends: the first and the last model; every-k: ends plus
# full control at every k-th nadir in between (study.trial).
STUDY_LAYOUTS = ("cantilever", "ends", "every-k")


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


@dataclass(frozen=True)
class StudyOptions:
    """methods: labels of METHOD_SPECS. photos: strip lengths (photos per strip, >= 4). layouts: of
    STUDY_LAYOUTS. sigma_images: plate noise (plate units, mm; 0 = noise-free). trials: noise
    realisations per configuration. seed: the study seed. every_k: spacing of the every-k layout
    (nadirs). n_check: check points turned from tie points (besides the relabelled control of the
    cantilever layout). overlap: forward overlap."""

    methods: tuple[str, ...] = METHOD_LABELS
    photos: tuple[int, ...] = (4, 8, 16, 32)
    layouts: tuple[str, ...] = ("cantilever", "ends")
    sigma_images: tuple[float, ...] = (0.005,)
    trials: int = 10
    seed: int = 0
    every_k: int = 2
    n_check: int = 2
    overlap: float = 0.6

    def __post_init__(self):
        for name in ("methods", "photos", "layouts", "sigma_images"):
            object.__setattr__(self, name, tuple(dict.fromkeys(getattr(self, name))))
            _require(len(getattr(self, name)) > 0, f"study: {name} must not be empty")
        for m in self.methods:
            _require(m in METHOD_SPECS, f"study: unknown method {m!r} (one of {', '.join(METHOD_LABELS)})")
        for lay in self.layouts:
            _require(lay in STUDY_LAYOUTS, f"study: unknown layout {lay!r} (one of {', '.join(STUDY_LAYOUTS)})")
        _require(all(int(n) == n and 4 <= n <= 999 for n in self.photos), "study: strips of 4 to 999 photos")
        _require(all(s >= 0 for s in self.sigma_images), "study: sigma_image must be non-negative")
        _require(int(self.trials) == self.trials and self.trials >= 1, "study: at least one trial")
        _require(int(self.seed) == self.seed and self.seed >= 0, "study: the seed is a non-negative integer")
        _require(self.every_k >= 1 and self.n_check >= 0, "study: every_k >= 1 and n_check >= 0")


@dataclass(frozen=True)
class Task:
    """One (configuration, trial): all methods of the study on one simulated strip."""

    n_photos: int
    layout: str
    sigma_image: float
    trial: int
    seed: int  # the trial's own seed: simulate_project("strip", ..., seed) would draw the same strip
    methods: tuple[str, ...]
    every_k: int
    n_check: int
    overlap: float

    @property
    def key(self) -> tuple:
        return (self.layout, self.n_photos, self.sigma_image, self.trial)


def trial_seed(study_seed: int, n_photos: int, layout: str, sigma_image: float, trial: int) -> int:
    """The seed of one trial: SeedSequence(study_seed, spawn_key=(n, crc32(layout), sigma in nm, trial)),
    reduced to one 63-bit integer (written to study.csv)."""
    key = (int(n_photos), zlib.crc32(layout.encode()), int(round(sigma_image * 1e9)), int(trial))
    state = np.random.SeedSequence(int(study_seed), spawn_key=key).generate_state(2, dtype=np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1]))


def tasks_of(options: StudyOptions) -> list[Task]:
    """Every (configuration, trial) of the study, in a fixed order."""
    return [
        Task(n, layout, float(s), t, trial_seed(options.seed, n, layout, s, t), options.methods,
             options.every_k, options.n_check, options.overlap)
        for layout in options.layouts
        for n in options.photos
        for s in options.sigma_images
        for t in range(options.trials)
    ]
