"""``icprl export-data``: write one of our datasets as a Hugging Face DatasetDict, Parquet files or a Minari root.

    icprl export-data data/darkroom-step_preference-<hash> --format hf --out exports/darkroom_ipref
    icprl export-data data/darkroom-reward-<hash> --format minari --out exports/darkroom_reward_minari

The dataset is verified against its manifest (every file's SHA-256) first; ``--out`` must not exist (the export
is staged in a hidden sibling directory and renamed into place). ``icprl import --format hf|parquet|minari
EXPORT --out DIR`` brings it back byte for byte. What maps to what: ``docs/data_formats.md``.
"""

from __future__ import annotations

from pathlib import Path

from icprl_lightning.commands import command_parser
from icprl_lightning.data.interop import EXPORTERS, export_dataset
from icprl_lightning.data.store import DatasetError


def main(argv: list[str] | None = None) -> Path:
    parser = command_parser("icprl export-data", __doc__)
    parser.add_argument("dataset", help="an icprl dataset directory (it holds manifest.json)")
    parser.add_argument("--format", required=True, choices=sorted(EXPORTERS),
                        help="hf: DatasetDict saved to disk (Arrow); parquet: one file per split; minari: reward "
                        "contexts as episodes, under a Minari root at --out")
    parser.add_argument("--out", required=True, help="the export directory to create (must not exist)")
    args = parser.parse_args(argv)
    try:
        path = export_dataset(args.dataset, args.format, args.out)
    except (ValueError, OSError, DatasetError) as e:
        parser.exit(2, f"icprl export-data: error: {e}\n")
    print(f"exported {args.dataset} as {args.format} to {path}; bring it back with: icprl import {path} "
          f"--format {args.format} --out DIR")
    return path
