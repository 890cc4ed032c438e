"""Every way of giving ``icprl fit|validate|test|predict`` a checkpoint goes through one check, on the parsed
config (``commands.trainer.ICPRLCLI._parse_ckpt_path`` -> ``checkpoints.checkpoint_for_lightning``), and the seal
covers every part a resume restores (``checkpoints.seal``).

A payload pickle writes a marker file when unpickled the unsafe way; whichever way its path is spelled, the
marker never appears, and the error is one line with exit status 2.
"""

from __future__ import annotations

import glob
import http.server
import threading
from pathlib import Path

import lightning as L
import pytest
import torch
from factories import tiny_darkroom_args

from icprl_lightning.checkpoints import CHECKSUM_KEY, CLASS_KEY, SEAL_KEY, checksum, seal
from icprl_lightning.commands import main
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

REPO = Path(__file__).resolve().parents[2]
CONFIG = str(REPO / "configs/icpo_darkroom.yaml")


class Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",)


@pytest.fixture()
def evil(tmp_path) -> tuple[Path, Path]:
    """A checkpoint-looking file whose unpickling runs code, and the marker that code would write."""
    marker = tmp_path / "marker"
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    ckpt = {CLASS_KEY: "icprl_lightning.methods.icpo.ICPOModule", "state_dict": module.state_dict(),
            "hyper_parameters": dict(module.hparams), "loops": Payload(marker)}
    path = tmp_path / "evil.ckpt"
    torch.save(ckpt, path)
    return path, marker


def _refused(capsys, argv: list[str], match: str) -> str:
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"icprl {argv[0]}: error: "), err
    assert match in err, err
    return err


def _spellings(path: Path, tmp_path: Path) -> dict[str, list[str]]:
    config = tmp_path / "with_ckpt.yaml"
    config.write_text(f"ckpt_path: {path}\n")
    return {
        "long": ["--ckpt_path", str(path)],
        "long_equals": [f"--ckpt_path={path}"],
        "short_config_file": ["-c", str(config)],
        "config_file": ["--config", str(config)],
        "inline_yaml": ["--config", f"{{ckpt_path: {path}}}"],
    }


@pytest.mark.parametrize("spelling", ["long", "long_equals", "short_config_file", "config_file", "inline_yaml"])
@pytest.mark.parametrize("subcommand", ["fit", "validate"])
def test_every_spelling_of_a_payload_path_is_refused_and_never_runs(evil, tmp_path, capsys, spelling, subcommand):
    path, marker = evil
    argv = [subcommand, "--config", CONFIG, *_spellings(path, tmp_path)[spelling]]
    _refused(capsys, argv, "was refused: it holds pickled objects other than tensors")
    assert not marker.exists()


@pytest.mark.parametrize("subcommand", ["test", "predict"])
def test_test_and_predict_check_their_checkpoint_too(evil, capsys, subcommand):
    path, marker = evil
    _refused(capsys, [subcommand, "--config", CONFIG, "--ckpt_path", str(path)], "was refused")
    assert not marker.exists()


def test_an_abbreviated_option_is_an_error_not_another_option(evil, capsys):
    path, marker = evil
    err = _refused(capsys, ["validate", "--config", CONFIG, "--ckpt_pa", str(path)], "unknown option --ckpt_pa")
    assert "did you mean '--ckpt_path'" in err
    assert not marker.exists()


def test_a_config_before_the_subcommand_is_refused(evil, tmp_path, capsys):
    path, marker = evil
    (tmp_path / "top.yaml").write_text(f"validate:\n  ckpt_path: {path}\n")
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["-c", str(tmp_path / "top.yaml"), "validate", "--config", CONFIG])
    assert info.value.code == 2 and "unknown subcommand '-c'" in capsys.readouterr().err
    assert not marker.exists()


def test_no_environment_variable_sets_a_checkpoint(evil, monkeypatch, capsys):
    path, marker = evil
    for name in ("ICPRL_VALIDATE__CKPT_PATH", "VALIDATE__CKPT_PATH", "PL_VALIDATE__CKPT_PATH", "ICPRL_CKPT_PATH"):
        monkeypatch.setenv(name, str(path))
    with pytest.raises(SystemExit) as info:
        main(["validate", "--config", CONFIG, "--print_config"])
    assert info.value.code == 0
    assert "ckpt_path: null" in capsys.readouterr().out
    assert not marker.exists()


class _CountingHandler(http.server.BaseHTTPRequestHandler):
    requests = 0

    def do_GET(self):  # noqa: N802 (http.server's name)
        type(self).requests += 1
        self.send_response(200)
        self.end_headers()

    def log_message(self, *args):
        pass


@pytest.mark.parametrize("url", ["http://127.0.0.1:{port}/model.ckpt", "file:///etc/passwd",
                                 "s3://bucket/model.ckpt"])
def test_a_url_is_refused_without_being_fetched(capsys, url):
    server = http.server.HTTPServer(("127.0.0.1", 0), _CountingHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        _refused(capsys, ["fit", "--config", CONFIG, "--ckpt_path", url.format(port=server.server_port)],
                 "only a local checkpoint file is loaded")
    finally:
        server.shutdown()
    assert _CountingHandler.requests == 0


@pytest.mark.parametrize("special", ["last", "best", "hpc", "registry"])
def test_lightnings_special_values_are_refused(capsys, special):
    _refused(capsys, ["validate", "--config", CONFIG, "--ckpt_path", special], "is refused")


def test_weights_only_false_is_refused_however_spelled(tmp_path, capsys):
    (tmp_path / "w.yaml").write_text("weights_only: false\n")
    _refused(capsys, ["validate", "--config", CONFIG, "--config", str(tmp_path / "w.yaml")],
             "weights_only false is refused")


# --- the seal: what a resume restores is covered too ---------------------------------------------------


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict:
    """A real fit's last.ckpt (optimizer, loops, callback and RNG states), and the args that made it."""
    root = tmp_path_factory.mktemp("fit")
    args = ["--config", CONFIG, "--trainer.logger", "false", "--trainer.default_root_dir", str(root),
            "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1",
            "--trainer.enable_progress_bar", "false", "--evaluation", "null", "--best_checkpoint", "null",
            *tiny_darkroom_args(str(root / "data"))]
    main(["fit", *args])
    (last,) = glob.glob(str(root / "**" / "last.ckpt"), recursive=True)
    return {"path": Path(last), "args": args, "root": root}


def _rewrite(src: Path, out: Path, edit, reseal: bool = False) -> Path:
    ckpt = torch.load(src, weights_only=True)
    edit(ckpt)
    if reseal:  # consistent digests: only the finiteness check can catch it
        ckpt[CHECKSUM_KEY] = checksum(ckpt[CLASS_KEY], ckpt["hyper_parameters"], ckpt["state_dict"])
        ckpt[SEAL_KEY] = seal(ckpt)
    torch.save(ckpt, out)
    return out


def _first_moment(ckpt: dict) -> torch.Tensor:
    state = ckpt["optimizer_states"][0]["state"]
    return state[sorted(state)[0]]["exp_avg"]


def test_the_seal_covers_every_part_of_a_real_checkpoint(trained):
    ckpt = torch.load(trained["path"], weights_only=True)
    for part in ("optimizer_states", "loops", "callbacks", "state_dict", "hyper_parameters", "epoch", "global_step"):
        assert part in ckpt[SEAL_KEY], part
    assert ckpt[SEAL_KEY] == seal(ckpt)


def _flip_first_moment(ckpt: dict) -> None:
    _first_moment(ckpt).view(torch.int32).view(-1)[0] ^= 1


def _nan_first_moment(ckpt: dict) -> None:
    _first_moment(ckpt).view(-1)[0] = float("nan")


def _damage_rng(ckpt: dict) -> None:
    key = next(k for k in ckpt if "rng" in str(k))
    ckpt[key] = {"python": [1, 2]} if isinstance(ckpt[key], dict) else [0]


@pytest.mark.parametrize("damage, match", [
    (_flip_first_moment, "its 'optimizer_states' entry does not match the checksum"),
    (lambda c: c["loops"]["fit_loop"].update(epoch_progress={}), "its 'loops' entry does not match"),
    (_damage_rng, "entry does not match the checksum"),
    (lambda c: c.update(global_step=10_000), "its 'global_step' entry does not match"),
    (lambda c: c.update(extra=torch.zeros(1)), "it has a 'extra' entry that was not there"),
    (lambda c: c.pop("lr_schedulers"), "its 'lr_schedulers' entry is missing"),
])
def test_a_damaged_part_is_refused_by_a_resume_and_named(trained, tmp_path, capsys, damage, match):
    bad = _rewrite(trained["path"], tmp_path / "bad.ckpt", damage)
    _refused(capsys, ["fit", *trained["args"], "--ckpt_path", str(bad)], match)


def test_a_resealed_nan_moment_is_refused_as_unusable(trained, tmp_path, capsys):
    bad = _rewrite(trained["path"], tmp_path / "nan.ckpt", _nan_first_moment, reseal=True)
    _refused(capsys, ["fit", *trained["args"], "--ckpt_path", str(bad)],
             "is unusable: optimizer_states.0.state.")


@pytest.mark.parametrize("forge", [
    lambda rng: rng.update(python=[3, [1, 2], None]),
    lambda rng: rng.update(numpy=["MT19937", torch.zeros(3, dtype=torch.int64), 0, 0, 0.0]),
    lambda rng: rng.update(torch=torch.zeros(3, dtype=torch.uint8)),
    lambda rng: rng.pop("numpy"),
])
def test_a_resealed_forged_rng_entry_is_one_error_naming_it(trained, tmp_path, capsys, forge):
    bad = _rewrite(trained["path"], tmp_path / "rng.ckpt", lambda c: forge(c["icprl_rng"]), reseal=True)
    _refused(capsys, ["fit", *trained["args"], "--ckpt_path", str(bad)],
             "the checkpoint's icprl_rng entry is not the RNG states a fit saves")


def test_a_resume_needs_the_seal_but_weights_alone_do_not(trained, tmp_path, capsys):
    old = _rewrite(trained["path"], tmp_path / "old.ckpt", lambda c: c.pop(SEAL_KEY))
    _refused(capsys, ["fit", *trained["args"], "--ckpt_path", str(old)], f"has no {SEAL_KEY}")
    main(["validate", *trained["args"], "--ckpt_path", str(old)])  # the weights are covered by the checksum


def test_a_checkpoint_of_another_size_fails_before_any_data_is_generated(trained, tmp_path, capsys):
    bandit_data = tmp_path / "bandit_data"
    _refused(capsys, ["validate", "--config", str(REPO / "configs/icpo_bandit.yaml"), "--trainer.logger", "false",
                      "--data.init_args.root_dir", str(bandit_data), "--ckpt_path", str(trained["path"])],
             "does not fit the model this config builds")
    assert not bandit_data.exists()


def test_lightning_loads_a_private_verified_copy(trained, monkeypatch):
    """What Lightning's own loader opens is never the user's path: a file swapped after the check is not read."""
    opened = []
    real = L.pytorch.trainer.connectors.checkpoint_connector._CheckpointConnector.resume_start

    def spy(self, checkpoint_path=None, *a, **k):
        opened.append(str(checkpoint_path))
        return real(self, checkpoint_path, *a, **k)

    monkeypatch.setattr(L.pytorch.trainer.connectors.checkpoint_connector._CheckpointConnector, "resume_start", spy)
    main(["validate", *trained["args"], "--ckpt_path", str(trained["path"])])
    assert opened and all("icprl-verified-" in p and str(trained["path"]) != p for p in opened)
