"""Generate each config's dataset in a scratch directory and print its files' SHA-256 as JSON.

    python scripts/dataset_checksums.py configs/*.yaml > checksums.json
    python scripts/dataset_checksums.py --compare checksums.json configs/*.yaml

The regression guarantee of a refactor (DESIGN.md, "Deterministic"): the same config must give the
same dataset bytes. ``--compare`` exits 1 and names every file whose checksum changed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from icprl_lightning.data.config import datamodule_from_config


def checksums(config: str, root: str) -> dict[str, str]:
    """``config`` is one file, or a base and its overlays joined by '+' (``base.yaml+paper/x.yaml``)."""
    dm = datamodule_from_config(*config.split("+"), root_dir=root, progress=False)
    dm.prepare_data()
    manifest = json.loads((dm.path / "manifest.json").read_text())
    return {rel: meta["sha256"] for rel, meta in sorted(manifest["files"].items())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="+")
    parser.add_argument("--compare", help="a JSON file of an earlier run to compare against")
    args = parser.parse_args(argv)
    reference = json.loads(Path(args.compare).read_text()) if args.compare else None
    out, failed = {}, []
    with tempfile.TemporaryDirectory() as root:
        for config in args.configs:
            start = time.time()
            out[config] = checksums(config, root)
            print(f"{config}: {len(out[config])} files in {time.time() - start:.0f} s", file=sys.stderr)
            if reference is not None and config in reference and reference[config] != out[config]:
                changed = sorted(k for k in set(reference[config]) | set(out[config])
                                 if reference[config].get(k) != out[config].get(k))
                failed.append(config)
                print(f"  CHANGED: {', '.join(changed)}", file=sys.stderr)
    print(json.dumps(out, indent=1, sort_keys=True))
    if failed:
        print(f"{len(failed)} of {len(args.configs)} configs changed their dataset bytes", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
