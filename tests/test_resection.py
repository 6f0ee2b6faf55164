"""Spatial resection (striptri.equations.resection): exact orientations from exact plates, for coplanar
points (calibration sheet, homography start) and points in general position (DLT start), in
any attitude, with the centre far from the origin."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from striptri.geometry.camera import project
from striptri.equations.resection import resect


def _case(rng, planar: bool, n: int):
    R = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
    centre = np.array([1000.0, -2000.0, 300.0])
    # points 20-40 m in front of the camera (along -z of the camera frame), within a 60 deg cone
    d = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), -np.ones(n)]) * rng.uniform(20, 40, (n, 1))
    if planar:  # a plane through the points, oblique to the view
        normal = np.array([0.3, -0.2, 1.0])
        d[:, 2] = -(30.0 + d[:, :2] @ normal[:2]) / normal[2]
    X = centre + d @ R.T
    xy = project(R, centre, np.array([24.0, 0.0, 0.0]), X)
    return R, centre, X, xy


@pytest.mark.parametrize("planar,n", [(True, 4), (True, 12), (False, 6), (False, 15)])
def test_resection_recovers_exact_orientation(planar, n):
    rng = np.random.default_rng(11 + n)
    for _ in range(5):
        R, centre, X, xy = _case(rng, planar, n)
        res = resect(xy, X, 24.0)
        np.testing.assert_allclose(res.centre, centre, atol=1e-7)
        np.testing.assert_allclose(res.R, R, atol=1e-10)
        assert res.rms < 1e-9


def test_resection_refuses_too_few_points():
    rng = np.random.default_rng(1)
    _, _, X, xy = _case(rng, False, 5)
    with pytest.raises(ValueError, match="six"):
        resect(xy, X, 24.0)
    with pytest.raises(ValueError, match="four"):
        resect(xy[:3], X[:3], 24.0)
