"""Summaries of a study's rows: the growth law of the error at the strip end, predicted against
empirical precision, and the error along the strip. Pure functions of tables."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from striptri.study.options import METHOD_SPECS

GROWTH_COLUMNS = ("method", "procedure", "direction", "layout", "sigma_image", "n_sizes", "a", "b",
                  "se_b", "log_a", "se_log_a", "trials")
PRECISION_COLUMNS = ("method", "layout", "n_photos", "sigma_image", "trials", "predicted_last",
                     "empirical_last", "ratio", "sigma0_mean")


def label_of(row: dict) -> str:
    """The METHOD_SPECS label of a study.csv row."""
    spec = (row["method"], row["procedure"], row["direction"])
    return next(k for k, v in METHOD_SPECS.items() if v == spec)


def fit_power_law(n, error) -> dict:
    """Least squares fit of log error = log a + b log n. n, error: (k,) positive.
    -> {a, b, log_a, se_b, se_log_a, n_sizes}; the standard errors from the residual scatter
    (k - 2 degrees of freedom; nan for k = 2). Raises ValueError for fewer than two sizes or a
    non-positive value."""
    n, error = np.asarray(n, dtype=float), np.asarray(error, dtype=float)
    if len(n) < 2 or len(np.unique(n)) < 2:
        raise ValueError("a power law needs errors at two strip lengths or more")
    if not (np.all(n > 0) and np.all(error > 0)):
        raise ValueError("a power law is fitted to positive values only")
    X = np.column_stack([np.ones_like(n), np.log(n)])
    y = np.log(error)
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = len(n) - 2
    if dof > 0:
        s2 = float(np.sum((y - X @ beta) ** 2) / dof)
        cov = s2 * np.linalg.inv(X.T @ X)
        se_log_a, se_b = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    else:
        se_log_a = se_b = math.nan
    return {"a": math.exp(beta[0]), "b": float(beta[1]), "log_a": float(beta[0]), "se_b": se_b,
            "se_log_a": se_log_a, "n_sizes": len(n)}


def _ok(rows):
    return [r for r in rows if r["status"] == "ok"]


def rms(values) -> float:
    v = np.asarray(list(values), dtype=float)
    return float(np.sqrt(np.mean(v**2))) if len(v) else math.nan


def end_errors(rows) -> dict:
    """(label, layout, sigma_image) -> {n_photos: RMS over trials of the last centre's error}."""
    groups = defaultdict(lambda: defaultdict(list))
    for r in _ok(rows):
        groups[(label_of(r), r["layout"], r["sigma_image"])][r["n_photos"]].append(r["centre_last"])
    return {k: {n: rms(v) for n, v in sorted(by_n.items())} for k, by_n in groups.items()}


def growth_table(rows) -> dict:
    """growth.csv: per method, layout and noise level the law RMS(last centre error) = a n^b."""
    cols = {c: [] for c in GROWTH_COLUMNS}
    trials = defaultdict(set)
    for r in _ok(rows):
        trials[(label_of(r), r["layout"], r["sigma_image"])].add(r["trial"])
    for (label, layout, sigma), by_n in sorted(end_errors(rows).items(), key=lambda kv: _order(kv[0])):
        ns = [n for n, e in by_n.items() if e > 0]
        try:
            fit = fit_power_law(ns, [by_n[n] for n in ns])
        except ValueError:
            fit = {"a": math.nan, "b": math.nan, "log_a": math.nan, "se_b": math.nan, "se_log_a": math.nan,
                   "n_sizes": len(ns)}
        method, procedure, direction = METHOD_SPECS[label]
        values = {"method": method, "procedure": procedure, "direction": direction, "layout": layout,
                  "sigma_image": sigma, "trials": len(trials[(label, layout, sigma)]), **fit}
        for c in GROWTH_COLUMNS:
            cols[c].append(values[c])
    return cols


def precision_table(rows) -> dict:
    """precision.csv: for the simultaneous methods, the predicted mean error of the last centre
    (RMS over trials of sigma from N^-1, a priori) against the empirical RMS of its error, and the
    mean sigma0 (to compare with 1, the injected plate noise being the stated one)."""
    groups = defaultdict(list)
    for r in _ok(rows):
        if r["predicted_last"] is not None and not math.isnan(r["predicted_last"]):
            groups[(r["method"], r["layout"], r["n_photos"], r["sigma_image"])].append(r)
    cols = {c: [] for c in PRECISION_COLUMNS}
    for (method, layout, n, sigma), rs in sorted(groups.items()):
        pred = rms(r["predicted_last"] for r in rs)
        emp = rms(r["centre_last"] for r in rs)
        values = {"method": method, "layout": layout, "n_photos": n, "sigma_image": sigma, "trials": len(rs),
                  "predicted_last": pred, "empirical_last": emp, "ratio": emp / pred if pred > 0 else math.nan,
                  "sigma0_mean": float(np.mean([r["sigma0"] for r in rs]))}
        for c in PRECISION_COLUMNS:
            cols[c].append(values[c])
    return cols


def along_strip(results) -> dict:
    """(label, layout, n_photos, sigma_image) -> (n,) RMS over trials of each centre's error.
    results: [(task, along)] with along: label -> (n,) errors, as run_task returns."""
    groups = defaultdict(list)
    for task, along in results:
        for label, e in along.items():
            groups[(label, task.layout, task.n_photos, task.sigma_image)].append(e)
    return {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in groups.items()}


def _order(key):
    label, layout, sigma = key
    return (layout, sigma, list(METHOD_SPECS).index(label))
