"""The comparison-budget study (evaluation/comparison_budget.py) on a tiny case: every source of comparisons is
deployed on its first k, k = 0 is the same empty context for all, the budgets reached follow the means, and the
table says "not within K" from the JSON alone."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from factories import save_untrained

from icprl_lightning.evaluation.base import Run
from icprl_lightning.evaluation.comparison_budget import ComparisonBudget, PrefixAgent
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.online import OnlineAgent
from icprl_lightning.registry import EVALUATIONS

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> str:
    torch.manual_seed(0)
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=6,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    return str(save_untrained(module, tmp_path_factory.mktemp("budget") / "icpo.ckpt"))


def test_every_source_is_deployed_on_its_first_k_comparisons(tiny_ipref, checkpoint):
    study = EVALUATIONS.get("comparison_budget")(rules=["top_two", "uniform"], diagnostics=["flipped"],
                                                 budgets=[0, 3, 6], episodes=2, targets=[0.01, 1.0])
    result = study.run([Run("ICPO", tiny_ipref, (checkpoint,))], [0])["results"]["ICPO"]
    assert result["budgets"] == [0, 3, 6] and result["tasks"] == 20
    rows = result["rows"]
    assert list(rows) == ["online top_two", "online uniform", "online top_two, flipped labels", "offline",
                          "offline, flipped labels"]
    assert len({row["mean"][0] for row in rows.values()}) == 1  # k = 0: the empty context, whatever the source
    for row in rows.values():
        low, high = np.array(row["interval"]).T
        assert np.all(low <= np.array(row["mean"]) + 1e-9) and np.all(np.array(row["mean"]) <= high + 1e-9)
        first = next((k for k, m in zip(result["budgets"], row["mean"], strict=True) if m >= 0.01), None)
        assert row["reach"] == {"0.01": first, "1.0": None}  # an untrained model never walks the optimal path


def test_a_prefix_agent_acts_as_the_online_agent_on_the_first_k_comparisons(tiny_ipref, checkpoint):
    context = tiny_ipref.held_out("rollouts")[0].context
    obs = context.states[:, 0]
    prefixed, plain = PrefixAgent(OnlineAgent.load(checkpoint), 3), OnlineAgent.load(checkpoint)
    prefixed.reset(context)
    plain.reset(context.map(lambda x: x[:, :3]))
    assert torch.equal(prefixed.act(obs), plain.act(obs)) and prefixed.agent.length == 3
    PrefixAgent(plain, 0).reset(context)
    assert plain.length == 0


def test_the_table_says_not_within_the_largest_budget():
    payload = {"quality": "medium", "episodes": 5, "targets": [0.5, 0.8],
               "annotator": {"class_path": "icprl_lightning.annotators.BradleyTerryAnnotator",
                             "init_args": {"temperature": 1.0}},
               "results": {"ICPO": {"budgets": [0, 50, 100], "checkpoints": ["a", "b"], "tasks": 20,
                                    "rows": {"offline": {"mean": [0.1, 0.6, 0.7],
                                                         "interval": [[0.0, 0.2], [0.5, 0.7], [0.6, 0.8]],
                                                         "reach": {"0.5": 50, "0.8": None}}}}}}
    table = ComparisonBudget.markdown(payload)
    assert "| offline | 50 | not within 100 |" in table and "| 50 | 0.60 (0.50–0.70) |" in table
    assert "2 training seeds × 20 held-out tasks" in table


@pytest.mark.parametrize(("option", "value", "match"), [
    ("rules", ["best"], "rules"), ("diagnostics", ["own"], "diagnostics"), ("episodes", 0, "episodes"),
    ("budgets", [-1], "budgets"), ("targets", [1.5], "targets"), ("temperature", 0.0, "temperature")])
def test_a_bad_option_is_one_error_naming_it(option, value, match):
    with pytest.raises(ValueError, match=match):
        ComparisonBudget(**{option: value})
