import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from icprl_lightning.data.store import DatasetError, DatasetNotFoundError, load_dataset, write_dataset

CONFIG = {"family": "toy", "seed": 1}


def _splits():
    rng = np.random.default_rng(0)
    return {"train": {"x": rng.normal(size=(10, 3)).astype(np.float32), "y": np.arange(10, dtype=np.int8)}}


def test_round_trip_is_memory_mapped(tmp_path):
    write_dataset(tmp_path / "d", _splits(), CONFIG, info={"agreement": 0.8})
    ds = load_dataset(tmp_path / "d", CONFIG)
    np.testing.assert_array_equal(ds["train"]["x"], _splits()["train"]["x"])
    assert isinstance(ds["train"]["x"], np.memmap)
    assert ds.manifest["info"]["agreement"] == 0.8 and ds.manifest["sizes"]["train"]["x"] == [10, 3]
    with pytest.raises(KeyError, match="no split 'val'"):
        ds["val"]


def test_refuses_to_overwrite_unless_asked(tmp_path):
    write_dataset(tmp_path / "d", _splits(), CONFIG)
    with pytest.raises(FileExistsError):
        write_dataset(tmp_path / "d", _splits(), CONFIG)
    write_dataset(tmp_path / "d", _splits(), {**CONFIG, "seed": 2}, overwrite=True)
    assert load_dataset(tmp_path / "d", {**CONFIG, "seed": 2})


def test_missing_corrupt_truncated_and_mismatched_are_clear_errors(tmp_path):
    with pytest.raises(DatasetNotFoundError, match="No dataset"):
        load_dataset(tmp_path / "nothing", CONFIG, regenerate_hint="run X")
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    with pytest.raises(DatasetError, match=r"seed: on disk 1, requested 2"):
        load_dataset(path, {**CONFIG, "seed": 2})
    x = path / "train" / "x.npy"
    data = bytearray(x.read_bytes())
    data[-1] ^= 0xFF
    x.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="checksum"):
        load_dataset(path, CONFIG, regenerate_hint="run X")
    x.write_bytes(bytes(data[:-8]))
    with pytest.raises(DatasetError, match="truncated") as err:
        load_dataset(path, CONFIG, regenerate_hint="run X")
    assert "run X" in str(err.value)
    (path / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetError, match="corrupt"):
        load_dataset(path, CONFIG)
    (path / "manifest.json").unlink()
    with pytest.raises(DatasetError, match="no manifest.json"):
        load_dataset(path, CONFIG)


def test_schema_version_mismatch(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["schema_version"] = 999
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="schema version 999"):
        load_dataset(path, CONFIG)


def test_interrupted_write_leaves_nothing(tmp_path):
    """Kill a writer in the middle of a large write: no dataset appears; the next write cleans up."""
    script = textwrap.dedent(f"""
        import numpy as np, os, sys
        from icprl_lightning.data import store
        real_save = np.save
        def slow_save(path, arr):
            real_save(path, arr)
            print("saved", flush=True)
            import time; time.sleep(30)
        store.np.save = slow_save
        store.write_dataset({str(tmp_path / 'd')!r}, {{"train": {{"a": np.zeros(5), "b": np.ones(5)}}}}, {{}})
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "saved"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / "d").exists()
    assert any(p.name.startswith(".d.tmp-") for p in tmp_path.iterdir())
    with pytest.raises(DatasetNotFoundError):
        load_dataset(tmp_path / "d")
    write_dataset(tmp_path / "d", _splits(), CONFIG)
    assert [p.name for p in tmp_path.iterdir()] == ["d"]


def test_exception_during_write_cleans_up(tmp_path):
    class Unconvertible:
        def __array__(self, *args, **kwargs):
            raise TypeError("cannot become an array")

    with pytest.raises(TypeError):
        write_dataset(tmp_path / "d", {"train": {"x": np.zeros(3), "bad": Unconvertible()}}, CONFIG)
    assert list(tmp_path.iterdir()) == []
