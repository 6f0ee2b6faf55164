"""What was rejected, group by group: w, MDB, and its effect on the ground (the report's table and
summary.json's "blunders" "groups", docs/file-formats.md).

A *group* is the rows rejected together (BlunderResult.groups): one row when the gross error was
localised, several when their w-tests could not be told apart (separability; flag
"inseparable": detected, not localisable). Per group:

* ``w``: the signed w of the group's lead row (the largest |w| of the round, x or y) in the
  adjustment after which it was rejected; ``coordinate``: "x" or "y"; ``mdb``: that coordinate's
  MDB there (plate units) -- the internal reliability;
* ``bias_to_noise``: ``delta0 sqrt((1 - r) / r)`` of that coordinate, r = (sigma delta0 / MDB)^2:
  the effect an undetected error of the MDB would have had on all estimated quantities, in units
  of their precision (external reliability, measures.py);
* ``ground_effect``: what the group's measurements would have done to their point had they been
  kept: the point intersected from its kept rays plus the group's, minus from its kept rays alone,
  with the final orientations held (metres, reduced frame axes X, Y, Z). None (null) when the kept
  rays alone do not determine the point (e.g. the three rays of a three-ray point rejected
  together: the point drops out).
"""

from __future__ import annotations

import numpy as np

from ..equations.observations import observations_of
from ..model import Project
from ..equations.triangulation import GivenCoordinates, RayObservations, triangulate
from .outcome import BlunderResult


def rejection_groups(project: Project, det: BlunderResult) -> list[dict]:
    """One dict per rejected group of ``det`` (module doc), in the order of rejection. project:
    the project ``det`` was detected on (every original row)."""
    groups = det.groups
    if not groups:
        return []
    ip = project.image_points
    by_row = {rej.row: rej for rej in det.rejected}
    leads = [by_row[int(g[0])] for g in groups]  # the first row of a group is the one that was tested
    effect = _ground_effects(project, det, groups)
    out = []
    for g, rej, d in zip(groups, leads, effect):
        c = int(np.nanargmax(np.where(np.isnan(rej.w), -1.0, np.abs(rej.w))))
        sigma = float(ip.sigma_xy[rej.row, c])
        mdb = float(rej.mdb[c])
        r = (sigma * det.delta0 / mdb) ** 2 if np.isfinite(mdb) and mdb > 0 else float("nan")
        bnr = det.delta0 * np.sqrt((1.0 - r) / r) if 0 < r <= 1 else float("nan")
        out.append({
            "point_id": str(project.points.ids[ip.point_index[rej.row]]),
            "photo_ids": [str(project.photos.ids[ip.photo_index[i]]) for i in g],
            "rows": [int(i) for i in g],
            "localised": len(g) == 1,
            "round": int(rej.round),
            "coordinate": "xy"[c],
            "w": float(rej.w[c]),
            "mdb": mdb if np.isfinite(mdb) else None,
            "bias_to_noise": float(bnr) if np.isfinite(bnr) else None,
            "ground_effect": [float(v) for v in d] if np.all(np.isfinite(d)) else None,
        })
    return out


def _ground_effects(project: Project, det: BlunderResult, groups: list[np.ndarray]) -> np.ndarray:
    """(n_groups, 3) point with kept rays + the group's minus with the kept rays alone (module doc);
    nan where either is not determined. Each group is intersected as a point of its own."""
    ip = project.image_points
    result = det.result
    kept = np.zeros(len(ip), dtype=bool)
    kept[det.rows] = True
    kept[det.rejected_rows] = False  # a rejected row may be kept for its other coordinate (snooping)
    pt_of_group = np.array([ip.point_index[g[0]] for g in groups])
    # kept rows of each group's point, and the group's own rows, each tagged with the group number
    kept_rows = np.flatnonzero(kept)
    hit = np.isin(ip.point_index[kept_rows], pt_of_group)
    kept_rows = kept_rows[hit]
    base_rows, base_tag = [], []
    for k, p in enumerate(pt_of_group):
        rows = kept_rows[ip.point_index[kept_rows] == p]
        base_rows.append(rows)
        base_tag.append(np.full(len(rows), k))
    base_rows = np.concatenate(base_rows).astype(int)
    base_tag = np.concatenate(base_tag).astype(int)
    extra_rows = np.concatenate(groups).astype(int)
    extra_tag = np.concatenate([np.full(len(g), k) for k, g in enumerate(groups)]).astype(int)
    q = observations_of(project, result.offset).q_control[pt_of_group]
    control = GivenCoordinates(xyz_ground=result.control_adjusted[pt_of_group],
                               given=project.points.given_axes[pt_of_group], q_given=q)

    def intersect(rows, tag):
        rays = RayObservations(photo_index=ip.photo_index[rows], point_index=tag, xy_plate=ip.xy[rows],
                               sigma_xy=ip.sigma_xy[rows])
        tri = triangulate(rays, control, state=result.state, layout=result.layout)
        return np.where(tri.determined[:, None], tri.xyz, np.nan)

    with np.errstate(invalid="ignore"):
        return (intersect(np.concatenate([base_rows, extra_rows]), np.concatenate([base_tag, extra_tag]))
                - intersect(base_rows, base_tag))
