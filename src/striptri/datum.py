"""Datum diagnosis: which of the seven similarity elements the control leaves undetermined.

The coplanarity and scale conditions do not change when every photograph is moved by one
similarity transformation of the ground frame. Control points, observed elements and fixed
elements break that invariance; when they do not break it completely, N is singular along the
remaining similarity directions. For each infinitesimal similarity (translations tX, tY, tZ,
rotations about X, Y, Z, scale) the change of every unknown is computed; the directions
admissible under the fixed elements and the enforced base components are tested with the
generalised eigenproblem ``(H^T N H) c = lambda (H^T diag(N) H) c``. An eigenvalue near zero is a
datum defect, and its eigenvector says in words which translation, rotation or scale is free.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from .parameters import State, UnknownLayout
from .rotations import angles_jacobian

DIRECTION_NAMES = (
    "translation in X",
    "translation in Y",
    "translation in Z",
    "rotation about the X axis (omega of the whole block)",
    "rotation about the Y axis (phi of the whole block)",
    "rotation about the Z axis (kappa of the whole block)",
    "scale",
)
DEFECT_TOLERANCE = 1e-9


def similarity_changes(state: State, layout: UnknownLayout) -> np.ndarray:
    """Change of each photo element (n, 6, 7) under the seven infinitesimal similarities.

    Elements are those of the unknown parametrisation: centre, then the rotation vector (free
    rotation) or the angles (photos with some angles fixed). The rotation is about the centroid
    of the projection centres and the scale is centred there too.
    """
    O = state.xyz0 - state.xyz0.mean(axis=0)
    n = len(O)
    H = np.zeros((n, 6, 7))
    H[:, :3, :3] = np.eye(3)
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        H[:, :3, 3 + a] = np.cross(e, O)
        H[:, 3:, 3 + a] = np.einsum("nji,j->ni", state.R, e)  # d = R^T omega
    H[:, :3, 6] = O
    part = layout.partial_rotation
    if part.any():
        J = angles_jacobian(state.R[part], layout.convention)
        H[part, 3:, :] = np.einsum("nij,njk->nik", J, H[part, 3:, :])
    return H


def diagnose(N: sp.csr_matrix, state: State, layout: UnknownLayout) -> list[str]:
    """Names of the similarity directions left free by the control (empty when none)."""
    n_unknowns = layout.n_unknowns
    H_el = similarity_changes(state, layout)  # (n, 6, 7)
    cols = layout.photo_cols
    extent = max(float(np.ptp(state.xyz0, axis=0).max()), 1.0)
    units = np.array([1, 1, 1, extent, extent, extent, extent], dtype=float)
    H_el = H_el * units  # comparable columns: metres at the photo positions

    constraints = [H_el[cols < 0]]  # fixed elements must not move
    first_at_col: dict[int, tuple[int, int]] = {}
    for i, e in zip(*np.nonzero(cols >= 0)):
        c = int(cols[i, e])
        if c in first_at_col:  # tied elements (enforced base) must move together
            i0, e0 = first_at_col[c]
            constraints.append((H_el[i, e] - H_el[i0, e0])[None])
        else:
            first_at_col[c] = (i, e)
    C = np.concatenate(constraints, axis=0) if constraints else np.zeros((0, 7))
    scale = np.abs(C).max() if C.size else 1.0
    Z = la.null_space(C / scale, rcond=1e-9) if C.size else np.eye(7)
    if Z.shape[1] == 0:
        return []
    H = np.zeros((n_unknowns, 7))
    for c, (i, e) in first_at_col.items():
        H[c] = H_el[i, e]
    Hz = H @ Z
    K = Hz.T @ (N @ Hz)
    D = Hz.T @ (N.diagonal()[:, None] * Hz)
    keep = np.diag(D) > 0
    if not keep.any():
        return []
    lam, vec = la.eigh(K[np.ix_(keep, keep)], D[np.ix_(keep, keep)])
    defects = []
    for j in np.flatnonzero(lam < DEFECT_TOLERANCE * max(lam.max(), 1e-300) + 1e-14):
        coeff = Z[:, keep] @ vec[:, j]
        coeff = coeff / np.abs(coeff).max()
        defects.append(" combined with ".join(DIRECTION_NAMES[a] for a in np.flatnonzero(np.abs(coeff) > 0.3)))
    return defects


ADVICE = {
    "translation in X": "full or plan control",
    "translation in Y": "full or plan control",
    "translation in Z": "full or height control",
    "scale": "a second full or plan control point, or observed base components",
}


def explain(defects: list[str]) -> str:
    lines = [
        "the control leaves the datum undetermined: the measurements fix the shape of the model but "
        f"not its {len(defects)} similarity element(s):"
    ]
    lines += [f"  - {d}" for d in defects]
    lines.append(
        "Add control (at least two full points and one height point not on a line, i.e. seven "
        "independent datum elements), observed projection centres, or fix orientation elements."
    )
    return "\n".join(lines)
