"""Who labels a pair (DESIGN.md, "annotators/"): the Bradley–Terry oracle, B-Pref's scripted teachers, any
Python function, an HTTP endpoint (an LLM); a person answers in the browser (``labelling/online.py``,
``BrowserAnnotator``). A setting takes one as ``annotator``::

    setting:
      class_path: icprl_lightning.data.settings.TrajectoryPairs
      init_args:
        annotator:
          class_path: icprl_lightning.annotators.ScriptedTeacher
          init_args: {beta: 10.0, gamma: 0.99, epsilon: 0.1}

A data-side layer: it sees the oracle's utilities, so models and methods never import it.
"""

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.bradley_terry import BradleyTerryAnnotator
from icprl_lightning.annotators.endpoint import HTTPAnnotator
from icprl_lightning.annotators.function import CallableAnnotator
from icprl_lightning.annotators.labels import EQUAL, FIRST, SECOND, SKIP, AnnotatorError
from icprl_lightning.annotators.scripted import ScriptedTeacher

__all__ = ["EQUAL", "FIRST", "SECOND", "SKIP", "Annotator", "AnnotatorError", "BradleyTerryAnnotator",
           "CallableAnnotator", "HTTPAnnotator", "ScriptedTeacher", "StepQueries", "TrajectoryQueries"]
