"""``icprl export CKPT --out DIR``: a checkpoint as a Hugging Face-style model directory (``hub.py``)."""

from __future__ import annotations

import argparse
from pathlib import Path

import icprl_lightning.hub as source
from icprl_lightning.hub import CONFIG, export_model, reissue_results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icprl export", description=source.__doc__.split("\n")[0])
    parser.add_argument("checkpoint", help="a .ckpt of any icprl_lightning method, or a model directory (with "
                        "--results and --out the same directory: its card re-issued on those results)")
    parser.add_argument("--out", required=True, help="the model directory to write")
    parser.add_argument("--results", help="an `icprl evaluate` JSON of this checkpoint, shown in the model card")
    parser.add_argument("--run-config", help="the run's config.yaml (default: the one beside checkpoints/)")
    parser.add_argument("--command", help="the command that trained the checkpoint, recorded in config.json")
    parser.add_argument("--name", help="the model's name (default: the directory's)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing model directory")
    args = parser.parse_args(argv)
    if Path(args.checkpoint).is_dir() and (Path(args.checkpoint) / CONFIG).is_file():
        if args.results is None or Path(args.out).resolve() != Path(args.checkpoint).resolve():
            parser.error("a model directory takes --results and --out naming the same directory (its new results)")
        return print(f"wrote {reissue_results(args.checkpoint, args.results)}: results.json and its card")
    out = export_model(args.checkpoint, args.out, results=args.results, run_config=args.run_config,
                       command=args.command, name=args.name, overwrite=args.overwrite)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out} ({size / 1024:.1f} KiB): load it with load_agent({str(out)!r})")
