"""``icprl checkpoint verify|stamp PATH ...``: check checkpoints for damage, or stamp trusted old ones
(``checkpoints.py``). ``verify`` checks class name, checksum, seal and finite values without importing Lightning;
``--rebuild`` also builds the module as ``load_agent`` does (a file this version no longer fits), importing it.
"""

from __future__ import annotations

import argparse
import sys

import icprl_lightning.checkpoints as source
from icprl_lightning.checkpoints import CHECKSUM_KEY, build_module, load_raw, stamp_file, verify


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icprl checkpoint", description=source.__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("stamp", help="add the checksum to trusted checkpoints saved before it existed").add_argument(
        "paths", nargs="+")
    check = sub.add_parser("verify", help="check checkpoints (exit 1 if any fails)")
    check.add_argument("paths", nargs="+")
    check.add_argument("--resumable", action="store_true",
                       help="also require the seal over the training state that a resume restores")
    check.add_argument("--rebuild", action="store_true",
                       help="also build the module with this version of the package (imports Lightning: seconds)")
    parsed = parser.parse_args(args)
    failed = False
    for path in parsed.paths:
        try:
            if parsed.command == "stamp":
                print(f"{path}: {CHECKSUM_KEY} {stamp_file(path)}")
            else:
                ckpt = verify(load_raw(path), path, require_seal=parsed.resumable)
                if parsed.rebuild:
                    build_module(ckpt, path)
                print(f"{path}: ok")
        except (ValueError, FileNotFoundError) as e:
            print(f"error: {e}", file=sys.stderr)
            failed = True
    if failed:
        raise SystemExit(1)
