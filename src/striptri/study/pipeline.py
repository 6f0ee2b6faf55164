"""``striptri compare``: run a study and write its output folder atomically:
study.csv, growth.csv, precision.csv, along.csv and report.html (docs/study.md)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from striptri.io.csvtable import format_csv
from striptri.io.output import OutputReservation
from striptri.study.growth import along_strip, growth_table, precision_table
from striptri.study.options import StudyOptions, tasks_of
from striptri.study.report import report_html
from striptri.study.runner import Progress, run_tasks
from striptri.study.trial import ROW_COLUMNS


@dataclass
class StudyResult:
    out_dir: Path
    rows: list[dict]
    growth: dict
    precision: dict
    n_failed: int


def run_study(options: StudyOptions, workers: int | None = None, scheduler=None,
              progress: Progress | None = None) -> tuple[list[dict], dict]:
    """-> (rows of study.csv sorted by layout, n_photos, sigma_image, trial and method order,
    along-strip errors). workers / scheduler: study.runner.run_tasks."""
    results = run_tasks(tasks_of(options), workers=workers, scheduler=scheduler, progress=progress)
    rows = [row for _, task_rows, _ in results for row in task_rows]
    return rows, along_strip([(task, along) for task, _, along in results])


def columns_of(rows: list[dict], names) -> dict:
    return {c: [r[c] for r in rows] for c in names}


def along_table(along: dict) -> dict:
    cols = {c: [] for c in ("method", "layout", "n_photos", "sigma_image", "photo", "rms_centre_error")}
    for (label, layout, n, sigma), e in sorted(along.items(), key=lambda kv: (kv[0][1], kv[0][2], kv[0][3], kv[0][0])):
        for i, v in enumerate(e):
            for c, x in zip(cols, (label, layout, n, sigma, i + 1, float(v))):
                cols[c].append(x)
    return cols


def run_compare(out_dir, options: StudyOptions, workers: int | None = None, scheduler=None,
                progress: Progress | None = None) -> StudyResult:
    """Run the study and write out_dir (atomically: whole or not at all). The output location is
    checked and reserved before the first trial runs."""
    with OutputReservation(out_dir) as reservation:
        return _run_and_write(reservation, options, workers, scheduler, progress)


def _run_and_write(reservation: OutputReservation, options: StudyOptions, workers, scheduler, progress) -> StudyResult:
    rows, along = run_study(options, workers=workers, scheduler=scheduler, progress=progress)
    return commit_study(reservation, options, rows, along)


def commit_study(reservation: OutputReservation, described, rows: list[dict], along) -> StudyResult:
    """The study's five files (study.csv, growth.csv, precision.csv, along.csv, report.html) from its
    rows and along-strip errors, committed to the reserved output folder. described: what
    report_html reads of a study (StudyOptions, or its stand-in for a study on a project)."""
    growth, precision = growth_table(rows), precision_table(rows)
    files = {
        "study.csv": format_csv(columns_of(rows, ROW_COLUMNS)),
        "growth.csv": format_csv(growth),
        "precision.csv": format_csv(precision),
        "along.csv": format_csv(along_table(along)),
        "report.html": report_html(described, rows, growth, precision, along),
    }
    path = reservation.commit(files)
    return StudyResult(path, rows, growth, precision, sum(r["status"] != "ok" for r in rows))
