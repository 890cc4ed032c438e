"""A loaded ``Agent`` says what it takes: ``obs_dim``, ``action_spec``, ``max_context`` and ``context_kind``,
for a checkpoint of every context kind (tiny random-weight modules saved as training saves them), and a
context built from those properties alone is accepted by ``reset`` and ``act``."""

from __future__ import annotations

from typing import get_args

import pytest
import torch
from factories import save_untrained

from icprl_lightning import load_agent
from icprl_lightning.contexts import CONTEXT_TYPES, ActionSpec, context_fields
from icprl_lightning.deploy import Agent, ContextKind
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.dpt import DP2TModule, DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
# (module, its init arguments, the context kind its agent takes)
CASES = {
    "dpt": (DPTModule, dict(state_dim=2, action_dim=5, discrete=True, max_context=7), "reward"),
    "dp2t_step": (DP2TModule, dict(state_dim=3, action_dim=4, discrete=True, max_context=6), "step_preference"),
    "dp2t_pairs": (DP2TModule, dict(state_dim=2, action_dim=3, discrete=False, max_context=5,
                                    context_kind="trajectory_preference"), "trajectory_preference"),
    "icpo_continuous": (ICPOModule, dict(state_dim=4, action_dim=2, discrete=False, max_context=9),
                        "step_preference"),
    "icpo_bandit": (ICPOModule, dict(state_dim=0, action_dim=20, discrete=True, max_context=10), "step_preference"),
    "dit": (DITModule, dict(state_dim=2, action_dim=5, discrete=True, max_context=8), "reward_trajectory"),
}
pytestmark = pytest.mark.usefixtures("one_thread")


_save = save_untrained


@pytest.fixture(scope="module")
def agents(tmp_path_factory) -> dict[str, Agent]:
    root = tmp_path_factory.mktemp("agents")
    torch.manual_seed(0)
    return {name: load_agent(_save(cls(**kw, **SIZES), root / f"{name}.ckpt")) for name, (cls, kw, _) in CASES.items()}


def _context_from_properties(agent: Agent, batch: int, steps: int):
    """A valid context of the agent's kind, built from its properties only (no knowledge of the checkpoint)."""
    spec = agent.action_spec
    shapes = {"states": (agent.obs_dim,), "next_states": (agent.obs_dim,), "rewards": (), "preferred": ()}

    def value(field: str) -> torch.Tensor:
        base = field.removesuffix("_a").removesuffix("_b")
        if base in ("states", "next_states", "rewards"):
            return torch.rand(batch, steps, *shapes[base])
        if field == "preferred":  # one label per step (I-PRL) or per pair (T-PRL)
            return torch.ones(batch, steps) if agent.context_kind == "step_preference" else torch.ones(batch)
        if spec.discrete:  # an action field
            return torch.randint(0, spec.size, (batch, steps))
        return torch.rand(batch, steps, spec.size) * 2 - 1

    cls = CONTEXT_TYPES[agent.context_kind]
    return cls(**{field: value(field) for field in context_fields(agent.context_kind)
                  if field not in ("behavior_states", "behavior_actions")})


def test_context_kind_literal_lists_every_context_kind():
    assert set(get_args(ContextKind)) == set(CONTEXT_TYPES)


@pytest.mark.parametrize("name", list(CASES))
def test_agent_exposes_what_its_checkpoint_takes(agents, name):
    cls, kw, kind = CASES[name]
    agent = agents[name]
    assert agent.obs_dim == kw["state_dim"]
    assert agent.action_spec == ActionSpec(discrete=kw["discrete"], size=kw["action_dim"])
    assert agent.max_context == kw["max_context"]
    assert agent.context_kind == kind and agent.context_type is CONTEXT_TYPES[kind]

    context = _context_from_properties(agent, batch=3, steps=agent.max_context)
    agent.reset(context)
    actions = agent.act(torch.zeros(3, agent.obs_dim))
    assert actions.shape == ((3,) if agent.action_spec.discrete else (3, agent.action_spec.size))
    with pytest.raises(ValueError, match=f"at most {agent.max_context}"):
        agent.reset(_context_from_properties(agent, batch=3, steps=agent.max_context + 1))
