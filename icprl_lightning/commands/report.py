"""``icprl report RUN_DIR``: a run's learning curves and last held-out table (``evaluation/run_report.py``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console

from icprl_lightning.evaluation.run_report import FIGURE_NAME, report


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icprl report", description="A run's learning curves and last held-out "
                                     "results, from its metrics.csv; draws the curves into a PNG.")
    parser.add_argument("run", type=Path, help="the run directory `icprl fit` printed (or a metrics.csv)")
    parser.add_argument("--figure", type=Path, default=None,
                        help=f"where to write the PNG (default: <run>/{FIGURE_NAME})")
    parser.add_argument("--no-figure", action="store_true", help="print the report only")
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    run_dir = args.run.parent if args.run.is_file() else args.run
    figure = None if args.no_figure else (args.figure or run_dir / FIGURE_NAME)
    console = Console()
    if not console.is_terminal:
        console.width = 160  # a log file or a pipe: rows unwrapped
    try:
        report(args.run, figure, console)
    except (ValueError, OSError) as e:
        sys.stderr.write(f"icprl report: error: {e}\n")
        raise SystemExit(2) from None
