"""The columns of the unknowns (equations.parameters.build_layout), vectorised, against the element
by element assignment they replaced: photo by photo, its centre (a group of elements tied by
enforced base components takes the column of its first element, and is fixed when any member is)
then its free angles (none when all three are held), then each camera's free or observed elements."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from striptri.equations.parameters import _enforced_base_aliases, build_layout
from striptri.geometry.lens import NCP
from striptri.model import FREE, HELD, BaseComponents


def _reference_aliases(n, bases):
    parent = list(range(3 * n))

    def find(a):
        while parent[a] != a:
            a = parent[a]
        return a

    enforced = ~(bases.sigma > 0)
    for f, t, ax in zip(bases.photo_from[enforced], bases.photo_to[enforced], bases.axis[enforced]):
        ra, rb = find(3 * f + ax), find(3 * t + ax)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.array([find(a) for a in range(3 * n)]).reshape(n, 3)


def _reference_columns(alias, fixed_pos, fixed_ang, free_camera):
    n = len(alias)
    photo_cols = -np.ones((n, 6), dtype=int)
    root_col, fixed_roots, col = {}, set(alias[fixed_pos].tolist()), 0
    for i in range(n):
        for ax in range(3):
            root = int(alias[i, ax])
            if root in fixed_roots:
                continue
            if root not in root_col:
                root_col[root] = col
                col += 1
            photo_cols[i, ax] = root_col[root]
        for a in range(3):
            if not fixed_ang[i].all() and not fixed_ang[i, a]:
                photo_cols[i, 3 + a] = col
                col += 1
    camera_cols = -np.ones(free_camera.shape, dtype=int)
    for j, e in zip(*np.nonzero(free_camera)):
        camera_cols[j, e] = col
        col += 1
    return photo_cols, camera_cols, col


class _Sized(SimpleNamespace):
    def __len__(self):
        return self.n


@pytest.mark.parametrize("seed", range(40))
def test_the_columns_equal_the_element_by_element_assignment(seed):
    rng = np.random.default_rng(seed)
    n, n_cam = int(rng.integers(1, 60)), int(rng.integers(1, 4))
    nb = int(rng.integers(0, 3 * n))
    bases = BaseComponents(photo_from=rng.integers(0, n, nb), photo_to=rng.integers(0, n, nb),
                           axis=rng.integers(0, 3, nb), value=np.zeros(nb),
                           sigma=np.where(rng.random(nb) < 0.7, 0.0, 0.1))  # sigma 0: enforced
    centre = np.where(rng.random((n, 3)) < 0.2, HELD, FREE)
    angle = np.where(rng.random((n, 3)) < 0.2, HELD, FREE)
    angle[rng.integers(0, n)] = HELD  # one photo with all its angles held
    interior = np.where(rng.random((n_cam, NCP)) < 0.3, FREE, HELD)
    project = SimpleNamespace(
        photos=_Sized(n=n, centre_state=centre, angle_state=angle, angles=np.zeros((n, 3))),
        cameras=_Sized(n=n_cam, interior_state=interior), bases=bases, gnss=None,
        settings=SimpleNamespace(rotation="opk"))
    alias = _enforced_base_aliases(project)
    np.testing.assert_array_equal(alias, _reference_aliases(n, bases))
    layout = build_layout(project)
    photo_cols, camera_cols, n_unknowns = _reference_columns(alias, centre == HELD, angle == HELD, interior != HELD)
    np.testing.assert_array_equal(layout.photo_cols, photo_cols)
    np.testing.assert_array_equal(layout.camera_cols, camera_cols)
    assert layout.n_unknowns == n_unknowns
