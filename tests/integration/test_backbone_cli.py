"""The backbone and the optimizer on the command line and in configs (``models/config.py``): YAML
``backbone: {n_layer: ...}``, flags ``--model.init_args.backbone.n_layer 4``, each method's own default for the keys
not given; a wrong key or value inside either is one line on stderr and exit status 2, before anything is
generated."""

from __future__ import annotations

from pathlib import Path

import pytest

from icprl_lightning.commands import main, run_cli
from icprl_lightning.models.config import OptimizerConfig, TransformerConfig

REPO = Path(__file__).resolve().parents[2]


def _model(tmp_path: Path, *args: str):
    return run_cli([*args, "--trainer.logger", "false", "--trainer.default_root_dir", str(tmp_path),
                    "--data.init_args.root_dir", str(tmp_path / "data")], run=False).model


@pytest.mark.parametrize("extra, expected", [
    ([], TransformerConfig(n_layer=3, n_embd=64, n_head=4)),  # the config's YAML mapping
    (["--model.init_args.backbone.n_layer", "4"], TransformerConfig(n_layer=4, n_embd=64, n_head=4)),
    (["--model.init_args.backbone", "{n_embd: 32, dropout: 0.1}"],
     TransformerConfig(n_layer=3, n_embd=32, n_head=4, dropout=0.1)),
    (["--config", str(REPO / "configs/paper/icpo_darkroom.yaml")], TransformerConfig(n_layer=6, n_embd=256, n_head=8)),
])
def test_the_backbone_from_yaml_flags_and_overlays(extra, expected, tmp_path):
    model = _model(tmp_path, "--config", str(REPO / "configs/icpo_darkroom.yaml"), *extra)
    assert model.backbone == expected and model.policy.transformer.config == expected
    assert model.hparams.backbone == expected.as_dict()  # plain values: what the checkpoint stores


def test_the_optimizer_from_yaml_and_flags(tmp_path):
    model = _model(tmp_path, "--config", str(REPO / "configs/icpo_darkroom.yaml"),
                   "--model.init_args.optimizer.lr_schedule", "cosine", "--model.init_args.optimizer.warmup_steps", "5")
    expected = OptimizerConfig(lr=1e-3, lr_schedule="cosine", warmup_steps=5)  # the config's lr kept
    assert model.optimizer_config == expected and model.hparams.optimizer == expected.as_dict()


def test_a_method_keeps_its_own_default_for_the_keys_not_given(tmp_path):
    model = _model(tmp_path, "--model", "icprl_lightning.methods.reward_gen.RewardGenModule",
                   "--data", "icprl_lightning.data.PreferenceDataModule",
                   "--data.init_args.family", "icprl_lightning.families.darkroom.DarkRoomFamily",
                   "--data.init_args.setting", "icprl_lightning.data.settings.TrajectoryPairs",
                   "--model.init_args.backbone.n_layer", "2")
    assert model.backbone == TransformerConfig(n_layer=2, n_embd=32, n_head=4)  # RewardGen's 4 × 32 × 4 default


@pytest.mark.parametrize("extra, expected", [
    (["--model.init_args.backbone.n_layers", "4"],
     "model.init_args.backbone.n_layers: backbone has no key 'n_layers' (did you mean 'n_layer'?)"),
    (["--model.init_args.backbone", "{n_heads: 2}"],
     "model.init_args.backbone.n_heads: backbone has no key 'n_heads' (did you mean 'n_head'?)"),
    (["--model.init_args.backbone.n_head", "1.5"], "model.init_args.backbone.n_head: expected int, got '1.5'"),
    (["--model.init_args.backbone.n_head", "3"],
     "backbone.n_head: must divide backbone.n_embd (each head gets n_embd / n_head channels), got n_head=3 with "
     "n_embd=64"),
    (["--model.init_args.lr", "0.01"],
     "model.init_args.lr: ICPOModule has no argument 'lr' (it is 'optimizer.lr' now)"),
    (["--model.init_args.optimizer.lr", "0"], "optimizer.lr: must be > 0, got 0.0"),
])
def test_a_wrong_backbone_key_or_value_is_one_line(extra, expected, tmp_path, capsys):
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["fit", "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--trainer.logger", "false",
              "--data.init_args.root_dir", str(tmp_path / "data"), *extra])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err == f"icprl fit: error: {expected}\n"
    assert not (tmp_path / "data").exists()
