"""``icprl import SOURCE --out DIR``: recorded preference data as one of our datasets (``data/importer.py``)."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from icprl_lightning.data.importer import (
    EXPORT_FORMATS,
    FORMATS,
    KINDS,
    ImportSummary,
    import_preferences,
    read_source,
)
from icprl_lightning.data.source_files import MAX_SOURCE_BYTES
from icprl_lightning.data.store import DatasetError


def _foreign_arrays(args: argparse.Namespace) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any], str]:
    """(arrays, source row of each, origin, kind) of TRL rows or segment-pair label arrays (``data/interop``)."""
    from icprl_lightning.data.interop import preference_rows

    origin: dict[str, Any] = {"format": args.format, "source": str(args.source)}
    if args.format == "trl":
        if args.kind is None:
            raise ValueError(f"--format trl needs --kind ({' or '.join(preference_rows.ROW_COLUMNS)})")
        arrays, rows = preference_rows.trl_arrays(preference_rows.read_table(args.source), args.kind, args.seed)
        return arrays, rows, origin, args.kind
    if args.kind not in (None, "trajectory_preference"):
        raise ValueError(f"--format bpref imports segment pairs as trajectory_preference, not --kind {args.kind}")
    arrays, rows, dropped = preference_rows.label_arrays(read_source(args.source, args.max_source_bytes),
                                                         args.label_convention, args.ties)
    origin.update(label_convention=args.label_convention, ties=args.ties, ties_dropped=dropped)
    return arrays, rows, origin, "trajectory_preference"


def main(argv: list[str] | None = None) -> ImportSummary | str:
    """``icprl import``: see the module docstring; ``--format`` other than npz: ``data/interop``."""
    parser = argparse.ArgumentParser(
        prog="icprl import", description="Check recorded preference arrays and write them as an icprl dataset "
        "(format: docs/recorded_data.md), or bring back an `icprl export-data` export, or import TRL chosen/rejected "
        "rows or segment-pair label arrays (docs/data_formats.md).")
    parser.add_argument("source", help="an .npz file or a directory of <field>.npy files; with --format: the export "
                        "directory, the TRL table (Parquet file or save_to_disk directory) or the label arrays")
    parser.add_argument("--out", required=True, help="the dataset directory to write")
    parser.add_argument("--format", choices=FORMATS, default="npz",
                        help="npz: recorded arrays (default); hf|parquet|minari: an export of `icprl export-data`, "
                        "rebuilt byte for byte; trl: chosen/rejected rows; bpref: segment pairs with labels")
    parser.add_argument("--kind", choices=sorted(KINDS), help="the context kind (npz, trl; bpref: trajectory pairs)")
    actions = parser.add_mutually_exclusive_group()
    actions.add_argument("--n-actions", type=int, help="discrete actions: indices in [0, n_actions)")
    actions.add_argument("--action-dim", type=int, help="continuous actions: vectors of this size")
    parser.add_argument("--val-fraction", type=float, default=0.1, help="share of the tasks held out for val")
    parser.add_argument("--seed", type=int, default=0, help="seeds the train/val task split (and a TRL pair's order)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing icprl dataset at --out")
    parser.add_argument("--max-source-bytes", type=int, default=MAX_SOURCE_BYTES,
                        help="refuse sources whose arrays declare more bytes than this (default: 8 GiB)")
    parser.add_argument("--ties", choices=("refuse", "drop"), default="refuse",
                        help="bpref: a tie (0.5) is refused (default) or its row dropped; no method trains on 0.5")
    parser.add_argument("--label-convention", choices=("imitation", "bpref"), default="imitation",
                        help="bpref: imitation (label = P(segment 1 preferred)) or bpref (1 = segment 2 preferred)")
    args = parser.parse_args(argv)
    if args.format in EXPORT_FORMATS:
        given = [flag for flag, value in (("--kind", args.kind), ("--n-actions", args.n_actions),
                                          ("--action-dim", args.action_dim)) if value is not None]
        if given:
            parser.error(f"{', '.join(given)} not used with --format {args.format}: the export carries its kind and "
                         "actions")
        from icprl_lightning.data.interop import import_export

        try:
            path = import_export(args.format, args.source, args.out, overwrite=args.overwrite)
        except (ValueError, OSError, DatasetError) as e:
            parser.exit(2, f"icprl import: error: {e}\n")
        summary = (f"rebuilt the exported dataset {args.source} ({args.format}) into {path}; every file matches its "
                   "exported SHA-256")
        print(summary)
        return summary
    if args.n_actions is None and args.action_dim is None:
        parser.error("one of the arguments --n-actions --action-dim is required")
    if args.format == "npz" and args.kind is None:
        parser.error("the following arguments are required: --kind")
    try:
        source, rows, origin, kind = args.source, None, None, args.kind
        if args.format in ("trl", "bpref"):
            source, rows, origin, kind = _foreign_arrays(args)
        summary = import_preferences(source, args.out, kind, n_actions=args.n_actions, action_dim=args.action_dim,
                                     val_fraction=args.val_fraction, seed=args.seed, overwrite=args.overwrite,
                                     max_source_bytes=args.max_source_bytes, source_rows=rows, origin=origin)
    except (ValueError, OSError, DatasetError) as e:  # each one line naming the field, file or path
        parser.exit(2, f"icprl import: error: {e}\n")
    print(summary)
    return summary
