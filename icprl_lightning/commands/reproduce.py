"""``icprl reproduce TABLE``: train and evaluate every run of a results table (``reproduce/``)."""

from __future__ import annotations

from pathlib import Path

import icprl_lightning.reproduce.runner as source
from icprl_lightning.commands import command_parser
from icprl_lightning.reproduce.children import Interrupted, WorkLocked
from icprl_lightning.reproduce.experiments import EXPERIMENTS, TableError, load_table, load_tables
from icprl_lightning.reproduce.runner import RecordError, redraw, reproduce


def main(argv: list[str] | None = None) -> dict:
    parser = command_parser("icprl reproduce", source.__doc__)
    parser.add_argument("table", nargs="?", help=f"a table of {EXPERIMENTS}/ (its file's name), or the path of an "
                        "experiment file (*.yaml)")
    parser.add_argument("--list", action="store_true", help=f"list the tables of {EXPERIMENTS}/ and what one fit "
                        "costs")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    parser.add_argument("--jobs", type=int, default=2, help="fits at a time (each gets cores / jobs threads)")
    parser.add_argument("--threads", type=int, help="torch threads per fit (default: cores / jobs)")
    parser.add_argument("--work", default="runs/reproduce", help="fit logs, run directories and records")
    parser.add_argument("--out", default="docs/results", help="where the tables and figures go: one folder per "
                        "table, <out>/<table>/")
    parser.add_argument("--refit", action="store_true", help="train again even where a fit is recorded")
    parser.add_argument("--dry-run", action="store_true", help="print the fit commands, run nothing")
    parser.add_argument("--only", nargs="+", metavar="RUN", help="train only these runs (and the earlier stages "
                        "they need), evaluate nothing")
    parser.add_argument("--render", action="store_true", help="only rewrite the generated docs from the JSON in "
                        "docs/results: each table's summary.md (bootstrap intervals), the index, the claims table of "
                        "docs/RESULTS.md and README.md (reproduce/render.py)")
    parser.add_argument("--redraw", action="store_true", help="only redraw the figures from the table's JSON "
                        "outputs in --out (after a change to the figure code)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be ≥ 1, got {args.jobs}")
    try:  # a user's file, not a bug: one line, no traceback
        if args.render:
            from icprl_lightning.reproduce.render import render

            for path in render():
                print(f"wrote {path}", flush=True)
            return {}
        if args.list or args.table is None:
            for table in load_tables().values():
                runs = f"{len(table.runs)} runs of {table.runs_from}" if table.runs_from else f"{len(table.runs)} runs"
                online = " (online)" if any(e.online for e in table.evaluations) else ""
                print(f"{table.name}: {table.title}{online}; {runs} × seeds; {table.budget}")
            return {}
        table = load_table(args.table)
        if args.redraw:
            sources = redraw(table, Path(args.out) / table.name)
            print(f"{table.name}: figures redrawn from {', '.join(map(str, sources))}", flush=True)
            return {}
        return reproduce(table, args.seeds, args.jobs, Path(args.work), Path(args.out) / table.name, args.refit,
                         args.dry_run, args.threads, args.only)
    except (RecordError, TableError, WorkLocked) as e:
        parser.exit(2, f"{parser.prog}: error: {e}\n")
    except Interrupted as e:
        parser.exit(128 + e.signum, f"{parser.prog}: {e}: the running fits were stopped and recorded as interrupted "
                                    f"in {args.work}; run the same command again to resume them\n")
