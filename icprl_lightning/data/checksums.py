"""Same config, same dataset bytes: generate configs' datasets in a scratch directory and compare their checksums.

    icprl analyze checksums configs/*.yaml > checksums.json
    icprl analyze checksums --compare tests/fixtures/dataset_checksums.json configs/icpo_darkroom.yaml

The regression guarantee of a refactor (deterministic data: the same config and seed give the same bytes).
A config is one file, or a base and its overlays joined by ``+`` (``base.yaml+paper/x.yaml``). Prints the
SHA-256 of every file of each dataset (from its manifest) as JSON; ``--compare`` also names every file
whose checksum differs from the reference's and exits with status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="icprl analyze checksums", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("configs", nargs="+", help="config files (a base and its overlays joined by '+')")
    parser.add_argument("--compare", type=Path, help="a JSON of an earlier run to compare against")
    args = parser.parse_args(argv)
    reference = json.loads(args.compare.read_text()) if args.compare else None
    out, failed = {}, []
    with tempfile.TemporaryDirectory() as root:
        for config in args.configs:
            start = time.time()
            out[config] = dataset_checksums(config, root)
            print(f"{config}: {len(out[config])} files in {time.time() - start:.0f} s", file=sys.stderr)
            if reference is not None and config in reference and reference[config] != out[config]:
                failed.append(config)
                print(f"  CHANGED: {', '.join(changed_files(reference[config], out[config]))}", file=sys.stderr)
    print(json.dumps(out, indent=1, sort_keys=True))
    if failed:
        print(f"{len(failed)} of {len(args.configs)} configs changed their dataset bytes", file=sys.stderr)
        raise SystemExit(1)
    return 0
