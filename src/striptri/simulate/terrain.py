"""A smooth random terrain surface Z(X, Y): a mean height plus a few plane sine waves."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from striptri.simulate.design import TerrainDesign


@dataclass(frozen=True)
class Terrain:
    """``Z = mean_z + sum_k amplitude_k sin(wave_vector_k . (X, Y) + phase_k)``.
    amplitude: (k,) m, with sum = relief; wave_vector: (k, 2) rad/m; phase: (k,) rad."""

    mean_z: float
    amplitude: np.ndarray
    wave_vector: np.ndarray
    phase: np.ndarray

    def z(self, xy_ground: np.ndarray) -> np.ndarray:
        """Terrain height at ground points. xy_ground: (..., 2) m -> (...,) m."""
        arg = np.asarray(xy_ground, dtype=float) @ self.wave_vector.T + self.phase
        return self.mean_z + np.sin(arg) @ self.amplitude


def make_terrain(design: TerrainDesign, footprint: float, rng: np.random.Generator) -> Terrain:
    """Random terrain for a flight whose photos cover ``footprint`` metres on the ground."""
    k = design.n_waves
    weights = rng.uniform(0.2, 1.0, k)
    amplitude = design.relief * weights / weights.sum()
    lo, hi = design.wavelength_range
    wavelength = footprint * rng.uniform(lo, hi, k)
    direction = rng.uniform(0.0, 2.0 * np.pi, k)
    wave_vector = (2.0 * np.pi / wavelength)[:, None] * np.stack([np.cos(direction), np.sin(direction)], -1)
    phase = rng.uniform(0.0, 2.0 * np.pi, k)
    return Terrain(float(design.mean_z), amplitude, wave_vector, phase)
