"""``icprl export CKPT --out DIR``: a checkpoint as a Hugging Face-style model directory (``hub.py``)."""

from __future__ import annotations

import argparse

import icprl_lightning.hub as source
from icprl_lightning.hub import export_model


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icprl export", description=source.__doc__.split("\n")[0])
    parser.add_argument("checkpoint", help="a .ckpt of any icprl_lightning method")
    parser.add_argument("--out", required=True, help="the model directory to write")
    parser.add_argument("--results", help="an `icprl evaluate` JSON of this checkpoint, shown in the model card")
    parser.add_argument("--run-config", help="the run's config.yaml (default: the one beside checkpoints/)")
    parser.add_argument("--command", help="the command that trained the checkpoint, recorded in config.json")
    parser.add_argument("--name", help="the model's name (default: the directory's)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing model directory")
    args = parser.parse_args(argv)
    out = export_model(args.checkpoint, args.out, results=args.results, run_config=args.run_config,
                       command=args.command, name=args.name, overwrite=args.overwrite)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out} ({size / 1024:.1f} KiB): load it with load_agent({str(out)!r})")
