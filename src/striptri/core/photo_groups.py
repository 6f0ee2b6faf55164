"""Photo groups without a datum of their own (core.diagnosis): photos that share no tie point with
the rest form a group, and a group needs its own control (or observed elements) to fix its seven
similarity elements."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..equations.datum import describe
from ..equations.groups import adjusted_kind
from ..model import FREE, FULL, HEIGHT, PLAN, Project, given_axes
from ..geometry.rotations import angles_jacobian
from .listing import LIST_MAX


# ------------------------------------------------------------------------------------- photo groups


@dataclass
class PhotoGroups:
    """Connected components of the photos over shared points (and enforced or observed base
    components): ``label`` (n_photos,) the group of every photo, groups numbered by their first
    photo; ``free`` per group the (7, d) coefficients of the similarity directions its own control
    and observed or fixed elements leave free (datum.describe's basis); ``project`` for the names."""

    label: np.ndarray
    free: list
    extent: float
    centroids: np.ndarray
    project: Project

    @property
    def count(self) -> int:
        return len(self.free)

    def lacking(self) -> list[int]:
        return [g for g, f in enumerate(self.free) if f.shape[1]]

    def explain(self) -> list[str]:
        """Words for groups that lack a datum (empty with one group, or when every group has one)."""
        if self.count < 2 or not self.lacking():
            return []
        ids = self.project.photos.ids
        lines = [f"the photos form {self.count} groups that share no points, and each group needs its own datum "
                 "(control, observed or fixed elements):"]
        shown = range(min(self.count, LIST_MAX))
        for g in shown:
            members = np.flatnonzero(self.label == g)
            names = ", ".join(ids[k] for k in members[:LIST_MAX]) + (
                f" and {len(members) - LIST_MAX} more" if len(members) > LIST_MAX else "")
            free = self.free[g]
            if free.shape[1] == 0:
                state = "its datum is fixed"
            elif free.shape[1] == 7:
                state = ("no datum: it has no control point and no observed or fixed element, so its position, "
                         "orientation and scale are free")
            else:
                words = describe(free, self.extent, self.centroids[g])
                state = "its control leaves free: " + "; ".join(words)
            lines.append(f"  - group {g + 1}: photo{'s' if len(members) > 1 else ''} {names} "
                         f"({len(members)} photo{'s' if len(members) > 1 else ''}): {state}")
        if self.count > LIST_MAX:
            rest = self.count - LIST_MAX
            lines.append(f"  - and {rest} more group{'s' if rest > 1 else ''}")
        lines.append("Connect the groups with tie points measured in photos of both, or give every group enough "
                     "control of its own (two full points and one height point not on a line), or adjust each group "
                     "as a project of its own.")
        return ["\n".join(lines)]


def photo_groups(project: Project) -> PhotoGroups:
    """The connected components of the photos (scipy.sparse.csgraph) over the points that link them
    (seen in two or more photos) and the base components (bases.csv), and the similarity directions
    each group's own datum leaves free: the rank of the rows that the control coordinates of its
    points and its observed or fixed elements put on the seven similarity coefficients."""
    ph, ip, pts = project.photos, project.image_points, project.points
    n, n_pt = len(ph), len(pts)
    rays = np.bincount(ip.point_index, minlength=n_pt)
    kinds = adjusted_kind(pts.kind)
    link = rays[ip.point_index] >= 2
    rows = np.concatenate([ip.photo_index[link], project.bases.photo_from])
    cols = np.concatenate([n + ip.point_index[link], project.bases.photo_to])
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + n_pt, n + n_pt))
    _, comp = connected_components(graph, directed=False)
    # renumber the groups of the photos by their first photo
    _, first, photo_label = np.unique(comp[:n], return_index=True, return_inverse=True)
    relabel = np.argsort(np.argsort(first))
    label = relabel[photo_label]
    n_groups = len(first)

    extent = max(float(np.ptp(ph.xyz0, axis=0).max()) if n else 1.0, 1.0)
    size = np.bincount(label, minlength=n_groups)
    centroids = np.stack([np.bincount(label, ph.xyz0[:, a], n_groups) for a in range(3)], 1) / size[:, None]
    H_rows, owner = _datum_rows(project, label, rays, kinds, extent, centroids)
    free = []
    for g in range(n_groups):
        M = H_rows[owner == g]
        if len(M) == 0:
            free.append(np.eye(7))
            continue
        M = M / np.linalg.norm(M, axis=1, keepdims=True)
        _, sv, Vt = np.linalg.svd(M, full_matrices=True)
        rank = int(np.sum(sv > 1e-6 * sv[0]))
        free.append(Vt[rank:].T)
    return PhotoGroups(label, free, extent, centroids, project)


def _similarity_rows(X: np.ndarray, extent: float) -> np.ndarray:
    """(m, 3, 7) the change of ground coordinates X (relative to their group's centroid) under the
    seven scaled similarity coefficients (datum.similarity_changes' basis)."""
    m = len(X)
    H = np.zeros((m, 3, 7))
    H[:, :, :3] = np.eye(3)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        H[:, :, 3 + k] = np.cross(e, X) / extent
    H[:, :, 6] = X / extent
    return H


def _datum_rows(project: Project, label, rays, kinds, extent, centroids):
    """Rows (r, 7) on the similarity coefficients of each group, and the group of each row: the given
    coordinates of control points with conditions, the observed or fixed centres and angles, the
    enforced or observed base components."""
    ph, ip, pts = project.photos, project.image_points, project.points
    rows, owner = [], []
    # control points: the group of any photo that sees them; approximate positions where not given
    given = given_axes(kinds)
    has_cond = 2 * rays - (3 - given.sum(axis=1)) > 0  # groups.condition_count
    ctrl = np.flatnonzero(has_cond & np.isin(kinds, (FULL, PLAN, HEIGHT)) & given.any(axis=1))
    if len(ctrl):
        first_row = np.full(len(pts), -1)
        first_row[ip.point_index[::-1]] = np.arange(len(ip))[::-1]
        g = label[ip.photo_index[first_row[ctrl]]]
        mean_centre = np.zeros((len(pts), 3))
        np.add.at(mean_centre, ip.point_index, ph.xyz0[ip.photo_index])
        mean_centre /= np.maximum(rays, 1)[:, None]
        X = np.where(given[ctrl] & np.isfinite(pts.xyz_given[ctrl]), pts.xyz_given[ctrl], mean_centre[ctrl])
        H = _similarity_rows(X - centroids[g], extent)
        sel = given[ctrl]
        rows.append(H[sel])
        owner.append(np.repeat(g, 3)[sel.ravel()])
    # observed or fixed centres and angles
    H_photo = _similarity_rows(ph.xyz0 - centroids[label], extent)
    held_c = ph.centre_state != FREE
    rows.append(H_photo[held_c])
    owner.append(np.repeat(label, 3)[held_c.ravel()])
    held_a = ph.angle_state != FREE
    if held_a.any():
        k = np.flatnonzero(held_a.any(axis=1))
        # an angle changes by J R^T omega under a ground rotation omega (R <- Exp(omega) R)
        J = angles_jacobian(ph.R_ground_from_cam[k], project.settings.rotation)
        Hrot = np.zeros((len(k), 3, 7))
        Hrot[:, :, 3:6] = J @ np.swapaxes(ph.R_ground_from_cam[k], 1, 2) / extent
        rows.append(Hrot[held_a[k]])
        owner.append(np.repeat(label[k], 3)[held_a[k].ravel()])
    b = project.bases
    if len(b):
        # a base component O_to - O_from does not move under a translation
        d = _similarity_rows(ph.xyz0[b.photo_to] - ph.xyz0[b.photo_from], extent)[np.arange(len(b)), b.axis]
        d[:, :3] = 0.0
        rows.append(d)
        owner.append(label[b.photo_to])
    rows = [r for r in rows if len(r)]
    if not rows:
        return np.zeros((0, 7)), np.zeros(0, dtype=int)
    M = np.concatenate(rows)
    own = np.concatenate([o for o in owner if len(o)])
    ok = np.linalg.norm(M, axis=1) > 0
    return M[ok], own[ok]
