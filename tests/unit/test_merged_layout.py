"""The merged layout (``models/policy.py``): token j is E(c_j) + E_q(s_{j+1}), one causal pass scores every
context step before its comparison is seen. It is the same function of (s, D_{1:v}) through every entry point
(the causal pass, the general forward, encode + query, and a checkpoint), and never sees what it scores."""

from __future__ import annotations

import pytest
import torch

from icprl_lightning import StepPreferenceContext, load_agent
from icprl_lightning.contexts import ActionSpec
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.losses import icpo_loss
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.models.tokenizers import preferred_first
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError

TOL = dict(atol=1e-5, rtol=1e-5)
SPECS = [ActionSpec(discrete=True, size=5), ActionSpec(discrete=False, size=3)]


def _policy(spec: ActionSpec, seed: int = 0, normalize: bool = False) -> InContextPolicy:
    torch.manual_seed(seed)
    policy = InContextPolicy("step_preference", 2, spec,
                             backbone=TransformerConfig(n_layer=2, n_embd=16, n_head=2), max_context=12,
                             layout="merged", normalize_inputs=normalize)
    with torch.no_grad():
        for p in policy.parameters():
            p.normal_(0.0, 0.3)
        if normalize:
            policy.normalizer.state_mean.fill_(-1.0)
            policy.normalizer.state_std.fill_(0.5)
    return policy.eval()


def _context(spec: ActionSpec, b: int = 3, t: int = 10, seed: int = 1) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(seed)
    if spec.discrete:
        actions, alt = (torch.randint(0, spec.size, (b, t), generator=g) for _ in range(2))
    else:
        actions, alt = (torch.rand(b, t, spec.size, generator=g) * 2 - 1 for _ in range(2))
    return StepPreferenceContext(torch.randn(b, t, 2, generator=g), actions, alt,
                                 torch.randint(0, 2, (b, t), generator=g).float())


@pytest.mark.parametrize("spec", SPECS)
@pytest.mark.parametrize("normalize", [False, True])
def test_causal_pass_equals_the_general_forward_and_the_cache(spec, normalize):
    policy, context = _policy(spec, normalize=normalize), _context(spec)
    t = context.states.shape[1]
    causal = policy.next_step_outputs(context)
    torch.testing.assert_close(causal, policy(context, context.states, torch.arange(t)), **TOL)
    queries = torch.randn(3, 4, 2)
    full = policy(context, queries, torch.full((4,), t))
    torch.testing.assert_close(policy.query(policy.encode(context), queries), full, **TOL)
    # a prefix's cache answers as the causal pass does at that position, for the next step's own state
    for v in (1, 5, t - 1):
        prefix = context.map(lambda x, v=v: x[:, :v])
        cached = policy.query(policy.encode(prefix), context.states[:, v:v + 1])[:, 0]
        torch.testing.assert_close(cached, causal[:, v], **TOL)


@pytest.mark.parametrize("spec", SPECS)
def test_position_j_sees_the_first_j_comparisons_and_the_next_state_only(spec):
    policy, context = _policy(spec), _context(spec)
    base = policy.next_step_outputs(context)
    j = 4
    later = context.map(lambda x: x.clone())
    later.actions[:, j:] = _context(spec, seed=7).actions[:, j:]  # comparison j + 1 (0-based j) and after
    later.preferred[:, j:] = 1 - later.preferred[:, j:]
    later.states[:, j + 1:] += 3.0  # states after s_{j+1}
    moved = policy.next_step_outputs(later)
    torch.testing.assert_close(moved[:, : j + 1], base[:, : j + 1], **TOL)
    assert (moved[:, j + 1:] - base[:, j + 1:]).abs().max() > 1e-3  # not vacuous: later positions see them
    # the query state s_{j+1} itself moves position j, and an earlier label moves it too
    query = context.map(lambda x: x.clone())
    query.states[:, j] += 1.0
    assert (policy.next_step_outputs(query)[:, j] - base[:, j]).abs().max() > 1e-3
    label = context.map(lambda x: x.clone())
    label.preferred[:, j - 1] = 1 - label.preferred[:, j - 1]
    assert (policy.next_step_outputs(label)[:, j] - base[:, j]).abs().max() > 1e-3


def test_appended_policy_has_no_causal_pass():
    policy = InContextPolicy("step_preference", 2, SPECS[0],
                             backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2), max_context=4)
    with pytest.raises(ValueError, match="merged layout's training pass"):
        policy.next_step_outputs(_context(SPECS[0], t=4))


def _icpo(layout: str, **kwargs) -> ICPOModule:
    torch.manual_seed(0)
    return ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10,
                      backbone=TransformerConfig(n_layer=2, n_embd=16, n_head=2),
                      beta=0.5, lam=1.0, pair_source="next", layout=layout, **kwargs)


def _batch(context: StepPreferenceContext) -> ContextSamples:
    return ContextSamples(context)


def test_icpo_next_loss_is_the_same_objective_in_both_layouts():
    """Aligned order: the merged loss is ICPO's loss on T_θ(· | s_{t+1}, D_{1:t}) from the general forward,
    and the appended layout's ``next`` source scores the same comparisons."""
    context = _context(SPECS[0])
    merged = _icpo("merged", pair_steps="aligned")
    loss, _ = merged.loss(_batch(context))
    t = context.states.shape[1]
    logp = merged.policy(context, context.states, torch.arange(t)).log_softmax(-1)
    plus, minus = preferred_first(context)
    by_hand = icpo_loss(logp.gather(-1, plus[..., None]).squeeze(-1), logp.gather(-1, minus[..., None]).squeeze(-1),
                        0.5, 1.0)
    torch.testing.assert_close(loss, by_hand, **TOL)
    appended = _icpo("appended", pair_steps="aligned")
    logp = appended.policy(context, context.states, torch.arange(t)).log_softmax(-1)
    torch.testing.assert_close(appended.loss(_batch(context))[0], icpo_loss(
        logp.gather(-1, plus[..., None]).squeeze(-1), logp.gather(-1, minus[..., None]).squeeze(-1), 0.5, 1.0), **TOL)
    assert not merged.needs_pairs and not appended.needs_pairs


def test_shuffled_order_scores_a_permutation_of_the_steps():
    """pair_steps shuffled reorders D per sample: the loss differs from the aligned one and changes per draw,
    and with one label-free step the loss is order-invariant (every order scores the same single step)."""
    context = _context(SPECS[0])
    module = _icpo("merged").train().requires_grad_(False)
    losses = {round(float(module.loss(_batch(context))[0]), 6) for _ in range(3)}
    assert len(losses) == 3
    single = context.map(lambda x: x[:, :1])
    assert len({round(float(module.loss(_batch(single))[0]), 6) for _ in range(3)}) == 1


def test_bad_combinations_name_the_field():
    with pytest.raises(HyperparameterError, match="pair_source 'next'"):
        ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10, layout="merged")
    with pytest.raises(HyperparameterError, match="queries_per_context"):
        _icpo("merged", queries_per_context=4)
    with pytest.raises(HyperparameterError, match="layout"):
        _icpo("sideways")


def test_merged_checkpoint_loads_and_acts_as_its_policy(tmp_path):
    module = _icpo("merged")
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
    path = tmp_path / "merged.ckpt"
    torch.save(checkpoint, path)
    agent = load_agent(path)
    assert agent.policy.layout == "merged"
    context, obs = _context(SPECS[0]), torch.randn(3, 2)
    agent.reset(context)
    expected = module.policy(context, obs[:, None], torch.tensor([context.states.shape[1]]))[:, 0].argmax(-1)
    assert torch.equal(agent.act(obs), expected)
    uncached = load_agent(path, use_cache=False)
    uncached.reset(context)
    assert torch.equal(uncached.act(obs), expected)
