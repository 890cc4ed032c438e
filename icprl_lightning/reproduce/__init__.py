"""``icprl reproduce TABLE``: remake a table of ``docs/RESULTS.md`` from scratch (``runner.py`` says how).

``tables.py`` is the catalogue (runs, evaluations, ``TABLES``), ``runner.py`` trains and evaluates,
``fit_logs.py`` reads a finished fit's CSV log, ``figures.py`` draws what ``icprl evaluate`` does not.
"""

from icprl_lightning.reproduce.figures import FIGURES
from icprl_lightning.reproduce.fit_logs import final_epoch_means, learning_curve
from icprl_lightning.reproduce.runner import fit_command, fit_inputs, main, needed_runs, reproduce, stages
from icprl_lightning.reproduce.tables import (
    MISTAKE_RATES,
    REACH_CONTEXTS_PER_GOAL,
    REACH_RECIPES,
    REACH_SCALES,
    RECIPE_TITLES,
    TABLES,
    Evaluation,
    Run,
    Table,
    slug,
)

__all__ = ["FIGURES", "MISTAKE_RATES", "REACH_CONTEXTS_PER_GOAL", "REACH_RECIPES", "REACH_SCALES", "RECIPE_TITLES",
           "TABLES", "Evaluation", "Run", "Table", "final_epoch_means", "fit_command", "fit_inputs", "learning_curve",
           "main", "needed_runs", "reproduce", "slug", "stages"]
