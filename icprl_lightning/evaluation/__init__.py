"""Evaluation on held-out tasks, used alike by the callbacks and by ``icprl evaluate``.

Every evaluation deploys through the public ``Agent`` (``icprl_lightning.deploy``) and reports the paper's metrics:
the latent return of in-context episodes on held-out tasks (``rollout``), and the weak regret of dueling-bandit
duels vs context size (``duels``; paper, appendix "Dueling Bandit Experiments"). ``diagnostics`` changes a context
in one stated way (flipped or random labels, another task's context) to show what a policy reads from it.
``report`` renders both as tables, markdown, JSON and figures; ``command`` builds the tables of ``icprl evaluate``
(its command line: ``commands/evaluate.py``). ``online_mdp`` and ``online_bandit`` deploy an agent that asks for
comparisons as it acts (``icprl evaluate online``, ``online_command.evaluate_online``). The measurements of ``icprl
analyze`` read a model's or a dataset's insides: ``reward_quality``, ``reward_bayes``, ``icrg_labels`` (the reward
stage, over ``trajectory_data``), ``dit_advantages``, ``dit_weights`` and ``label_ceiling``. The suites come from
``icprl_lightning.data.suites``: evaluation imports data, never the reverse.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> its module, imported on first use (PEP 562): ``icprl report`` reads tables without torch
_EXPORTS = {
    **dict.fromkeys(("DIAGNOSTICS", "diagnose", "diagnose_suite"), "diagnostics"),
    **dict.fromkeys(("agent_duels", "behavior_duels", "curve_mean_sem", "dts_duels", "evaluate_duels", "method_name",
                     "regret_curve", "seed_mean_curves", "summarize_regret"), "duels"),
    **dict.fromkeys(("regret_table", "results_table"), "report"),
    **dict.fromkeys(("episode_stats", "rollout_in_context", "rollout_seeds", "suite_env", "summarize"), "rollout"),
}
__all__ = ["DIAGNOSTICS", "agent_duels", "behavior_duels", "curve_mean_sem", "diagnose", "diagnose_suite",
           "dts_duels", "episode_stats", "evaluate_duels", "method_name", "regret_curve", "regret_table",
           "results_table", "rollout_in_context", "rollout_seeds", "seed_mean_curves", "suite_env", "summarize",
           "summarize_regret"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'icprl_lightning.evaluation' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"icprl_lightning.evaluation.{module}"), name)
    globals()[name] = value
    return value
