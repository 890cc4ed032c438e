"""``icprl import`` and the dataset loader under hostile input and resource faults.

* Forged ``.npy`` headers (a 10^12-element shape in a tiny file), sources beyond the size limit,
  truncated or bit-flipped ``.npz`` archives: one ``ValueError`` naming the file and member, raised before
  any array is allocated.
* A full disk (ENOSPC, simulated) while the dataset is written: "no space left on <path>", nothing left
  behind, an existing dataset untouched.
* Hypothesis over the importer's arrays (shapes, dtypes, NaN/inf/huge values, label values, kinds) and
  over manifests (mutated values, deleted keys, garbage): every case imports *and then loads*, or raises
  the project's error (``ValueError`` / ``DatasetError``) with a one-line message — never a raw numpy,
  torch, ``KeyError`` or ``TypeError``.
"""

from __future__ import annotations

import errno
import io
import json
import shutil
import tempfile
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icprl_lightning.commands import main
from icprl_lightning.data import store
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.data.store import MANIFEST, DatasetError, load_dataset
from icprl_lightning.io import StorageError

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
N, T, S, N_ACTIONS = 6, 4, 2, 3


def _arrays(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"states": rng.normal(size=(N, T, S)), "actions": rng.integers(0, N_ACTIONS, (N, T)),
            "alt_actions": rng.integers(0, N_ACTIONS, (N, T)), "preferred": rng.integers(0, 2, (N, T)),
            "task_index": np.repeat(np.arange(N // 2), 2)}


def _one_line_naming(err: BaseException, *names: str) -> str:
    text = str(err)
    assert "\n" not in text and text, text
    assert any(name in text for name in names), (names, text)
    return text


# ---- forged headers and size limits: refused before anything is allocated ------------------------------------

def _npy_bytes(shape: tuple[int, ...], dtype: str, data: bytes) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": dtype, "fortran_order": False, "shape": shape})
    return out.getvalue() + data


def _forged_npz(path: Path, member_size: int | None = None) -> Path:
    """A valid source whose states member's header claims 10^12 float64 (8 TB) in a few bytes."""
    with zipfile.ZipFile(path, "w") as archive:
        for name, array in _arrays().items():
            if name == "states":
                archive.writestr("states.npy", _npy_bytes((10**6, 10**6, 1), "<f8", b"\0" * 64))
            else:
                buffer = io.BytesIO()
                np.save(buffer, array)
                archive.writestr(f"{name}.npy", buffer.getvalue())
    if member_size is not None:  # also forge the archive's record of the member's size
        data = bytearray(path.read_bytes())
        info = zipfile.ZipFile(path).getinfo("states.npy")
        real = info.file_size.to_bytes(4, "little")
        for at in (info.header_offset + 22, data.rfind(b"states.npy") - 46 + 24):  # local header, central dir
            assert data[at:at + 4] == real
            data[at:at + 4] = member_size.to_bytes(4, "little")
        path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("member_size", [None, 2**32 - 1])
def test_a_forged_npy_shape_in_an_npz_allocates_nothing(tmp_path, member_size):
    source = _forged_npz(tmp_path / "bomb.npz", member_size)
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as err:
            import_preferences(source, tmp_path / "ds", n_actions=N_ACTIONS)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    text = _one_line_naming(err.value, f"{source} (member 'states.npy')")
    assert "[1000000, 1000000, 1]" in text and peak < 50 << 20, (text, peak)
    assert not (tmp_path / "ds").exists()


def test_a_forged_npy_file_in_a_directory_is_refused_by_its_header(tmp_path):
    source = tmp_path / "src"
    source.mkdir()
    for name, array in _arrays().items():
        np.save(source / f"{name}.npy", array)
    (source / "actions.npy").write_bytes(_npy_bytes((10**12,), "<i8", b"\0" * 80))
    with pytest.raises(ValueError, match=r"truncated or corrupt") as err:
        import_preferences(source, tmp_path / "ds", n_actions=N_ACTIONS)
    _one_line_naming(err.value, str(source / "actions.npy"))


def test_the_size_limit_counts_declared_bytes_of_all_members(tmp_path):
    np.savez(tmp_path / "src.npz", **_arrays())
    with pytest.raises(ValueError, match="more than the limit of 1,000") as err:
        import_preferences(tmp_path / "src.npz", tmp_path / "ds", n_actions=N_ACTIONS, max_source_bytes=1000)
    _one_line_naming(err.value, str(tmp_path / "src.npz"))
    import_preferences(tmp_path / "src.npz", tmp_path / "ds", n_actions=N_ACTIONS)  # the default limit: fine


def test_object_members_and_other_files_are_refused_by_name(tmp_path):
    with zipfile.ZipFile(tmp_path / "src.npz", "w") as archive:
        archive.writestr("states.npy", _npy_bytes((2,), "|O", b"\0" * 16))
    with pytest.raises(ValueError, match="no objects") as err:
        import_preferences(tmp_path / "src.npz", tmp_path / "ds", n_actions=N_ACTIONS)
    _one_line_naming(err.value, "member 'states.npy'")
    with zipfile.ZipFile(tmp_path / "other.npz", "w") as archive:
        archive.writestr("notes.txt", "hello")
    with pytest.raises(ValueError, match="'notes.txt' is not an .npy"):
        import_preferences(tmp_path / "other.npz", tmp_path / "ds", n_actions=N_ACTIONS)
    (tmp_path / "dir").mkdir()
    (tmp_path / "dir" / "states.npy").mkdir()  # a directory where a file should be: refused naming it
    with pytest.raises(ValueError, match=r"dir/states\.npy is a directory, not a regular file"):
        import_preferences(tmp_path / "dir", tmp_path / "ds", n_actions=N_ACTIONS)


@FUZZ
@given(cut=st.floats(0.0, 1.0, exclude_max=True), flips=st.lists(st.tuples(st.floats(0, 1, exclude_max=True),
                                                                           st.integers(1, 255)), max_size=3))
def test_truncated_or_damaged_npz_is_one_error_naming_it(cut, flips):
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "src.npz"
        np.savez_compressed(source, **_arrays())
        data = bytearray(source.read_bytes())
        for where, value in flips:
            data[int(where * len(data))] ^= value
        source.write_bytes(bytes(data[:max(1, int(cut * len(data)))] if cut else data))
        try:
            import_preferences(source, Path(tmp) / "ds", n_actions=N_ACTIONS)
        except ValueError as e:
            _one_line_naming(e, str(source), "field '")
        else:
            RecordedPreferenceDataModule(str(Path(tmp) / "ds")).setup("fit")


# ---- a full disk while writing -------------------------------------------------------------------------------

def _disk_fills_after(monkeypatch, saves: int) -> None:
    real_save = np.save
    calls = []

    def save(file, array, *args, **kwargs):
        calls.append(file)
        if len(calls) > saves:
            Path(file).write_bytes(b"\x93NUMPY partial")  # the part that fit
            raise OSError(errno.ENOSPC, "No space left on device", str(file))
        return real_save(file, array, *args, **kwargs)

    monkeypatch.setattr(store.np, "save", save)


def test_a_full_disk_during_import_says_so_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    np.savez(tmp_path / "src.npz", **_arrays())
    _disk_fills_after(monkeypatch, saves=3)
    out = tmp_path / "out" / "ds"
    with pytest.raises(StorageError) as err:
        import_preferences(tmp_path / "src.npz", out, n_actions=N_ACTIONS)
    assert err.value.errno == errno.ENOSPC and isinstance(err.value, OSError)
    text = _one_line_naming(err.value, f"no space left on {out}")
    assert "nothing was written" in text, text
    assert list((tmp_path / "out").iterdir()) == []  # no dataset, no staged leftovers, no lock file
    with pytest.raises(SystemExit) as exit_:
        main(["import", str(tmp_path / "src.npz"), "--out", str(out), "--kind", "step_preference",
              "--n-actions", str(N_ACTIONS)])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.strip().startswith(f"icprl import: error: no space left on {out}")


def test_a_full_disk_while_overwriting_keeps_the_old_dataset(tmp_path, monkeypatch):
    out = tmp_path / "ds"
    import_preferences(_arrays(), out, n_actions=N_ACTIONS)
    before = (out / MANIFEST).read_text()
    _disk_fills_after(monkeypatch, saves=0)
    with pytest.raises(StorageError, match=f"no space left on {out}.*already there is unchanged"):
        import_preferences(_arrays(1), out, n_actions=N_ACTIONS, overwrite=True, seed=1)
    assert (out / MANIFEST).read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    load_dataset(out)  # whole, checksums and all


def test_a_full_disk_writing_the_manifest_leaves_nothing(tmp_path, monkeypatch):
    def dump(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store.json, "dump", dump)
    with pytest.raises(StorageError, match=f"no space left on {tmp_path / 'ds'}"):
        store.write_dataset(tmp_path / "ds", {"train": {"x": np.zeros(3)}}, {})
    assert list(tmp_path.iterdir()) == []


# ---- Hypothesis: the importer's arrays ----------------------------------------------------------------------

DTYPES = ["float16", "float32", "float64", "int8", "int32", "int64", "uint8", "uint64", "bool", "complex64", "U2"]
SPECIAL = [np.nan, np.inf, -np.inf, 1e30, -1e7, 1e6, 2, -1, 0.5, N_ACTIONS, 1e300]


@st.composite
def sources(draw) -> tuple[str, dict[str, np.ndarray], dict]:
    kind = draw(st.sampled_from(["step_preference", "trajectory_preference"]))
    discrete = draw(st.booleans())
    n, t, s = draw(st.integers(1, 5)), draw(st.integers(1, 4)), draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    action = (lambda: rng.integers(0, N_ACTIONS, (n, t))) if discrete else (lambda: rng.normal(size=(n, t, 2)))
    if kind == "step_preference":
        arrays = {"states": rng.normal(size=(n, t, s)), "actions": action(), "alt_actions": action(),
                  "preferred": rng.integers(0, 2, (n, t))}
    else:
        arrays = {"states_a": rng.normal(size=(n, t, s)), "actions_a": action(), "states_b": rng.normal(size=(n, t, s)),
                  "actions_b": action(), "preferred": rng.integers(0, 2, n)}
    if draw(st.booleans()):
        arrays["task_index"] = rng.integers(0, 3, n)
    if draw(st.booleans()):
        arrays.update(query_states=rng.normal(size=(n, t, s)), optimal_actions=action())
    for _ in range(draw(st.integers(0, 3))):  # a few mutations of random fields
        name = draw(st.sampled_from(sorted(arrays)))
        x = arrays[name]
        how = draw(st.sampled_from(["dtype", "value", "drop_row", "drop_step", "extra_axis", "drop_axis", "remove"]))
        if how == "dtype":
            with np.errstate(all="ignore"):
                x = x.astype(draw(st.sampled_from(DTYPES)))
        elif how == "value" and x.size and x.dtype.kind in "fiu":
            x = x.astype(np.float64)
            x.reshape(-1)[draw(st.integers(0, x.size - 1))] = draw(st.sampled_from(SPECIAL))
        elif how == "drop_row":
            x = x[:-1]
        elif how == "drop_step" and x.ndim > 1:
            x = x[:, :-1]
        elif how == "extra_axis":
            x = x[..., None]
        elif how == "drop_axis" and x.ndim > 1 and x.shape[-1] > 0:
            x = x[..., 0]
        elif how == "remove":
            arrays.pop(name)
            continue
        arrays[name] = x
    actions = {"n_actions": N_ACTIONS} if discrete else {"action_dim": 2}
    return kind, arrays, actions


@FUZZ
@given(case=sources(), val_fraction=st.sampled_from([0.0, 0.3]))
def test_fuzzed_arrays_import_and_load_or_are_one_clear_error(case, val_fraction):
    kind, arrays, actions = case
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ds"
        try:
            import_preferences(arrays, out, kind=kind, val_fraction=val_fraction, **actions)
        except ValueError as e:  # the importer's and the schema's errors (InvalidDatasetError is one)
            _one_line_naming(e, "field '", "val_fraction")
            assert not out.exists()
            return
        dm = RecordedPreferenceDataModule(str(out), batch_size=2)  # what imports also loads, and serves
        dm.setup("fit")
        batch = next(iter(dm.train_dataloader()))
        assert all(v.isfinite().all() for v in vars(batch.context).values() if v is not None and v.is_floating_point())


# ---- Hypothesis: manifests ------------------------------------------------------------------------------------

SCALARS = (st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False, allow_infinity=False)
           | st.text(max_size=8))
JSON = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6)


def _paths(x, prefix=()) -> list[tuple]:
    """Every (key or index) path into a JSON value, the root included."""
    out = [prefix]
    if isinstance(x, dict):
        for k, v in x.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            out += _paths(v, (*prefix, i))
    return out


@pytest.fixture(scope="module")
def recorded_dataset(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("recorded") / "ds"
    import_preferences(_arrays(), path, n_actions=N_ACTIONS, val_fraction=0.34)
    return path


@FUZZ
@given(data=st.data())
def test_fuzzed_manifests_load_or_are_one_clear_error(recorded_dataset, data):
    manifest = json.loads((recorded_dataset / MANIFEST).read_text())
    how = data.draw(st.sampled_from(["replace", "delete", "garbage"]))
    if how == "garbage":
        text = data.draw(st.one_of(st.binary(max_size=40).map(lambda b: b.decode("latin-1")), JSON.map(json.dumps)))
    else:
        paths = [p for p in _paths(manifest) if p] if how == "delete" else _paths(manifest)
        depth = data.draw(st.sampled_from(sorted({len(p) for p in paths})))  # shallow keys as often as deep ones
        path = data.draw(st.sampled_from([p for p in paths if len(p) == depth]))
        if path:
            parent = manifest
            for key in path[:-1]:
                parent = parent[key]
            if how == "delete":
                del parent[path[-1]]
            else:
                parent[path[-1]] = data.draw(JSON)
        else:
            manifest = data.draw(JSON)
        text = json.dumps(manifest)
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "ds"
        shutil.copytree(recorded_dataset, copy)
        (copy / MANIFEST).write_text(text, encoding="latin-1")
        try:
            dm = RecordedPreferenceDataModule(str(copy), batch_size=2)
            dm.setup("fit")
            next(iter(dm.train_dataloader()))
        except (DatasetError, ValueError) as e:
            _one_line_naming(e, str(copy))
