"""Datasets that travel: export to Hugging Face (Arrow), Parquet and Minari and back byte for byte, with provenance;
TRL chosen/rejected rows and segment-pair label arrays imported, ties handled, bad input refused by name."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from factories import darkroom_data
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icprl_lightning.commands import SUBCOMMANDS
from icprl_lightning.commands.export_data import main as export_main
from icprl_lightning.commands.import_data import main as import_main
from icprl_lightning.data.interop import ExportError, export_dataset, import_export
from icprl_lightning.data.interop.minari_format import NAMESPACE, NAMESPACE_METADATA
from icprl_lightning.data.interop.preference_rows import label_arrays, trl_arrays
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.data.store import load_dataset, write_dataset


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def assert_same_dataset(original: Path, rebuilt: Path) -> None:
    """Every file (each .npy and manifest.json) byte-identical, and the arrays equal with dtype and shape."""
    a, b = files(original), files(rebuilt)
    assert sorted(a) == sorted(b)
    assert [name for name in a if a[name] != b[name]] == []
    x, y = load_dataset(original), load_dataset(rebuilt)
    for split, fields in x.splits.items():
        for name, array in fields.items():
            other = y[split][name]
            assert (other.dtype, other.shape) == (array.dtype, array.shape)
            np.testing.assert_array_equal(other, array)


@pytest.fixture(scope="module")
def small_reward(tmp_path_factory) -> Path:
    """A reward-context dataset small enough for Minari's one-directory-per-episode storage (a few seconds)."""
    dm = darkroom_data("reward", root_dir=str(tmp_path_factory.mktemp("reward")), size=4, horizon=6, n_train_tasks=4,
                       n_test_tasks=2, trajectories_per_task=2, val_trajectories_per_task=1, eval_contexts_per_task=1,
                       calibration_episodes=2, query_labels=True, progress=False)
    dm.prepare_data()
    return Path(dm.path)


@pytest.fixture(scope="module")
def kinds(tiny_ipref, tprl, tiny_reward, tprl_rewards) -> dict[str, Path]:
    return {"step_preference": Path(tiny_ipref.path), "trajectory_preference": Path(tprl.path),
            "reward": Path(tiny_reward.path), "reward_trajectory": Path(tprl_rewards.path)}


@pytest.mark.parametrize("fmt", ["hf", "parquet"])
@pytest.mark.parametrize("kind", ["step_preference", "trajectory_preference", "reward", "reward_trajectory"])
def test_tabular_round_trip_is_byte_identical(kinds, tmp_path, kind, fmt):
    export_dataset(kinds[kind], fmt, tmp_path / "export")
    import_export(fmt, tmp_path / "export", tmp_path / "back")
    assert_same_dataset(kinds[kind], tmp_path / "back")


def test_minari_round_trip_is_byte_identical_and_readable_by_minari(small_reward, tmp_path, monkeypatch):
    export_main([str(small_reward), "--format", "minari", "--out", str(tmp_path / "minari")])
    import_main([str(tmp_path / "minari"), "--format", "minari", "--out", str(tmp_path / "back")])
    assert_same_dataset(small_reward, tmp_path / "back")
    import minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    train = load_dataset(small_reward)["train"]
    episodes = minari.load_dataset(f"{NAMESPACE}/train-v0")
    assert episodes.total_episodes == len(train["states"])
    episode = next(episodes.iterate_episodes([1]))
    np.testing.assert_array_equal(episode.observations[:-1], train["states"][1])
    np.testing.assert_array_equal(episode.observations[-1], train["next_states"][1, -1])
    np.testing.assert_array_equal(episode.actions, train["actions"][1])
    np.testing.assert_array_equal(episode.rewards, train["rewards"][1])
    assert episode.truncations[-1] and not episode.terminations.any()


def test_provenance_travels_in_each_format(small_reward, tmp_path):
    import datasets

    minari_root = os.environ.get("MINARI_DATASETS_PATH")
    manifest = json.loads((small_reward / "manifest.json").read_text())
    for fmt in ("hf", "parquet", "minari"):
        export_dataset(small_reward, fmt, tmp_path / fmt)
    hf = datasets.load_from_disk(str(tmp_path / "hf"))
    assert {json.loads(part.info.description)["manifest"]["config"]["seed"] for part in hf.values()} == {0}
    assert json.loads(hf["train"].info.description)["manifest"] == manifest
    for file in (tmp_path / "parquet").glob("*.parquet"):
        assert json.loads(pq.read_schema(file).metadata[b"icprl"])["manifest"] == manifest
    namespace = json.loads((tmp_path / "minari" / NAMESPACE / NAMESPACE_METADATA).read_text())
    assert namespace["icprl"]["manifest"] == manifest
    assert sorted(hf) == ["eval_high", "eval_low", "eval_medium", "tasks.test_goals", "tasks.train_goals", "train",
                          "val"]
    assert hf["train"].column_names == sorted(load_dataset(small_reward)["train"])
    assert os.environ.get("MINARI_DATASETS_PATH") == minari_root  # pointed at --out only while writing


def test_minari_refuses_kinds_that_are_not_episodes(kinds, tmp_path):
    for kind in ("step_preference", "trajectory_preference", "reward_trajectory"):
        with pytest.raises(ExportError, match=f"holds '{kind}' contexts.*--format hf or --format parquet"):
            export_dataset(kinds[kind], "minari", tmp_path / kind)
        assert not (tmp_path / kind).exists()


def test_minari_refuses_independent_transitions(tmp_path):
    rng = np.random.default_rng(0)
    split = {"states": rng.random((3, 4, 2), dtype=np.float32), "actions": rng.integers(0, 5, (3, 4)).astype(np.int8),
             "rewards": rng.random((3, 4), dtype=np.float32), "next_states": rng.random((3, 4, 2), dtype=np.float32)}
    write_dataset(tmp_path / "d", {"train": split}, {"context_kind": "reward"})
    with pytest.raises(ExportError, match="split 'train', row 0: next_states differs"):
        export_dataset(tmp_path / "d", "minari", tmp_path / "out")


def test_a_changed_export_is_refused_naming_the_field(small_reward, tmp_path):
    export_dataset(small_reward, "parquet", tmp_path / "export")
    file = tmp_path / "export" / "train.parquet"
    table = pq.read_table(file)
    column = table.column_names.index("rewards")
    reversed_rows = table.column("rewards").take(pa.array(np.arange(table.num_rows)[::-1]))
    pq.write_table(table.set_column(column, "rewards", reversed_rows), file)  # the metadata kept, one field changed
    with pytest.raises(SystemExit) as exit_info:
        import_main([str(tmp_path / "export"), "--format", "parquet", "--out", str(tmp_path / "back")])
    assert exit_info.value.code == 2
    with pytest.raises(ExportError, match="field 'train/rewards' differs from the exported dataset"):
        import_export("parquet", tmp_path / "export", tmp_path / "back")
    assert not (tmp_path / "back").exists()


def test_a_foreign_table_is_not_an_export(tmp_path):
    (tmp_path / "rows").mkdir()
    pq.write_table(pa.table({"chosen": [1, 2]}), tmp_path / "rows" / "train.parquet")
    with pytest.raises(ExportError, match="no 'icprl' metadata.*--format trl"):
        import_export("parquet", tmp_path / "rows", tmp_path / "out")
    with pytest.raises(ExportError, match="not a Minari root exported"):
        import_export("minari", tmp_path / "rows", tmp_path / "out")


def test_export_refuses_an_existing_out_and_the_cli_lists_the_command(small_reward, tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    with pytest.raises(SystemExit):
        export_main([str(small_reward), "--format", "hf", "--out", str(tmp_path / "taken")])
    assert "exists" in capsys.readouterr().err
    assert SUBCOMMANDS["export-data"][0] == "icprl_lightning.commands.export_data"


# ---- TRL chosen/rejected rows ------------------------------------------------------------------------------

def step_rows(n_contexts: int = 6, t: int = 4, seed: int = 0) -> dict[str, list]:
    rng = np.random.default_rng(seed)
    rows = n_contexts * t
    return {"prompt": rng.random((rows, 2)).tolist(), "chosen": rng.integers(0, 5, rows).tolist(),
            "rejected": rng.integers(0, 5, rows).tolist(),
            "context_id": np.repeat(np.arange(n_contexts) * 7, t).tolist(),  # any ids
            "task_index": np.repeat(np.arange(n_contexts) // 2, t).tolist()}


def test_trl_step_rows_import_with_the_winner_recoverable(tmp_path):
    columns = step_rows()
    pq.write_table(pa.table(columns), tmp_path / "rows.parquet")
    import_main([str(tmp_path / "rows.parquet"), "--format", "trl", "--kind", "step_preference", "--n-actions", "5",
                 "--out", str(tmp_path / "data"), "--val-fraction", "0.34"])
    dm = RecordedPreferenceDataModule(str(tmp_path / "data"), pairs=True)  # the whole schema check of the loader
    chosen, rejected = np.asarray(columns["chosen"]), np.asarray(columns["rejected"])
    states = np.asarray(columns["prompt"], np.float32)
    labels = []
    for split in ("train", "val"):
        data = dm.dataset[split]
        for row, first in enumerate(data["source_row"]):
            steps = first + np.arange(4)  # context k holds rows 4k..4k+3 in table order
            won = np.where(data["preferred"][row] == 1, data["actions"][row], data["alt_actions"][row])
            lost = np.where(data["preferred"][row] == 1, data["alt_actions"][row], data["actions"][row])
            np.testing.assert_array_equal(won, chosen[steps])
            np.testing.assert_array_equal(lost, rejected[steps])
            np.testing.assert_array_equal(data["states"][row], states[steps])
            labels.append(np.asarray(data["preferred"][row]))
    assert 0 < np.concatenate(labels).mean() < 1  # the pair order is randomized: no constant label
    assert dm.dataset.manifest["info"]["origin"]["format"] == "trl"


def test_trl_trajectory_rows_from_a_saved_hf_dataset(tmp_path):
    import datasets

    rng = np.random.default_rng(1)
    def trajectory():
        return {"states": rng.random((5, 2)).tolist(), "actions": rng.standard_normal((5, 3)).tolist()}
    rows = {"chosen": [trajectory() for _ in range(8)], "rejected": [trajectory() for _ in range(8)],
            "task_index": [0, 0, 1, 1, 2, 2, 3, 3]}
    datasets.Dataset.from_dict(rows).save_to_disk(str(tmp_path / "rows"))
    import_main([str(tmp_path / "rows"), "--format", "trl", "--kind", "trajectory_preference", "--action-dim", "3",
                 "--out", str(tmp_path / "data"), "--val-fraction", "0"])
    data = load_dataset(tmp_path / "data")["train"]
    for row, source in enumerate(data["source_row"]):
        a_won = data["preferred"][row] == 1
        winner = data["actions_a"][row] if a_won else data["actions_b"][row]
        np.testing.assert_allclose(winner, np.asarray(rows["chosen"][source]["actions"], np.float32))
    assert data["actions_a"].dtype == np.float32 and data["states_a"].shape == (8, 5, 2)


@pytest.mark.parametrize("columns, message", [
    ({**step_rows(), "label": [1] * 24}, "unknown column 'label'"),
    ({k: v for k, v in step_rows().items() if k != "rejected"}, "missing column 'rejected'"),
    ({**step_rows(), "prompt": [[0.0, 1.0]] * 23 + [[0.0]]}, "column 'prompt' must hold numbers of one shape"),
    ({**step_rows(), "context_id": [0] * 5 + [1] * 19}, "column 'context_id': every context needs the same number"),
    ({**step_rows(), "task_index": list(range(24))}, "column 'task_index' differs within context 0"),
])
def test_bad_trl_rows_are_refused_naming_the_column(columns, message):
    with pytest.raises(ValueError, match=message):
        trl_arrays(columns, "step_preference", seed=0)


def test_trl_trajectory_rows_refuse_a_prompt():
    with pytest.raises(ValueError, match="unknown column 'prompt' \\(T-PRL trajectories carry their states"):
        trl_arrays({"prompt": [0], "chosen": [{}], "rejected": [{}]}, "trajectory_preference", seed=0)


# ---- imitation / B-Pref segment-pair label arrays -----------------------------------------------------------

def segment_pairs(label) -> dict[str, np.ndarray]:
    n = len(label)
    rng = np.random.default_rng(2)
    return {"states_1": rng.random((n, 3, 2)), "actions_1": rng.integers(0, 4, (n, 3)),
            "states_2": rng.random((n, 3, 2)), "actions_2": rng.integers(0, 4, (n, 3)),
            "label": np.asarray(label, dtype=np.float64), "task_index": np.arange(n) // 2}


def test_ties_are_refused_with_the_count_and_the_option(tmp_path, capsys):
    np.savez(tmp_path / "pairs.npz", **segment_pairs([1, 0, 0.5, 1, 0.5, 0]))
    with pytest.raises(SystemExit) as exit_info:
        import_main([str(tmp_path / "pairs.npz"), "--format", "bpref", "--n-actions", "4", "--out",
                     str(tmp_path / "data")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "field 'label' holds 2 ties" in err and "among 6 rows" in err and "--ties drop" in err
    assert not (tmp_path / "data").exists()


def test_dropped_ties_keep_the_source_rows_and_the_labels(tmp_path):
    arrays = segment_pairs([1, 0, 0.5, 1, 0.5, 0, 1, 1])
    np.savez(tmp_path / "pairs.npz", **arrays)
    import_main([str(tmp_path / "pairs.npz"), "--format", "bpref", "--n-actions", "4", "--ties", "drop",
                 "--val-fraction", "0", "--out", str(tmp_path / "data")])
    stored = load_dataset(tmp_path / "data")
    data = stored["train"]
    assert sorted(data["source_row"].tolist()) == [0, 1, 3, 5, 6, 7]
    np.testing.assert_array_equal(data["preferred"], arrays["label"][data["source_row"]].astype(np.uint8))
    np.testing.assert_array_equal(data["actions_b"], arrays["actions_2"][data["source_row"]])
    assert stored.manifest["info"]["origin"]["ties_dropped"] == 2


def test_bpref_convention_means_segment_two_and_minus_one_is_a_tie():
    arrays, rows, dropped = label_arrays(segment_pairs([1, 0, -1, 1]), convention="bpref", ties="drop")
    assert rows.tolist() == [0, 1, 3] and dropped == 1
    assert arrays["preferred"].tolist() == [0, 1, 0]  # B-Pref's 1: segment 2 (ξ_b) won


@pytest.mark.parametrize("change, message", [
    ({"label": np.array([1, 0, 0.3, 1.0])}, "field 'label' holds 1 values outside"),
    ({"label": np.array([1, 0, -1, 1])}, "field 'label' holds 1 values outside"),  # -1 is B-Pref's, not imitation's
    ({"actions_2": np.zeros((3, 3), int)}, "field 'actions_2' has \\(3,\\) rows, 'label' has 4"),
    ({"reward": np.zeros(4)}, "unknown field 'reward'"),
])
def test_bad_label_arrays_are_refused_naming_the_field(change, message):
    with pytest.raises(ValueError, match=message):
        label_arrays({**segment_pairs([1, 0, 0, 1]), **change}, convention="imitation", ties="drop")


def test_the_npz_path_stays_the_default(tmp_path):
    arrays = segment_pairs([1, 0, 1, 0])
    np.savez(tmp_path / "pairs.npz", states_a=arrays["states_1"], actions_a=arrays["actions_1"],
             states_b=arrays["states_2"], actions_b=arrays["actions_2"], preferred=arrays["label"])
    import_main([str(tmp_path / "pairs.npz"), "--kind", "trajectory_preference", "--n-actions", "4",
                 "--val-fraction", "0", "--out", str(tmp_path / "data")])
    info = load_dataset(tmp_path / "data").manifest["info"]
    assert "origin" not in info and info["source"] == str(tmp_path / "pairs.npz")


# ---- any array the store holds survives a table round trip --------------------------------------------------

DTYPES = [np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.float16, np.float32, np.float64, np.bool_]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_store_arrays_round_trip_through_tables(tmp_path_factory, data):
    root = tmp_path_factory.mktemp("fuzz")
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    n = data.draw(st.integers(0, 4), label="rows")
    split = {}
    for i in range(data.draw(st.integers(1, 3), label="fields")):
        shape = (n, *data.draw(st.lists(st.integers(0, 3), max_size=3), label="row shape"))
        dtype = np.dtype(data.draw(st.sampled_from(DTYPES)))
        values = rng.standard_normal(shape) * 100 if dtype.kind == "f" else rng.integers(0, 100, shape)
        split[f"field{i}"] = values.astype(dtype)
    other = {"goals": rng.integers(0, 9, (n + 1, 2))}  # a second row count in one split: one table per field
    write_dataset(root / "d", {"train": split, "tasks": {**other, "theta": rng.standard_normal((2, 3))}},
                  {"seed": 0})
    fmt = data.draw(st.sampled_from(["hf", "parquet"]))
    export_dataset(root / "d", fmt, root / "export")
    import_export(fmt, root / "export", root / "back")
    assert_same_dataset(root / "d", root / "back")
