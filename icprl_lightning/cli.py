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
import sys
import warnings

import lightning as L
from lightning.pytorch.cli import LightningArgumentParser, LightningCLI, SaveConfigCallback

from icprl_lightning.callbacks.run_directory import RunDirectory, run_directory


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
