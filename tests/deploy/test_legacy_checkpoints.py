"""Checkpoints whose hyperparameters hold the backbone's sizes flat (``n_layer``, ``n_embd``, ``n_head``,
``dropout``, as saved before methods took one ``TransformerConfig``) still verify, load and act as they did. The
checkpoint reader gathers the sizes into ``backbone`` (``checkpoints.hyperparameters``) on a copy, after the
checksum and the seal were checked on the entries as saved, which it never rewrites.

``tests/fixtures/legacy/`` holds an ICPO (1 layer × 8 wide, dropout 0.1) and an ICRG (its policy, Q̂, V̂ and
RewardGen each 1 × 8; RewardGen causal, rewards in [0, 1]) with scrambled weights, and ``expected.json``: a fixed
step context, a T-PRL pair with a behavior trajectory, four observations, and what the agents did on them. They
were written once, with the flat-size code, from the repository root (``PYTHONPATH=. python make_legacy.py``)::

    import json
    from pathlib import Path

    import torch

    from icprl_lightning import load_agent
    from icprl_lightning.contexts import StepPreferenceContext, TrajectoryPreferenceContext
    from icprl_lightning.methods.icpo import ICPOModule
    from icprl_lightning.methods.icrg import ICRGModule
    from tests.factories import save_untrained

    out = Path("tests/fixtures/legacy")
    out.mkdir(parents=True, exist_ok=True)


    def scramble(module, seed):
        g = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            for p in module.parameters():
                p.copy_(torch.randn(p.shape, generator=g) * 0.5)
        return module


    torch.manual_seed(0)
    icpo = scramble(ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10, n_layer=1, n_embd=8,
                               n_head=2, dropout=0.1), 1)
    save_untrained(icpo, out / "icpo_1x8.ckpt")
    reward_gen = {"n_layer": 1, "n_embd": 8, "n_head": 2, "max_context": 6, "dropout": 0.0, "causal": True,
                  "reward_range": [0.0, 1.0], "normalize_inputs": False}
    icrg = scramble(ICRGModule(state_dim=2, action_dim=5, discrete=True, max_context=6,
                               reward_gen_hparams=reward_gen, n_layer=1, n_embd=8, n_head=2), 2)
    icrg.reward_gen.reward_mean.fill_(0.3)
    icrg.reward_gen.reward_std.fill_(0.7)
    save_untrained(icrg, out / "icrg_1x8.ckpt")

    g = torch.Generator().manual_seed(3)
    B, T = 3, 6
    step = StepPreferenceContext(torch.randint(0, 10, (B, T, 2), generator=g).float(),
                                 torch.randint(0, 5, (B, T), generator=g), torch.randint(0, 5, (B, T), generator=g),
                                 torch.randint(0, 2, (B, T), generator=g).float())
    pair = TrajectoryPreferenceContext(
        torch.randint(0, 10, (B, T, 2), generator=g).float(), torch.randint(0, 5, (B, T), generator=g),
        torch.randint(0, 10, (B, T, 2), generator=g).float(), torch.randint(0, 5, (B, T), generator=g),
        torch.randint(0, 2, (B,), generator=g), torch.randint(0, 10, (B, T, 2), generator=g).float(),
        torch.randint(0, 5, (B, T), generator=g))
    obs = torch.randint(0, 10, (4, B, 2), generator=g).float()

    record = {"step_context": {k: v.tolist() for k, v in vars(step).items()},
              "pair_context": {k: v.tolist() for k, v in vars(pair).items()}, "obs": obs.tolist()}
    agent = load_agent(out / "icpo_1x8.ckpt")
    agent.reset(step)
    record["icpo_actions"] = [agent.act(o).tolist() for o in obs]
    logits = agent.policy(agent.context, obs[0][:, None], torch.tensor([T]))[:, 0]
    record["icpo_logits"] = [[round(x, 6) for x in row] for row in logits.tolist()]
    agent = load_agent(out / "icrg_1x8.ckpt", greedy=True)
    agent.reset(pair)
    record["icrg_rewards"] = [[round(x, 6) for x in row] for row in agent.labeled_context.rewards.tolist()]
    record["icrg_actions"] = [agent.act(o).tolist() for o in obs]
    (out / "expected.json").write_text(json.dumps(record) + "\\n")  # then one key per line
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from icprl_lightning import StepPreferenceContext, TrajectoryPreferenceContext, load_agent
from icprl_lightning.checkpoints import FLAT_GROUPS, checkpoint_for_lightning, hyperparameters, load_raw, verify
from icprl_lightning.commands.checkpoint import main as checkpoint_main
from icprl_lightning.commands.trainer import CLIError, _verified_sizes_fit
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.models.config import OptimizerConfig, TransformerConfig

LEGACY = Path(__file__).resolve().parents[1] / "fixtures" / "legacy"
ICPO, ICRG = LEGACY / "icpo_1x8.ckpt", LEGACY / "icrg_1x8.ckpt"
EXPECTED = json.loads((LEGACY / "expected.json").read_text())
OBS = torch.tensor(EXPECTED["obs"])


def _context(cls: type, fields: dict) -> StepPreferenceContext | TrajectoryPreferenceContext:
    return cls(**{k: torch.tensor(v) for k, v in fields.items()})


def test_legacy_icpo_acts_as_it_did():
    agent = load_agent(ICPO)
    assert isinstance(agent.policy, torch.nn.Module) and agent.max_context == 10
    context = _context(StepPreferenceContext, EXPECTED["step_context"])
    agent.reset(context)
    assert [agent.act(o).tolist() for o in OBS] == EXPECTED["icpo_actions"]
    logits = agent.policy(agent.context, OBS[0][:, None], torch.tensor([context.states.shape[1]]))[:, 0]
    torch.testing.assert_close(logits, torch.tensor(EXPECTED["icpo_logits"]), atol=1e-5, rtol=0)


def test_legacy_icrg_labels_and_acts_as_it_did():
    agent = load_agent(ICRG, greedy=True)
    assert agent.reward_model.causal and agent.reward_model.reward_range == (0.0, 1.0)
    agent.reset(_context(TrajectoryPreferenceContext, EXPECTED["pair_context"]))
    torch.testing.assert_close(agent.labeled_context.rewards, torch.tensor(EXPECTED["icrg_rewards"]), atol=1e-5,
                               rtol=0)
    assert [agent.act(o).tolist() for o in OBS] == EXPECTED["icrg_actions"]


@pytest.mark.parametrize("path", [ICPO, ICRG])
def test_legacy_files_verify_as_saved_and_read_with_a_backbone_and_an_optimizer(path):
    raw = load_raw(path)
    verify(raw, path, require_seal=True)  # checksum and seal: the entries as saved
    saved = raw["hyper_parameters"]
    backbone, optimizer = FLAT_GROUPS["backbone"], FLAT_GROUPS["optimizer"]
    assert not {"backbone", "optimizer"} & set(saved) and set(backbone) <= set(saved) and "lr" in saved
    read = hyperparameters(raw)
    assert not set(backbone + optimizer) & set(read) and read["backbone"]["n_embd"] == 8
    assert read["optimizer"] == {k: saved[k] for k in optimizer if k in saved}
    TransformerConfig.coerce(read["backbone"]), OptimizerConfig.coerce(read["optimizer"])
    assert raw["hyper_parameters"] is saved and "backbone" not in saved  # the file's own entry is not rewritten
    verify(raw, path, require_seal=True)


def test_the_reader_gathers_every_size_of_the_icrg_checkpoint():
    read = hyperparameters(load_raw(ICRG))
    assert read["backbone"] == {"n_layer": 1, "n_embd": 8, "n_head": 2, "dropout": 0.0}
    assert read["reward_gen_hparams"] == {"backbone": {"n_layer": 1, "n_embd": 8, "n_head": 2, "dropout": 0.0},
                                          "max_context": 6, "causal": True, "reward_range": [0.0, 1.0],
                                          "normalize_inputs": False}
    assert hyperparameters({"hyper_parameters": {**read, "cross_fit_hparams": [{"n_layer": 2}, {"n_layer": 3}]}})[
        "cross_fit_hparams"] == [{"backbone": {"n_layer": 2}}, {"backbone": {"n_layer": 3}}]
    assert hyperparameters({"hyper_parameters": read}) == read  # the current form passes unchanged


def test_icprl_checkpoint_verify_accepts_the_legacy_files(capsys):
    checkpoint_main(["verify", "--resumable", str(ICPO), str(ICRG)])
    assert capsys.readouterr().out.count(": ok") == 2


def test_a_resume_from_a_legacy_file_compares_the_backbone_it_gathered():
    """``--ckpt_path``: the verified copy Lightning loads, and the size check the CLI runs before any data."""
    copy = load_raw(checkpoint_for_lightning(str(ICPO), "fit"))
    same = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10,
                      backbone=TransformerConfig(n_layer=1, n_embd=8, n_head=2, dropout=0.1))
    _verified_sizes_fit(same, copy, str(ICPO))
    wider = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10,
                       backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    with pytest.raises(CLIError, match=r"\(checkpoint vs config: backbone\.n_embd 8 vs 16\)$"):
        _verified_sizes_fit(wider, copy, str(ICPO))


def test_a_new_checkpoint_holds_the_backbone_as_plain_values(tmp_path):
    """Read with ``weights_only=True`` (no class unpickled), by our reader and by Lightning's own loader."""
    from factories import save_untrained

    backbone = TransformerConfig(n_layer=1, n_embd=8, n_head=2, dropout=0.1)
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10, backbone=backbone)
    path = save_untrained(module, tmp_path / "icpo.ckpt")
    raw = torch.load(path, weights_only=True)
    assert raw["hyper_parameters"]["backbone"] == {"n_layer": 1, "n_embd": 8, "n_head": 2, "dropout": 0.1}
    assert dict(module.hparams_initial)["backbone"] == raw["hyper_parameters"]["backbone"]  # what loggers record
    for loaded in (load_agent(path).policy, ICPOModule.load_from_checkpoint(path, weights_only=True).policy):
        assert loaded.transformer.config == backbone
        torch.testing.assert_close(loaded.state_dict(), module.policy.state_dict())
    icrg = ICRGModule.load_from_checkpoint(ICRG, weights_only=True,  # Lightning's loader: the gathered sizes as
                                           **{k: v for k, v in hyperparameters(load_raw(ICRG)).items()  # overrides
                                              if k in ("backbone", "reward_gen_hparams")})
    assert icrg.backbone == TransformerConfig(n_layer=1, n_embd=8, n_head=2)
