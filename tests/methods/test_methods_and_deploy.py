"""Each module updates its parameters; checkpoint -> load_agent -> act; the deployment API's errors."""

import lightning as L
import pytest
import torch
from factories import darkroom_data  # noqa: E402

from icprl_lightning import StepPreferenceContext, load_agent
from icprl_lightning.contexts import RewardContext
from icprl_lightning.methods.dpt import DP2TModule, DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError

SIZES = dict(backbone=TransformerConfig(n_layer=2, n_embd=32, n_head=2))


def _module(cls, dm, **kw):
    return cls(state_dim=dm.state_dim, action_dim=dm.action_spec.size, discrete=True,
               max_context=dm.context_length, **SIZES, **kw)


@pytest.mark.parametrize("cls,fixture,kw", [
    (ICPOModule, "tiny_ipref", {}),
    (ICPOModule, "tiny_ipref", {"pair_source": "context"}),
    (DP2TModule, "tiny_ipref", {}),
    (DPTModule, "tiny_reward", {}),
])
def test_every_parameter_moves_after_a_step(cls, fixture, kw, request):
    dm = request.getfixturevalue(fixture)
    torch.manual_seed(0)
    model = _module(cls, dm, **kw)
    before = {k: v.clone() for k, v in model.named_parameters()}
    opt = model.configure_optimizers()
    loss, _ = model.loss(next(iter(dm.train_dataloader())))
    loss.backward()
    opt.step()
    frozen = [k for k, v in model.named_parameters() if torch.equal(v, before[k])]
    assert frozen == [], frozen


def test_icpo_refuses_data_without_pairs_before_a_step(tiny_ipref, tiny_kwargs):
    """ICPO's default loss scores another trajectory of the task: a fit on data without pairs stops at its start
    (the pairing check, also without the CLI), not inside the loss."""
    dm = darkroom_data(root_dir=tiny_ipref.root_dir, pairs=False, **tiny_kwargs)
    trainer = L.Trainer(fast_dev_run=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False)
    model = _module(ICPOModule, dm)
    with pytest.raises(HyperparameterError, match="ICPOModule .*needs PreferenceDataModule with pairs: true"):
        trainer.fit(model, datamodule=dm)
    assert trainer.global_step == 0


@pytest.fixture(scope="module")
def icpo_checkpoint(tmp_path_factory, request):
    dm = request.getfixturevalue("tiny_ipref")
    root = tmp_path_factory.mktemp("ckpt")
    trainer = L.Trainer(max_steps=2, limit_val_batches=1, logger=False, default_root_dir=root,
                        enable_progress_bar=False, enable_model_summary=False)
    model = _module(ICPOModule, dm)
    trainer.fit(model, datamodule=dm)
    path = root / "icpo.ckpt"
    trainer.save_checkpoint(path)
    return path, dm


def _eval_context(dm, quality="high"):
    return next(s for s in dm.held_out("rollouts") if s.quality == quality).context


def test_checkpoint_round_trip_cached_equals_uncached(icpo_checkpoint):
    path, dm = icpo_checkpoint
    ctx = _eval_context(dm)
    obs = ctx.states[:, 0]
    cached = load_agent(path, greedy=True)
    uncached = load_agent(path, greedy=True, use_cache=False)
    cached.reset(ctx)
    uncached.reset(ctx)
    for _ in range(3):
        a = cached.act(obs)
        assert a.shape == (ctx.batch_size,) and a.dtype == torch.int64
        assert torch.equal(a, uncached.act(obs))
        obs = torch.rand_like(obs) * 9


@pytest.mark.slow  # torch.compile: tens of seconds of compilation
def test_compiled_agent_acts_as_the_eager_one(icpo_checkpoint):
    """load_agent(compile=True) runs the query step through torch.compile: the same logits to float tolerance,
    over a second reset (new context, same shapes: no recompile needed) too."""
    path, dm = icpo_checkpoint
    eager, compiled = load_agent(path), load_agent(path, compile=True)
    for quality in ("high", "low"):
        ctx = _eval_context(dm, quality)
        eager.reset(ctx)
        compiled.reset(ctx)
        obs = ctx.states[:, 0]
        for _ in range(3):
            actions = compiled.act(obs)
            assert actions.shape == (ctx.batch_size,) and actions.dtype == torch.int64
            eager.act(obs)  # encodes the eager cache
            logits = eager.policy.query(eager.cache, obs[:, None])[:, 0]
            torch.testing.assert_close(compiled._compiled_query(compiled.cache, obs[:, None])[:, 0], logits)
            top2 = logits.topk(2).values
            clear = top2[:, 0] - top2[:, 1] > 1e-4  # the argmax is unambiguous at float tolerance
            assert torch.equal(actions[clear], logits.argmax(-1)[clear])
            obs = torch.rand_like(obs) * 9
    with pytest.raises(ValueError, match="use_cache=True"):
        load_agent(path, use_cache=False, compile=True)


def test_sampling_is_seeded(icpo_checkpoint):
    path, dm = icpo_checkpoint
    ctx = _eval_context(dm)
    runs = []
    for _ in range(2):
        agent = load_agent(path, greedy=False, seed=7)
        agent.reset(ctx)
        runs.append(torch.stack([agent.act(ctx.states[:, t]) for t in range(5)]))
    assert torch.equal(runs[0], runs[1])


def test_bad_inputs_are_clear_errors(icpo_checkpoint, tmp_path):
    path, dm = icpo_checkpoint
    agent = load_agent(path)
    assert agent.greedy  # ICPO's own default
    ctx = _eval_context(dm)
    with pytest.raises(RuntimeError, match="reset"):
        agent.act(torch.zeros(ctx.batch_size, 2))
    with pytest.raises(ValueError, match=r"states must have shape \[B, T, S=2\]"):
        agent.reset(StepPreferenceContext(ctx.states[..., :1], ctx.actions, ctx.alt_actions, ctx.preferred))
    with pytest.raises(ValueError, match="actions must be an integer tensor"):
        agent.reset(StepPreferenceContext(ctx.states, ctx.actions.float(), ctx.alt_actions, ctx.preferred))
    with pytest.raises(ValueError, match="outside"):
        agent.reset(StepPreferenceContext(ctx.states, ctx.actions + 5, ctx.alt_actions, ctx.preferred))
    with pytest.raises(ValueError, match="takes a StepPreferenceContext"):
        agent.reset(RewardContext(ctx.states, ctx.actions, ctx.preferred, ctx.states))
    long = StepPreferenceContext(*(torch.cat([x, x], 1) for x in (ctx.states, ctx.actions, ctx.alt_actions,
                                                                 ctx.preferred)))
    with pytest.raises(ValueError, match="at most 100"):
        agent.reset(long)
    agent.reset(ctx)
    with pytest.raises(ValueError, match=r"obs must be a float tensor of shape \[B=\d+, S=2\]"):
        agent.act(torch.zeros(ctx.batch_size + 1, 2))
    with pytest.raises(FileNotFoundError, match="No checkpoint"):
        load_agent(tmp_path / "missing.ckpt")
    broken = tmp_path / "broken.ckpt"
    broken.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(ValueError, match="not a readable checkpoint"):
        load_agent(broken)
    foreign = tmp_path / "foreign.ckpt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(ValueError, match="not an icprl_lightning checkpoint"):
        load_agent(foreign)
