"""A strip for the tests of observed distances (test_bundle_distances, test_conditions_distances)."""

from __future__ import annotations

import numpy as np

from striptri import simulate as sim


def strip_with_truth(sigma_image, seed=3, n_photos=5):
    """A simulated strip (control at the ends, 2 extra ties per model, approximations 1 m and 0.1
    deg off) -> (project, indices of the points with two or more rays, true coordinates (n_pt, 3)
    in the project's point order)."""
    design = sim.SyntheticDesign(flight=sim.FlightDesign(n_photos=n_photos), control=sim.ControlDesign(layout="ends"),
                                 points=sim.PointDesign(extra_ties_per_model=2))
    truth = sim.make_truth(design, np.random.default_rng(seed))
    project = sim.perturb(truth, sim.NoiseOptions(sigma_image=sigma_image, approx_position_error=1.0,
                                                  approx_angle_error=0.1), np.random.default_rng(seed + 1))
    rays = np.bincount(project.image_points.point_index, minlength=len(project.points))
    usable = np.flatnonzero(rays >= 2)
    true_xyz = np.array([truth.xyz_ground[truth.point_ids.index(pid)] for pid in project.points.ids])
    return project, usable, true_xyz
