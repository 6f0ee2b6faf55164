"""Method-comparison studies (DESIGN section 9; ``striptri compare``; docs/study.md).

* :mod:`.options` -- StudyOptions, the tasks (configuration x trial) and their seeds;
* :mod:`.trial` -- one task: simulate a strip, adjust it by every method, errors against the truth;
* :mod:`.runner` -- run the tasks serially, on local processes or on a Dask cluster;
* :mod:`.growth` -- growth law a n^b, predicted against empirical precision, error along the strip;
* :mod:`.report` -- figures and report.html;
* :mod:`.pipeline` -- run_compare: the study and its output folder.
"""

from striptri.study.growth import fit_power_law, growth_table, precision_table
from striptri.study.options import METHOD_LABELS, STUDY_LAYOUTS, StudyOptions, Task, tasks_of, trial_seed
from striptri.study.pipeline import StudyResult, run_compare, run_study
from striptri.study.trial import ROW_COLUMNS, cantilever_project, run_task, simulate_task

__all__ = [
    "METHOD_LABELS", "ROW_COLUMNS", "STUDY_LAYOUTS", "StudyOptions", "StudyResult", "Task", "cantilever_project",
    "fit_power_law", "growth_table", "precision_table", "run_compare", "run_study", "run_task", "simulate_task",
    "tasks_of", "trial_seed",
]
