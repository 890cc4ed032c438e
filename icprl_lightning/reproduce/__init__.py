"""``icprl reproduce TABLE``: remake a results table from scratch (``runner.py`` says how).

Each table is an experiment file, ``configs/experiment/<table>.yaml``: ``experiments.py`` reads it into a table
(``tables.py``: runs and evaluations), ``runner.py`` trains and evaluates, ``fit_logs.py`` reads a finished fit's
CSV log, ``figures.py`` draws what ``icprl evaluate`` does not.
"""

from icprl_lightning.reproduce.experiments import EXPERIMENTS, TableError, load_table, load_tables, table_names
from icprl_lightning.reproduce.figures import FIGURES
from icprl_lightning.reproduce.fit_logs import final_epoch_means, learning_curve
from icprl_lightning.reproduce.runner import evaluate_online, fit_command, fit_inputs, reproduce
from icprl_lightning.reproduce.tables import (
    Evaluation,
    OnlineEvaluation,
    Run,
    Table,
    needed_runs,
    slug,
    stages,
)

__all__ = ["EXPERIMENTS", "FIGURES", "Evaluation", "OnlineEvaluation", "Run", "Table", "TableError",
           "evaluate_online", "final_epoch_means", "fit_command", "fit_inputs", "learning_curve", "load_table",
           "load_tables", "needed_runs", "reproduce", "slug", "stages", "table_names"]
