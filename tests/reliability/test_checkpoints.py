"""Checkpoints are untrusted input (checkpoints.py): no pickle payload runs, only allow-listed classes are
built, and every damaged or foreign file is one clear error — from ``load_agent``, from ICRG's
``reward_gen_checkpoint`` and from ``icprl validate/test --ckpt_path``."""

from __future__ import annotations

import contextlib
import glob
import os
import pickle
import re
import zipfile
from pathlib import Path

import lightning as L
import pytest
import torch
from factories import save_untrained, tiny_darkroom_args

from icprl_lightning import StepPreferenceContext, load_agent
from icprl_lightning.checkpoints import CHECKSUM_KEY, CLASS_KEY, SEAL_KEY, checksum, seal
from icprl_lightning.commands import main
from icprl_lightning.commands.checkpoint import main as checkpoints_main
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.registry import BUILTIN_METHODS, class_path, method_class

REPO = Path(__file__).resolve().parents[2]
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=10)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
pytestmark = pytest.mark.filterwarnings("ignore:Detected pickle protocol 4:UserWarning")  # the legacy pickle


_save = save_untrained


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("ckpts")
    torch.manual_seed(0)
    return {"icpo": _save(ICPOModule(**ENV, **SIZES), root / "icpo.ckpt"),
            "reward_gen": _save(RewardGenModule(**ENV, **SIZES), root / "reward_gen.ckpt")}


class Payload:
    """Unpickling this calls exec, which writes ``marker``: what a malicious checkpoint would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",)


class ShellPayload(Payload):
    def __reduce__(self):
        return os.system, (f"echo pwned > '{self.marker}'",)


def _malicious(good: Path, out: Path, marker: Path, kind: str) -> Path:
    ckpt = torch.load(good, weights_only=True)
    if kind == "in_state_dict":  # a real checkpoint, class path and all, with one poisoned entry
        ckpt["state_dict"]["policy.evil"] = Payload(marker)
        torch.save(ckpt, out)
    elif kind == "whole_file":
        torch.save(Payload(marker), out)
    elif kind == "os_system":
        torch.save({**ckpt, "loops": ShellPayload(marker)}, out)
    else:  # a plain (non-zip) pickle, the legacy torch format
        out.write_bytes(pickle.dumps({CLASS_KEY: ckpt[CLASS_KEY], "state_dict": Payload(marker)}))
    return out


MALICIOUS = ["in_state_dict", "whole_file", "os_system", "legacy_pickle"]
# torch names the refused global; a legacy (non-zip) pickle is refused before torch reads it, as unreadable
REFUSED = r"was refused: it holds pickled objects other than tensors.*its pickle names \S*(exec|system)\)"
UNREADABLE = "is not a readable checkpoint: .*no zip archive"


def test_the_payload_is_real_under_weights_only_false(saved, tmp_path):
    """The control: the same file, read the unsafe way, does run its payload."""
    for kind in MALICIOUS:
        marker = tmp_path / f"control_{kind}"
        path = _malicious(saved["icpo"], tmp_path / f"{kind}.ckpt", marker, kind)
        # the legacy reader runs the payload, then finds no magic number after it
        with contextlib.suppress(RuntimeError):
            torch.load(path, weights_only=False)
        assert marker.read_text().strip() == "pwned", kind


def _edited(good: Path, out: Path, edit) -> Path:
    ckpt = torch.load(good, weights_only=True)
    edit(ckpt)
    torch.save(ckpt, out)
    return out


def _restamped(edit):
    """An edit whose checksum is recomputed: consistent, so only the rebuild can catch it."""
    def apply(ckpt: dict) -> None:
        edit(ckpt)
        ckpt[CHECKSUM_KEY] = checksum(ckpt[CLASS_KEY], ckpt["hyper_parameters"], ckpt["state_dict"])
        ckpt[SEAL_KEY] = seal(ckpt)
    return apply


def _flip_weight(ckpt: dict) -> None:
    w = ckpt["state_dict"]["policy.head.weight"] if "policy.head.weight" in ckpt["state_dict"] else next(
        v for v in ckpt["state_dict"].values() if v.is_floating_point() and v.numel() > 1)
    w.view(torch.int32).view(-1)[0] ^= 1  # one bit of one float


def _flip_byte_in_file(good: Path, out: Path) -> Path:
    """Flip a bit inside the largest stored tensor's bytes of the zip archive itself."""
    data = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as z:
        info = max((i for i in z.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    name_len, extra_len = (int.from_bytes(data[info.header_offset + o:info.header_offset + o + 2], "little")
                           for o in (26, 28))
    start = info.header_offset + 30 + name_len + extra_len
    data[start + info.file_size // 2] ^= 0x10
    out.write_bytes(bytes(data))
    return out


class Foreign(L.LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(2, 2)


def _bad_files(good: Path, d: Path) -> dict[str, tuple[Path, type[Exception], str]]:
    """Every damaged or foreign kind of file: (path, exception type, what the message must say)."""
    d.mkdir(exist_ok=True)
    raw = good.read_bytes()
    (d / "truncated.ckpt").write_bytes(raw[: len(raw) // 2])
    (d / "header_only.ckpt").write_bytes(raw[:1000])
    (d / "random.ckpt").write_bytes(bytes(torch.randint(0, 256, (4096,), generator=torch.Generator().manual_seed(0),
                                                        dtype=torch.uint8).tolist()))
    (d / "empty.ckpt").write_bytes(b"")
    (d / "text.ckpt").write_text("state_dict: {}\n")
    torch.save({"a": 1}, d / "foreign_dict.ckpt")
    torch.save(torch.zeros(3), d / "foreign_tensor.ckpt")
    _save(Foreign(), d / "foreign_lightning.ckpt")
    (d / "a_directory.ckpt").mkdir(exist_ok=True)
    readable, foreign = "not a readable checkpoint", "not an icprl_lightning checkpoint"
    damaged = "is damaged: its weights or hyperparameters do not match the checksum"
    not_allowed = "which is not a registered method"
    return {
        "missing": (d / "missing.ckpt", FileNotFoundError, "No checkpoint at"),
        "directory": (d / "a_directory.ckpt", ValueError, "is a directory, not a checkpoint file"),
        "truncated": (d / "truncated.ckpt", ValueError, readable),
        "header_only": (d / "header_only.ckpt", ValueError, readable),
        "random_bytes": (d / "random.ckpt", ValueError, readable),
        "empty": (d / "empty.ckpt", ValueError, readable),
        "text": (d / "text.ckpt", ValueError, readable),
        "foreign_dict": (d / "foreign_dict.ckpt", ValueError, foreign),
        "foreign_tensor": (d / "foreign_tensor.ckpt", ValueError, foreign),
        "foreign_lightning": (d / "foreign_lightning.ckpt", ValueError, foreign),
        "flipped_weight": (_edited(good, d / "flipped.ckpt", _flip_weight), ValueError, damaged),
        "flipped_file_byte": (_flip_byte_in_file(good, d / "flipped_byte.ckpt"), ValueError,
                              f"{damaged}|{readable}"),
        "edited_hparam": (_edited(good, d / "lr.ckpt", lambda c: c["hyper_parameters"].update(lr=1.0)),
                          ValueError, damaged),
        "dropped_weight": (_edited(good, d / "dropped.ckpt", lambda c: c["state_dict"].popitem()), ValueError,
                           damaged),
        "class_os_system": (_edited(good, d / "os_system.ckpt", lambda c: c.update({CLASS_KEY: "os.system"})),
                            ValueError, not_allowed),
        "class_other_module": (_edited(good, d / "cli.ckpt",
                                       lambda c: c.update({CLASS_KEY: "icprl_lightning.commands.ICPRLCLI"})),
                               ValueError, not_allowed),
        "hparams_class_path": (_edited(good, d / "hp_class.ckpt",
                                       lambda c: c["hyper_parameters"].update(_class_path="os.system")),
                               ValueError, "hyper_parameters name class 'os.system'"),
        "non_tensor_entry": (_edited(good, d / "non_tensor.ckpt", lambda c: c["state_dict"].update(x=[1])),
                             ValueError, "state_dict entry 'x' is not a tensor"),
        "class_not_a_string": (_edited(good, d / "list_class.ckpt", lambda c: c.update({CLASS_KEY: ["os"]})),
                               ValueError, not_allowed),
        "unfit_hparams": (_edited(good, d / "unfit.ckpt", _restamped(lambda c: c["hyper_parameters"]["backbone"].update(
            n_embd=8))), ValueError, "does not fit ICPOModule"),
        "relabeled_class": (_edited(good, d / "relabeled.ckpt", _restamped(lambda c: c.update(
            {CLASS_KEY: "icprl_lightning.methods.reward_gen.RewardGenModule"}))), ValueError,
            "does not fit RewardGenModule"),
        "no_checksum": (_edited(good, d / "old.ckpt", lambda c: (c.pop(CHECKSUM_KEY), c.pop(SEAL_KEY))), ValueError,
                        "has no icprl_sha256 checksum .*`icprl checkpoint stamp "),
    }


BAD_KINDS = ["missing", "directory", "truncated", "header_only", "random_bytes", "empty", "text", "foreign_dict",
             "foreign_tensor", "foreign_lightning", "flipped_weight", "flipped_file_byte", "edited_hparam",
             "dropped_weight", "class_os_system", "class_other_module", "class_not_a_string", "unfit_hparams",
             "relabeled_class", "hparams_class_path", "non_tensor_entry",
             "no_checksum"]


@pytest.fixture(scope="module")
def bad(saved, tmp_path_factory):
    files = _bad_files(saved["icpo"], tmp_path_factory.mktemp("bad"))
    assert sorted(files) == sorted(BAD_KINDS)
    return files


def test_the_builtin_methods_are_the_packages_lightning_modules():
    classes = [method_class(name) for name in BUILTIN_METHODS]
    assert [class_path(c) for c in classes] == list(BUILTIN_METHODS)
    assert all(issubclass(c, L.LightningModule) and c.__module__.startswith("icprl_lightning.methods.")
               for c in classes)


def test_saved_checksum_covers_class_hparams_and_weights(saved):
    ckpt = torch.load(saved["icpo"], weights_only=True)
    assert ckpt[CLASS_KEY] == "icprl_lightning.methods.icpo.ICPOModule"
    assert ckpt[CHECKSUM_KEY] == checksum(ckpt[CLASS_KEY], ckpt["hyper_parameters"], ckpt["state_dict"])
    assert len(ckpt[CHECKSUM_KEY]) == 64


def _context(b: int = 3, t: int = 6) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(1)
    return StepPreferenceContext(torch.rand(b, t, 2, generator=g), torch.randint(0, 5, (b, t), generator=g),
                                 torch.randint(0, 5, (b, t), generator=g),
                                 torch.randint(0, 2, (b, t), generator=g).float())


def test_good_checkpoint_round_trips(tmp_path):
    torch.manual_seed(3)
    module = ICPOModule(**ENV, **SIZES).eval()
    path = _save(module, tmp_path / "icpo.ckpt")
    ctx, obs = _context(), torch.rand(3, 2)
    before, after = module.make_agent(), load_agent(path)
    before.reset(ctx)
    after.reset(ctx)
    logits = module.policy(ctx, obs[:, None], torch.full((1,), 6))
    assert logits.std() > 0  # a real, non-constant policy
    for _ in range(3):
        assert torch.equal(before.act(obs), after.act(obs))
        obs = torch.rand_like(obs)


@pytest.mark.parametrize("kind", MALICIOUS)
def test_malicious_pickle_is_refused_by_load_agent_and_never_runs(saved, tmp_path, kind):
    marker = tmp_path / "marker"
    path = _malicious(saved["icpo"], tmp_path / "evil.ckpt", marker, kind)
    with pytest.raises(ValueError, match=rf"{path} ({UNREADABLE if kind == 'legacy_pickle' else REFUSED})"):
        load_agent(path)
    assert not marker.exists()


@pytest.mark.parametrize("kind", MALICIOUS)
def test_malicious_reward_gen_checkpoint_is_refused_by_icrg(saved, tmp_path, kind):
    marker = tmp_path / "marker"
    path = _malicious(saved["reward_gen"], tmp_path / "evil.ckpt", marker, kind)
    with pytest.raises(ValueError, match=rf"reward_gen_checkpoint: {path} "
                                         rf"({UNREADABLE if kind == 'legacy_pickle' else REFUSED})"):
        ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(path))
    assert not marker.exists()


@pytest.mark.parametrize("kind", MALICIOUS)
@pytest.mark.parametrize("subcommand", ["validate", "test"])
def test_malicious_checkpoint_is_refused_by_the_cli(saved, tmp_path, capsys, kind, subcommand):
    marker = tmp_path / "marker"
    path = _malicious(saved["icpo"], tmp_path / "evil.ckpt", marker, kind)
    _cli_refuses(subcommand, path, UNREADABLE if kind == "legacy_pickle" else REFUSED, capsys)
    assert not marker.exists()


def _cli_refuses(subcommand: str, path: Path, match: str, capsys, *extra: str) -> None:
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main([subcommand, "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--ckpt_path", str(path), *extra])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"icprl {subcommand}: error: "), err
    assert str(path) in err
    assert re.search(match, err), err


@pytest.mark.parametrize("kind", BAD_KINDS)
def test_bad_file_is_one_clear_error_from_load_agent(bad, kind):
    path, error, match = bad[kind]
    with pytest.raises(error, match=match) as info:
        load_agent(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("kind", BAD_KINDS)
def test_bad_file_is_one_clear_error_from_icprl_validate(bad, kind, capsys):
    path, _, match = bad[kind]
    _cli_refuses("validate", path, match, capsys)


@pytest.mark.parametrize("kind", ["missing", "truncated", "foreign_dict", "flipped_weight", "no_checksum"])
def test_bad_reward_gen_checkpoint_is_one_clear_error_from_icrg(saved, tmp_path, kind):
    path, error, match = _bad_files(saved["reward_gen"], tmp_path / "bad")[kind]
    with pytest.raises(error, match=f"reward_gen_checkpoint: .*{match}"):
        ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(path))


def test_icrg_reads_a_good_reward_gen_and_refuses_another_method(saved):
    model = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(saved["reward_gen"]))
    stored = torch.load(saved["reward_gen"], weights_only=True)["state_dict"]
    for k, v in model.reward_gen.state_dict().items():
        assert torch.equal(v, stored[f"reward.{k}"])
    with pytest.raises(ValueError, match=r"icpo.ckpt is not a RewardGen checkpoint \(it holds ICPOModule\)"):
        ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(saved["icpo"]))


def test_cli_refuses_weights_only_false(saved, capsys):
    with pytest.raises(SystemExit):
        main(["validate", "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--ckpt_path", str(saved["icpo"]),
              "--weights_only", "false"])
    assert capsys.readouterr().err == ("icprl validate: error: weights_only false is refused: icprl checkpoints "
                                       "hold only tensors and plain values\n")


@pytest.mark.slow
def test_cli_validates_a_good_checkpoint_end_to_end(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    data = tiny_darkroom_args(str(tmp_path / "data"))
    args = ["--config", str(REPO / "configs/icpo_darkroom.yaml"), "--trainer.logger", "false",
            "--trainer.default_root_dir", str(tmp_path), *data]
    main(["fit", *args, "--trainer.max_steps", "1", "--trainer.limit_val_batches", "1"])
    (ckpt,) = glob.glob(str(tmp_path / "**" / "last.ckpt"), recursive=True)
    main(["validate", *args, "--ckpt_path", ckpt, "--trainer.limit_val_batches", "1"])  # no SystemExit


@pytest.mark.parametrize("kind", ["unfit_hparams", "relabeled_class"])
def test_verify_rebuild_refuses_an_intact_file_this_version_cannot_build(bad, kind, capsys):
    """Plain ``verify`` checks the file's integrity (intact here: re-checksummed after the edit) without Lightning;
    ``--rebuild`` builds the module as ``load_agent`` does, and names what does not fit."""
    path, _, match = bad[kind]
    checkpoints_main(["verify", str(path)])
    assert f"{path}: ok" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        checkpoints_main(["verify", "--rebuild", str(path)])
    assert re.search(match, capsys.readouterr().err)


def test_stamp_adds_the_checksum_to_a_trusted_old_file(bad, tmp_path, capsys):
    old = tmp_path / "old.ckpt"
    old.write_bytes(bad["no_checksum"][0].read_bytes())
    checkpoints_main(["stamp", str(old)])
    load_agent(old)
    checkpoints_main(["verify", str(old)])
    assert f"{old}: ok" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        checkpoints_main(["stamp", str(bad["class_os_system"][0])])
    with pytest.raises(SystemExit):
        checkpoints_main(["verify", str(bad["flipped_weight"][0])])
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())
    assert os.path.getsize(old) > 0
