import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

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


# ---- overwrite replaces only our own datasets ----------------------------------------------------

TINY_GEN = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=1,
                calibration_episodes=2, progress=False)


def _user_files(path):
    path.mkdir()
    (path / "thesis.tex").write_text("years of work")
    (path / "sub").mkdir()
    (path / "sub" / "data.csv").write_text("1,2,3")


def _assert_user_files(path):
    assert (path / "thesis.tex").read_text() == "years of work"
    assert (path / "sub" / "data.csv").read_text() == "1,2,3"


def _not_ours_cases(tmp_path):
    """(name, make) of things at a path that overwrite must refuse, each leaving them untouched."""
    def manifest(text):
        def make(p):
            _user_files(p)
            (p / "manifest.json").write_text(text)
        return make

    def symlink(p):
        target = tmp_path / f"{p.name}-target"
        write_dataset(target, _splits(), CONFIG)
        p.symlink_to(target)

    return [("user files", _user_files), ("empty dir", lambda p: p.mkdir()),
            ("plain file", lambda p: p.write_text("not a dir")),
            ("corrupt manifest", manifest("{not json")), ("manifest a list", manifest("[1, 2]")),
            ("other schema", manifest(json.dumps({"schema_version": 999}))),
            ("no schema", manifest(json.dumps({"files": {}}))),
            ("binary manifest", lambda p: (_user_files(p), (p / "manifest.json").write_bytes(b"\xff\xfe\x00"))),
            ("symlink to a dataset", symlink)]


def _snapshot(path):
    if path.is_symlink():
        return ("link", os.readlink(path))
    if path.is_file():
        return ("file", path.read_bytes())
    return ("dir", sorted((str(p.relative_to(path)), p.read_bytes() if p.is_file() else None)
                          for p in path.rglob("*")))


def test_overwrite_refuses_what_is_not_our_dataset_and_keeps_it(tmp_path):
    from icprl_lightning.data.store import NotReplaceableError

    for i, (name, make) in enumerate(_not_ours_cases(tmp_path)):
        target = tmp_path / f"case{i}"
        make(target)
        before = _snapshot(target)
        with pytest.raises(NotReplaceableError, match="refusing to delete or replace it") as err:
            write_dataset(target, _splits(), CONFIG, overwrite=True)
        assert str(target) in str(err.value), name
        assert isinstance(err.value, FileExistsError)
        assert _snapshot(target) == before, name
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(f".case{i}.")], name  # no staging, no lock
    with pytest.raises(NotReplaceableError, match="is a file, not an icprl dataset"):
        write_dataset(tmp_path / "case2", _splits(), CONFIG, overwrite=True)
    with pytest.raises(NotReplaceableError, match=r"it has no manifest\.json"):
        write_dataset(tmp_path / "case0", _splits(), CONFIG, overwrite=True)
    with pytest.raises(NotReplaceableError, match="symbolic link"):
        write_dataset(tmp_path / "case8", _splits(), CONFIG, overwrite=True)


def test_overwrite_replaces_a_real_dataset(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    write_dataset(path, {"train": {"z": np.ones(4)}}, {**CONFIG, "seed": 5}, overwrite=True)
    ds = load_dataset(path, {**CONFIG, "seed": 5})
    assert sorted(ds["train"]) == ["z"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_datamodule_overwrite_refuses_user_files_before_generating(tmp_path, monkeypatch):
    from factories import darkroom_data

    from icprl_lightning.data.store import NotReplaceableError

    user = tmp_path / "mine"
    _user_files(user)
    dm = darkroom_data(data_dir=str(user), overwrite=True, **TINY_GEN)
    generated = []
    monkeypatch.setattr(type(dm.setting), "generate", lambda *a, **k: generated.append(1))
    with pytest.raises(NotReplaceableError, match=f"{user} exists and is not an icprl dataset"):
        dm.prepare_data()
    _assert_user_files(user)
    assert generated == []  # refused before spending the generation
    plain = tmp_path / "plain"
    plain.write_text("keep")
    with pytest.raises(NotReplaceableError, match="is a file"):
        darkroom_data(data_dir=str(plain), overwrite=True, **TINY_GEN).prepare_data()
    assert plain.read_text() == "keep"
    without_overwrite = darkroom_data(data_dir=str(user), **TINY_GEN)  # loading it is an error, deleting nothing
    with pytest.raises(DatasetError, match="no manifest.json"):
        without_overwrite.prepare_data()
    _assert_user_files(user)


def test_datamodule_overwrite_replaces_its_dataset(tmp_path):
    from factories import darkroom_data

    dm = darkroom_data(root_dir=str(tmp_path), **TINY_GEN)
    dm.prepare_data()
    first = json.loads((dm.path / "manifest.json").read_text())
    (dm.path / "train" / "states.npy").write_bytes(b"garbage")  # corrupt: overwrite must regenerate it
    again = darkroom_data(root_dir=str(tmp_path), overwrite=True, **TINY_GEN)
    again.prepare_data()
    assert json.loads((dm.path / "manifest.json").read_text()) == first
    assert again.load()["train"]["states"].shape[0] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [dm.path.name]


def test_importer_uses_the_shared_check(tmp_path):
    from icprl_lightning.data import importer
    from icprl_lightning.data.store import NotReplaceableError, check_replaceable_dataset

    assert importer.check_replaceable_dataset is check_replaceable_dataset
    plain = tmp_path / "plain"
    plain.write_text("keep")
    arrays = {"states": np.zeros((4, 3, 2), np.float32), "actions": np.zeros((4, 3), np.int64),
              "alt_actions": np.ones((4, 3), np.int64), "preferred": np.ones((4, 3), np.int64)}
    with pytest.raises(NotReplaceableError, match="is a file"):
        importer.import_preferences(arrays, plain, n_actions=2, val_fraction=0.0, overwrite=True)
    assert plain.read_text() == "keep"


def _stage(path, files, **kw):
    from icprl_lightning.io import staged_directory

    with staged_directory(path, **kw) as tmp:
        for name, text in files.items():
            (tmp / name).write_text(text)


def test_staged_directory_needs_its_marker_and_replaces_only_its_kind(tmp_path):
    from icprl_lightning.io import NotReplaceableError

    kw = dict(marker="summary.json", schema_version=1, what="SAC oracle directory")
    with pytest.raises(RuntimeError, match="has no summary.json"):
        _stage(tmp_path / "o", {"model.zip": "x"}, **kw)
    assert list(tmp_path.iterdir()) == []
    _stage(tmp_path / "o", {"summary.json": json.dumps({"schema_version": 1})}, **kw)
    with pytest.raises(FileExistsError, match="pass overwrite"):
        _stage(tmp_path / "o", {}, **kw)
    _stage(tmp_path / "o", {"summary.json": json.dumps({"schema_version": 1, "run": 2})}, overwrite=True, **kw)
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["run"] == 2
    dataset = write_dataset(tmp_path / "d", _splits(), CONFIG)  # a dataset is not an oracle directory
    with pytest.raises(NotReplaceableError, match="is not a SAC oracle directory .*no summary.json"):
        _stage(dataset, {"summary.json": json.dumps({"schema_version": 1})}, overwrite=True, **kw)
    assert load_dataset(dataset, CONFIG)
    user = tmp_path / "u"
    _user_files(user)
    with pytest.raises(NotReplaceableError):
        _stage(user, {"summary.json": json.dumps({"schema_version": 1})}, overwrite=True, **kw)
    _assert_user_files(user)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "o", "u"]


def test_sac_oracle_refuses_user_files_before_training(tmp_path):
    pytest.importorskip("stable_baselines3")
    from icprl_lightning.families.metaworld_reach.sac import train_sac_oracle
    from icprl_lightning.io import NotReplaceableError

    user = tmp_path / "u"
    _user_files(user)
    with pytest.raises(NotReplaceableError, match="not a SAC oracle directory"):
        train_sac_oracle(np.zeros((1, 3)), user, timesteps=10, overwrite=True)
    _assert_user_files(user)


# ---- concurrent writers -------------------------------------------------------------------------------------

def _prepare_in_child(root, counter, log_file, barrier):
    """A child process: prepare the tiny dataset, counting generations in ``counter``."""
    import logging
    import time

    from factories import darkroom_data

    logging.basicConfig(filename=log_file, level=logging.INFO)
    dm = darkroom_data(root_dir=root, **TINY_GEN)
    cls = type(dm.setting)
    real = cls.generate

    def counted(self, *args, **kwargs):
        with open(counter, "a") as f:
            f.write(f"{os.getpid()}\n")
        time.sleep(2.0)  # so the other process surely arrives while this one generates
        return real(self, *args, **kwargs)

    cls.generate = counted
    barrier.wait(timeout=120)
    dm.prepare_data()
    ds = dm.load()
    return json.dumps({"path": str(ds.path), "files": ds.manifest["files"], "n": int(ds["train"]["states"].shape[0])})


def _child_main(root, counter, log_file, barrier, out):
    with open(out, "w") as f:
        f.write(_prepare_in_child(root, counter, log_file, barrier))


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
def test_two_processes_preparing_one_dataset_generate_it_once(tmp_path):
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(2)
    counter = tmp_path / "generations.txt"
    root = tmp_path / "data"
    procs = [ctx.Process(target=_child_main, args=(str(root), str(counter), str(tmp_path / f"log{i}.txt"), barrier,
                                                  str(tmp_path / f"out{i}.json"))) for i in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0, 0]
    results = [json.loads((tmp_path / f"out{i}.json").read_text()) for i in range(2)]
    assert results[0] == results[1] and results[0]["n"] > 0
    assert len(counter.read_text().split()) == 1  # one generation; the other process waited and loaded it
    logs = [(tmp_path / f"log{i}.txt").read_text() for i in range(2)]
    assert sum("is being written by another process" in log for log in logs) == 1
    assert sorted(p.name for p in root.iterdir()) == [Path(results[0]["path"]).name]  # no lock, staging or trash


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
def test_a_live_writer_is_waited_for_not_deleted(tmp_path, caplog):
    """Another process mid-write holds the lock: a second writer waits (with a log line), the first finishes."""
    script = textwrap.dedent(f"""
        import numpy as np, time
        from icprl_lightning.data import store
        real_save = store.np.save
        def slow_save(path, arr):
            real_save(path, arr)
            print("saved", flush=True)
            time.sleep(2)
        store.np.save = slow_save
        store.write_dataset({str(tmp_path / 'd')!r}, {{"train": {{"a": np.zeros(5)}}}}, {{"who": "first"}})
        print("done", flush=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "saved"
    live = [p for p in tmp_path.iterdir() if p.name.startswith(".d.tmp-")]
    assert len(live) == 1 and live[0].name.startswith(f".d.tmp-{proc.pid}-")
    with caplog.at_level("WARNING", logger="icprl_lightning.io"):
        write_dataset(tmp_path / "d", _splits(), CONFIG, overwrite=True)
    assert proc.stdout.readline().strip() == "done"
    assert proc.wait() == 0  # its staging directory was not deleted under it
    assert f"is being written by another process (pid {proc.pid}" in caplog.text
    assert load_dataset(tmp_path / "d", CONFIG)  # then replaced by the second writer
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_stale_leftovers_of_dead_pids_are_cleaned_live_ones_kept_without_the_lock(tmp_path):
    from icprl_lightning.io import remove_stale

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        for name in (f".d.tmp-{dead.pid}-aaaa", f".d.old-{dead.pid}-bbbb", f".d.tmp-{alive.pid}-cccc",
                     f".d.tmp-{os.getpid()}-dddd", ".d.tmp-nopid"):
            (tmp_path / name).mkdir()
            (tmp_path / name / "x.npy").write_text("x")
        removed = remove_stale(tmp_path / "d", lock_held=False)
        assert sorted(p.name for p in removed) == [f".d.old-{dead.pid}-bbbb", f".d.tmp-{dead.pid}-aaaa"]
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            [f".d.tmp-{alive.pid}-cccc", f".d.tmp-{os.getpid()}-dddd", ".d.tmp-nopid"])
        write_dataset(tmp_path / "d", _splits(), CONFIG)  # under the lock no leftover is anyone's live work
        assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    finally:
        alive.kill()
        alive.wait()


# ---- a field the setting needs but the manifest does not list -----------------------------------------------

def test_missing_field_is_a_dataset_error_naming_it(tmp_path):
    from factories import darkroom_data

    from icprl_lightning.data.store import MissingFieldError

    dm = darkroom_data(root_dir=str(tmp_path), **TINY_GEN)
    dm.prepare_data()
    manifest_path = dm.path / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    del manifest["files"]["train/states.npy"]
    manifest_path.write_text(json.dumps(manifest))
    with pytest.raises(MissingFieldError, match=r"lacks train/states\.npy .*not in its manifest\.json") as err:
        darkroom_data(root_dir=str(tmp_path), **TINY_GEN).load()
    assert str(dm.path) in str(err.value) and "overwrite" in str(err.value)
    with pytest.raises(DatasetError, match="lacks train/states.npy"):
        darkroom_data(root_dir=str(tmp_path), **TINY_GEN).prepare_data()
    ds = load_dataset(dm.path)
    with pytest.raises(DatasetError, match=rf"{dm.path} has no field 'states' in split 'train'"):
        ds["train"]["states"]
    with pytest.raises(KeyError):  # still a KeyError for `except KeyError` callers
        ds["train"]["states"]
    assert ds["val"]["states"].shape[0] > 0


def test_malformed_manifest_entries_are_dataset_errors(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    manifest = json.loads((path / "manifest.json").read_text())
    for files in ({"train/x.npy": {"sha256": "0"}}, {"x.npy": {"bytes": 1, "sha256": "0"}},
                  {"../train/x.npy": {"bytes": 1, "sha256": "0"}}, {"train/x.npy": 3}, [1]):
        (path / "manifest.json").write_text(json.dumps({**manifest, "files": files}))
        with pytest.raises(DatasetError, match="corrupt"):
            load_dataset(path, CONFIG)


def test_manifest_entries_outside_the_dataset_or_of_the_wrong_type_are_refused(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    manifest = json.loads((path / "manifest.json").read_text())
    entry = manifest["files"]["train/x.npy"]
    for files in ({"/x.npy": entry}, {"./x.npy": entry}, {"train/": entry}, {"train/x.npy": {**entry, "bytes": "1"}},
                  {"train/x.npy": {**entry, "bytes": True}}, {"train/x.npy": {**entry, "sha256": None}}):
        (path / "manifest.json").write_text(json.dumps({**manifest, "files": files}))
        with pytest.raises(DatasetError, match="corrupt .*bad file entry"):
            load_dataset(path, CONFIG)
    for key in ("config", "info", "sizes", "files"):
        (path / "manifest.json").write_text(json.dumps({**manifest, key: [1]}))
        with pytest.raises(DatasetError, match=f"its '{key}' is a JSON list, not an object"):
            load_dataset(path)


def test_a_file_whose_header_disagrees_with_its_manifest_entry_is_refused(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    np.save(path / "train" / "x.npy", np.zeros((3, 10), np.float32))
    with pytest.raises(DatasetError, match=r"train/x\.npy holds shape \[3, 10\], dtype float32; the manifest says "
                                           r"shape \[10, 3\]"):
        load_dataset(path, CONFIG, verify=False)  # same size, no checksum: only the header comparison sees it


def test_an_unreadable_manifest_or_file_is_a_dataset_error_naming_it(tmp_path):
    path = write_dataset(tmp_path / "d", _splits(), CONFIG)
    (path / "train" / "y.npy").unlink()
    (path / "train" / "y.npy").mkdir()
    with pytest.raises(DatasetError, match=r"file train/y\.npy is missing"):
        load_dataset(path, CONFIG)
    (path / "manifest.json").unlink()
    (path / "manifest.json").mkdir()
    with pytest.raises(DatasetError, match=r"cannot read manifest\.json"):
        load_dataset(path, CONFIG)


def test_a_full_disk_is_one_line_naming_the_path_and_cleans_up(tmp_path, monkeypatch):
    import errno

    from icprl_lightning.data import store
    from icprl_lightning.io import StorageError

    real_save = np.save

    def save(file, array, *args, **kwargs):
        if Path(file).name == "y.npy":
            Path(file).write_bytes(b"half")
            raise OSError(errno.ENOSPC, "No space left on device", str(file))
        real_save(file, array, *args, **kwargs)

    monkeypatch.setattr(store.np, "save", save)
    with pytest.raises(StorageError, match=rf"^no space left on {tmp_path / 'd'} \(while writing the dataset\); "
                                           "the partial copy was removed, nothing was written") as err:
        write_dataset(tmp_path / "d", _splits(), CONFIG)
    assert isinstance(err.value, OSError) and err.value.errno == errno.ENOSPC and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []

    def denied(file, array, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(file))

    monkeypatch.setattr(store.np, "save", denied)
    with pytest.raises(StorageError, match=rf"writing the dataset {tmp_path / 'd'} failed: Permission denied "
                                           r"\(.*x\.npy\)"):
        write_dataset(tmp_path / "d", _splits(), CONFIG)
    assert list(tmp_path.iterdir()) == []
