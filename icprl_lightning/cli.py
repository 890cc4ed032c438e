"""The ``icprl`` command: LightningCLI (fit / validate / test / predict) plus generate, evaluate, import.

    icprl fit --config configs/icpo_darkroom.yaml [--model.init_args.lr 1e-3] [--print_config]
    icprl fit --config configs/icpo_darkroom.yaml --config configs/paper/icpo_darkroom.yaml   # an overlay
    icprl validate --config configs/icpo_darkroom.yaml --ckpt_path runs/.../last.ckpt
    icprl generate --config configs/icpo_darkroom.yaml [--data.init_args.overwrite true]
    icprl evaluate --run NAME=CONFIG:CKPT [...] --out docs/results/x    (evaluation/command.py)
    icprl import arrays.npz --out data/mine --kind step_preference --n-actions 5   (data/importer.py)

Model and data are chosen by ``class_path`` / ``init_args`` (subclass mode). The environment sizes are
written once, by the DataModule, and linked into the model. The resolved config is saved beside the
run's checkpoints.
"""

from __future__ import annotations

import os
import random
import secrets
import sys
import time
import warnings

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.cli import LightningArgumentParser, LightningCLI, SaveConfigCallback
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from lightning.pytorch.loggers.logger import DummyLogger

RUN_DIR_ATTR = "_icprl_run_dir"


def run_directory(trainer: L.Trainer, pl_module: L.LightningModule | None = None) -> str:
    """The run's own directory, chosen once per ``fit`` (cached on the trainer) and created.

    With a logger it is the logger's version directory, ``<save_dir>/<name>/<version>`` (for W&B
    ``<save_dir>/<project>/<run id>``, for CSV/TensorBoard their ``log_dir``), which is where Lightning's
    ``ModelCheckpoint`` without a ``dirpath`` writes too. Without one (``--trainer.logger false``, or
    ``fast_dev_run``, which swaps loggers for a dummy) it is a fresh ``<default_root_dir>/<model>-<time>-<hex>``,
    so two runs of one config never share a directory.
    """
    cached = getattr(trainer, RUN_DIR_ATTR, None)
    if cached is not None:
        return cached
    loggers = [lg for lg in trainer.loggers if not isinstance(lg, DummyLogger)]
    run_dir = None
    if loggers:
        logger = loggers[0]
        if isinstance(logger, (CSVLogger, TensorBoardLogger)):
            run_dir = logger.log_dir
        else:
            version = logger.version
            version = version if isinstance(version, str) else f"version_{version}"
            run_dir = os.path.join(logger.save_dir or trainer.default_root_dir, str(logger.name), version)
    elif trainer.is_global_zero:
        name = type(pl_module).__name__.removesuffix("Module").lower() if pl_module is not None else "run"
        while True:  # a fresh directory, even for two runs started in the same second
            run_dir = os.path.join(trainer.default_root_dir,
                                   f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-{secrets.token_hex(2)}")
            try:
                os.makedirs(run_dir)
                break
            except FileExistsError:
                continue
    run_dir = os.path.abspath(trainer.strategy.broadcast(run_dir))  # rank 0's choice on every rank
    os.makedirs(run_dir, exist_ok=True)
    setattr(trainer, RUN_DIR_ATTR, run_dir)
    return run_dir


class RunDirectory(Callback):
    """Puts every ``fit`` in its own run directory (``run_directory``) and makes its resume exact.

    ``setup`` points each ``ModelCheckpoint`` without a ``dirpath`` at ``<run>/checkpoints`` (without a logger
    Lightning would use the shared ``<default_root_dir>/checkpoints``) and prints the run directory; the end
    of ``fit`` prints where the best and the last checkpoint are (the path a pipeline's next stage takes, e.g.
    ICRG's ``--model.init_args.reward_gen_checkpoint``). A checkpoint also stores the Python, NumPy and
    torch RNG states, restored on ``--ckpt_path``, and validation runs RNG-isolated, so a run resumed from a
    checkpoint saved at the end of an epoch draws the same shuffles as one that was never interrupted.
    """

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage != "fit":
            return
        run_dir = run_directory(trainer, pl_module)
        for callback in trainer.checkpoint_callbacks:
            if isinstance(callback, ModelCheckpoint) and callback.dirpath is None:
                callback.dirpath = os.path.join(run_dir, "checkpoints")
        if trainer.is_global_zero:
            print(f"run directory: {run_dir}", flush=True)

    def on_fit_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        for callback in trainer.checkpoint_callbacks:
            if not isinstance(callback, ModelCheckpoint):
                continue
            best, last = callback.best_model_path, callback.last_model_path
            if best and os.path.exists(best):
                print(f"best checkpoint: {os.path.abspath(best)}", flush=True)
            if last and os.path.exists(last):
                print(f"last checkpoint: {os.path.abspath(last)}", flush=True)

    # Validation during fit draws from the global RNGs too (e.g. ICPO's pair draws); it runs isolated, as
    # Lightning's sanity check does, so the training stream is the same whether or not a run validated, and
    # a checkpoint saved at an epoch's last step resumes into exactly the draws the uninterrupted run makes.
    def on_validation_start(self, trainer, pl_module) -> None:
        self._val_rng = None if trainer.sanity_checking else _rng_state()

    def on_validation_end(self, trainer, pl_module) -> None:
        rng, self._val_rng = getattr(self, "_val_rng", None), None
        if rng is not None:
            _set_rng_state(rng)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint["icprl_rng"] = _rng_state()

    def on_load_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        # callbacks are restored before the fit loop makes its first iterator (which draws the shuffle)
        if "icprl_rng" in checkpoint:
            _set_rng_state(checkpoint["icprl_rng"])


def _rng_state() -> dict:
    """The Python, NumPy and torch (CPU) RNG states, as tensors and plain values only: checkpoints are read
    with ``weights_only`` loading, which refuses numpy objects."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    return {"python": random.getstate(), "torch": torch.get_rng_state(),
            "numpy": [kind, torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss), float(gauss)]}


def _set_rng_state(state: dict) -> None:
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    kind, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    torch.set_rng_state(state["torch"])


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
            self.parser.save(self.config, os.path.join(run_dir, self.config_filename), skip_none=False,
                             overwrite=self.overwrite, multifile=self.multifile)


class ICPRLCLI(LightningCLI):
    def add_arguments_to_parser(self, parser: LightningArgumentParser) -> None:
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

    def before_fit(self) -> None:
        self.check_pairing()

    def before_validate(self) -> None:
        self.check_pairing()

    def before_test(self) -> None:
        self.check_pairing()


def run_cli(args: list[str], run: bool = True) -> ICPRLCLI:
    """Parse ``args`` as the command line would be (tests call this) and run the subcommand.

    Every ``fit`` gets its own run directory (``RunDirectory``, also under ``fast_dev_run``, where Lightning
    adds no config callback), holding its ``config.yaml`` (``SaveConfigToRun``) and checkpoints.
    W&B defaults to offline (``WANDB_MODE=offline``) unless ``WANDB_MODE`` says otherwise, e.g. ``disabled``;
    the configs do not set the logger's ``offline: true``, which Lightning turns into ``WANDB_MODE=dryrun``
    over a ``disabled`` one.
    """
    warnings.filterwarnings("ignore", message=".*args parameter is intended to run from within Python.*")
    os.environ.setdefault("WANDB_MODE", "offline")
    wandb = sys.modules.get("wandb")  # a W&B run left by an earlier fit in this process: WandbLogger would reuse it
    if wandb is not None and getattr(wandb, "run", None) is not None:
        wandb.finish()
    return ICPRLCLI(L.LightningModule, L.LightningDataModule, subclass_mode_model=True, subclass_mode_data=True,
                    save_config_callback=SaveConfigToRun,
                    # the DataModule shards its rows itself under several processes (data/datamodule.py)
                    trainer_defaults={"callbacks": [RunDirectory()], "use_distributed_sampler": False},
                    args=args, run=run, parser_kwargs={"default_env": False})


def main(args: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if args is None else args)
    if argv and argv[0] == "generate":
        cli = run_cli(argv[1:], run=False)
        cli.datamodule.prepare_data()
        print(f"dataset ready at {cli.datamodule.path}")
        return
    if argv and argv[0] == "evaluate":
        from icprl_lightning.evaluation.command import main as evaluate_main

        evaluate_main(argv[1:])
        return
    if argv and argv[0] == "reproduce":
        from icprl_lightning.reproduce import main as reproduce_main

        reproduce_main(argv[1:])
        return
    if argv and argv[0] == "import":
        from icprl_lightning.data.importer import main as import_main

        import_main(argv[1:])
        return
    if argv and argv[0] in ("fit", "validate", "test", "predict"):
        from icprl_lightning.checkpoints import check_cli_checkpoint

        try:  # before the CLI is built: it reads the file's hyperparameters and would fail with a traceback
            checked = check_cli_checkpoint(argv[1:])
        except (ValueError, FileNotFoundError) as e:
            sys.stderr.write(f"icprl {argv[0]}: error: {e}\n")
            raise SystemExit(2) from None
        if checked:
            argv.append("--weights_only=true")  # Lightning's own load of the verified file, explicitly
    run_cli(argv)


if __name__ == "__main__":
    main()
