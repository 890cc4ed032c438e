"""Hostile files stay small and harmless (``untrusted.py``): a checkpoint that would inflate or read beyond its own
size is refused before ``torch.load``; deeply nested or alias-bomb JSON/YAML, FIFOs and oversized files are one
error naming the file at every door; the SAC oracle loads only verified files of its own directory; and
hyperparameters read from a file are type-checked before a model is built."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from factories import save_untrained
from safetensors.torch import load_file

from icprl_lightning import load_agent
from icprl_lightning.checkpoints import CHECKSUM_KEY, CLASS_KEY, checkpoint_for_lightning, checksum
from icprl_lightning.commands.checkpoint import main as checkpoint_main
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.interop.provenance import ExportError, parse
from icprl_lightning.data.store import SCHEMA_VERSION as STORE_SCHEMA
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.metaworld_reach.sac_weights import CHECKSUMS, MANIFEST, ExportedSAC
from icprl_lightning.hub import CONFIG, WEIGHTS, export_model
from icprl_lightning.io import sha256
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.reproduce.experiments import TableError, load_table
from icprl_lightning.reproduce.runner import RecordError, read_record
from icprl_lightning.untrusted import MAX_DEPTH, UntrustedFileError, read_json
from icprl_lightning.validation import HyperparameterError

pytestmark = pytest.mark.usefixtures("one_thread")
ORACLE = Path(__file__).resolve().parents[2] / "icprl_lightning/families/metaworld_reach/sac_oracle_v1"
DEEP_JSON = "[" * 100_000 + "]" * 100_000
DEEP_YAML = "a: " + "[" * 100_000 + "]" * 100_000 + "\n"
ALIAS_BOMB = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 10) + "]\n" for i in range(8))


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=6,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    return save_untrained(module, tmp_path_factory.mktemp("good") / "good.ckpt")


def _deflated(good: Path, out: Path, extra: int = 0) -> Path:
    """``good`` with every member deflated (plus ``extra`` zero bytes in the weights): a valid checkpoint that
    ``torch.load`` reads, inflating it in memory first."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for m in src.infolist():
            data = src.read(m.filename)
            if extra and m.filename.endswith("/data/0"):
                data += bytes(extra)
            dst.writestr(m.filename, data)
    return out


def _forged_size(good: Path, out: Path) -> Path:
    """``good`` whose central directory declares one member of 1 GB (stored, sizes agreeing)."""
    raw = bytearray(good.read_bytes())
    at = raw.index(b"PK\x01\x02")  # the first central-directory entry
    raw[at + 20:at + 28] = struct.pack("<II", 1 << 30, 1 << 30)  # compressed and uncompressed size
    out.write_bytes(bytes(raw))
    return out


def test_a_deflated_checkpoint_is_refused_before_torch_inflates_it(good, tmp_path, capsys):
    bomb = _deflated(good, tmp_path / "bomb.ckpt", extra=80 << 20)
    assert bomb.stat().st_size < 1 << 20  # < 1 MB on disk, 80 MB inflated
    plain = _deflated(good, tmp_path / "deflated.ckpt")
    assert torch.load(plain, weights_only=True)[CLASS_KEY] == torch.load(good, weights_only=True)[CLASS_KEY]
    refused = r"member '.*' is compressed .*torch.save never compresses"
    for path in (bomb, plain):
        with pytest.raises(ValueError, match=refused):
            load_agent(path)
        with pytest.raises(ValueError, match=refused):
            checkpoint_for_lightning(str(path), "fit")
        with pytest.raises(ValueError, match=refused):
            export_model(path, tmp_path / "exported")
        with pytest.raises(SystemExit):
            checkpoint_main(["verify", str(path)])
        assert "is compressed" in capsys.readouterr().err + capsys.readouterr().out
    assert not (tmp_path / "exported").exists()
    load_agent(good)  # the control: the same checkpoint stored as torch.save writes it


def test_a_member_declared_beyond_the_file_is_refused(good, tmp_path):
    with pytest.raises(ValueError, match=r"declares 1,073,741,824 bytes, beyond the file's"):
        load_agent(_forged_size(good, tmp_path / "forged.ckpt"))


def test_a_non_zip_torch_file_is_refused_before_torch_allocates(tmp_path):
    legacy = tmp_path / "legacy.ckpt"
    torch.save({"x": torch.zeros(3)}, legacy, _use_new_zipfile_serialization=False)
    with pytest.raises(ValueError, match="not a readable checkpoint: .*no zip archive"):
        load_agent(legacy)


# ---- JSON and YAML at every door ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def model_dir(good, tmp_path_factory) -> Path:
    return export_model(good, tmp_path_factory.mktemp("model") / "model")


def _copy(model_dir: Path, tmp_path: Path) -> Path:
    out = tmp_path / "model"
    shutil.copytree(model_dir, out)
    return out


@pytest.mark.parametrize("text, problem", [(DEEP_JSON, f"nests deeper than {MAX_DEPTH} levels"),
                                           ("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1),
                                            f"nests deeper than {MAX_DEPTH} levels"),
                                           ('{"a": "\xff', "is not valid JSON")])
def test_a_hostile_json_is_one_error_naming_the_file_at_each_door(model_dir, tmp_path, text, problem):
    model = _copy(model_dir, tmp_path)
    (model / CONFIG).write_text(text)
    with pytest.raises(ValueError, match=rf"{model / CONFIG} {problem}"):
        load_agent(model)
    record = tmp_path / "run-seed0.json"
    record.write_text(text)
    with pytest.raises(RecordError, match=rf"fit record {record} is damaged \({record} {problem}"):
        read_record(record)
    with pytest.raises(ExportError, match=rf"data.parquet: its 'icprl' metadata {problem}"):
        parse(text, "data.parquet")


def _provenance(**edit) -> str:
    files = {"train/states.npy": {"shape": [2, 3], "dtype": "float32", "sha256": "ab"}}
    found = {"export_version": 1, "manifest": {"schema_version": STORE_SCHEMA, "files": files, "config": {}},
             "tables": {"train": ["train", ["states"]]}}
    for path, value in edit.items():
        *parents, leaf = path.split(".")
        node = found
        for key in parents:
            node = node[key]
        node[leaf] = value
    return json.dumps(found)


@pytest.mark.parametrize("edit, field", [
    ({"manifest.config": [1]}, "manifest.config must be a mapping"),
    ({"manifest.files": {"states.npy": {"shape": [1], "dtype": "f4", "sha256": "a"}}}, "named <split>/<field>.npy"),
    ({"manifest.files": {"train/states.npy": [1, 2]}}, "must be a mapping with a sha256 string"),
    ({"manifest.files": {"train/states.npy": {"shape": "2x3", "dtype": "f4", "sha256": "a"}}}, ".shape must be"),
    ({"manifest.files": {"train/states.npy": {"shape": [-1], "dtype": "f4", "sha256": "a"}}}, ".shape must be"),
    ({"manifest.files": {"train/states.npy": {"shape": [2], "dtype": "O", "sha256": "a"}}}, ".dtype must be"),
    ({"manifest.files": {"train/states.npy": {"shape": [2], "sha256": "a"}}}, ".dtype must be"),
    ({"tables": {"train": "train"}}, "tables['train'] must be [split, [field, ...]]"),
])
def test_forged_export_metadata_is_one_error_naming_the_field(edit, field):
    parse(_provenance(), "x.parquet")  # the control: the unedited metadata parses
    with pytest.raises(ExportError, match=rf"^x.parquet: its 'icprl' metadata's .*{re.escape(field)}"):
        parse(_provenance(**edit), "x.parquet")


@pytest.mark.parametrize("text, problem", [(DEEP_YAML, f"nests deeper than {MAX_DEPTH} levels"),
                                           (ALIAS_BOMB, "holds more than 2,000,000 values"),
                                           ("a: [1, 2\n", "is not valid YAML")])
def test_a_hostile_yaml_is_one_error_naming_the_file(tmp_path, text, problem):
    table = tmp_path / "table.yaml"
    table.write_text(text)
    with pytest.raises(TableError, match=rf"{table} {problem}"):
        load_table(table)


def test_a_fifo_or_an_oversized_file_is_refused_without_reading_it(model_dir, tmp_path):
    model = _copy(model_dir, tmp_path)
    (model / CONFIG).unlink()
    os.mkfifo(model / CONFIG)  # opening it for reading would block until a writer comes: never
    def hang(*_):
        raise TimeoutError("the reader blocked on the FIFO")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(20)  # a hang fails the test instead of stopping the suite
    try:
        with pytest.raises(ValueError, match=rf"{model / CONFIG} is a FIFO \(named pipe\), not a regular file"):
            load_agent(model)
        with pytest.raises(TableError, match="is a FIFO"):
            load_table(_fifo(tmp_path / "t.yaml"))
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    big = tmp_path / "big.json"
    big.write_text("[" + "0," * 1000 + "0]")
    with pytest.raises(UntrustedFileError, match=rf"{big} is 2,003 bytes, more than the 1,000"):
        read_json(big, max_bytes=1000)


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


# ---- hyperparameters read from a file -------------------------------------------------------------------------

@pytest.mark.parametrize("key, value, kind", [("discrete", "false", "true or false"),
                                              ("normalize_inputs", 1, "true or false"),
                                              ("lambda_on_preferred", "no", "true or false"),
                                              ("max_context", 6.0, "an integer"),
                                              ("optimizer.lr", float("nan"), "finite"),
                                              ("lam", "0.5", "a finite number")])
def test_a_resealed_config_json_of_the_wrong_type_is_refused(model_dir, tmp_path, key, value, kind):
    model = _copy(model_dir, tmp_path)
    config = json.loads((model / CONFIG).read_text())
    *group, name = key.split(".")  # a key inside a group (optimizer.lr)
    (config["hyperparameters"][group[0]] if group else config["hyperparameters"])[name] = value
    config[CHECKSUM_KEY] = checksum(config["method"], config["hyperparameters"], load_file(model / WEIGHTS))
    (model / CONFIG).write_text(json.dumps(config))
    refused = (rf"its hyperparameters do not build ICPOModule \(HyperparameterError: {key}: must be {kind}" if group
               else f"hyperparameter '{key}' of ICPOModule must be {kind}")  # a group checks its own keys' types
    with pytest.raises(ValueError, match=rf"{model / CONFIG}: {refused}"):
        load_agent(model)


def test_a_family_flag_that_is_not_a_boolean_is_refused():
    with pytest.raises(HyperparameterError, match="DarkRoomFamily: terminate_on_goal must be true or false, got 'no'"):
        DarkRoomFamily(terminate_on_goal="no")
    with pytest.raises(HyperparameterError, match="ICPOModule: discrete must be true or false, got 'false'"):
        ICPOModule(state_dim=2, action_dim=5, discrete="false", max_context=6)


# ---- the SAC oracle's directory -------------------------------------------------------------------------------

def _oracle(tmp_path: Path, edit) -> Path:
    """A copy of the shipped oracle with ``edit(directory, manifest)`` applied and its checksums made consistent."""
    out = tmp_path / "oracle"
    shutil.copytree(ORACLE, out)
    manifest = json.loads((out / MANIFEST).read_text())
    edit(out, manifest)
    (out / MANIFEST).write_text(json.dumps(manifest))
    names = sorted(p.name for p in out.iterdir() if p.name != CHECKSUMS and p.name != "unlisted.pt")
    (out / CHECKSUMS).write_text("".join(f"{sha256(out / n)}  {n}\n" for n in names))
    return out


class Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",)


def test_the_oracle_loads_only_verified_files_of_its_own_directory(tmp_path):
    outside = tmp_path / "outside.pt"
    shutil.copy(ORACLE / "actor_100.pt", outside)

    def name(file):
        def edit(out, manifest):
            manifest["policies"]["100"]["file"] = file
            shutil.copy(ORACLE / "actor_100.pt", out / "unlisted.pt")
        return edit

    for file in ("../outside.pt", str(outside), "unlisted.pt", ["actor_100.pt"], MANIFEST):
        shutil.rmtree(tmp_path / "oracle", ignore_errors=True)
        refused = f"names weight file {re.escape(repr(file))}, which is not a file of the oracle directory listed in"
        with pytest.raises(ValueError, match=f"{refused} {CHECKSUMS}"):
            ExportedSAC(_oracle(tmp_path, name(file)))
    marker = tmp_path / "marker"
    shutil.rmtree(tmp_path / "oracle")
    payload = _oracle(tmp_path, lambda out, _: torch.save({"w": Payload(marker)}, out / "actor_100.pt"))
    with pytest.raises(ValueError, match=r"actor_100.pt was refused: .*its pickle names \S*exec"):
        ExportedSAC(payload)
    assert not marker.exists()
    shutil.rmtree(tmp_path / "oracle")
    assert ExportedSAC(_oracle(tmp_path, lambda out, m: None)).levels  # the control: a consistent copy loads


# ---- icprl import ---------------------------------------------------------------------------------------------

def _arrays(actions: int) -> dict[str, np.ndarray]:
    return {"states": np.zeros((4, 3, 2), np.float32), "actions": np.full((4, 3), actions, np.int64),
            "alt_actions": np.zeros((4, 3), np.int64), "preferred": np.ones((4, 3), np.uint8)}


def test_action_indices_beyond_int32_are_stored_without_wrapping(tmp_path):
    n = 3_000_000_001
    import_preferences(_arrays(n - 1), tmp_path / "data", n_actions=n, val_fraction=0.0)
    stored = [a for p in (tmp_path / "data").rglob("actions.npy") if (a := np.load(p)).size]
    assert stored and all(int(a.min()) == int(a.max()) == n - 1 for a in stored), [a.dtype for a in stored]


def test_a_fifo_named_like_a_source_field_is_refused_without_blocking(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name, array in _arrays(1).items():
        np.save(source / f"{name}.npy", array)
    (source / "states.npy").unlink()
    os.mkfifo(source / "states.npy")

    def hang(*_):
        raise TimeoutError("the import blocked on the FIFO")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(20)
    try:
        with pytest.raises(ValueError, match=rf"{source / 'states.npy'} is a FIFO \(named pipe\), not a regular file"):
            import_preferences(source, tmp_path / "data", n_actions=5)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert not (tmp_path / "data").exists()
