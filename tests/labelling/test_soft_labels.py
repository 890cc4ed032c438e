"""Ties stay 0.5 from a person's answer to the loss: exported as soft labels, trained on by ICPO and RewardGen,
refused before training by a method that reads labels as 0 or 1."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from icprl_lightning.commands import run_cli
from icprl_lightning.contexts import ActionSpec, StepPreferenceContext, TrajectoryPreferenceContext
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.labelling.export import export
from icprl_lightning.labelling.session import open_session
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.losses import soft_label_loss
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.tokenizers import StepPreferenceTokenizer, TrajectoryPreferenceTokenizer
from icprl_lightning.preferences import has_soft_labels

TINY = ["--model.init_args.backbone", "{n_layer: 1, n_embd: 16, n_head: 2}", "--trainer.max_steps", "3",
        "--trainer.logger", "false", "--trainer.enable_progress_bar", "false", "--data.init_args.batch_size", "8",
        "--data.init_args.pairs", "true"]


def test_soft_label_loss_by_hand():
    first, second = torch.tensor([1.0, 2.0, 4.0]), torch.tensor([3.0, 5.0, 0.0])
    # y = 1: the first order's loss; y = 1/2: the mean of both; y = 0: the second order's
    assert soft_label_loss(first, second, torch.tensor([1.0, 0.5, 0.0])).item() == pytest.approx((1 + 3.5 + 0) / 3)


def test_a_tie_token_is_the_same_whichever_action_comes_first():
    torch.manual_seed(0)
    tok = StepPreferenceTokenizer(2, ActionSpec(True, 5), 8)
    s, a, b = torch.rand(1, 3, 2), torch.tensor([[0, 1, 2]]), torch.tensor([[3, 4, 0]])
    y = torch.tensor([[0.5, 1.0, 0.0]])
    swapped = tok(StepPreferenceContext(s, b, a, 1 - y))
    torch.testing.assert_close(tok(StepPreferenceContext(s, a, b, y)), swapped)
    hard = tok(StepPreferenceContext(s, a, b, torch.tensor([[1.0, 1.0, 0.0]])))  # the winner-first path
    torch.testing.assert_close(tok(StepPreferenceContext(s, a, b, y))[:, 1:], hard[:, 1:])


def test_a_tied_trajectory_pair_token_is_the_same_in_either_order():
    torch.manual_seed(0)
    tok = TrajectoryPreferenceTokenizer(2, ActionSpec(True, 5), 8)
    s, t, a, b = torch.rand(2, 4, 2), torch.rand(2, 4, 2), torch.randint(0, 5, (2, 4)), torch.randint(0, 5, (2, 4))
    y = torch.tensor([0.5, 1.0])
    torch.testing.assert_close(tok(TrajectoryPreferenceContext(s, a, t, b, y)),
                               tok(TrajectoryPreferenceContext(t, b, s, a, 1 - y)))


def bradley_terry_person(session, who: str, rng: np.random.Generator, tau: float = 1.0, tie: float = 1.0) -> None:
    """A scripted person at temperature τ: equal when the two differ by less than ``tie`` (DarkRoom's A* and returns
    are whole numbers: 1 means equally good), skips one pair in ten."""
    u1, u2 = session.arrays["utility_first"], session.arrays["utility_second"]
    for i, pair in enumerate(session.pair_ids):
        if rng.random() < 0.1:
            label = "skip"
        elif abs(u1[i] - u2[i]) < tie:
            label = "equal"
        else:
            label = "first" if rng.random() < 1 / (1 + np.exp(-(u1[i] - u2[i]) / tau)) else "second"
        session.log.answer(who, pair, label, f"{who}-{i:08d}", int(rng.integers(300, 3000)))


def labelled(tmp_path, view, pairs, ties="soft", tie=1.0):
    session = open_session(tmp_path / "session", view, pairs, 0)
    for k, who in enumerate(("ann", "bob")):
        bradley_terry_person(session, who, np.random.default_rng(k), tie=tie)
    summary = export(session, tmp_path / "out", ties=ties)
    return session, summary, str(tmp_path / "out" / "dataset")


def test_icpo_trains_on_ties_as_one_half(tmp_path):
    _, summary, data = labelled(tmp_path, "darkroom_steps", 80)
    assert summary["ties"] > 0
    dm = RecordedPreferenceDataModule(data, pairs=True)
    labels = np.concatenate([dm.dataset[s]["preferred"].ravel() for s in ("train", "val")])
    assert dm.soft_labels and labels.dtype == np.float32 and np.sum(labels == 0.5) == summary["ties"]
    cli = run_cli(["fit", "--config", "configs/recorded_icpo.yaml", "--data.init_args.data_dir", data,
                   "--trainer.default_root_dir", str(tmp_path), *TINY])
    assert cli.trainer.state.finished and torch.isfinite(cli.trainer.callback_metrics["train/loss"])


def test_reward_gen_trains_on_ties_and_dp2t_refuses_them(tmp_path):
    _, summary, data = labelled(tmp_path, "darkroom_trajectories", 40, tie=8.0)  # returns within 8 steps: equal
    assert summary["ties"] > 0
    args = ["--data", "icprl_lightning.data.recorded.RecordedPreferenceDataModule", "--data.init_args.data_dir",
            data, "--trainer.default_root_dir", str(tmp_path), "--evaluation", "null", *TINY]  # no simulator
    cli = run_cli(["fit", "--model", "icprl_lightning.methods.reward_gen.RewardGenModule", *args])
    assert cli.trainer.state.finished and torch.isfinite(cli.trainer.callback_metrics["train/loss"])
    with pytest.raises(ValueError, match=r"holds soft labels \(ties stored as 0.5\) and DP2TModule trains on labels "
                                         r"of 0 or 1 only"):
        run_cli(["fit", "--model", "icprl_lightning.methods.dpt.DP2TModule", "--model.init_args.context_kind",
                 "trajectory_preference", *args])


def test_ties_drop_writes_labels_every_method_takes(tmp_path):
    _, summary, data = labelled(tmp_path, "darkroom_steps", 40, ties="drop")
    dm = RecordedPreferenceDataModule(data)
    assert not dm.soft_labels and dm.dataset["train"]["preferred"].dtype == np.uint8
    assert dm.dataset.manifest["info"]["origin"]["ties_left_out"] == summary["ties"] > 0


def test_icpo_scores_a_tie_in_both_orders(tmp_path):
    """Swapping every pair's two actions (and y to 1 − y) leaves ICPO's loss as it was: a tie has no order."""
    _, _, data = labelled(tmp_path, "darkroom_steps", 80)
    dm = RecordedPreferenceDataModule(data, batch_size=64, pairs=True)
    batch = next(iter(dm.train_dataloader()))
    assert has_soft_labels(batch.pair.preferred) and has_soft_labels(batch.context.preferred)

    def swapped(c):
        return StepPreferenceContext(c.states, c.alt_actions, c.actions, 1 - c.preferred)

    torch.manual_seed(0)
    model = ICPOModule(2, 5, True, 1, backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    losses = []
    for b in (batch, batch._replace(context=swapped(batch.context), pair=swapped(batch.pair))):
        torch.manual_seed(1)  # the same query draws
        losses.append(model.loss(b)[0])
    torch.testing.assert_close(losses[0], losses[1])
