"""Same config, same dataset bytes: generate configs' datasets in a scratch directory and compare their checksums.

    icprl analyze checksums configs/*.yaml > checksums.json
    icprl analyze checksums --compare tests/fixtures/dataset_checksums.json configs/icpo_darkroom.yaml

The regression guarantee of a refactor (deterministic data: the same config and seed give the same bytes).
A config is one file, or a base and its overlays joined by ``+`` (``base.yaml+paper/x.yaml``). Prints the
SHA-256 of every file of each dataset (from its manifest) as JSON; ``--compare`` also names every file
whose checksum differs from the reference's and exits with status 1.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from icprl_lightning.data.config import datamodule_from_config


def dataset_checksums(config: str, root: str | Path) -> dict[str, str]:
    """The SHA-256 of each file of ``config``'s dataset, generated under ``root`` (``config``: files joined by '+')."""
    dm = datamodule_from_config(*config.split("+"), root_dir=str(root), progress=False)
    dm.prepare_data()
    manifest = json.loads((dm.path / "manifest.json").read_text())
    return {rel: meta["sha256"] for rel, meta in sorted(manifest["files"].items())}


def changed_files(reference: Mapping[str, str], current: Mapping[str, str]) -> list[str]:
    """The files whose checksum differs between two ``dataset_checksums`` results (or that only one has)."""
    return sorted(k for k in set(reference) | set(current) if reference.get(k) != current.get(k))
