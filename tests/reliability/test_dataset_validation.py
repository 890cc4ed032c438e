"""A dataset is checked as a whole when it is loaded (``data/schema.py``), generated or imported alike.

Every split (train, val, eval_*) against the schema its DataModule's model expects: dtypes, one row count
and one step count per split, state and action sizes, labels, action indices, finite values within
``MAX_MAGNITUDE``. A bad dataset is one ``InvalidDatasetError`` naming the split and the field, raised by
``setup()`` (generated data) or by building the DataModule (recorded data) — before any batch is served,
not an ``IndexError`` at the end of the first full epoch.
"""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from factories import bandit_data, darkroom_data

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data import schema
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.data.schema import DatasetSchema, check_dataset
from icprl_lightning.data.store import MANIFEST, DatasetError, InvalidDatasetError, load_dataset, write_dataset
from icprl_lightning.io import sha256

TINY_GEN = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=1,
                calibration_episodes=2, n_train_tasks=4, n_test_tasks=2, progress=False)


def _valid(n: int = 4, t: int = 3) -> dict[str, np.ndarray]:
    """A valid DarkRoom step-preference split of n contexts of t steps, in the store's dtypes."""
    rng = np.random.default_rng(0)
    return {"states": rng.integers(0, 10, (n, t, 2)).astype(np.float32),
            "actions": rng.integers(0, 5, (n, t)).astype(np.int8),
            "alt_actions": rng.integers(0, 5, (n, t)).astype(np.int8),
            "preferred": rng.integers(0, 2, (n, t)).astype(np.uint8),
            "task_index": np.repeat(np.arange(n // 2), 2).astype(np.int32), "quality": np.zeros(n, np.int8)}


def _set(field: str, make):
    return lambda split: split.update({field: make(split[field])})


def _one_value(value):
    def change(x):
        x = x.copy()
        x.reshape(-1)[1] = value
        return x
    return change


# (split, change, field named, what the message says)
BAD = {
    "float64 states": ("train", _set("states", lambda x: x.astype(np.float64)), "states", "float64, not float32"),
    "int8 states": ("val", _set("states", lambda x: x.astype(np.int8)), "states", "int8, not float32"),
    "int64 labels": ("train", _set("preferred", lambda x: x.astype(np.int64)), "preferred", "not uint8"),
    "float discrete actions": ("train", _set("actions", lambda x: x.astype(np.float32)), "actions",
                               "not integer action indices"),
    "a label column short": ("val", _set("preferred", lambda x: x[:-1]), "preferred", "3 rows .* 'states' has 4"),
    "one field a step short": ("train", _set("alt_actions", lambda x: x[:, :-1]), "alt_actions",
                               "2 steps .* 'states' has 3"),
    "3-D labels": ("train", _set("preferred", lambda x: x[..., None]), "preferred", "3 axes; expected"),
    "state size 3": ("train", _set("states", lambda x: np.concatenate([x, x[..., :1]], -1)), "states",
                     "state size 3, the model's state size is 2"),
    "longer than the model's context": ("train", lambda s: s.update({k: np.concatenate([v] * 40, 1)
                                                                     for k, v in s.items() if v.ndim > 1}),
                                        "states", "T = 120 steps, longer than the model's context of 100"),
    "huge finite state": ("val", _set("states", _one_value(1e30)), "states", r"beyond ±1e\+06"),
    "state just beyond the bound": ("train", _set("states", _one_value(np.float32(1.5e6))), "states", "beyond"),
    "float task ids": ("train", _set("task_index", lambda x: x.astype(np.float32)), "task_index", "not integer"),
    "string field": ("train", _set("quality", lambda x: x.astype("U1")), "quality", "non-numeric"),
    "label 2 in an eval split": ("eval_low", _set("preferred", _one_value(2)), "preferred", r"found \[2\]"),
    "NaN in an eval split": ("eval_high", _set("states", _one_value(np.nan)), "states", "1 NaN"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_generated_store_is_checked_as_a_whole_at_setup(case, tmp_path):
    split, change, field, what = BAD[case]
    dm = darkroom_data(data_dir=str(tmp_path / "ds"), progress=False, n_train_tasks=2, n_test_tasks=2)
    splits = {name: _valid() for name in ("train", "val", "eval_low", "eval_high")}
    change(splits[split])
    write_dataset(dm.path, splits, dm.generator_config())
    with pytest.raises(InvalidDatasetError, match=what) as err:
        dm.setup("fit")
    text = str(err.value)
    assert f"split {split!r}, field {field!r}" in text and str(dm.path) in text and "To fix" in text, text
    assert "\n" not in text
    assert isinstance(err.value, ValueError) and isinstance(err.value, DatasetError)


def test_the_bound_itself_and_the_task_split_are_accepted(tmp_path):
    dm = darkroom_data(data_dir=str(tmp_path / "ds"), progress=False, n_train_tasks=2, n_test_tasks=2)
    train = _valid()
    train["states"][0, 0, 0] = schema.MAX_MAGNITUDE
    tasks = {"train_darkroom": np.arange(6).reshape(3, 2), "test_darkroom": np.arange(2.0)}  # own row counts
    write_dataset(dm.path, {"train": train, "val": _valid(6, 2), "tasks": tasks}, dm.generator_config())
    dm.setup("fit")


def test_a_row_count_mismatch_is_refused_before_the_epoch_not_an_index_error(tmp_path):
    """The failure the check exists for: states one row longer than the labels passed ``fast_dev_run`` (its
    batches come from the first rows) and raised IndexError when the last batch reached the missing row."""
    dm = darkroom_data(data_dir=str(tmp_path / "ds"), progress=False, n_train_tasks=2, n_test_tasks=2, batch_size=2)
    train = _valid(8)
    train["preferred"] = train["preferred"][:7]
    write_dataset(dm.path, {"train": train, "val": _valid()}, dm.generator_config())
    with pytest.raises(InvalidDatasetError, match=r"split 'train', field 'preferred' .* 7 rows"):
        dm.setup("fit")


@pytest.mark.parametrize("kind", ["step_preference", "reward", "trajectory_preference", "reward_trajectory"])
def test_every_generated_kind_passes(kind, tmp_path):
    dm = darkroom_data(context_kind=kind, root_dir=str(tmp_path), **TINY_GEN)
    dm.prepare_data()
    dm.setup("fit")
    assert {s for s in dm.load().splits} >= {"train", "val", "eval_low", "tasks"}


def test_generated_bandit_data_passes(tmp_path):
    dm = bandit_data(root_dir=str(tmp_path), n_train_problems=3, contexts_per_problem=2, n_val_problems=2,
                     val_contexts_per_problem=2, n_eval_problems=2, horizon=6, progress=False)
    dm.prepare_data()
    dm.setup("fit")


# ---- recorded data: checked when the DataModule is built -----------------------------------------------------

def _recorded(tmp_path: Path, seed: int = 0, overwrite: bool = False) -> Path:
    rng = np.random.default_rng(1)
    n, t = 8, 5
    arrays = {"states": rng.normal(size=(n, t, 3)), "actions": rng.integers(0, 4, (n, t)),
              "alt_actions": rng.integers(0, 4, (n, t)), "preferred": rng.integers(0, 2, (n, t)),
              "task_index": np.repeat(np.arange(4), 2)}
    import_preferences(arrays, tmp_path / "ds", n_actions=4, val_fraction=0.25, seed=seed, overwrite=overwrite)
    return tmp_path / "ds"


def rewrite(path: Path, rel: str, array: np.ndarray) -> None:
    """Replace one stored file and make its manifest entry agree, so only the whole-dataset check can object."""
    np.save(path / rel, array)
    manifest = json.loads((path / MANIFEST).read_text())
    manifest["files"][rel].update(sha256=sha256(path / rel), bytes=(path / rel).stat().st_size,
                                  shape=list(array.shape), dtype=str(array.dtype))
    (path / MANIFEST).write_text(json.dumps(manifest))


@pytest.mark.parametrize("rel,change,what", [
    ("train/states.npy", lambda x: x.astype(np.float64), "float64, not float32"),
    ("val/states.npy", lambda x: x * 1e7, "beyond"),
    ("val/actions.npy", lambda x: x[:, :-1], "4 steps .* 'states' has 5"),
    ("train/preferred.npy", lambda x: x[:-1], "5 rows .* 'states' has 6"),
    ("train/actions.npy", lambda x: np.where(x == 0, 4, x), r"outside \[0, 4\)"),
    ("val/task_index.npy", lambda x: x.astype(np.float64), "not integer"),
    ("train/source_row.npy", lambda x: np.asarray(x[0]), "is a scalar"),
])
def test_recorded_data_is_checked_as_a_whole_when_built(rel, change, what, tmp_path):
    path = _recorded(tmp_path)
    rewrite(path, rel, change(np.load(path / rel)))
    split, field = rel.removesuffix(".npy").split("/")
    with pytest.raises(InvalidDatasetError, match=what) as err:
        RecordedPreferenceDataModule(str(path))
    assert f"split {split!r}, field {field!r}" in str(err.value) and "icprl import" in str(err.value)


def test_recorded_config_types_and_fields_are_checked(tmp_path):
    path = _recorded(tmp_path)
    good = (path / MANIFEST).read_text()
    for key, value in (("state_dim", "3"), ("action_size", 0), ("discrete", 1), ("context_length", None)):
        manifest = json.loads(good)
        manifest["config"][key] = value
        (path / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(DatasetError, match=f"manifest config {key!r} is {value!r}"):
            RecordedPreferenceDataModule(str(path))
    manifest = json.loads(good)
    manifest["config"]["state_dim"] = 2  # the arrays hold 3
    (path / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(InvalidDatasetError, match="state size 3, the model's state size is 2"):
        RecordedPreferenceDataModule(str(path))
    manifest = json.loads(good)
    del manifest["files"]["val/preferred.npy"]
    (path / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match=r"lacks val/preferred\.npy"):
        RecordedPreferenceDataModule(str(path))


def test_a_dataset_replaced_between_build_and_setup_is_refused(tmp_path):
    path = _recorded(tmp_path)
    dm = RecordedPreferenceDataModule(str(path))
    _recorded(tmp_path, seed=5, overwrite=True)  # another dataset at the path, checked by nobody yet
    with pytest.raises(DatasetError, match="changed on disk"):
        dm.setup("fit")


# ---- cost on memory-mapped data -------------------------------------------------------------------------------

def test_the_value_check_streams_a_memory_map_in_blocks(tmp_path, monkeypatch):
    """Checking 16 MB of states allocates a few blocks' worth, not a copy of the data."""
    n, t = 2048, 1024
    states = np.lib.format.open_memmap(tmp_path / "states.npy", mode="w+", dtype=np.float32, shape=(n, t, 2))
    states[:] = 1.0
    del states
    splits = {"train": {"states": np.load(tmp_path / "states.npy", mmap_mode="r"),
                        "actions": np.zeros((n, t), np.int8), "alt_actions": np.zeros((n, t), np.int8),
                        "preferred": np.zeros((n, t), np.uint8)}}
    monkeypatch.setattr(schema, "_CHUNK_VALUES", 1 << 16)
    tracemalloc.start()
    try:
        schema.check_splits(splits, DatasetSchema("step_preference", ActionSpec(True, 5), 2), where="mem")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < splits["train"]["states"].nbytes / 8, peak


def test_check_dataset_names_the_path(tmp_path):
    write_dataset(tmp_path / "d", {"train": {**_valid(), "preferred": _valid()["preferred"] + 1}}, {})
    with pytest.raises(InvalidDatasetError, match=rf"Dataset {tmp_path / 'd'}: split 'train', field 'preferred'.*"
                                                   r"found \[2\]\. To fix: regenerate"):
        check_dataset(load_dataset(tmp_path / "d"), DatasetSchema("step_preference", ActionSpec(True, 5)),
                      "regenerate")
