"""What ``icprl fit | validate | test | predict | generate`` says before Lightning is imported.

A missing ``--config`` file, or no config at all, is known from the command line alone: saying so takes
milliseconds, where the LightningCLI would first spend seconds importing Lightning to report it. A missing file
gets the closest config under ``configs/`` (as ``--trainer.max_epoch`` gets "did you mean"), no config at all
the command that starts.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import Path

CONFIGS = Path("configs")
START = "icprl fit --config configs/smoke.yaml"  # two minutes on 2 CPU cores: the whole pipeline, small


def config_paths(argv: Sequence[str]) -> list[str]:
    """The values of every ``--config FILE`` / ``--config=FILE`` (or ``-c``) of ``argv``."""
    paths = []
    for i, arg in enumerate(argv):
        if arg in ("--config", "-c") and i + 1 < len(argv):
            paths.append(argv[i + 1])
        elif arg.startswith(("--config=", "-c=")):
            paths.append(arg.partition("=")[2])
    return paths


def closest_config(path: str, root: Path = CONFIGS) -> str | None:
    """The config file under ``root`` whose path is closest to ``path`` (None when none is close)."""
    known = [str(p) for p in sorted(root.rglob("*.yaml"))] if root.is_dir() else []
    close = difflib.get_close_matches(path.removeprefix("./"), known, n=1, cutoff=0.6)
    return close[0] if close else None


def config_problem(subcommand: str, argv: Sequence[str]) -> str | None:
    """One line saying what is wrong with the configs ``argv`` names (None: nothing known to be wrong).

    ``argv`` is what follows the subcommand; with ``--help`` or ``--print_config`` nothing is checked here."""
    if any(a in ("-h", "--help") or a.startswith("--print_config") for a in argv):
        return None
    paths = config_paths(argv)
    if not paths and not any(a.startswith(("--model", "--data", "-c")) for a in argv):
        return (f"no --config given: a config names the method and its data; start with `{START}` "
                f"(configs/*.yaml are the others; icprl {subcommand} --help lists every option)")
    for path in paths:
        if not path.lstrip().startswith(("{", "[")) and not Path(path).is_file():  # not inline YAML
            close = closest_config(path)
            hint = (f" (did you mean {close!r}?)" if close else
                    "" if CONFIGS.is_dir() else " (run icprl from the repository's root, where configs/ is)")
            return f"--config {path}: no such file{hint}"
    return None
