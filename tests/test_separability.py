"""Separable and inseparable gross errors, and the separable snooping procedure (issue 18).

The blocks: ``striptri simulate block --photos 20 --strips 5 --check-points 12`` (60 % / 30 %
overlap, perimeter control, scripts/study_blunders.py), four seeds; 2 % of the rows of points in
three or more photos (not check points) get 10-30 sigma in x or in y.
"""

from __future__ import annotations

import csv
import io
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from striptri.core.runs import RunOptions
from striptri.adjustment import AdjustmentOptions, adjust
from striptri.model import TIE
from striptri.pipeline import adjust_products
from striptri.precision.residuals import plate_blocks_of, residual_cofactors
from striptri.reliability import FLAG_INSEPARABLE, FLAG_REJECTED, BlunderOptions, detect_blunders
from striptri.reliability.rejections import rejection_groups
from striptri.reliability.snooping import RETEST_SIGMA_FACTOR
from striptri.reliability.separability import RHO_MAX, RHO_MIN, Correlations, plate_cofactor_blocks

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from study_blunders import SIGMA, block, run, summary  # noqa: E402

SEEDS = (1, 2, 3, 4)
OPTIONS = AdjustmentOptions(method="conditions")


@pytest.fixture(scope="module")
def clean_block():
    project = block(1)
    return project, adjust(project, OPTIONS)


def three_ray_strip_points(project):
    """Indices of tie points seen by exactly three photos, all of one strip (photo ids 'SNNN').
    (A control point's given coordinates check its x coordinates one by one.)"""
    ip = project.image_points
    rays = np.bincount(ip.point_index, minlength=len(project.points.ids))
    strip = np.array([str(i)[0] for i in project.photos.ids])[ip.photo_index]
    out = []
    for pt in np.flatnonzero((rays == 3) & (project.points.kind == TIE)):
        rows = np.flatnonzero(ip.point_index == pt)
        if len(set(strip[rows])) == 1:
            out.append(pt)
    return np.array(out)


def test_the_blocks_of_qvv_extend_its_diagonal(clean_block):
    project, result = clean_block
    blocks = plate_cofactor_blocks(project, result, OPTIONS)
    q = residual_cofactors(project, result, OPTIONS).plate
    diag = np.zeros_like(q)
    for rows, qvv in blocks:
        assert np.allclose(qvv, np.swapaxes(qvv, 1, 2), rtol=0, atol=1e-12 * np.abs(qvv).max())
        g, j = np.nonzero(rows >= 0)
        diag[rows[g, j]] = np.diagonal(qvv, axis1=1, axis2=2).reshape(len(rows), -1, 2)[g, j]
    assert np.allclose(diag, q, rtol=1e-10, atol=1e-14)


def test_the_reliability_pass_gives_the_same_blocks(clean_block):
    """The conditions form's pass that computes the redundancy numbers gives the blocks too
    (residual_cofactors with plate_blocks): the same blocks as plate_cofactor_blocks, and the same
    diagonal as without them. (This small block's own pass takes the collinearity form, whose
    blocks equal these: tests/test_bundle_precision.py.)"""
    project, result = clean_block
    reference = plate_cofactor_blocks(project, result, OPTIONS)
    cof = residual_cofactors(project, result, OPTIONS, plate_blocks=True, form="conditions")
    assert len(cof.plate_blocks) == len(reference)
    for (rows, qvv), (rows_ref, qvv_ref) in zip(cof.plate_blocks, reference):
        np.testing.assert_array_equal(rows, rows_ref)
        np.testing.assert_allclose(qvv, qvv_ref, rtol=0, atol=1e-12 * np.abs(qvv_ref).max())
    np.testing.assert_array_equal(cof.plate, residual_cofactors(project, result, OPTIONS, form="conditions").plate)


@pytest.mark.parametrize("method", ("conditions", "bundle"))
def test_the_blocks_of_the_suspected_points_are_their_blocks_of_the_whole_pass(clean_block, method):
    """Snooping forms blocks of Qvv only in a round with a w above the critical value, and only for
    the points of such rows (precision.residuals.plate_blocks_of): each point's correlations equal
    those of the pass over every point (the conditions form; for a bundle result the collinearity
    form), and no other point has any."""
    project = clean_block[0]
    options = AdjustmentOptions(method=method)
    result = adjust(project, options)
    ip = project.image_points
    m = len(ip)
    every = Correlations(residual_cofactors(project, result, options, plate_blocks=True).plate_blocks, m)
    suspects = np.zeros(len(project.points), dtype=bool)
    suspects[::7] = True
    some = Correlations(plate_blocks_of(project, result, options, suspects), m)
    for i in range(m):
        rows, rho = some.of_row(i)
        if not suspects[ip.point_index[i]]:
            assert not len(rows)
            continue
        rows_ref, rho_ref = every.of_row(i)
        assert len(rows) > 1
        a, b = np.argsort(rows), np.argsort(rows_ref)
        np.testing.assert_array_equal(rows[a], rows_ref[b])
        np.testing.assert_allclose(rho[a], rho_ref[b], rtol=0, atol=1e-9)


def test_the_x_of_a_three_ray_strip_point_are_correlated_to_one(clean_block):
    """One scale transfer checks the three x coordinates: their w-tests correlate with |rho| ~ 1,
    above RHO_MAX (never told apart), while the y stay below RHO_MIN (always told apart)."""
    project, result = clean_block
    corr = Correlations(plate_cofactor_blocks(project, result, OPTIONS), len(project.image_points))
    ip = project.image_points
    pts = three_ray_strip_points(project)
    assert len(pts) > 50
    for pt in pts:
        rows = np.flatnonzero(ip.point_index == pt)
        others, rho = corr.of_row(rows[0])
        assert sorted(others) == sorted(rows)
        x = np.abs(rho[others != rows[0], 0, 0])
        y = np.abs(rho[others != rows[0], 1, 1])
        assert np.all(x > RHO_MAX) and np.all(y < RHO_MIN)  # measured: x > 0.998, y < 0.7


def test_the_three_x_of_a_three_ray_point_are_one_inseparable_group(clean_block):
    """20 sigma in x of one ray of a three-ray strip point: detected, not localisable. All three
    rows are rejected as one group flagged "inseparable" and reported so; the classic procedure
    rejects one of them as if found."""
    project, _ = clean_block
    ip = project.image_points
    pt = three_ray_strip_points(project)[5]
    rows = np.flatnonzero(ip.point_index == pt)
    xy = ip.xy.copy()
    xy[rows[1], 0] += 20 * SIGMA
    spoiled = replace(project, image_points=replace(ip, xy=xy))
    out = detect_blunders(spoiled, OPTIONS, BlunderOptions())
    assert list(out.flag[rows]) == [FLAG_INSEPARABLE] * 3
    groups = [g for g in out.groups if pt in ip.point_index[g]]
    assert len(groups) == 1 and sorted(groups[0]) == sorted(rows)
    report = [g for g in rejection_groups(spoiled, out) if g["point_id"] == str(project.points.ids[pt])]
    assert len(report) == 1 and not report[0]["localised"] and sorted(report[0]["rows"]) == sorted(rows)
    assert report[0]["coordinate"] == "x" and abs(report[0]["w"]) > out.critical
    assert report[0]["ground_effect"] is None  # the point lost all its rays
    # the group is inseparable in x only: the three y come back at full weight, their w tested
    assert np.all(np.isin(rows, out.rows))
    np.testing.assert_array_equal(out.weights[rows], [[RETEST_SIGMA_FACTOR**-2, 1.0]] * 3)
    assert np.all(np.isnan(out.w[rows, 0])) and np.all(np.abs(out.w[rows, 1]) <= out.critical)
    classic = detect_blunders(spoiled, OPTIONS, BlunderOptions(procedure="classic"))
    assert np.sum(classic.flag[rows] == FLAG_REJECTED) == 1 and not np.any(classic.flag[rows] == FLAG_INSEPARABLE)


@pytest.fixture(scope="module")
def study():
    out, cleans = {}, {}
    for mode in ("snoop", "snoop-classic", "robust"):
        rs = []
        for s in SEEDS:
            r, cleans[s] = run(s, mode, 0.02, 10.0, 30.0, clean=cleans.get(s))
            rs.append(r)
        out[mode] = summary(rs)
    return out


@pytest.mark.xdist_group("separability_study")  # one worker makes the study for both tests
def test_separable_snooping_meets_the_issue_targets(study):
    """>= 95 % of the 68 gross errors rejected (alone or in their inseparable group), false alarms
    <= 1 % of the clean rows outside those groups, check-point RMS (3D, 48 check points over the
    four seeds) within 10 % of the blunder-free adjustment, pooled and in every seed (rejected rows
    keep their other coordinate, snooping.readmit_coordinates). Measured: 67 of 68 (the one missed
    is an 11-sigma x error below its coordinate's MDB of 14 sigma), 10 false alarms (0.30 %), RMS
    +2.2 % pooled, +9.7 % in the worst seed (+12.4 % with whole rows rejected)."""
    s = study["snoop"]
    assert s["n_blunders"] == 68
    assert s["detected"] >= 0.95
    assert s["false_rate"] <= 0.01
    assert abs(s["rms_ratio"] - 1.0) <= 0.10
    assert s["worst_rms_ratio"] <= 1.10


@pytest.mark.xdist_group("separability_study")
def test_separable_snooping_is_better_than_the_classic_and_robust(study):
    """Measured: snoop 67/68 with 10 false alarms, classic 63/68 with 11, robust 59/68 with 16."""
    new, classic, rob = study["snoop"], study["snoop-classic"], study["robust"]
    assert new["found"] > classic["found"] and new["found"] > rob["found"]
    assert new["false"] < classic["false"] and new["false"] < rob["false"]


def test_the_outputs_report_an_inseparable_group(clean_block):
    """End to end (pipeline): residuals.csv flags the three rows "inseparable" (its design columns
    unchanged), summary.json lists the group with its w, MDB and no ground effect, the report says
    "detected, not localisable"; --blunders snoop-classic is the old procedure."""
    project, _ = clean_block
    ip = project.image_points
    pt = three_ray_strip_points(project)[5]
    rows = np.flatnonzero(ip.point_index == pt)
    xy = ip.xy.copy()
    xy[rows[0], 0] -= 25 * SIGMA
    spoiled = replace(project, image_points=replace(ip, xy=xy))
    products = adjust_products(spoiled, OPTIONS, RunOptions(blunders="snoop"))
    table = list(csv.DictReader(io.StringIO(products.files["residuals.csv"])))
    assert list(table[0])[:6] == ["photo_id", "point_id", "vx", "vy", "w", "flag"]
    assert [table[i]["flag"] for i in rows] == ["inseparable"] * 3
    summary = json.loads(products.files["summary.json"])
    groups = [g for g in summary["blunders"]["groups"] if g["point_id"] == str(project.points.ids[pt])]
    assert len(groups) == 1 and sorted(groups[0]["rows"]) == sorted(int(i) for i in rows)
    assert groups[0]["localised"] is False and groups[0]["mdb"] > 0 and groups[0]["ground_effect"] is None
    assert summary["blunders"]["inseparable"] >= 3
    assert "detected, not localisable" in products.files["report.html"]
    classic = adjust_products(spoiled, OPTIONS, RunOptions(blunders="snoop-classic"))
    table = list(csv.DictReader(io.StringIO(classic.files["residuals.csv"])))
    assert sorted(table[i]["flag"] for i in rows) in (["", "", "rejected"], ["", "dropped", "rejected"])
