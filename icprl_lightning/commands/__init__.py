"""The commands room: every subcommand of ``icprl``, one dispatch table (``SUBCOMMANDS``, ``GROUPS``) and one file per
program in this folder. Library modules hold no ``main()`` and import no argparse; each program here parses its
options and calls the library.

    icprl fit --config configs/icpo_darkroom.yaml [--model.init_args.optimizer.lr 1e-3] [--print_config]
    icprl fit --config configs/icpo_darkroom.yaml --config configs/paper/icpo_darkroom.yaml   # an overlay
    icprl validate --config configs/icpo_darkroom.yaml --ckpt_path runs/.../last.ckpt
    icprl generate --config configs/icpo_darkroom.yaml [--data.init_args.overwrite true]
    icprl evaluate --run NAME=CONFIG:CKPT [...]                                   (evaluate.py)
    icprl evaluate --run NAME=CONFIG:CKPT --data configs/eval/reach_fresh_goals.yaml   (other held-out tasks)
    icprl evaluate online --config CONFIG --ckpt CKPT [...]                       (evaluate_online.py)
    icprl evaluate ad --run NAME=CONFIG:CKPT --episodes 20 [...]                  (evaluate_ad.py)
    icprl import arrays.npz --out data/mine --kind step_preference --n-actions 5  (import_data.py)
    icprl import exports/ipref_hf --format hf --out data/mine       (also parquet, minari, trl, bpref)
    icprl export-data data/<dataset> --format hf|parquet|minari --out DIR         (export_data.py)
    icprl export runs/.../last.ckpt --out DIR     (a Hugging Face-style model directory, export.py)
    icprl report runs/icprl/<run id>                                              (report.py)
    icprl checkpoint verify|stamp PATH ...                                        (checkpoint.py)
    icprl oracle train|export ...                                                 (oracle_*.py)
    icprl baseline sac|dqn|tune-bandit ...                                        (baseline_*.py)
    icprl analyze NAME ...                                                        (analyze_*.py)
    icprl label --session DIR --view VIEW --pairs N [--export OUT]                (label.py, labelling/)

``fit`` / ``validate`` / ``test`` / ``predict`` / ``generate`` are a LightningCLI (``trainer.py``). The
other subcommands are plain argparse programs, each a ``main(argv)`` in its own file; ``oracle``,
``baseline`` and ``analyze`` are groups whose second word picks the program (``GROUPS``). This module imports
none of them until one is asked for, so ``icprl --help`` answers without loading torch or Lightning.

``analyze`` holds the measurements beside the results tables: each reads a checkpoint's or a dataset's
insides with inputs and outputs of its own, where ``evaluate`` deploys agents and prints one kind of table.

A user's mistake (an unknown or mistyped key, a value out of range, a bad checkpoint or dataset, a model that
does not fit the data) is one line on stderr, ``icprl <subcommand>: error: ...``, and exit status 2; the
traceback is shown only with ``--verbose`` (anywhere on the line) or ``ICPRL_VERBOSE=1``, which also shows
Lightning's hardware banner and the model summary of a fit.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from icprl_lightning.commands.config_hints import config_problem

# name -> (module, one line of help); each module has a main(argv). An empty module means the LightningCLI
# (``commands/trainer.py``) or, for a name of GROUPS, the program its second word names
_C = "icprl_lightning.commands."
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "fit": ("", "train a method (generates its dataset first if missing)"),
    "validate": ("", "one validation epoch of a checkpoint"),
    "test": ("", "one test epoch of a checkpoint"),
    "predict": ("", "predictions of a checkpoint"),
    "generate": ("", "only build a config's dataset"),
    "evaluate": (_C + "evaluate", "deploy checkpoints on held-out tasks, with the context diagnostics"),
    "reproduce": (_C + "reproduce", "train and evaluate every run of a results table"),
    "import": (_C + "import_data",
               "import recorded preference data (npz, HF datasets, Parquet, Minari, TRL rows, B-Pref labels)"),
    "export-data": (_C + "export_data", "write a dataset as Hugging Face datasets (Arrow), Parquet or Minari"),
    "report": (_C + "report", "a run's learning curves and last held-out table, from its directory, no server needed"),
    "checkpoint": (_C + "checkpoint", "verify checkpoints, or stamp trusted old ones"),
    "export": (_C + "export", "write a checkpoint as a Hugging Face-style model directory"),
    "oracle": ("", "train the Meta-World Reach SAC oracle, or export its weights for data generation"),
    "baseline": ("", "RL from scratch per held-out task (SAC, DQN); tuning of the dueling-bandit baselines"),
    "analyze": ("", "measurements beside the tables: reward models, DIT's advantages, label ceiling, checksums"),
    "label": (_C + "label", "a labelling page in the browser for people's preferences, and its answers' export"),
}
# group -> verb -> (module, one line of help)
GROUPS: dict[str, dict[str, tuple[str, str]]] = {
    "oracle": {
        "train": (_C + "oracle_train",
                  "train one goal-conditioned SB3 SAC on Reach goals; pick its behavior checkpoints"),
        "export": (_C + "oracle_export",
                   "write a training run's weights as a checksummed, pickle-free oracle directory"),
    },
    "baseline": {
        "sac": (_C + "baseline_sac", "SB3 SAC from scratch on each held-out Meta-World Reach goal"),
        "dqn": (_C + "baseline_dqn", "SB3 DQN from scratch on each held-out DarkRoom goal"),
        "tune-bandit": (_C + "baseline_tune_bandit",
                        "tune the feature-aware dueling-bandit baselines on training problems only"),
    },
    "analyze": {
        "reward-quality": (_C + "analyze_reward_quality",
                           "RewardGen's held-out pair accuracy and label correlation with the latent reward"),
        "reward-bayes": (_C + "analyze_reward_bayes",
                         "the Bayes-optimal DarkRoom reward from one T-PRL pair, in the same measures"),
        "icrg-labels": (_C + "analyze_icrg_labels",
                        "ICRG's reward labels against the latent reward, in pretraining and at deployment"),
        "dit-advantages": (_C + "analyze_dit_advantages",
                           "correlation of DIT's advantages with each step's progress (and the SAC oracle's A*)"),
        "dit-weights": (_C + "analyze_dit_weights",
                        "which DarkRoom actions DIT's exp(A/eta) weights favour, against the behavior's"),
        "label-ceiling": (_C + "analyze_label_ceiling",
                          "the exact goal posterior of DarkRoom I-PRL contexts' labels: what any learner can earn"),
        "checksums": (_C + "analyze_checksums",
                      "generate configs' datasets in a scratch directory and print or compare their SHA-256"),
    },
}
VERBOSE_ENV = "ICPRL_VERBOSE"


def command_parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """A program's parser whose --help prints ``doc`` (its library module's docstring) as written."""
    return argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)


def baseline_parser(prog: str, doc: str, paper_episodes: int, default_episodes: int, family: str,
                    eval_every: int, eval_episodes: int, test_episodes: int, out: str) -> argparse.ArgumentParser:
    """The options ``icprl baseline sac`` and ``dqn`` share (``family``: the help of --family-seed)."""
    parser = command_parser(prog, doc.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=default_episodes,
                        help=f"training episodes per goal (paper: {paper_episodes})")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--family-seed", type=int, default=0, help=family)
    parser.add_argument("--eval-every", type=int, default=eval_every, help="episodes between checkpoint evaluations")
    parser.add_argument("--eval-episodes", type=int, default=eval_episodes)
    parser.add_argument("--test-episodes", type=int, default=test_episodes)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest for these MLPs)")
    parser.add_argument("--out", type=Path, default=Path(out))
    return parser


def run_baseline(prog: str, ns: argparse.Namespace, args: Sequence[str] | None, digits: int,
                 run: Callable[[], dict[str, Any]]) -> Path:
    """``run()`` with ``--threads`` torch threads; its result, with the family seed and the command line, written
    to ``--out``; the return and success printed."""
    import torch

    from icprl_lightning.io import write_json_atomic

    torch.set_num_threads(ns.threads)
    result = run()
    result["family_seed"] = ns.family_seed
    result["command"] = f"{prog} " + " ".join(sys.argv[1:] if args is None else args)
    out = write_json_atomic(ns.out, result)
    print(f"return {result['return']['mean']:.{digits}f} ± {result['return']['sem']:.{digits}f}, success "
          f"{result['success']['mean']:.2f} ± {result['success']['sem']:.2f} -> {out}")
    return out


def usage() -> str:
    width = max(map(len, SUBCOMMANDS))
    lines = ["usage: icprl SUBCOMMAND [options]      (icprl SUBCOMMAND --help for its options)", "",
             "In-context preference-based RL: train on many tasks from preferences, deploy on held-out ones.", "",
             "subcommands:"]
    lines += [f"  {name:<{width}}  {text}" for name, (_, text) in SUBCOMMANDS.items()]
    lines += ["", "options:", f"  --verbose{' ' * (width - 7)}show the traceback of an error (or {VERBOSE_ENV}=1)"]
    return "\n".join(lines)


def group_usage(group: str) -> str:
    verbs = GROUPS[group]
    width = max(map(len, verbs))
    lines = [f"usage: icprl {group} VERB [options]      (icprl {group} VERB --help for its options)", "",
             SUBCOMMANDS[group][1], "", "verbs:"]
    lines += [f"  {verb:<{width}}  {text}" for verb, (_, text) in verbs.items()]
    return "\n".join(lines)


def _unknown(what: str, name: str, known: dict, where: str, listing: str) -> NoReturn:
    """Exit 2 with one line naming the unknown ``name`` and the closest known one."""
    import difflib

    close = difflib.get_close_matches(name, known, n=1)
    sys.stderr.write(f"{where}: error: unknown {what} {name!r}{f' (did you mean {close[0]!r}?)' if close else ''}; "
                     f"{listing} lists them\n")
    raise SystemExit(2)


def run_cli(args: list[str], run: bool = True, verbose: bool | None = None):
    """Parse ``args`` as the command line would be (tests call this) and run the LightningCLI subcommand."""
    from icprl_lightning.commands.trainer import run_cli as run_trainer_cli

    return run_trainer_cli(args, run=run, verbose=verbose)


def _generate(argv: list[str]) -> None:
    cli = run_cli(argv, run=False)
    cli.datamodule.prepare_data()
    print(f"dataset ready at {cli.datamodule.path}")


def _user_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean "the input is wrong", not "the program is": said in one line."""
    errors: list[type[BaseException]] = [ValueError, FileNotFoundError, FileExistsError, IsADirectoryError,
                                         NotADirectoryError, PermissionError]
    store = sys.modules.get("icprl_lightning.data.store")  # loaded by then if a dataset was read
    if store is not None:
        errors.append(store.DatasetError)
    io = sys.modules.get("icprl_lightning.io")  # loaded by then if anything was written
    if io is not None:
        errors.append(io.StorageError)  # a full disk or a failing write: one line naming the path
    return tuple(errors)


def _one_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = " ".join(lines) if len(lines) <= 3 else lines[0]
    return text or type(error).__name__


# Lightning's lines that describe the machine, not the run: shown with --verbose only
BANNER = ("GPU available:", "TPU available:", "HPU available:", "Seed set to ")
QUIETED_LOGGERS = ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.seed")


class _Quiet:
    """A logging filter dropping records that start with one of ``hidden`` (Lightning's adverts, "💡 Tip: ...
    litlogger", not about this run; and the banner unless --verbose)."""

    def __init__(self, hidden: tuple[str, ...]) -> None:
        self.hidden = hidden

    def filter(self, record) -> bool:
        return not record.getMessage().startswith(self.hidden)


def _quiet_dependency_noise(verbose: bool = False) -> None:
    """Silence, each by name, messages of dependencies that a user of ``icprl`` cannot act on, and (unless
    ``verbose``) Lightning's hardware banner. Called again (tests run several commands in one process), it
    replaces its filters rather than adding to them."""
    import logging
    import warnings

    # Lightning's own _pytree helper builds torch's deprecated LeafSpec: only a Lightning release fixes it
    warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated",
                            category=FutureWarning)
    for name in QUIETED_LOGGERS:
        logger = logging.getLogger(name)
        for old in [f for f in logger.filters if isinstance(f, _Quiet)]:
            logger.removeFilter(old)
        logger.addFilter(_Quiet(("💡 Tip:",) + (() if verbose else BANNER)))


def main(args: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if args is None else args)
    verbose = "--verbose" in argv or os.environ.get(VERBOSE_ENV, "") not in ("", "0")
    _quiet_dependency_noise(verbose)
    argv = [a for a in argv if a != "--verbose"]
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return
    name, rest = argv[0], argv[1:]
    if name not in SUBCOMMANDS:
        _unknown("subcommand", name, SUBCOMMANDS, "icprl", "icprl --help")
    module, _ = SUBCOMMANDS[name]
    if name in GROUPS:
        if not rest:
            sys.stderr.write(f"icprl {name}: error: name one of {', '.join(GROUPS[name])}; icprl {name} --help "
                             "says what each does\n")
            raise SystemExit(2)
        if rest[0] in ("-h", "--help"):
            print(group_usage(name))
            return
        if rest[0] not in GROUPS[name]:
            _unknown("verb", rest[0], GROUPS[name], f"icprl {name}", f"icprl {name} --help")
        module, _ = GROUPS[name][rest[0]]
        name, rest = f"{name} {rest[0]}", rest[1:]
    problem = None if module else config_problem(name, rest)  # before Lightning is imported
    if problem:
        sys.stderr.write(f"icprl {name}: error: {problem}\n")
        raise SystemExit(2)
    try:
        if name == "generate":
            _generate(rest)
        elif not module:
            run_cli(argv, verbose=verbose)
        else:
            importlib.import_module(module).main(rest)
    except _user_errors() as e:
        if verbose:
            raise
        sys.stderr.write(f"icprl {name}: error: {_one_line(e)}\n")
        raise SystemExit(2) from None
    except Exception as e:
        finite = sys.modules.get("icprl_lightning.callbacks.finite_check")  # loaded by then if a fit ran
        if verbose or finite is None or not isinstance(e, finite.NonFiniteError):
            raise
        sys.stderr.write(f"icprl {name}: error: {_one_line(e)}\n")  # the fit failed: status 1, not a usage error
        raise SystemExit(1) from None
