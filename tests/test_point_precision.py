"""Schmid's (92) as written once (equations.point_precision.joint_form) against plain linear
error propagation of a random Gauss-Helmert model: the point X = G x^ + F l^ is linear in the
observations l, so Cov(X) = T Q T^T with T = dX/dl; no term of (92) may be missing or doubled."""

from __future__ import annotations

import numpy as np

from striptri.equations.point_precision import joint_form


def test_joint_form_equals_propagation_through_the_estimator():
    rng = np.random.default_rng(92)
    batch, c, u, o, r = 4, 7, 3, 12, 3  # groups, conditions, unknowns, observations, point coordinates
    terms = []
    expected = []
    for _ in range(batch):
        A = rng.normal(size=(c, o))
        B = rng.normal(size=(c, u))
        Q = rng.uniform(0.5, 2.0, o)  # cofactors of the observations
        G = rng.normal(size=(r, u))  # dX/dx
        F = rng.normal(size=(r, o))  # dX/dl
        M = (A * Q) @ A.T
        Mi = np.linalg.inv(M)
        Qxx = np.linalg.inv(B.T @ Mi @ B)
        # w = A l (+ const): x^ = -Qxx B^T M^-1 A l; v = -Q A^T M^-1 (A l + B x^); l^ = l + v
        dx_dl = -Qxx @ B.T @ Mi @ A
        dv_dl = -(Q[:, None] * A.T) @ Mi @ (A + B @ dx_dl)
        T = G @ dx_dl + F @ (np.eye(o) + dv_dl)
        expected.append(T @ (Q[:, None] * T.T))
        terms.append((G @ Qxx @ G.T, G @ Qxx @ B.T, B @ Qxx @ B.T, M, Mi, A * Q, Q, F))
    stacked = [np.stack(t) for t in zip(*terms)]
    got = joint_form(*stacked)
    np.testing.assert_allclose(got, np.stack(expected), rtol=1e-10, atol=1e-12 * np.abs(np.stack(expected)).max())
