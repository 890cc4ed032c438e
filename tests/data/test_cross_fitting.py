"""Cross-fitted ICRG labels: fold-held-out data, the fold record, fold-model labels.

``PreferenceDataModule(folds=k, holdout_fold=i)`` leaves the training tasks t with t % k == i out of the train
and val loaders; ``ICRGModule(cross_fit_checkpoints=[...])`` labels each row of task t with the RewardGen
that held out fold t % k.
"""

from __future__ import annotations

import pathlib
from types import SimpleNamespace

import lightning as L
import numpy as np
import pytest
import torch
from factories import bandit_data, darkroom_data

from icprl_lightning import load_agent
from icprl_lightning.checkpoints import SEAL_KEY, load_module, seal
from icprl_lightning.methods.icrg import ICRGAgent, ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError

# 4 training tasks × 3 train (2 val) pairs: fold 0 = tasks {0, 2} = train rows {0, 1, 2, 6, 7, 8}
TINY = dict(n_train_tasks=4, n_test_tasks=2, trajectories_per_task=3, val_trajectories_per_task=2,
            eval_contexts_per_task=1, calibration_episodes=2, reference_episodes=2, progress=False, pairs=True)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)


pytestmark = pytest.mark.usefixtures("one_thread")


def data(root: str, **kw):
    return darkroom_data("trajectory_preference", root_dir=root, **{**TINY, "batch_size": 3, **kw})


@pytest.fixture(scope="module")
def full(data_root):
    dm = data(data_root, batch_size=12)
    dm.prepare_data()
    return dm


def rows_drawn(loader) -> list[int]:
    return [int(r) for batch in loader.sampler for r in batch]


# ---- (a) the held-out fold leaves the loaders ---------------------------------------------------------

def test_holdout_fold_serves_exactly_the_other_folds_tasks_once(full):
    dm = data(full.root_dir, folds=2, holdout_fold=1)
    assert dm.path == full.path and dm.generator_config() == full.generator_config()  # same dataset on disk
    train = dm.train_dataloader()
    assert sorted(rows_drawn(train)) == [0, 1, 2, 6, 7, 8]  # tasks 0 and 2, each row once
    tasks = torch.cat([b.task for b in train])
    assert sorted(tasks.tolist()) == [0, 0, 0, 2, 2, 2]
    assert sorted(rows_drawn(dm.val_dataloader())) == [0, 1, 4, 5]  # val: 2 pairs per task
    assert sorted(torch.cat([b.task for b in dm.val_dataloader()]).tolist()) == [0, 0, 2, 2]
    other = data(full.root_dir, folds=2, holdout_fold=0)
    assert sorted(rows_drawn(other.train_dataloader())) == [3, 4, 5, 9, 10, 11]
    # the pair partner stays within the row's task, which is kept whole
    batch = next(iter(train))
    states = np.asarray(dm.load()["train"]["states_a"])
    for pair, task in zip(batch.pair.states_a.numpy(), batch.task.tolist(), strict=True):
        row = int(np.flatnonzero((states == pair).all(axis=(1, 2)))[0])
        assert row // 3 == task


def test_without_holdout_every_row_is_served_with_its_task(full):
    assert sorted(rows_drawn(full.train_dataloader())) == list(range(12))
    batch = full.train_dataloader().dataset[[0, 4, 7, 11]]
    assert batch.task.dtype == torch.int64 and batch.task.tolist() == [0, 1, 2, 3]
    assert full.kept_rows("train") is None


def test_ranks_draw_disjoint_shards_of_the_kept_rows(full):
    shards = []
    for rank in range(2):
        dm = data(full.root_dir, folds=2, holdout_fold=0, batch_size=1)
        dm.trainer = SimpleNamespace(world_size=2, global_rank=rank,
                                     _accelerator_connector=SimpleNamespace(use_distributed_sampler=False))
        loader = dm.train_dataloader()
        loader.sampler.set_epoch(1)
        shards.append(rows_drawn(loader))
    assert not set(shards[0]) & set(shards[1])
    assert sorted(shards[0] + shards[1]) == [3, 4, 5, 9, 10, 11]


def test_fold_settings_are_saved_and_a_resumed_fit_must_match(full):
    dm = data(full.root_dir, folds=2, holdout_fold=1)
    assert dm.state_dict() == {"folds": 2, "holdout_fold": 1}
    dm.trainer = SimpleNamespace(state=SimpleNamespace(fn="validate"))
    dm.load_state_dict({"folds": 1, "holdout_fold": None})  # validating on other rows is fine
    dm.trainer = SimpleNamespace(state=SimpleNamespace(fn="fit"))
    dm.load_state_dict({"folds": 2, "holdout_fold": 1})
    with pytest.raises(HyperparameterError, match="folds=1, holdout_fold=None.*--data.init_args.holdout_fold"):
        dm.load_state_dict({"folds": 1, "holdout_fold": None})


# ---- (b) bad values name the field ----------------------------------------------------------------------

@pytest.mark.parametrize(("kw", "match"), [
    ({"folds": 0}, "folds must be >= 1, got 0"),
    ({"folds": 2.0, "holdout_fold": 0}, "folds must be an integer"),
    ({"folds": True}, "folds must be an integer"),
    ({"folds": 2}, "folds=2 needs holdout_fold in \\[0, 2\\)"),
    ({"holdout_fold": 0}, "holdout_fold needs folds >= 2"),
    ({"folds": 2, "holdout_fold": 2}, "holdout_fold must be <= 1"),
    ({"folds": 2, "holdout_fold": -1}, "holdout_fold must be >= 0"),
    ({"folds": 3, "holdout_fold": "1"}, "holdout_fold must be an integer"),
])
def test_bad_fold_settings_name_the_field(tmp_path, kw, match):
    with pytest.raises(HyperparameterError, match=f"PreferenceDataModule: {match}"):
        data(str(tmp_path), **kw)


def test_more_folds_than_tasks_and_bandit_holdout_are_refused(full):
    with pytest.raises(HyperparameterError, match=r"folds must be <= the number of training tasks \(4\), got 5"):
        data(full.root_dir, folds=5, holdout_fold=0).train_dataloader()
    with pytest.raises(HyperparameterError, match="holdout_fold must be None with BanditDuels"):
        bandit_data(folds=2, holdout_fold=0)


# ---- (c) ICRG labels each row with its fold's model ----------------------------------------------------

def _fit_save(model, dm, path: pathlib.Path) -> pathlib.Path:
    trainer = L.Trainer(max_steps=1, limit_val_batches=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    trainer.save_checkpoint(path)
    return path


@pytest.fixture(scope="module")
def reward_gens(full, tmp_path_factory) -> dict[str, pathlib.Path]:
    out = tmp_path_factory.mktemp("reward_gens")
    paths = {}
    for name, seed, kw in (("main", 0, {}), ("fold0", 1, {"folds": 2, "holdout_fold": 0}),
                           ("fold1", 2, {"folds": 2, "holdout_fold": 1})):
        torch.manual_seed(seed)
        paths[name] = _fit_save(RewardGenModule(**ENV, **SIZES), data(full.root_dir, **kw), out / f"{name}.ckpt")
    return paths


def _labels(model, context, pair, rows):
    states = torch.cat([pair.states_a, pair.states_b], 1)[rows]
    actions = torch.cat([pair.actions_a, pair.actions_b], 1)[rows]
    with torch.no_grad():
        return model.label(context.map(lambda x: x[rows]), states, actions)


def test_checkpoints_record_their_fold(reward_gens):
    assert torch.load(reward_gens["fold1"], weights_only=True)["PreferenceDataModule"] == {"folds": 2,
                                                                                          "holdout_fold": 1}
    assert torch.load(reward_gens["main"], weights_only=True)["PreferenceDataModule"] == {"folds": 1,
                                                                                         "holdout_fold": None}


def test_each_row_is_labeled_by_the_model_that_held_out_its_task(full, reward_gens):
    folds = [str(reward_gens["fold0"]), str(reward_gens["fold1"])]
    model = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(reward_gens["main"]), cross_fit_checkpoints=folds)
    assert len(model.hparams.cross_fit_hparams) == 2
    assert not any(p.requires_grad for p in model.cross_fit.parameters())
    model.train()
    assert not model.cross_fit.training and not model.reward_gen.training
    for i, path in enumerate(folds):
        stored = torch.load(path, weights_only=True)["state_dict"]
        for k, v in model.cross_fit[i].state_dict().items():
            assert torch.equal(v, stored[f"reward.{k}"])
    batch = full.train_dataloader().dataset[list(range(12))]  # every task; pair partners drawn once, here
    a, b = model.labeled_trajectories(batch)
    got = torch.cat([a.rewards, b.rewards], 1)
    pair, context = batch.context, batch.pair
    for i in range(2):
        mine = torch.nonzero(batch.task % 2 == i).squeeze(1)
        assert mine.tolist() == [r for r in range(12) if (r // 3) % 2 == i]
        torch.testing.assert_close(got[mine], _labels(model.cross_fit[i], context, pair, mine))
        other = _labels(model.cross_fit[1 - i], context, pair, mine)
        assert (got[mine] - other).abs().max() > 1e-3  # so a label from the wrong fold would fail
    in_sample = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(reward_gens["main"]))
    assert in_sample.cross_fit is None
    a, b = in_sample.labeled_trajectories(batch)  # without cross-fitting: R_ψ labels every row, as before
    torch.testing.assert_close(torch.cat([a.rewards, b.rewards], 1),
                               _labels(in_sample.reward_gen, context, pair, torch.arange(12)))
    with pytest.raises(ValueError, match="samples need task, the training-task index, which this data does not"):
        model.labeled_trajectories(batch._replace(task=None))


# ---- (d) a cross-fitted ICRG checkpoint deploys without the RewardGen files ---------------------------

def test_cross_fitted_checkpoint_round_trips_without_the_reward_gen_files(full, reward_gens, tmp_path):
    torch.manual_seed(0)
    model = ICRGModule(**ENV, **SIZES, value_epochs=0, reward_gen_checkpoint=str(reward_gens["main"]),
                       cross_fit_checkpoints=[str(reward_gens["fold0"]), str(reward_gens["fold1"])])
    path = _fit_save(model, full, tmp_path / "icrg.ckpt")
    # Lightning keeps submodule modes through fit: the frozen labelers stayed in eval mode (no dropout)
    assert model.policy.training and not model.reward_gen.training and not model.cross_fit.training
    moved = {name: p.rename(tmp_path / f"gone-{name}.ckpt") for name, p in reward_gens.items()}
    try:
        loaded = load_module(path)
        agent = load_agent(path, greedy=True, seed=0)
    finally:
        for name, p in moved.items():
            p.rename(reward_gens[name])
    assert isinstance(agent, ICRGAgent)  # deployment labels with the main R_ψ, not a fold model
    torch.testing.assert_close(agent.reward_model.state_dict(), model.reward_gen.state_dict())
    assert loaded.hparams.cross_fit_hparams == model.hparams.cross_fit_hparams
    for mine, theirs in zip(model.cross_fit, loaded.cross_fit, strict=True):
        torch.testing.assert_close(mine.state_dict(), theirs.state_dict())
    batch = full.train_dataloader().dataset[list(range(12))]
    torch.testing.assert_close(loaded.labeled_trajectories(batch)[0].rewards,
                               model.eval().labeled_trajectories(batch)[0].rewards)
    ctx = next(s for s in full.held_out("rollouts") if s.quality == "low").context
    agent.reset(ctx)
    assert agent.act(ctx.behavior_states[:, 0]).shape == (ctx.batch_size,)


# ---- (e) fold checkpoints that do not fit are refused -----------------------------------------------------

def _with_record(src: pathlib.Path, dst: pathlib.Path, record: dict | None) -> str:
    ckpt = torch.load(src, weights_only=True)
    ckpt.pop("PreferenceDataModule")
    if record is not None:
        ckpt["PreferenceDataModule"] = record
    ckpt[SEAL_KEY] = seal(ckpt)  # a consistent file, as a fit of that other fold layout would save
    torch.save(ckpt, dst)
    return str(dst)


def test_mismatched_fold_checkpoints_are_refused(reward_gens, tmp_path):
    f0, f1, main = (str(reward_gens[k]) for k in ("fold0", "fold1", "main"))
    build = lambda folds, stage1=main: ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=stage1,  # noqa: E731
                                                  cross_fit_checkpoints=folds)
    with pytest.raises(ValueError, match=r"cross_fit_checkpoints\[0\]: .*fold1.ckpt was trained with folds=2, "
                                         r"holdout_fold=1; entry 0 of 2 must be trained with --data.init_args.folds 2 "
                                         r"--data.init_args.holdout_fold 0"):
        build([f1, f0])
    with pytest.raises(ValueError, match=r"cross_fit_checkpoints\[0\]: .*folds=1, holdout_fold=None"):
        build([main, f1])
    three = _with_record(reward_gens["fold0"], tmp_path / "k3.ckpt", {"folds": 3, "holdout_fold": 0})
    with pytest.raises(ValueError, match=r"cross_fit_checkpoints\[0\]: .*folds=3, holdout_fold=0"):
        build([three, f1])
    bare = _with_record(reward_gens["fold1"], tmp_path / "bare.ckpt", None)
    with pytest.raises(ValueError, match=r"cross_fit_checkpoints\[1\]: .*records no fold settings"):
        build([f0, bare])
    with pytest.raises(HyperparameterError, match="cross_fit_checkpoints must be a list of k >= 2"):
        build([f0])
    with pytest.raises(FileNotFoundError, match=r"cross_fit_checkpoints\[1\]: "):
        build([f0, str(tmp_path / "missing.ckpt")])
    with pytest.raises(ValueError, match="reward_gen_checkpoint: .*holdout_fold=0"):
        build([f0, f1], stage1=f0)
    with pytest.raises(HyperparameterError, match="cross_fit_hparams must be a list of k >= 2"):
        ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=main, cross_fit_hparams=[{"n_layer": 1}])


# ---- icprl analyze icrg-labels: the labels ICRG trains on and deploys with, against the latent reward ----------------

def test_label_quality_scores_the_labels_each_icrg_trains_on(full, reward_gens, tmp_path):
    from icprl_lightning.evaluation import icrg_labels

    rewards = darkroom_data("reward_trajectory", root_dir=full.root_dir, **{k: v for k, v in TINY.items()
                                                                            if k != "pairs"})
    rewards.prepare_data()
    checkpoints = {}
    for name, extra in (("in-sample", {}), ("cross-fitted", {"cross_fit_checkpoints": [str(reward_gens["fold0"]),
                                                                                        str(reward_gens["fold1"])]})):
        torch.manual_seed(0)
        model = ICRGModule(**ENV, **SIZES, value_epochs=0, reward_gen_checkpoint=str(reward_gens["main"]), **extra)
        checkpoints[name] = _fit_save(model, full, tmp_path / f"{name}.ckpt")
    scores = {name: icrg_labels.training_labels(load_module(path).eval(), full, rewards, rows=12, seed=0)
              for name, path in checkpoints.items()}
    assert all(-1 <= s <= 1 for s in scores.values())
    assert scores["in-sample"] != pytest.approx(scores["cross-fitted"])  # other labelers on the same rows
    # the deployment labels are the agent's, which both ICRGs share (the main R_ψ)
    deployed = {name: icrg_labels.deployment_labels(path, full, rewards) for name, path in checkpoints.items()}
    assert deployed["in-sample"] == pytest.approx(deployed["cross-fitted"])
    assert set(deployed["in-sample"]) == {"low", "medium", "high"}
    other = darkroom_data("reward_trajectory", root_dir=str(tmp_path / "other"), **{
        **{k: v for k, v in TINY.items() if k != "pairs"}, "seed": 1})
    other.prepare_data()
    with pytest.raises(ValueError, match="different training trajectories"):
        icrg_labels.training_labels(load_module(checkpoints["in-sample"]).eval(), full, other, rows=12, seed=0)
