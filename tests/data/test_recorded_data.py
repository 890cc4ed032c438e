"""Bring your own data: `icprl import` checks and converts arrays, any method trains on them, the agent deploys.

The recorded data here are DarkRoom-like and made in the test: a 5×5 grid, 5 actions (stay, up, down,
left, right), one goal cell per task, and a step label that prefers the action ending nearer the goal.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from factories import TINY_MODEL

from icprl_lightning import StepPreferenceContext, TrajectoryPreferenceContext, load_agent
from icprl_lightning.commands import main, run_cli
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.data.store import DatasetError

REPO = Path(__file__).resolve().parents[2]
MOVES = np.array([[0, 0], [0, 1], [0, -1], [-1, 0], [1, 0]])  # stay, up, down, left, right
SIZE, T, N_ACTIONS = 5, 12, 5


def _distance_after(states: np.ndarray, actions: np.ndarray, goals: np.ndarray) -> np.ndarray:
    moved = np.clip(states + MOVES[actions], 0, SIZE - 1)
    return np.abs(moved - goals).sum(-1)


def darkroom_like(n_tasks: int = 6, per_task: int | list[int] = 4, seed: int = 0) -> dict[str, np.ndarray]:
    """Recorded I-PRL steps as a user would have them: float64 states, int64 actions, rows in any task order."""
    rng = np.random.default_rng(seed)
    counts = [per_task] * n_tasks if isinstance(per_task, int) else per_task
    task = rng.permutation(np.repeat(np.arange(n_tasks) * 10 + 3, counts))  # arbitrary ids, shuffled rows
    goals = rng.integers(0, SIZE, (n_tasks, 2))[(task - 3) // 10][:, None, :]  # (N, 1, 2)
    n = len(task)
    actions, alt = rng.integers(0, N_ACTIONS, (2, n, T))
    states = np.empty((n, T, 2))
    pos = rng.integers(0, SIZE, (n, 2))
    for h in range(T):  # a random walk: the next state follows the first action
        states[:, h] = pos
        pos = np.clip(pos + MOVES[actions[:, h]], 0, SIZE - 1)
    preferred = (_distance_after(states, actions, goals) <= _distance_after(states, alt, goals)).astype(np.int64)
    return {"states": states, "actions": actions, "alt_actions": alt, "preferred": preferred, "task_index": task}


def _import(arrays: dict, tmp_path: Path, **kw):
    kw.setdefault("n_actions", N_ACTIONS)
    return import_preferences(arrays, tmp_path / "ds", **kw)


# ---- (a) every bad input is refused, naming the field ------------------------------------------------------

def _bad(change):
    arrays = darkroom_like()
    change(arrays)
    return arrays


BAD_INPUTS = {
    "missing field": (lambda a: a.pop("alt_actions"), "alt_actions", "missing"),
    "unknown field": (lambda a: a.update(prefered=a["preferred"]), "prefered", "unknown"),
    "states not 3-D": (lambda a: a.update(states=a["states"][..., 0]), "states", "shape"),
    "N mismatch": (lambda a: a.update(preferred=a["preferred"][:-1]), "preferred", "rows"),
    "T mismatch": (lambda a: a.update(alt_actions=a["alt_actions"][:, :-1]), "alt_actions", "steps"),
    "actions with a trailing axis": (lambda a: a.update(actions=a["actions"][..., None]), "actions", "axes"),
    "integer states": (lambda a: a.update(states=a["states"].astype(np.int64)), "states", "floating"),
    "float discrete actions": (lambda a: a.update(actions=a["actions"].astype(np.float32)), "actions", "integer"),
    "bool actions": (lambda a: a.update(alt_actions=a["alt_actions"] > 2), "alt_actions", "bool"),
    "action index = n_actions": (lambda a: a["actions"].__setitem__((0, 0), N_ACTIONS), "actions", "outside"),
    "negative action index": (lambda a: a["alt_actions"].__setitem__((1, 2), -1), "alt_actions", "outside"),
    "label 2": (lambda a: a["preferred"].__setitem__((0, 0), 2), "preferred", "0 or 1"),
    "label -1": (lambda a: a["preferred"].__setitem__((0, 0), -1), "preferred", "0 or 1"),
    "label 0.5": (lambda a: a.update(preferred=np.where(a["preferred"] > 0, 1.0, 0.5)), "preferred", "0 or 1"),
    "NaN state": (lambda a: a["states"].__setitem__((2, 3, 1), np.nan), "states", "NaN"),
    "inf state": (lambda a: a["states"].__setitem__((2, 3, 1), -np.inf), "states", "inf"),
    "state beyond float32": (lambda a: a["states"].__setitem__((0, 0, 0), 1e300), "states", "float32"),
    "huge finite state": (lambda a: a["states"].__setitem__((0, 0, 0), 1e30), "states", r"beyond ±1e\+06"),
    "huge query state": (lambda a: a.update(query_states=a["states"] * 1e7, optimal_actions=a["actions"]),
                         "query_states", "beyond"),
    "NaN label": (lambda a: a.update(preferred=np.where(a["preferred"] > 0, 1.0, np.nan)), "preferred", "NaN"),
    "no contexts (N=0)": (lambda a: [a.update({k: v[:0]}) for k, v in list(a.items())], "states", "empty"),
    "no steps (T=0)": (lambda a: [a.update({k: v[:, :0]}) for k, v in list(a.items()) if v.ndim > 1],
                       "states", "empty"),
    "task ids of the wrong length": (lambda a: a.update(task_index=a["task_index"][1:]), "task_index", r"shape \[N="),
    "float task ids": (lambda a: a.update(task_index=a["task_index"] + 0.5), "task_index", "integer"),
    "query states without labels": (lambda a: a.update(query_states=a["states"]), "optimal_actions", "both"),
    "string field": (lambda a: a.update(preferred=a["preferred"].astype(str)), "preferred", "numeric"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_import_refuses_bad_arrays_naming_the_field(case, tmp_path):
    change, field, what = BAD_INPUTS[case]
    with pytest.raises(ValueError, match=what) as err:
        _import(_bad(change), tmp_path)
    assert f"'{field}'" in str(err.value)
    assert not (tmp_path / "ds").exists()  # nothing written


def test_import_refuses_continuous_mismatches(tmp_path):
    arrays = darkroom_like()
    arrays.update(actions=np.zeros((*arrays["actions"].shape, 3)), alt_actions=np.zeros((*arrays["actions"].shape, 3)))
    with pytest.raises(ValueError, match="'actions' has action size 3, --action-dim is 2"):
        import_preferences(arrays, tmp_path / "ds", action_dim=2)
    arrays["alt_actions"] = arrays["alt_actions"].astype(np.int64)
    with pytest.raises(ValueError, match="'alt_actions' must be floating"):
        import_preferences(arrays, tmp_path / "ds", action_dim=3)
    arrays["alt_actions"] = np.full(arrays["alt_actions"].shape, np.inf)
    with pytest.raises(ValueError, match="'alt_actions' holds inf"):
        import_preferences(arrays, tmp_path / "ds", action_dim=3)
    with pytest.raises(ValueError, match="exactly one of n_actions"):
        import_preferences(arrays, tmp_path / "ds", n_actions=5, action_dim=3)


def test_val_split_needs_two_tasks(tmp_path):
    arrays = darkroom_like(n_tasks=1)
    with pytest.raises(ValueError, match="'task_index'"):
        _import(arrays, tmp_path, val_fraction=0.2)
    assert _import(arrays, tmp_path, val_fraction=0.0).manifest_info["contexts"] == {"train": 4, "val": 0}


def test_cli_error_is_one_line_naming_the_field(tmp_path, capsys):
    arrays = _bad(lambda a: a["preferred"].__setitem__((0, 0), 2))
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(SystemExit) as exit_:
        main(["import", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "ds"), "--kind", "step_preference",
              "--n-actions", "5"])
    assert exit_.value.code == 2
    assert "icprl import: error: field 'preferred' must hold only 0 or 1" in capsys.readouterr().err


def test_overwrite_only_replaces_our_datasets(tmp_path):
    arrays = darkroom_like()
    source = tmp_path / "src"
    source.mkdir()
    for k, v in arrays.items():
        np.save(source / f"{k}.npy", v)
    _import(arrays, tmp_path)
    with pytest.raises(FileExistsError, match="--overwrite"):
        _import(arrays, tmp_path)
    _import(arrays, tmp_path, overwrite=True, seed=1)
    assert json.loads((tmp_path / "ds" / "manifest.json").read_text())["config"]["seed"] == 1
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="not an icprl dataset"):
        import_preferences(source, theirs, n_actions=N_ACTIONS, overwrite=True)
    assert (theirs / "notes.txt").read_text() == "keep me"
    (source / "manifest.json").write_text(json.dumps({"schema_version": 1}))  # the source inside the target
    with pytest.raises(FileExistsError, match="inside"):
        import_preferences(source, source, n_actions=N_ACTIONS, overwrite=True)
    assert (source / "states.npy").exists()


# ---- what the importer writes ------------------------------------------------------------------------------

def test_import_converts_reorders_task_major_and_splits_by_task(tmp_path):
    arrays = darkroom_like(n_tasks=10, per_task=[2, 3, 4, 2, 5, 2, 3, 2, 2, 6])
    summary = _import(arrays, tmp_path, val_fraction=0.2, seed=3)
    dm = RecordedPreferenceDataModule(str(tmp_path / "ds"))
    info = dm.dataset.manifest["info"]
    assert info["tasks"] == {"train": 8, "val": 2} and summary.manifest_info == info
    stored = {split: dm.dataset[split] for split in ("train", "val")}
    assert set(stored["val"]["task_index"]) == set(info["val_tasks"])
    assert not set(stored["train"]["task_index"]) & set(stored["val"]["task_index"])
    for split in stored.values():
        assert split["states"].dtype == np.float32 and split["actions"].dtype == np.int8
        assert split["preferred"].dtype == np.uint8 and split["task_index"].dtype == np.int64
        assert np.all(np.diff(split["task_index"]) >= 0)  # task-major
        rows = split["source_row"]
        for task in np.unique(split["task_index"]):  # each task keeps its recorded order
            assert np.all(np.diff(rows[split["task_index"] == task]) > 0)
        for k in ("states", "actions", "alt_actions", "preferred", "task_index"):
            np.testing.assert_array_equal(split[k], arrays[k][rows])
    assert sorted(np.concatenate([s["source_row"] for s in stored.values()])) == list(range(len(arrays["states"])))
    assert (dm.state_dim, dm.action_spec.size, dm.action_spec.discrete, dm.context_length) == (2, 5, True, T)
    assert dm.context_kind == "step_preference" and dm.offers == frozenset()
    other = tmp_path / "again"
    import_preferences(arrays, other, n_actions=N_ACTIONS, val_fraction=0.2, seed=3)  # same seed, same bytes
    assert [f["sha256"] for f in json.loads((other / "manifest.json").read_text())["files"].values()] == \
        [f["sha256"] for f in dm.dataset.manifest["files"].values()]


def test_pairs_come_from_another_row_of_the_same_task(tmp_path):
    arrays = darkroom_like(n_tasks=5, per_task=[2, 3, 7, 2, 4])
    _import(arrays, tmp_path, val_fraction=0.0)
    dm = RecordedPreferenceDataModule(str(tmp_path / "ds"), batch_size=6, pairs=True)
    dm.setup("fit")
    train = dm.dataset["train"]
    key = {train["states"][i].tobytes(): i for i in range(len(train["states"]))}
    torch.manual_seed(0)
    for batch in dm.train_dataloader():
        for own, pair in zip(batch.context.states.numpy(), batch.pair.states.numpy(), strict=True):
            i, j = key[own.tobytes()], key[pair.tobytes()]
            assert i != j and train["task_index"][i] == train["task_index"][j]
        assert batch.context.preferred.dtype == torch.float32 and batch.context.actions.dtype == torch.int64


def test_datamodule_errors_name_the_fix(tmp_path):
    arrays = darkroom_like(n_tasks=3, per_task=[3, 1, 2])
    _import(arrays, tmp_path, val_fraction=0.0)
    with pytest.raises(ValueError, match="single row"):
        RecordedPreferenceDataModule(str(tmp_path / "ds"), pairs=True)
    with pytest.raises(ValueError, match="query_states"):
        RecordedPreferenceDataModule(str(tmp_path / "ds"), query_labels=True)
    arrays.pop("task_index")
    _import(arrays, tmp_path, val_fraction=0.0, overwrite=True)
    with pytest.raises(ValueError, match="task_index"):
        RecordedPreferenceDataModule(str(tmp_path / "ds"), pairs=True)
    with pytest.raises(DatasetError, match="No dataset"):
        RecordedPreferenceDataModule(str(tmp_path / "nothing"))
    file = tmp_path / "ds" / "train" / "states.npy"
    data = bytearray(file.read_bytes())
    data[-1] ^= 0xFF  # one corrupt byte of the last state: found by the checksums setup verifies
    file.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="checksum"):
        RecordedPreferenceDataModule(str(tmp_path / "ds")).setup("fit")


# ---- (b) end to end: import -> icprl fit -> load_agent -> act ------------------------------------------------

def test_import_fit_icpo_and_deploy(tmp_path, capsys):
    arrays = darkroom_like(n_tasks=8, per_task=4)
    np.savez(tmp_path / "prefs.npz", **arrays)
    data = tmp_path / "recorded"
    main(["import", str(tmp_path / "prefs.npz"), "--out", str(data), "--kind", "step_preference",
          "--n-actions", "5", "--val-fraction", "0.25", "--seed", "0"])
    printed = capsys.readouterr().out
    assert "imported 32 step_preference contexts (T=12, S=2, 5 discrete actions)" in printed
    assert "train: 24 contexts, 6 tasks" in printed and "val: 8 contexts, 2 tasks" in printed
    runs = tmp_path / "runs"
    main(["fit", "--config", str(REPO / "configs/recorded_icpo.yaml"), "--data.init_args.data_dir", str(data),
          "--data.init_args.batch_size", "8", "--trainer.max_steps", "4", "--trainer.logger", "false",
          "--trainer.default_root_dir", str(runs), "--trainer.enable_progress_bar", "false",
          "--model.init_args.backbone", "{n_layer: 1, n_embd: 16, n_head: 2}"])
    agent = load_agent(next(runs.glob("*/checkpoints/last.ckpt")))
    val = RecordedPreferenceDataModule(str(data)).dataset["val"]
    context = StepPreferenceContext(torch.from_numpy(np.array(val["states"])),
                                    torch.from_numpy(np.array(val["actions"], dtype=np.int64)),
                                    torch.from_numpy(np.array(val["alt_actions"], dtype=np.int64)),
                                    torch.from_numpy(np.array(val["preferred"], dtype=np.float32)))
    agent.reset(context)
    actions = agent.act(torch.rand(8, 2) * (SIZE - 1))
    assert actions.shape == (8,) and actions.dtype == torch.int64
    assert actions.min() >= 0 and actions.max() < N_ACTIONS


# ---- T-PRL: import round trip, DP²T trains on it with query labels; a kind mismatch is named ---------------

def _trajectory_pairs(n_tasks: int = 4, per_task: int = 3, h: int = 6, action_dim: int = 2, seed: int = 1):
    rng = np.random.default_rng(seed)
    n = n_tasks * per_task
    goal = rng.normal(size=(n_tasks, action_dim))[np.repeat(np.arange(n_tasks), per_task)]
    acts = rng.normal(size=(2, n, h, action_dim))
    score = -np.linalg.norm(acts - goal[None, :, None], axis=-1).sum(-1)  # (2, N)
    return {"states_a": rng.normal(size=(n, h, 3)), "actions_a": acts[0], "states_b": rng.normal(size=(n, h, 3)),
            "actions_b": acts[1], "preferred": score[0] > score[1],  # bool labels are accepted
            "task_index": np.repeat(np.arange(n_tasks), per_task),
            "query_states": rng.normal(size=(n, h, 3)), "optimal_actions": np.repeat(goal[:, None], h, axis=1)}


def test_trajectory_preference_round_trip_and_dp2t(tmp_path):
    arrays = _trajectory_pairs()
    source = tmp_path / "pairs"
    source.mkdir()
    for k, v in arrays.items():
        np.save(source / f"{k}.npy", v)
    import_preferences(source, tmp_path / "ds", kind="trajectory_preference", action_dim=2, val_fraction=0.25)
    dm = RecordedPreferenceDataModule(str(tmp_path / "ds"), batch_size=4, pairs=True, query_labels=True)
    dm.setup("fit")
    assert (dm.context_kind, dm.state_dim, dm.action_spec.discrete, dm.context_length) == \
        ("trajectory_preference", 3, False, 6)
    train = dm.dataset["train"]
    for k, v in arrays.items():
        np.testing.assert_allclose(train[k], v[train["source_row"]].astype(train[k].dtype))
    batch = next(iter(dm.val_dataloader()))
    assert batch.query_states.shape[1:] == (6, 3) and batch.optimal_actions.shape[1:] == (6, 2)
    for context in (batch.context, batch.pair):
        assert isinstance(context, TrajectoryPreferenceContext)
        context.validate(dm.state_dim, dm.action_spec)
    data_args = ["--data", "icprl_lightning.data.recorded.RecordedPreferenceDataModule", "--evaluation", "null",
                 "--data.init_args.data_dir", str(tmp_path / "ds"), "--data.init_args.query_labels", "true",
                 "--trainer.fast_dev_run", "1", "--trainer.logger", "false", "--trainer.default_root_dir",
                 str(tmp_path), "--trainer.enable_progress_bar", "false"]
    cli = run_cli(["fit", "--model", "icprl_lightning.methods.dpt.DP2TModule",
                   "--model.init_args.context_kind", "trajectory_preference", *TINY_MODEL, *data_args])
    assert cli.trainer.state.finished and cli.model.hparams.max_context == 6 and not cli.model.hparams.discrete
    cli = run_cli(["fit", "--model", "icprl_lightning.methods.reward_gen.RewardGenModule", *TINY_MODEL, *data_args,
                   "--data.init_args.pairs", "true"])  # scores another pair of the task, as configured by default
    assert cli.trainer.state.finished
    with pytest.raises(ValueError, match="step_preference contexts but .* holds trajectory_preference"):
        run_cli(["fit", "--model", "icprl_lightning.methods.dpt.DP2TModule", *TINY_MODEL, *data_args])
