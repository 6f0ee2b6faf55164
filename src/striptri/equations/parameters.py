"""The unknowns: current estimates, their columns in the normal matrix, and the update.

Columns: per photo, in photo order, the corrections (dX0, dY0, dZ0, d1, d2, d3) where d is the
rotation vector of ``R <- R Exp(d)`` (DESIGN section 1); then per camera (c, xp, yp), last.
A column of -1 is an element held fixed. Two elements may share a column: a base component
enforced exactly (Schmid 24) makes ``dO[to, axis]`` the same unknown as ``dO[from, axis]``.

When only some of a photo's angles are held fixed, the photo's rotation unknowns are the
corrections of its free angles, carried to the rotation vector by ``T = J^-1[:, free]``
(J the angle Jacobian of rotations.angles_jacobian), and the fixed angles are restored exactly
after each update.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .gnss_unknowns import GROUPS as GNSS_GROUPS, GnssColumns, GnssState, gnss_columns, initial_gnss_state
from ..geometry.lens import CAMERA_ELEMENTS, NCP, PLATE, has_distortion
from ..model import FREE, HELD, Project
from ..geometry.rotations import R_from_angles, angles_from_R, angles_jacobian, exp_so3

ELEMENT_NAMES = ("X0", "Y0", "Z0", "rot1", "rot2", "rot3")


@dataclass(frozen=True)
class State:
    """Current estimates: R_ground_from_cam (n, 3, 3) the rotation of each photo from its camera
    frame to the ground frame; xyz0 (n, 3) its projection centre in the reduced ground frame (ground
    minus ``offset``); interior (ncam, NCP) the camera elements."""

    R_ground_from_cam: np.ndarray
    xyz0: np.ndarray
    interior: np.ndarray  # (ncam, NCP) lens.CAMERA_ELEMENTS
    camera_of_photo: np.ndarray
    convention: np.ndarray | None = None  # (ncam,) lens.PLATE / lens.IMAGE (None: all PLATE)
    gnss: GnssState | None = None  # lever arms, boresights, shifts, drifts (None: not in the model)

    def __post_init__(self):
        if self.convention is None:
            object.__setattr__(self, "convention", np.full(len(self.interior), PLATE, dtype=int))

    def camera_terms(self, photo_index: np.ndarray):
        """Camera elements (..., NCP) and conventions (...,) of the photos photo_index (...)."""
        cam = self.camera_of_photo[photo_index]
        return self.interior[cam], self.convention[cam]

    def updated(self, layout: "UnknownLayout", dx: np.ndarray) -> "State":
        """Apply a correction vector (DESIGN section 4: x <- x (+) dx)."""
        dxp = np.concatenate([dx, [0.0]])  # column -1 reads a zero
        d_photo = dxp[layout.photo_cols]  # (n, 6)
        xyz0 = self.xyz0 + d_photo[:, :3]
        T = layout.rotation_maps(self)
        d_rot = np.einsum("nij,nj->ni", T, d_photo[:, 3:])
        R = self.R_ground_from_cam @ exp_so3(d_rot)
        R = layout.restore_fixed_angles(R)
        interior = self.interior + dxp[layout.camera_cols]
        gnss = self.gnss.updated(layout.gnss_cols, dxp) if self.gnss is not None else None
        return State(R_ground_from_cam=R, xyz0=xyz0, interior=interior, camera_of_photo=self.camera_of_photo,
                     convention=self.convention, gnss=gnss)


@dataclass(frozen=True)
class UnknownLayout:
    photo_cols: np.ndarray  # (n, 6) int, -1 = fixed
    camera_cols: np.ndarray  # (ncam, NCP) int, -1 = fixed
    n_unknowns: int
    convention: str
    angle_fixed: np.ndarray  # (n, 3) bool
    fixed_angles: np.ndarray  # (n, 3) radians (used where angle_fixed)
    gnss_cols: GnssColumns | None = None  # after the camera columns (striptri.equations.gnss_unknowns)

    def _column_sets(self) -> list:
        """Rows of columns of every photo, camera and GNSS element set, in column order."""
        extra = self.gnss_cols.blocks() if self.gnss_cols is not None else []
        return list(self.photo_cols) + list(self.camera_cols) + extra

    @property
    def camera_elements(self) -> np.ndarray:
        """Indices (lens.CAMERA_ELEMENTS) of the camera elements estimated in some camera: the
        camera columns each ray carries in the linearised equations."""
        return np.flatnonzero((self.camera_cols >= 0).any(axis=0))

    @property
    def camera_width(self) -> int:
        """Camera columns per ray in the linearised equations (0: cameras held, the rays carry only
        their photo's 6 columns)."""
        return len(self.camera_elements)

    def lens_in_play(self, state: "State") -> bool:
        """True when some additional parameter (k, p, b) is nonzero or estimated."""
        return has_distortion(state.interior, self.camera_cols >= 0)

    @property
    def partial_rotation(self) -> np.ndarray:
        """Photos whose rotation is neither all free nor all fixed."""
        nfix = self.angle_fixed.sum(axis=1)
        return (nfix > 0) & (nfix < 3)

    def rotation_maps(self, state: State) -> np.ndarray:
        """T (n, 3, 3): rotation vector = T @ (rotation unknowns of the photo)."""
        n = len(self.photo_cols)
        T = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        part = self.partial_rotation
        if part.any():
            Jinv = np.linalg.inv(angles_jacobian(state.R_ground_from_cam[part], self.convention))
            Jinv[np.broadcast_to(self.angle_fixed[part][:, None, :], Jinv.shape)] = 0.0
            T[part] = Jinv
        return T

    def restore_fixed_angles(self, R: np.ndarray) -> np.ndarray:
        part = self.partial_rotation
        if not part.any():
            return R
        R = R.copy()
        angles = angles_from_R(R[part], self.convention)
        fixed = self.angle_fixed[part]
        angles[fixed] = self.fixed_angles[part][fixed]
        R[part] = R_from_angles(angles, self.convention)
        return R

    def _new_column_sets(self) -> tuple[np.ndarray, np.ndarray]:
        """(the element sets of _column_sets that bring new columns, the first new column of each):
        a set's new columns are those beyond every column of the sets before it (a column shared by
        an enforced base component belongs to the photo that brought it). Vectorised over the sets
        (one row each, padded with -1)."""
        sets = self._column_sets()
        if not sets:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        width = max(len(c) for c in sets)
        cols = np.full((len(sets), width), -1, dtype=np.int64)
        photo = np.asarray(self.photo_cols, dtype=np.int64).reshape(len(self.photo_cols), -1)
        cols[:len(photo), :photo.shape[1]] = photo
        for i, c in enumerate(sets[len(photo):], start=len(photo)):  # cameras and GNSS: a few sets
            cols[i, :len(c)] = c
        before = np.maximum.accumulate(np.concatenate([[-1], cols.max(axis=1)[:-1]]))  # the largest column so far
        new = cols > before[:, None]
        has = new.any(axis=1)
        first = np.where(new, cols, np.iinfo(np.int64).max).min(axis=1)
        return np.flatnonzero(has), first[has].astype(int)

    def block_starts(self) -> np.ndarray:
        """First column of each photo's block of new columns, then of each camera's (columns are
        numbered photo by photo, cameras last, so every block is a contiguous range)."""
        return self._new_column_sets()[1]

    def block_groups(self, strip_ids) -> np.ndarray:
        """For each block of :meth:`block_starts`, the index of its photo's strip (the strips
        numbered in order of first appearance), -1 for a camera block. ``strip_ids``: (n_photos,)
        strings; photos with an empty strip id form no strip (-1 as well): the solvers then group
        them by themselves (solvers.strips)."""
        ids = np.asarray(list(strip_ids), dtype=object)
        photo_of_block = self._new_column_sets()[0]
        n = len(self.photo_cols)
        groups = np.full(len(photo_of_block), -1, dtype=int)
        is_photo = photo_of_block < n
        if len(ids) == n and is_photo.any():
            names = ids[photo_of_block[is_photo]].astype(str)
            _, first, inverse = np.unique(names, return_index=True, return_inverse=True)
            rank = np.empty(len(first), dtype=int)
            rank[np.argsort(first)] = np.arange(len(first))  # strips in order of first appearance
            g = rank[inverse]
            g[names == ""] = -1
            groups[is_photo] = g
        return groups

    def column_labels(self, photo_ids, camera_ids) -> list[str]:
        labels = [""] * self.n_unknowns
        for i, pid in enumerate(photo_ids):
            for e, col in enumerate(self.photo_cols[i]):
                if col >= 0 and not labels[col]:
                    labels[col] = f"photo {pid} {ELEMENT_NAMES[e]}"
        for i, cid in enumerate(camera_ids):
            for e, col in enumerate(self.camera_cols[i]):
                if col >= 0:
                    labels[col] = f"camera {cid} {CAMERA_ELEMENTS[e]}"
        if self.gnss_cols is not None:
            for name in GNSS_GROUPS:
                for k, row in enumerate(self.gnss_cols.group(name)):
                    for a, col in enumerate(row):
                        if col >= 0:
                            labels[col] = f"{name} {k} {'xyz'[a]}"
        return labels


def _enforced_base_aliases(project: Project) -> np.ndarray:
    """For each photo element (n, 3) of the centre, the (photo, axis) it is tied to: the smallest
    element index ``3 photo + axis`` of its group of elements joined by enforced base components
    (the connected components of that graph)."""
    n = len(project.photos)
    b = project.bases
    enforced = ~(b.sigma > 0)
    nodes = np.arange(3 * n)
    if not enforced.any():
        return nodes.reshape(n, 3)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = 3 * np.asarray(b.photo_from[enforced]) + b.axis[enforced]
    c = 3 * np.asarray(b.photo_to[enforced]) + b.axis[enforced]
    graph = coo_matrix((np.ones(len(a)), (a, c)), shape=(3 * n, 3 * n))
    _, label = connected_components(graph, directed=False)
    root = np.full(label.max() + 1, 3 * n)
    np.minimum.at(root, label, nodes)
    return root[label].reshape(n, 3)


def apply_enforced_bases(project: Project, xyz0: np.ndarray) -> np.ndarray:
    """Make the approximate centres satisfy the enforced base components exactly (Schmid 24)."""
    xyz0 = xyz0.copy()
    b = project.bases
    enforced = ~(b.sigma > 0)
    # propagate along the listed order; repeated so that chains given in any order settle
    for _ in range(max(1, int(enforced.sum()))):
        for f, t, ax, val in zip(b.photo_from[enforced], b.photo_to[enforced], b.axis[enforced], b.value[enforced]):
            xyz0[t, ax] = xyz0[f, ax] + val
    return xyz0


def build_layout(project: Project) -> UnknownLayout:
    """Columns of the unknowns, from the fixed/free/observed flags of the project."""
    photos, cams = project.photos, project.cameras
    n = len(photos)
    fixed_pos = photos.centre_state == HELD
    fixed_ang = photos.angle_state == HELD
    alias = _enforced_base_aliases(project)  # (n, 3) root element index 3*photo + axis
    # columns in the order of the photos, each photo's centre (a group of tied elements takes the
    # column of its first element; fixed when any member is fixed) then its free angles
    centre = ~np.isin(alias, alias[fixed_pos])
    angle = ~fixed_ang & ~fixed_ang.all(axis=1, keepdims=True)
    first = np.zeros(3 * n, dtype=bool)
    roots, where = np.unique(np.where(centre, alias, -1).ravel(), return_index=True)
    first[where[roots >= 0]] = True
    new = np.concatenate([first.reshape(n, 3), angle], axis=1)  # (n, 6) the elements that open a column
    cols = np.cumsum(new.ravel()).reshape(n, 6) - 1
    photo_cols = np.where(new, cols, -1)
    root_col = np.full(3 * n, -1)
    root_col[alias.ravel()[first]] = cols[:, :3].ravel()[first]
    photo_cols[:, :3] = np.where(centre, root_col[alias], -1)
    col = int(new.sum())
    free_or_observed = cams.interior_state != HELD
    camera_cols = np.where(free_or_observed, col + np.cumsum(free_or_observed.ravel()).reshape(free_or_observed.shape)
                           - 1, -1)
    col += int(free_or_observed.sum())
    gnss_cols = None
    if uses_gnss(project):
        gnss_cols, col = gnss_columns(project.gnss, col)
    return UnknownLayout(
        photo_cols=photo_cols,
        camera_cols=camera_cols,
        n_unknowns=col,
        convention=project.settings.rotation,
        angle_fixed=fixed_ang,
        fixed_angles=photos.angles.copy(),
        gnss_cols=gnss_cols,
    )


def uses_gnss(project: Project) -> bool:
    """True when the project's GNSS model (lever arm, boresight, shift, drift) is in play."""
    return project.gnss is not None and project.gnss.in_play


def reduction_offset(project: Project) -> np.ndarray:
    """A round offset near the middle of the project, subtracted from every ground coordinate
    internally so that national-grid coordinates (~1e6 m) cost no precision."""
    pts = [project.photos.xyz0]
    given = project.points.xyz_given
    if np.isfinite(given).any():
        pts.append(np.where(np.isfinite(given), given, np.nan))
    allp = np.concatenate(pts, axis=0)
    centre = np.nanmean(allp, axis=0)
    centre = np.where(np.isfinite(centre), centre, 0.0)
    return np.round(centre, -3)


def initial_state(project: Project, offset: np.ndarray) -> State:
    xyz0 = apply_enforced_bases(project, project.photos.xyz0 - offset)
    return State(
        R_ground_from_cam=project.photos.R_ground_from_cam.copy(),
        xyz0=xyz0,
        interior=project.cameras.interior.copy(),
        camera_of_photo=project.photos.camera_index.copy(),
        convention=project.cameras.convention.copy(),
        gnss=initial_gnss_state(project.gnss) if uses_gnss(project) else None,
    )


def with_state(project: Project, state: State, offset: np.ndarray) -> Project:
    """The project with an adjusted state as its approximate values, so that a re-adjustment takes
    few iterations: the free projection centres, every rotation (``R_ground_from_cam`` is only the
    approximation; observed and fixed angles live in ``photos.angles``, which stays) and the free
    camera elements. Observed elements (GNSS centres, observed camera elements) keep their observed
    values and fixed ones their given values, so the adjusted values never become observations."""
    ph, cams = project.photos, project.cameras
    xyz0 = np.where(ph.centre_state == FREE, state.xyz0 + offset, ph.xyz0)
    interior = np.where(cams.interior_state == FREE, state.interior, cams.interior)
    return replace(project, photos=replace(ph, xyz0=xyz0, R_ground_from_cam=state.R_ground_from_cam.copy()),
                   cameras=replace(cams, interior=interior))
