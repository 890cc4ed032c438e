"""The LightningCLI behind ``icprl fit | validate | test | predict | generate`` (``commands/__init__.py`` dispatches
to it).

Model and data are chosen by ``class_path`` / ``init_args`` (subclass mode). The environment sizes are
written once, by the DataModule, and linked into the model. The resolved config is saved beside the run's
checkpoints. Options cannot be abbreviated (``--trainer.max_epoch`` is a mistake, not ``max_epochs``), a
parse error is one line with "did you mean" (``parse_errors.py``), and the ``ckpt_path`` Lightning will load
is checked on the parsed config, however it was spelled (``ICPRLCLI._parse_ckpt_path``).
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import os
import re
import sys
import typing
import warnings
from typing import Any

import lightning as L
from lightning.pytorch.cli import LightningArgumentParser, LightningCLI, SaveConfigCallback

from icprl_lightning.callbacks.atomic_io import use_atomic_saves
from icprl_lightning.callbacks.defaults import NAMED_CALLBACKS, default_callbacks
from icprl_lightning.callbacks.run_directory import run_directory, unique_logger_versions
from icprl_lightning.callbacks.run_logs import wandb_in_run_directory
from icprl_lightning.progress import is_terminal


class SaveConfigToRun(SaveConfigCallback):
    """Save config.yaml in the run's own directory (``run_directory``), never in the working directory.

    Only ``fit`` saves it: ``validate``/``test`` of a checkpoint create no run to save it in, and must not
    drop a config.yaml into the working directory (nor refuse the second time because one is there).
    """

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage != "fit":
            return
        run_dir = run_directory(trainer, pl_module)
        if trainer.is_global_zero:
            self.parser.save(self.config, os.path.join(run_dir, self.config_filename), skip_unset=False,
                             overwrite=self.overwrite, multifile=self.multifile)


class CLIError(ValueError):
    """A mistake on the command line or in a config file, said in one line."""


def _close(word: str, options: list[str]) -> str:
    found = difflib.get_close_matches(word, options, n=1, cutoff=0.6)
    return f" (did you mean {found[0]!r}?)" if found else ""


def _arguments(class_path: str) -> dict[str, list[str]]:
    """The ``__init__`` arguments of a class jsonargparse already imported (never imports anything itself), over the
    whole MRO (a subclass may forward **kwargs to its base): each with its keys if it is a group (a dataclass, e.g.
    a method's ``backbone`` or ``optimizer``), else []."""
    module, _, name = class_path.rpartition(".")
    cls = getattr(sys.modules.get(module), name, None)
    arguments: dict[str, list[str]] = {}
    for klass in cls.__mro__ if isinstance(cls, type) else ():
        if "__init__" in vars(klass):
            try:
                hints = typing.get_type_hints(klass.__init__)
            except Exception:  # an annotation that does not resolve outside type checking
                hints = {}
            for key in inspect.signature(klass.__init__).parameters:
                group = hints.get(key)
                if key not in ("self", "args", "kwargs", *arguments):
                    arguments[key] = [f.name for f in dataclasses.fields(group)] if dataclasses.is_dataclass(
                        group) else []
    return arguments


def _option_names(parser: Any) -> list[str]:
    """Every ``--key`` a (sub)command parser accepts, nested groups included."""
    names = []
    for action in getattr(parser, "_actions", ()):
        names += [o for o in action.option_strings if o.startswith("--")]
    return names


def summarize_parse_error(message: str, parser: Any) -> str:
    """jsonargparse's multi-line parse error as one line naming the key, with "did you mean" when close.

    ``parser`` is the subcommand's parser (for the options it accepts)."""
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    keys = [m.group(1) for line in lines if (m := re.match(r'Parser key "([^"]+)"', line))]
    classes = [m.group(1) for line in lines if (m := re.search(r"class_path '([^']+)'", line))]
    given = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("Given value:")), None)
    for line in lines:
        if m := re.search(r"Option '([^']+)' is not accepted", line):
            key = ".init_args.".join([*keys, m.group(1)]) if keys else m.group(1)
            owner = classes[-1].rpartition(".")[2] if classes else "this class"
            known = _arguments(classes[-1]) if classes else {}  # a key moved into a group: --model.init_args.lr
            moved = [f"{group}.{m.group(1)}" for group, keys in known.items() if m.group(1) in keys]
            return (f"{key}: {owner} has no argument {m.group(1)!r}"
                    + (f" (it is {moved[0]!r} now)" if moved else _close(m.group(1), list(known))))
        if m := re.search(r"module '([^']+)' has no attribute '([^']+)'", line):
            module = sys.modules.get(m.group(1))
            names = [n for n in dir(module) if isinstance(getattr(module, n, None), type)] if module else []
            return (f"{'.'.join(keys[:1] or ['class_path'])}: {m.group(1)} has no class {m.group(2)!r}"
                    f"{_close(m.group(2), names)}")
        nested = re.search(r"Group '([^']+)' does not accept option '([^']+)'", line) or (
            classes and re.match(r"[Uu]nrecognized arguments: --([^=\s]+)\.([^.=\s]+)", line))
        if nested:  # a key inside a dataclass argument, e.g. model.init_args.backbone.n_layers
            group, option = nested.groups()
            key = ".init_args.".join([*keys, group]) + f".{option}"
            return f"{key}: {group} has no key {option!r}{_close(option, _arguments(classes[-1]).get(group, []))}"
        if m := re.match(r"[Uu]nrecognized arguments: (\S+)", line):
            option = m.group(1).split("=", 1)[0]
            return f"unknown option {option}{_close(option, _option_names(parser))}"
        if m := re.search(r'Key "([^"]+)" is not expected', line):
            key = m.group(1)
            return f"unknown key {key!r} in the config{_close('--' + key, _option_names(parser)).replace('--', '')}"
    expected = [m.group(1) for line in lines if (m := re.search(r"Expected a <class '([^']+)'>", line))]
    expected = [e for e in expected if e != "NoneType"]
    if keys and expected:
        if nested_arg := re.fullmatch(r"NestedArg\(key='[^']*', val='(.*)'\)", given or ""):  # inside an argument
            return f"{'.init_args.'.join(keys)}: expected {' or '.join(expected)}, got {nested_arg.group(1)!r}"
        return f"{keys[-1]}: expected {' or '.join(expected)}, got {given!r}"
    detail = next((line for line in reversed(lines) if not line.startswith(("Given value", "Subtypes", "- Expected"))),
                  lines[-1] if lines else message)
    return f"{lines[0]} {detail}" if lines and detail != lines[0] else detail


def _verified_sizes_fit(model: L.LightningModule, ckpt: dict, path: str) -> None:
    """The model this config builds takes the checkpoint's weights, or one line naming what differs, before
    any data is generated (Lightning would load them after ``prepare_data``, as a raw size mismatch)."""
    stored, here = ckpt["state_dict"], model.state_dict()
    missing, unexpected = sorted(set(here) - set(stored)), sorted(set(stored) - set(here))
    wrong = [(k, tuple(stored[k].shape), tuple(here[k].shape)) for k in sorted(set(here) & set(stored))
             if stored[k].shape != here[k].shape]
    if not (missing or unexpected or wrong):
        return
    from icprl_lightning.checkpoints import hyperparameters

    def sizes(hparams: dict) -> dict[str, Any]:  # the data's sizes and the backbone's, flat (backbone.n_layer)
        backbone = hparams.get("backbone") if isinstance(hparams.get("backbone"), dict) else {}
        return {**{k: hparams[k] for k in ("state_dim", "action_dim", "discrete", "max_context") if k in hparams},
                **{f"backbone.{k}": v for k, v in backbone.items() if k != "dropout"}}

    stored_sizes, here_sizes = sizes(hyperparameters(ckpt)), sizes(dict(model.hparams))
    differ = [f"{k} {stored_sizes[k]!r} vs {here_sizes[k]!r}" for k in stored_sizes
              if k in here_sizes and stored_sizes[k] != here_sizes[k]]
    what = (f"{wrong[0][0]} is {list(wrong[0][1])} in the checkpoint, {list(wrong[0][2])} here" if wrong
            else f"weights {', '.join((missing or unexpected)[:2])} {'missing from' if missing else 'not in'} "
                 "the checkpoint" if missing else f"the checkpoint has weights this model lacks ({unexpected[0]})")
    raise CLIError(f"ckpt_path {path} does not fit the model this config builds: {what}"
                   + (f" (checkpoint vs config: {'; '.join(differ)})" if differ else ""))


# What every config's trainer starts from (configs/trainer/cpu.yaml spells it out; a config or a later
# ``--trainer FILE`` such as configs/trainer/gpu.yaml or ddp.yaml overrides it): one CPU process, run directories
# under runs/, and a W&B logger (offline unless WANDB_MODE says otherwise) whose files land in the run directory.
TRAINER_DEFAULTS = {
    "accelerator": "cpu",
    "devices": 1,
    "default_root_dir": "runs",
    "logger": {"class_path": "lightning.pytorch.loggers.WandbLogger",
               "init_args": {"project": "icprl", "save_dir": "runs"}},
}


PRECISIONS = ("32-true", "32", "bf16-mixed", "bf16", "16-mixed", "16")  # what trains (CPU included), with aliases


class ICPRLCLI(LightningCLI):
    def parse_arguments(self, parser: LightningArgumentParser, args: Any) -> None:
        """As LightningCLI's, but a parse error is one ``CLIError`` line (``exit_on_error`` is off)."""
        from jsonargparse import ArgumentError

        try:
            super().parse_arguments(parser, args)
        except ArgumentError as e:
            subcommand = next((a for a in (args or []) if a in self.subcommands()), None)
            sub = getattr(self, "_subcommand_parsers", {}).get(subcommand, parser)
            raise CLIError(summarize_parse_error(str(e), sub)) from None

    def _instantiate_trainer(self, config: dict[str, Any], callbacks: list) -> L.Trainer:
        """As LightningCLI's, but the named callbacks (``callbacks/defaults.NAMED_CALLBACKS``; ``null`` drops one)
        come before the config's own, unless those hold one of their kind (a config listing its evaluation or
        ``ModelCheckpoint`` itself, as before these defaults, runs it once), and ``--trainer.enable_checkpointing
        false`` also drops the callbacks that save checkpoints, which Lightning would otherwise refuse beside it."""
        from lightning.pytorch.callbacks import Checkpoint

        precision = config.get("precision")
        if precision is not None and str(precision) not in PRECISIONS:  # before the Trainer imports or casts anything
            raise CLIError(f"trainer.precision {str(precision)!r} is refused: the batches are float32, so the weights "
                           f"stay float32 (autocast allowed); use one of {', '.join(PRECISIONS[::2])}")
        saving = config.get("enable_checkpointing") is not False
        if not saving:
            self.trainer_defaults = {**self.trainer_defaults, "callbacks": [
                c for c in self.trainer_defaults.get("callbacks", []) if not isinstance(c, Checkpoint)]}
        own = config.get("callbacks")
        own = [] if own is None else own if isinstance(own, list) else [own]
        named = [c for c, (_, _, kind) in zip(callbacks, NAMED_CALLBACKS.values(), strict=True)
                 if c is not None and not any(kind(o) for o in own) and (saving or not isinstance(c, Checkpoint))]
        config["callbacks"] = [*named, *own]
        return super()._instantiate_trainer(config, [])

    def _parse_ckpt_path(self) -> None:
        """Check the ``ckpt_path`` Lightning will load, on the parsed config (``checkpoints.checkpoint_for_
        lightning``), and hand Lightning a private copy of the verified contents, loaded ``weights_only``."""
        from icprl_lightning.checkpoints import checkpoint_for_lightning, load_raw

        self._verified_checkpoint = None
        subcommand = self.config.get("subcommand")
        if subcommand:
            section = self.config[subcommand]
            if section.get("weights_only") is False:
                raise CLIError("weights_only false is refused: icprl checkpoints hold only tensors and plain values")
            if section.get("ckpt_path") is not None:
                given = section["ckpt_path"]
                copy = checkpoint_for_lightning(given, subcommand)
                self._verified_checkpoint = (str(given), load_raw(copy))
                section["ckpt_path"] = copy
                if "weights_only" in section:
                    section["weights_only"] = True
        super()._parse_ckpt_path()

    def add_arguments_to_parser(self, parser: LightningArgumentParser) -> None:
        for key, (base, default, _) in NAMED_CALLBACKS.items():  # a config changes or drops them by key, not position
            parser.add_lightning_class_args(base, key, subclass_mode=True, required=False)
            parser.set_defaults({key: default})
        links = {"state_dim": lambda d: d.state_dim, "action_dim": lambda d: d.action_spec.size,
                 "discrete": lambda d: d.action_spec.discrete, "max_context": lambda d: d.context_length}
        for name, fn in links.items():
            parser.link_arguments("data", f"model.init_args.{name}", compute_fn=fn, apply_on="instantiate")

    def instantiate_classes(self) -> None:
        """As LightningCLI's, but an argument out of range surfaces as its own error (``validation.py``),
        "ICPOModule: beta must be > 0, got 0.0", not inside jsonargparse's "Does not validate ..."."""
        from icprl_lightning.validation import hyperparameter_cause

        try:
            super().instantiate_classes()
        except ValueError as err:
            cause = hyperparameter_cause(err)
            if cause is None or cause is err:
                raise
            raise cause from None

    # LightningCLI runs ``before_<subcommand>`` after instantiating model, data and trainer and before
    # ``trainer.<subcommand>``, so before ``prepare_data`` generates anything.
    def check_pairing(self) -> None:
        """The model's context kind vs the data's, and the data each callback reads (``validation.py``)."""
        from icprl_lightning.validation import check_pairing

        check_pairing(self.model, self.datamodule, getattr(self.trainer, "callbacks", ()))

    def check_checkpoint_fits(self) -> None:
        if getattr(self, "_verified_checkpoint", None) is not None:
            path, ckpt = self._verified_checkpoint
            _verified_sizes_fit(self.model, ckpt, path)

    def before_fit(self) -> None:
        use_atomic_saves(self.trainer)  # wraps or refuses the checkpoint IO before any data is generated
        unique_logger_versions(self.trainer)  # before Lightning makes the loggers' directories
        self.check_pairing()
        self.check_checkpoint_fits()
        wandb_in_run_directory(self.trainer)  # W&B starts its run before any callback's setup

    def before_validate(self) -> None:
        self.check_pairing()
        self.check_checkpoint_fits()

    before_test = before_validate

    def before_predict(self) -> None:
        self.check_checkpoint_fits()


def run_cli(args: list[str], run: bool = True, verbose: bool | None = None) -> ICPRLCLI:
    """Parse ``args`` as the command line would be (tests call this) and run the subcommand.

    Every ``fit`` gets its own run directory (``RunDirectory``, also under ``fast_dev_run``, where Lightning
    adds no config callback), holding its ``config.yaml`` (``SaveConfigToRun``) and checkpoints.
    W&B defaults to offline (``WANDB_MODE=offline``) unless ``WANDB_MODE`` says otherwise, e.g. ``disabled``;
    the configs do not set the logger's ``offline: true``, which Lightning turns into ``WANDB_MODE=dryrun``
    over a ``disabled`` one. ``verbose`` (``icprl --verbose``; None: ``ICPRL_VERBOSE``) shows the model summary.
    """
    warnings.filterwarnings("ignore", message=".*args parameter is intended to run from within Python.*")
    os.environ.setdefault("WANDB_MODE", "offline")
    wandb = sys.modules.get("wandb")  # a W&B run left by an earlier fit in this process: WandbLogger would reuse it
    if wandb is not None and getattr(wandb, "run", None) is not None:
        wandb.finish()
    if verbose is None:  # icprl --verbose passes it; ICPRL_VERBOSE=1 as for the tracebacks (commands/__init__.py)
        verbose = os.environ.get("ICPRL_VERBOSE", "") not in ("", "0")
    cli = ICPRLCLI(L.LightningModule, L.LightningDataModule, subclass_mode_model=True, subclass_mode_data=True,
                   save_config_callback=SaveConfigToRun,
                   # the DataModule shards its rows itself under several processes (data/datamodule.py)
                   # Lightning's bar only in a terminal: in a log, TrainingProgress prints plain lines instead;
                   # the model summary with --verbose only (a config may still ask for it)
                   trainer_defaults={**TRAINER_DEFAULTS, "callbacks": default_callbacks(),
                                     "use_distributed_sampler": False, "enable_progress_bar": is_terminal(),
                                     "enable_model_summary": verbose},
                   args=args, run=run, parser_kwargs=PARSER_KWARGS)
    wandb = sys.modules.get("wandb")
    if run and wandb is not None and getattr(wandb, "run", None) is not None:
        wandb.finish()  # now, not at exit, where W&B's closing lines keep their colour codes in a log
    return cli


# No environment variables are read; errors raise (``parse_arguments`` makes them one line); no option is
# abbreviated, in the main parser or a subcommand's: ``--ckpt_pa`` or ``--trainer.max_epoch`` is an error
# with "did you mean", never silently another option.
_STRICT = {"exit_on_error": False, "allow_abbrev": False}
PARSER_KWARGS = {"default_env": False, **_STRICT, **{sub: dict(_STRICT) for sub in ("fit", "validate", "test",
                                                                                     "predict")}}
