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

from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from .parameters import State, UnknownLayout
from ..geometry.rotations import angles_from_R, angles_jacobian, exp_so3, log_so3

DIRECTION_NAMES = (
    "translation in X",
    "translation in Y",
    "translation in Z",
    "rotation about the X axis (omega of the whole block)",
    "rotation about the Y axis (phi of the whole block)",
    "rotation about the Z axis (kappa of the whole block)",
    "scale",
)
# An exact invariance gives a Rayleigh quotient at rounding level (~1e-16); a very heavily weighted
# observation that does not constrain a direction can push a regular one down to ~1e-11. The strict
# value is used before every solve; the loose one names the defect once the factorisation failed.
STRICT_TOLERANCE = 1e-13
LOOSE_TOLERANCE = 1e-7


def similarity_changes(state: State, layout: UnknownLayout, centroid: np.ndarray | None = None) -> np.ndarray:
    """Change of each photo element (n, 6, 7) under the seven infinitesimal similarities.

    Elements are those of the unknown parametrisation: centre, then the rotation vector (free
    rotation) or the angles (photos with some angles fixed). The rotation is about the centroid
    of the projection centres (or ``centroid``) and the scale is centred there too.
    """
    O = state.xyz0 - (state.xyz0.mean(axis=0) if centroid is None else centroid)
    n = len(O)
    H = np.zeros((n, 6, 7))
    H[:, :3, :3] = np.eye(3)
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        H[:, :3, 3 + a] = np.cross(e, O)
        H[:, 3:, 3 + a] = np.einsum("nji,j->ni", state.R_ground_from_cam, e)  # d = R^T omega
    H[:, :3, 6] = O
    part = layout.partial_rotation
    if part.any():
        J = angles_jacobian(state.R_ground_from_cam[part], layout.convention)
        H[part, 3:, :] = np.einsum("nij,njk->nik", J, H[part, 3:, :])
    return H


@dataclass
class FreeDirections:
    """The similarity directions the control leaves free: ``H`` (n_unknowns, d) their change of the
    unknowns; ``coefficients`` (7, d) in the scaled similarity basis; ``extent`` of the block."""

    H: np.ndarray
    coefficients: np.ndarray
    extent: float

    def __len__(self) -> int:
        return self.H.shape[1]


def diagnose(acc, state: State, layout: UnknownLayout, tolerance: float = STRICT_TOLERANCE, offset=None) -> list[str]:
    """Names of the similarity directions left free by the control (empty when none)."""
    free = free_directions(acc, state, layout, tolerance)
    if len(free) == 0:
        return []
    centroid = state.xyz0.mean(axis=0) + (0.0 if offset is None else offset)
    return describe(free.coefficients, free.extent, centroid)


def _metric(acc) -> np.ndarray:
    """The diagonal the Rayleigh quotients are taken against: diag N, or for the bundle's reduced
    camera system the diagonal before the points' reduction (``datum_metric``). The reduction
    cancels most of a free direction's diagonal, and its rounding is of the order of the unreduced
    one: measured against the reduced diagonal, a free direction of a pair without control reached
    2e-12 and was taken for determined."""
    metric = getattr(acc, "datum_metric", None)
    return acc.N.diagonal() if metric is None else metric


def free_directions(acc, state: State, layout: UnknownLayout, tolerance: float = STRICT_TOLERANCE) -> FreeDirections:
    """The similarity directions left free by the control: those whose Rayleigh quotient
    h^T N h / h^T diag(N) h is below ``tolerance``.

    acc: the NormalAccumulator (N, and the sums B~^T g~, g~^T g~ of the misclosures). Translations
    and rotations leave every tie condition unchanged (B h = 0), but a change of scale multiplies
    them (B h_scale = g, homogeneous of degree one), so before convergence the scale direction is
    tested with ``B h_scale - g`` in place of ``B h_scale``.
    """
    N = acc.N
    extent = max(float(np.ptp(state.xyz0, axis=0).max()), 1.0)
    units = _units(extent)
    H, C = similarity_matrix(state, layout, extent)
    scale = np.abs(C).max() if C.size else 1.0
    Z = la.null_space(C / scale, rcond=1e-9) if C.size else np.eye(7)
    none = FreeDirections(np.zeros((layout.n_unknowns, 0)), np.zeros((7, 0)), extent)
    if Z.shape[1] == 0:
        return none
    K7 = H.T @ (N @ H)
    Hug = H.T @ acc.ug * units[6]  # the scale column is h_scale * units[6], so B h = g * units[6]
    K7[:, 6] -= Hug
    K7[6, :] -= Hug
    K7[6, 6] += acc.gPg * units[6] ** 2
    Hz = H @ Z
    K = Z.T @ K7 @ Z
    D = Hz.T @ (_metric(acc)[:, None] * Hz)
    keep = np.diag(D) > 0
    if not keep.any():
        return none
    lam, vec = la.eigh(K[np.ix_(keep, keep)], D[np.ix_(keep, keep)])
    free = Z[:, keep] @ vec[:, lam < tolerance]  # (7, d) coefficients of the free directions
    return FreeDirections(H @ free, free, extent)


@dataclass
class FreeNetwork:
    """Datum of a free network (no or too little control): the corrections satisfy ``C^T dx = t``.

    Solved by minimum constraints (the ``held`` unknowns, one per free direction, chosen by a
    pivoted QR so that they fix those directions well, are held at zero) followed by the
    S-transformation ``dx = S dx_min + H (C^T H)^-1 t``, ``S = I - H (C^T H)^-1 C^T``, which moves
    the solution along the free similarity directions H onto the constraints; ``Q = S Q_min S^T``
    (plus ``HK V HK^T``, HK = H (C^T H)^-1, when ``extra`` V is given: the point datum, where the
    constraint involves the datum points' own measurements, striptri.equations.point_datum).

    ``target`` t (d,): None is 0 (the increments alone constrained). ``mode``: "inner" (C on the
    photos: inner_constraints) or "inner-points" (C from the datum points, point_datum).
    ``points``: what the point datum's precision needs beyond Qxx (point_datum.PointTerms).
    ``misclosure`` (d,): how far the current unknowns are from the datum, in the constraint's
    terms (photos: ``C^T delta``; points: ``sum H_p^T (X_p - X0_p)``); None when only increments are
    constrained.
    """

    H: np.ndarray
    C: np.ndarray
    held: np.ndarray
    free: FreeDirections
    target: np.ndarray | None = None
    extra: np.ndarray | None = None
    mode: str = "inner"
    points: object = None
    misclosure: np.ndarray | None = None
    centroid: np.ndarray | None = None  # the similarities turn about it (None: the projection centres' centroid)

    def __len__(self) -> int:
        return self.H.shape[1]

    @staticmethod
    def of(free: FreeDirections, N) -> "FreeNetwork":
        C = inner_constraints(free, N)
        scaled = free.H * np.sqrt(N.diagonal())[:, None]
        _, _, piv = la.qr(scaled.T, pivoting=True, mode="economic")
        return FreeNetwork(free.H, C, np.sort(piv[: free.H.shape[1]]), free)

    def at(self, state: State, layout: UnknownLayout, N, initial: State | None = None,
           exact: bool = True) -> "FreeNetwork":
        """The same free directions at another state (the similarity directions move with the
        photos): H, C recomputed, the held unknowns kept. initial: the approximations; given, the
        step gets the right-hand side ``t = C^T H c`` that moves the photos by the similarity ``c``
        onto the datum ``C(x^)^T (x^ - x0) = 0`` (:func:`datum_move`), so that the adjusted unknowns
        meet it whatever the iteration's path. exact: False takes the linear move
        ``c = -(C^T H)^-1 C^T (x - x0)`` (a damped step, whose N is not that of the datum)."""
        H = similarity_matrix(state, layout, self.free.extent)[0] @ self.free.coefficients
        free = FreeDirections(H, self.free.coefficients, self.free.extent)
        C = inner_constraints(free, N)
        if initial is None:
            return FreeNetwork(H, C, self.held, free)
        if exact:
            target = C.T @ (H @ datum_move(free, state, layout, N, initial))
        else:
            target = -C.T @ displacement(initial, state, layout)
        return FreeNetwork(H, C, self.held, free, target, misclosure=target)

    def minimum_constraint_system(self, N):
        """N with the held unknowns replaced by identity rows and columns (scaled by N_ii)."""
        mask = np.zeros(N.shape[0])
        mask[self.held] = 1.0
        keep = sp.diags(1.0 - mask)
        return (keep @ N @ keep + sp.diags(mask * N.diagonal())).tocsr(), mask

    def transform(self, dx_min: np.ndarray) -> np.ndarray:
        """S dx_min (class doc); dx_min may be a vector or a matrix of columns."""
        CtH = self.C.T @ self.H
        return dx_min - self.H @ np.linalg.solve(CtH, self.C.T @ dx_min)

    def solution(self, dx_min: np.ndarray) -> np.ndarray:
        """The correction on the constraints ``C^T dx = t`` from a minimum-constraint one."""
        if self.target is None:
            return self.transform(dx_min)
        CtH = self.C.T @ self.H
        return dx_min - self.H @ np.linalg.solve(CtH, self.C.T @ dx_min - self.target)

    def datum_correction(self, n_diag: np.ndarray) -> float:
        """The move of the datum this step makes, ``s = H (C^T H)^-1 misclosure``, measured as
        ``sqrt(sum_i s_i^2 N_ii)`` (each element in units of its standard deviation if all others were
        known: the datum has none of its own): the convergence test adds it to the correction of
        the estimable functions, which does not see it (N s = 0). 0 without a misclosure."""
        if self.misclosure is None:
            return 0.0
        s = self.H @ np.linalg.solve(self.C.T @ self.H, self.misclosure)
        return float(np.sqrt(np.sum(s * s * np.maximum(n_diag, 0.0))))

    def solve(self, solver, N, rhs: np.ndarray):
        """Solve ``N dx = rhs`` on the constraints: minimum constraints by ``solver`` (a
        solvers.NormalSolver), then :meth:`solution`. Returns (dx, the solver's SolveResult)."""
        N_min, mask = self.minimum_constraint_system(N)
        solved = solver.solve(N_min, rhs * (1.0 - mask))
        return self.solution(solved.dx), solved

    def summary(self, state: State, offset) -> dict:
        """summary.json's \"datum\" entry of a free network: its mode, the free directions in words
        (describe) and, for the point datum, the number of datum points."""
        centroid = state.xyz0.mean(axis=0) if self.centroid is None else self.centroid
        out = {"mode": self.mode, "free_directions": describe(self.free.coefficients, self.free.extent,
                                                              centroid + offset)}
        if self.points is not None:
            out["n_datum_points"] = int(len(self.points.index))
        return out


def displacement(initial: State, state: State, layout: UnknownLayout) -> np.ndarray:
    """The unknowns' displacement (n_unknowns,) of ``state`` from ``initial`` in the columns of
    ``layout``, where a similarity moves them (the datum's right-hand side, FreeNetwork.at): centres
    (m), rotation vectors ``Log(R0^T R)`` (rad; the corrections of the free angles for photos with
    some held), GNSS shifts (m). Camera elements and the other GNSS unknowns read 0."""
    n = layout.n_unknowns
    delta = np.zeros(n + 1)  # column -1 writes into the sink
    cols = layout.photo_cols
    delta[cols[:, :3]] = state.xyz0 - initial.xyz0
    rot = log_so3(np.einsum("nji,njk->nik", initial.R_ground_from_cam, state.R_ground_from_cam))
    part = layout.partial_rotation
    if part.any():
        d_ang = (angles_from_R(state.R_ground_from_cam[part], layout.convention)
                 - angles_from_R(initial.R_ground_from_cam[part], layout.convention))
        rot[part] = (d_ang + np.pi) % (2 * np.pi) - np.pi
    delta[cols[:, 3:]] = rot
    if layout.gnss_cols is not None and state.gnss is not None and initial.gnss is not None:
        delta[layout.gnss_cols.shift] = state.gnss.shift - initial.gnss.shift
    delta[n] = 0.0
    return delta[:n]


def datum_move(free: FreeDirections, state: State, layout: UnknownLayout, N, initial: State,
               max_steps: int = 12) -> np.ndarray:
    """The similarity ``c`` (d,) of the free directions that moves the photos of ``state`` onto the
    photo datum: ``H'^T D' (x' - x0) = 0`` at the moved state x' (H' its similarity directions, D'
    its diag N, x0 the approximations; the inner constraints ``C^T (x - x0) = 0`` of the class doc).

    The fit does not change along the similarity, but D does: a similarity turns and scales each
    photo's centre block of N, ``N'_cc = Q N_cc Q^T / s^2`` (rotation vectors in the camera frame
    and the camera elements do not change). The linear move ``-(C^T H)^-1 C^T (x - x0)`` ignores
    that, and the datum then slides back by about half its move every iteration (31 iterations on
    a pair without control); solving the d equations by Newton with D moved along converges in
    the usual handful. Photos with held angles, tied centres and GNSS shifts keep their D (their
    blocks do not transform this simply): the result is then approximate, and the next iteration,
    which recomputes D, finishes it."""
    d = free.H.shape[1]
    extent, coefficients = free.extent, free.coefficients
    owners = _column_owners(layout)
    blocks = _centre_blocks(N, layout, owners)
    diag = np.asarray(N.diagonal(), dtype=float)
    g = state.xyz0.mean(axis=0)

    def equations(c: np.ndarray) -> np.ndarray:
        moved, Q, s = _moved(state, layout, coefficients @ c, extent, g)
        D = diag.copy()
        if blocks is not None:
            cols, Ncc = blocks
            D[cols] = np.einsum("ij,njk,ik->ni", Q, Ncc, Q) / s**2
        H = _similarity_columns(moved, layout, extent, owners) @ coefficients
        return H.T @ (D * displacement(initial, moved, layout))

    c = np.zeros(d)
    f = equations(c)
    G = free.H.T @ (diag[:, None] * free.H)
    if not np.any(f):
        return c
    step = 1e-3  # a millimetre of motion across the block
    J = np.empty((d, d))
    for j in range(d):
        e = np.zeros(d)
        e[j] = step
        J[:, j] = (equations(e) - f) / step
    try:
        last = np.inf
        for _ in range(max_steps):
            dc = -np.linalg.solve(J, f)
            c = c + dc
            size = np.sqrt(abs(dc @ G @ dc))  # in sd of the elements, as the correction test
            if size < 1e-11 or size > 0.5 * last:  # done, or at the rounding floor
                break
            last = size
            f = equations(c)
    except np.linalg.LinAlgError:
        c = np.zeros(d)
    if not np.all(np.isfinite(c)):
        c = np.zeros(d)
    if not c.any():  # the linear move (the iteration's fixed point is the same, only slower)
        c = -np.linalg.solve(G, equations(c))
    return c


def _column_owners(layout: UnknownLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The photo elements that own their unknown column (the first of tied elements), as flat
    indices into ``photo_cols`` (n*6,), their columns, and the tied elements after the first."""
    flat = layout.photo_cols.ravel()
    free_el = np.flatnonzero(flat >= 0)
    cols, first = np.unique(flat[free_el], return_index=True)
    owner = free_el[first]
    tied = np.setdiff1d(free_el, owner, assume_unique=True)
    return owner, cols, tied


def _centre_blocks(N, layout: UnknownLayout, owners) -> tuple[np.ndarray, np.ndarray] | None:
    """The 3x3 centre blocks of N (m, 3, 3) and their columns (m, 3) of the photos whose three
    centre elements are their own unknowns (free, not tied to another photo's); None when none."""
    cols = layout.photo_cols[:, :3]
    owns = np.zeros(layout.photo_cols.size, dtype=bool)
    owns[owners[0]] = True
    shared = np.isin(cols, layout.photo_cols.ravel()[owners[2]])  # a column another photo's element ties to
    own = (owns.reshape(-1, 6)[:, :3] & ~shared).all(axis=1)
    if not own.any():
        return None
    c = cols[own]
    rows = np.broadcast_to(c[:, :, None], (len(c), 3, 3))
    columns = np.broadcast_to(c[:, None, :], (len(c), 3, 3))
    values = np.asarray(N[rows.ravel(), columns.ravel()], dtype=float).reshape(len(c), 3, 3)
    return c, values


def _moved(state: State, layout: UnknownLayout, p: np.ndarray, extent: float, centroid: np.ndarray):
    """``state`` moved by the finite similarity ``p`` (7,) in the scaled basis of
    similarity_matrix (translation in m, rotation and scale in m across the block), turning and
    scaling about ``centroid``; the GNSS shifts move back with the translation. Returns the moved
    state, its rotation Q and its scale s."""
    t, w, s = p[:3], p[3:6] / extent, 1.0 + p[6] / extent
    Q = exp_so3(w)
    xyz0 = centroid + s * (state.xyz0 - centroid) @ Q.T + t
    R = layout.restore_fixed_angles(Q @ state.R_ground_from_cam)
    gnss = state.gnss
    if gnss is not None and layout.gnss_cols is not None:
        free_shift = layout.gnss_cols.shift >= 0
        gnss = replace(gnss, shift=np.where(free_shift, gnss.shift - t, gnss.shift))
    return replace(state, R_ground_from_cam=R, xyz0=xyz0, gnss=gnss), Q, s


def _similarity_columns(state: State, layout: UnknownLayout, extent: float, owners) -> np.ndarray:
    """H (n_unknowns, 7) of similarity_matrix, without its constraint rows."""
    H_el = (similarity_changes(state, layout) * _units(extent)).reshape(-1, 7)
    owner, cols, _ = owners
    H = np.zeros((layout.n_unknowns, 7))
    H[cols] = H_el[owner]
    if layout.gnss_cols is not None:
        shift = layout.gnss_cols.shift
        for a in range(3):
            H[shift[:, a][shift[:, a] >= 0], a] = -_units(extent)[a]
    return H


def inner_constraints(free: FreeDirections, N) -> np.ndarray:
    """Constraint matrix C (n_unknowns, d) of the free network: ``C^T dx = 0`` makes the corrections
    D-orthogonal (D = diag N) to the free similarity directions, the minimum-norm solution in the
    metric of the Jacobi-scaled unknowns (generalised inner constraints on all orientation
    unknowns). C is normalised so that C C^T has the scale of N along those directions:
    ``C = D H G^-1/2`` with ``G = H^T D H``."""
    d = N.diagonal()
    H = free.H
    G = H.T @ (d[:, None] * H)
    w, U = np.linalg.eigh(G)
    return (d[:, None] * H) @ (U / np.sqrt(w)) @ U.T


def _units(extent: float) -> np.ndarray:
    """Scales of the seven similarity coefficients: about one metre of motion across the block."""
    return np.array([1, 1, 1, 1 / extent, 1 / extent, 1 / extent, 1 / extent], dtype=float)


def similarity_matrix(state: State, layout: UnknownLayout, extent: float, centroid: np.ndarray | None = None):
    """H (n_unknowns, 7): the change of the unknowns under the seven scaled similarities (about the
    centroid of the projection centres, or ``centroid``), and the constraint rows (r, 7) that fixed
    and tied elements put on the similarity coefficients."""
    H_el = similarity_changes(state, layout, centroid) * _units(extent)  # (n, 6, 7)
    cols = layout.photo_cols
    owner, owned, tied = _column_owners(layout)
    flat = H_el.reshape(-1, 7)
    first = np.zeros(layout.n_unknowns, dtype=int)
    first[owned] = owner
    constraints = [H_el[cols < 0],  # fixed elements must not move
                   flat[tied] - flat[first[cols.ravel()[tied]]]]  # tied elements (enforced base) move together
    H = np.zeros((layout.n_unknowns, 7))
    H[owned] = flat[owner]
    if layout.gnss_cols is not None:  # a translation moves the GNSS shifts back (A = O + ... + shift)
        shift = layout.gnss_cols.shift
        for a in range(3):
            H[shift[:, a][shift[:, a] >= 0], a] = -_units(extent)[a]
    return H, np.concatenate(constraints, axis=0)


def describe(free: np.ndarray, extent: float, centroid: np.ndarray) -> list[str]:
    """Words for the span of free similarity directions (7, d) (coefficients scaled as in diagnose).

    Elementary directions (a translation along an axis, a rotation about an axis through the
    centroid of the projection centres, the scale) that lie in the span are named as such; what
    remains is described geometrically: a rotation about an axis through a named ground point, or
    a scale about a ground point.
    """
    Q, _ = np.linalg.qr(free)
    names, pure = [], []
    for a in range(7):
        e = np.zeros(7)
        e[a] = 1.0
        if np.linalg.norm(e - Q @ (Q.T @ e)) < 1e-6:
            names.append(DIRECTION_NAMES[a])
            pure.append(e)
    rest = Q - (np.array(pure).T @ (np.array(pure) @ Q) if pure else 0.0)
    U, sv, _ = np.linalg.svd(rest, full_matrices=False)
    for c in U[:, sv > 1e-6].T:
        names.append(_combined(c, extent, centroid))
    return names


def _combined(c: np.ndarray, extent: float, centroid: np.ndarray) -> str:
    t, omega, scale = c[:3], c[3:6] / extent, c[6] / extent
    fmt = lambda p: "(" + ", ".join(f"{v:.1f}" for v in p) + ")"  # noqa: E731
    if np.linalg.norm(omega) * extent > 1e-3 * np.abs(c).max() and abs(scale) * extent < 1e-3 * np.abs(c).max():
        w = omega / np.linalg.norm(omega)
        point = centroid + np.cross(omega, t) / (omega @ omega)
        axis = next((f"parallel to the {'XYZ'[k]} axis" for k in range(3) if abs(w[k]) > 0.99),
                    f"with direction {fmt(w)}")
        return f"rotation about an axis {axis} through the ground point {fmt(point)}"
    if abs(scale) * extent > 1e-3 * np.abs(c).max() and np.linalg.norm(omega) * extent < 1e-3 * np.abs(c).max():
        return f"scale about the ground point {fmt(centroid - t / scale)}"
    return " combined with ".join(DIRECTION_NAMES[a] for a in np.flatnonzero(np.abs(c) > 0.3 * np.abs(c).max()))


def explain(defects: list[str]) -> str:
    lines = [
        "the control leaves the datum undetermined: the measurements fix the shape of the model but "
        f"not its {len(defects)} similarity element(s):"
    ]
    lines += [f"  - {d}" for d in defects]
    lines.append(
        "Add control (at least two full points and one height point not on a line, i.e. seven "
        "independent datum elements), observed projection centres, or fix orientation elements; "
        "or adjust it as a free network (--datum inner or inner-points, or [datum] mode = \"inner\" or "
        "\"inner-points\" in project.toml)."
    )
    return "\n".join(lines)
