"""``icprl analyze checksums``: generate configs' datasets in a scratch directory and print or compare their SHA-256
(``data/checksums.py``).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import icprl_lightning.data.checksums as source
from icprl_lightning.commands import command_parser
from icprl_lightning.data.checksums import changed_files, dataset_checksums


def main(argv: Sequence[str] | None = None) -> int:
    parser = command_parser("icprl analyze checksums", source.__doc__)
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
