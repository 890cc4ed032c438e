"""Build a config's DataModule without the CLI (no model, trainer or logger): commands and tests use it.

Configs stack as on the command line (later files override earlier ones), and ``overrides`` set
DataModule arguments by name (``root_dir=..., progress=False``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import yaml
from jsonargparse import ArgumentParser


def datamodule_from_config(*paths: str | Path, **overrides: Any) -> L.LightningDataModule:
    """The DataModule the configs' ``data`` sections name (class_path + init_args), instantiated."""
    parser = ArgumentParser(exit_on_error=False)
    parser.add_subclass_arguments(L.LightningDataModule, "data", required=True)
    cfg = None
    for path in paths:  # only the data sections: a saved run config also holds trainer, model, ckpt_path...
        section = (yaml.safe_load(Path(path).read_text()) or {}).get("data")
        if section is not None:
            cfg = parser.parse_object({"data": section}, cfg_base=cfg)
    if cfg is None:
        raise ValueError(f"no data section in {', '.join(map(str, paths))}")
    for key, value in overrides.items():
        cfg["data"]["init_args"][key] = value
    return parser.instantiate_classes(cfg)["data"]
