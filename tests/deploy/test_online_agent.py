"""Online deployment (``online.py``): comparisons appended one token at a time into the KV cache give the
same policy as re-encoding the grown context, and as the full forward pass; empty starts; max_context."""

from __future__ import annotations

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icprl_lightning import OnlineAgent, StepPreferenceContext
from icprl_lightning.contexts import ActionSpec
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import LAYOUTS, InContextPolicy
from icprl_lightning.models.transformer import CausalTransformer
from icprl_lightning.online import PAIR_RULES, SampledPair, TopTwo, UniformPair

TOL = dict(atol=1e-5, rtol=1e-5)


def _policy(state_dim: int, spec: ActionSpec, max_context: int = 12, n_layer: int = 2, seed: int = 0,
            kind: str = "step_preference", layout: str = "appended", normalize_inputs: bool = False
            ) -> InContextPolicy:
    """A random untrained policy, its weights drawn wider than the init's so that every token moves the outputs
    (with ``normalize_inputs``, statistics that are far from the identity)."""
    torch.manual_seed(seed)
    policy = InContextPolicy(kind, state_dim, spec,
                             backbone=TransformerConfig(n_layer=n_layer, n_embd=16, n_head=2), max_context=max_context,
                             layout=layout, normalize_inputs=normalize_inputs)
    with torch.no_grad():
        for p in policy.parameters():
            p.normal_(0.0, 0.3)
        if normalize_inputs:
            policy.normalizer.state_mean.fill_(2.0)
            policy.normalizer.state_std.fill_(0.25)
    return policy.eval()


def _random_labels(b: int, g: torch.Generator):
    return lambda obs, first, second: torch.randint(0, 2, (b,), generator=g)


def _initial_context(b: int, t: int, state_dim: int, spec: ActionSpec, g: torch.Generator) -> StepPreferenceContext:
    if spec.discrete:
        actions, alt = (torch.randint(0, spec.size, (b, t), generator=g) for _ in range(2))
    else:
        actions, alt = (torch.rand(b, t, spec.size, generator=g) * 2 - 1 for _ in range(2))
    return StepPreferenceContext(torch.randn(b, t, state_dim, generator=g), actions, alt,
                                 torch.randint(0, 2, (b, t), generator=g))


def _check_against_reencoding(agent: OnlineAgent, obs: torch.Tensor) -> None:
    """The online agent's outputs and actions equal encode + query and forward on its grown context."""
    policy, context = agent.policy, agent.context
    online = agent.outputs(obs)
    query = obs[:, None, :]
    full = policy(context, query, torch.tensor([context.states.shape[1]]))[:, 0]
    torch.testing.assert_close(online, full, **TOL)
    if context.states.shape[1] > 0:  # encode needs at least one token
        torch.testing.assert_close(online, policy.query(policy.encode(context), query)[:, 0], **TOL)
    if policy.action_spec.discrete:
        assert torch.equal(agent.act(obs), full.argmax(-1))
    else:
        torch.testing.assert_close(agent.act(obs), full, **TOL)


SPECS = [ActionSpec(discrete=True, size=5), ActionSpec(discrete=False, size=3),
         ActionSpec(discrete=True, size=20)]  # the last with state_dim 0: the dueling-bandit context


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(spec_index=st.integers(0, len(SPECS) - 1), b=st.integers(1, 3), steps=st.integers(1, 7),
       start=st.integers(0, 3), n_layer=st.integers(1, 2), seed=st.integers(0, 2**16),
       layout=st.sampled_from(LAYOUTS), normalize=st.booleans())
def test_appending_one_token_at_a_time_equals_reencoding(spec_index, b, steps, start, n_layer, seed, layout,
                                                         normalize):
    """Both layouts (models/policy.py), with and without input standardization (which ``observe`` once skipped)."""
    spec = SPECS[spec_index]
    state_dim = 0 if spec_index == 2 else 2
    policy = _policy(state_dim, spec, n_layer=n_layer, seed=seed, layout=layout,
                     normalize_inputs=normalize and state_dim > 0)
    g = torch.Generator().manual_seed(seed)
    agent = OnlineAgent(policy, seed=seed)
    agent.reset(_initial_context(b, start, state_dim, spec, g) if start else b)
    for _ in range(steps):
        obs = torch.randn(b, state_dim, generator=g)
        _check_against_reencoding(agent, obs)
        agent.step(obs, _random_labels(b, g))
    assert agent.length == start + steps
    obs = torch.randn(b, state_dim, generator=g)
    _check_against_reencoding(agent, obs)
    # not vacuous: the context's labels, all flipped, change the outputs well beyond the tolerance (1e-5); one flipped
    # label can move an untrained 1-layer model by less (9e-5 was found)
    flipped = agent.context.map(lambda x: x.clone())
    flipped.preferred[:] = 1 - flipped.preferred
    visible = torch.tensor([agent.length])
    assert (policy(flipped, obs[:, None], visible) - agent.outputs(obs)[:, None]).abs().max() > 1e-4


def test_uncached_agent_gives_the_same_proposals_and_actions():
    spec, b = ActionSpec(discrete=True, size=5), 3
    policy = _policy(2, spec)
    cached, uncached = OnlineAgent(policy, seed=1), OnlineAgent(policy, seed=1, use_cache=False)
    cached.reset(b)
    uncached.reset(b)
    g = torch.Generator().manual_seed(0)
    for _ in range(6):
        obs = torch.randn(b, 2, generator=g)
        labels = torch.randint(0, 2, (b,), generator=g)
        pair, pair_ref = cached.propose(obs), uncached.propose(obs)
        assert all(torch.equal(x, y) for x, y in zip(pair, pair_ref, strict=True))
        cached.observe(obs, *pair, labels)
        uncached.observe(obs, *pair_ref, labels)
    obs = torch.randn(b, 2, generator=g)
    torch.testing.assert_close(cached.outputs(obs), uncached.outputs(obs), **TOL)


def test_empty_start_queries_position_zero():
    spec, b = ActionSpec(discrete=True, size=5), 2
    policy = _policy(2, spec)
    agent = OnlineAgent(policy)
    agent.reset(b)
    assert agent.length == 0 and agent.cache.length == 0
    obs = torch.randn(b, 2)
    torch.testing.assert_close(agent.outputs(obs), policy(agent.context, obs[:, None], torch.tensor([0]))[:, 0], **TOL)
    first, second = agent.propose(obs)
    assert first.shape == second.shape == (b,) and bool((first != second).all())  # uniform over the *other* arms


def test_extend_equals_encode_and_grows_geometrically():
    torch.manual_seed(0)
    net = CausalTransformer(TransformerConfig(n_layer=2, n_embd=16, n_head=2), max_context=20).eval()
    tokens, q = torch.randn(2, 20, 16), torch.randn(2, 1, 16)
    cache, capacities = net.empty_cache(2), []
    for i in range(20):
        net.extend(cache, tokens[:, i:i + 1])
        capacities.append(cache.capacity)
    ref = net.encode(tokens)
    for k, k_ref in zip(cache.keys, ref.keys, strict=True):  # stored transposed: (B, nh, hs, slots)
        torch.testing.assert_close(k[..., :20], k_ref[..., :20], **TOL)
    for v, v_ref in zip(cache.values, ref.values, strict=True):
        torch.testing.assert_close(v[:, :, :20], v_ref[:, :, :20], **TOL)
    torch.testing.assert_close(net.query(cache, q), net(tokens, q, torch.tensor([20])), **TOL)
    assert len(set(capacities)) <= 6 and max(capacities) == 21  # 2, 4, 8, 16, 21: O(log T) copies, capped
    # several tokens at once after an encoded prefix
    cache = net.encode(tokens[:, :5])
    net.extend(cache, tokens[:, 5:12])
    torch.testing.assert_close(net.query(cache, q), net(tokens[:, :12], q, torch.tensor([12])), **TOL)


def test_exceeding_max_context_is_a_clear_error():
    spec, b = ActionSpec(discrete=True, size=4), 2
    agent = OnlineAgent(_policy(1, spec, max_context=3))
    agent.reset(b)
    g = torch.Generator().manual_seed(0)
    for _ in range(3):
        agent.step(torch.randn(b, 1, generator=g), _random_labels(b, g))
    with pytest.raises(ValueError, match="max_context"):
        agent.step(torch.randn(b, 1, generator=g), _random_labels(b, g))
    assert agent.length == 3 and agent.cache.length == 3  # nothing changed
    agent.act(torch.randn(b, 1))  # still usable
    net = agent.policy.transformer
    with pytest.raises(ValueError, match="max_context 3"):
        net.extend(net.empty_cache(b), torch.zeros(b, 4, 16))
    with pytest.raises(ValueError, match="tokens must have shape"):
        net.extend(net.empty_cache(b), torch.zeros(b + 1, 1, 16))


def test_bad_comparisons_and_resets_are_clear_errors():
    spec, b = ActionSpec(discrete=True, size=4), 2
    agent = OnlineAgent(_policy(1, spec))
    with pytest.raises(RuntimeError, match="reset"):
        agent.propose(torch.zeros(b, 1))
    for bad in (0, True, "2", None):
        with pytest.raises(ValueError, match="batch size|batch_size"):
            agent.reset(bad)
    agent.reset(b)
    obs, a = torch.zeros(b, 1), torch.tensor([0, 1])
    with pytest.raises(ValueError, match="observe: preferred must hold only 0 or 1"):
        agent.observe(obs, a, a, torch.tensor([2, 0]))
    with pytest.raises(ValueError, match="observe: actions holds action indices outside"):
        agent.observe(obs, torch.tensor([0, 4]), a, torch.tensor([1, 0]))
    with pytest.raises(ValueError, match="observe: preferred must have shape"):
        agent.observe(obs, a, a, torch.tensor([1, 0, 1]))
    with pytest.raises(ValueError, match="obs must be"):
        agent.observe(torch.zeros(b + 1, 1), a, a, torch.tensor([1, 0]))
    assert agent.length == 0


def test_top_two_rule_and_continuous_refusal():
    agent = OnlineAgent(_policy(2, ActionSpec(discrete=True, size=6)), pair_rule=TopTwo())
    agent.reset(3)
    obs = torch.randn(3, 2)
    first, second = agent.propose(obs)
    top = agent.outputs(obs).topk(2).indices
    assert torch.equal(first, top[:, 0]) and torch.equal(second, top[:, 1])
    with pytest.raises(ValueError, match="TopTwo needs discrete actions"):  # when built, not at the first propose
        OnlineAgent(_policy(2, ActionSpec(discrete=False, size=2)), pair_rule=TopTwo())


@pytest.mark.parametrize("rule", [SampledPair, UniformPair])
def test_sampled_and_uniform_pairs_are_distinct_valid_and_seeded(rule):
    spec = ActionSpec(discrete=True, size=4)
    obs = torch.randn(64, 2)
    pairs = []
    for _ in range(2):
        agent = OnlineAgent(_policy(2, spec), pair_rule=rule(), seed=3)
        agent.reset(64)
        pairs.append(agent.propose(obs))
    (first, second), again = pairs
    assert torch.equal(first, again[0]) and torch.equal(second, again[1])  # same seed, same pairs
    assert bool((first != second).all()) and int(first.min()) >= 0 and int(first.max()) < spec.size
    assert len(set(first.tolist())) > 1 and len(set(second.tolist())) > 1


def test_sampled_pair_follows_the_policy_and_survives_a_saturated_softmax():
    spec = ActionSpec(discrete=True, size=5)
    agent = OnlineAgent(_policy(2, spec), pair_rule=SampledPair(), seed=0)
    agent.reset(1)
    logits = torch.tensor([[0.0, 8.0, 7.0, -5.0, -5.0]]).repeat(4000, 1)
    first, second = SampledPair()(agent, logits)
    # first ~ softmax: action 1 with prob e^8 / (e^8 + e^7 + ...) ≈ 0.73; the second then mostly action 2
    assert abs(float((first == 1).float().mean()) - 0.731) < 0.03
    assert float((second[first == 1] == 2).float().mean()) > 0.95
    saturated = torch.tensor([[0.0, 1e4, 0.0]])
    a, b = SampledPair()(agent, saturated)
    assert int(a) == 1 and int(b) in (0, 2)


def test_continuous_rules():
    spec = ActionSpec(discrete=False, size=2)
    agent = OnlineAgent(_policy(2, spec), pair_rule=UniformPair(), seed=0)
    agent.reset(5)
    first, second = agent.propose(torch.randn(5, 2))
    assert first.shape == second.shape == (5, 2) and float(first.abs().max()) <= 1
    with pytest.raises(ValueError, match="SampledPair needs discrete actions"):
        agent.pair_rule = SampledPair()
    assert isinstance(agent.pair_rule, UniformPair)  # the refused rule left the agent as it was
    with pytest.raises(ValueError, match="SampledPair needs discrete actions"):  # the rule called directly
        SampledPair()(agent, torch.randn(5, 2))
    assert set(PAIR_RULES) == {"action_uniform", "top_two", "sampled", "uniform"}


def test_other_context_kinds_are_refused():
    with pytest.raises(ValueError, match="online deployment appends step-preference"):
        OnlineAgent(_policy(2, ActionSpec(discrete=True, size=5), kind="reward"))


def test_loads_a_bandit_checkpoint(tmp_path):
    torch.manual_seed(0)
    module = ICPOModule(state_dim=0, action_dim=6, discrete=True, max_context=5,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
    path = tmp_path / "bandit.ckpt"
    torch.save(checkpoint, path)
    agent = OnlineAgent.load(path, seed=0)
    assert agent.greedy and agent.policy.state_dim == 0
    agent.reset(4)
    g = torch.Generator().manual_seed(0)
    for _ in range(5):
        agent.step(torch.zeros(4, 0), _random_labels(4, g))
    _check_against_reencoding(agent, torch.zeros(4, 0))
    proposals = []
    for _ in range(2):  # the same seed, the same duels
        online = OnlineAgent.load(path, seed=0)
        online.reset(4)
        proposals.append(torch.stack(online.propose(torch.zeros(4, 0))))
    assert torch.equal(*proposals)


@pytest.mark.parametrize("name, rule", sorted(PAIR_RULES.items()))
def test_pair_rules_resolve_by_name_when_the_agent_is_built(tmp_path, name, rule):
    agent = OnlineAgent(_policy(2, ActionSpec(discrete=True, size=4)), pair_rule=name, seed=0)
    assert type(agent.pair_rule) is rule
    agent.reset(3)
    first, second = agent.propose(torch.randn(3, 2))
    assert first.shape == second.shape == (3,)


@pytest.mark.parametrize("rule, message", [("top-two", "'top-two' is not a pair rule; the names are action_uniform, "
                                                       "sampled, top_two, uniform"),
                                           (TopTwo, r"is a class; pass an instance \(TopTwo\(\)\)"),
                                           (3, "must be a name"),
                                           ("sampled", "SampledPair needs discrete actions")])
def test_an_unknown_or_unfit_pair_rule_fails_when_the_agent_is_built(tmp_path, rule, message):
    torch.manual_seed(0)
    module = ICPOModule(state_dim=2, action_dim=3, discrete=rule != "sampled", max_context=5,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
    torch.save(checkpoint, tmp_path / "m.ckpt")
    with pytest.raises(ValueError, match=message):
        OnlineAgent.load(tmp_path / "m.ckpt", pair_rule=rule)
