"""Schmid's precision of the intersected points: the forms (90) and (92), each written once.

A point X is intersected from the adjusted rays of its photos (and its weighted given
coordinates): X = X(x^, l^), with x^ the adjusted orientation unknowns and l^ the adjusted
observations. Schmid (BRL 961, eqs. 87-92) gives its cofactors in two ways.

* **(90)**, the two parts: with the orientation held, the measurement part ``Qm = N_pp^-1``
  (``N_pp = J^T P J + P_given``, the point's own normal matrix); the orientation carries in through
  ``G = dX/dx = -Qm J^T P J_x``, the orientation part ``G Qxx G^T``. Their sum is the point's
  cofactor matrix when X is intersected from its *measured* rays, independent of the
  adjustment's: :func:`orientation_part` is the second term. Every method (conditions,
  bundle, sequential, and the joint groups of points tied by distances) calls it; they differ
  only in how they form G and read Qxx (by blocks of unknown sets, ``Covariance.group_forms``, or
  from Qcc gathered once per chunk in the bundle's collinearity form, which needs it again).

* **(92)**, the joint form: X depends on the adjusted observations too, and they are correlated
  with the adjusted unknowns. With ``F = dX/dl^``, ``Cov(l^) = Q - Qvv`` and
  ``Cov(x^, l^) = -Qxx B^T M^-1 A Q`` (``M = A Q A^T``), ``m_X^2 = m^2 F^T R F`` expands to
  :func:`joint_form` (docs/decisions.md: for points in the adjustment (90) and (92) agree to
  rounding). Used for the points of a chunk of groups (precision.residuals) and for the members of
  a joint group tied by distances.

Both without the factor sigma0^2 (cofactors).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..selected_inverse.covariance import Slots, ray_slots


def orientation_part(G: np.ndarray, photo: np.ndarray, camera: np.ndarray, photo_cols: np.ndarray,
                     camera_cols: np.ndarray, forms: Callable[[Sequence[Slots]], np.ndarray]) -> np.ndarray:
    """Schmid's (90), its orientation part ``G Qxx G^T`` (m, r, r) of m groups of k rays.

    G: (m, r, k, 6 + e) the derivatives of the r point coordinates of each group with respect to
    the photo elements of each of its k rays (photo_cols[photo], (n_photos, 6)) and then the e
    estimated elements of the ray's camera (camera_cols[camera], (n_cameras, e)); photo, camera:
    (m, k) the ray's photo and camera. forms: Qxx read for the groups' unknown sets, Slots -> G Qxx
    G^T (m, r, r), e.g. ``Covariance.group_forms``.
    """
    return forms(ray_slots(G, photo, photo_cols, camera, camera_cols))


def joint_form(GQG: np.ndarray, GQB: np.ndarray, BQB: np.ndarray, M: np.ndarray, M_inv: np.ndarray,
               AQ: np.ndarray, Q: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Schmid's (92): the cofactors (m, r, r) of the r coordinates of the points of each of m groups,
    ``G Qxx G^T + F Cov(l^) F^T + G Cov(x^, l^) F^T + (G Cov(x^, l^) F^T)^T``.

    Of each group with c conditions, u unknowns and o observations: GQG (m, r, r), GQB (m, r, c),
    BQB (m, c, c) the forms ``G Qxx G^T``, ``G Qxx B^T``, ``B Qxx B^T`` (G = dX/dx, B the
    conditions' derivatives by the unknowns); M (m, c, c) = A Q A^T and M_inv its inverse; AQ (m, c,
    o) = A Q; Q (m, o) the cofactors of the observations; F (m, r, o) = dX/dl. Then
    ``Qvv = (M^-1 A Q)^T (M - B Qxx B^T) M^-1 A Q``, ``Cov(l^) = Q - Qvv`` and
    ``G Cov(x^, l^) F^T = -(G Qxx B^T) M^-1 A Q F^T``.
    """
    MAQ = M_inv @ AQ  # (m, c, o)
    Qvv = np.swapaxes(MAQ, 1, 2) @ (M - BQB) @ MAQ
    Qll = Q[:, :, None] * np.eye(Q.shape[1]) - Qvv
    Ft = np.swapaxes(F, 1, 2)
    cross = -(GQB @ (MAQ @ Ft))
    return GQG + F @ Qll @ Ft + cross + np.swapaxes(cross, 1, 2)
