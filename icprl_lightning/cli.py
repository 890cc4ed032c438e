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
from lightning.pytorch.loggers import WandbLogger


class SaveConfigToRun(SaveConfigCallback):
    """Save config.yaml in the run's own directory (``<save_dir>/<project>/<run id>/``), not the shared root.

    Only ``fit`` saves it: ``validate``/``test`` of a checkpoint create no run to save it in, and must not
    drop a config.yaml into the working directory (nor refuse the second time because one is there).
    """

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage != "fit":
            return
        logger = trainer.logger
        if isinstance(logger, WandbLogger) and trainer.is_global_zero:
            version = logger.version if logger.version is not None else "run"
            run_dir = os.path.join(logger.save_dir or ".", str(logger.name), str(version))
            os.makedirs(run_dir, exist_ok=True)
            self.parser.save(self.config, os.path.join(run_dir, self.config_filename), skip_none=False,
                             overwrite=True, multifile=self.multifile)
            return
        super().setup(trainer, pl_module, stage)


class ICPRLCLI(LightningCLI):
    def add_arguments_to_parser(self, parser: LightningArgumentParser) -> None:
        links = {"state_dim": lambda d: d.state_dim, "action_dim": lambda d: d.action_spec.size,
                 "discrete": lambda d: d.action_spec.discrete, "max_context": lambda d: d.context_length}
        for name, fn in links.items():
            parser.link_arguments("data", f"model.init_args.{name}", compute_fn=fn, apply_on="instantiate")


def run_cli(args: list[str], run: bool = True) -> ICPRLCLI:
    """Parse ``args`` as the command line would be (tests call this) and run the subcommand."""
    warnings.filterwarnings("ignore", message=".*args parameter is intended to run from within Python.*")
    return ICPRLCLI(L.LightningModule, L.LightningDataModule, subclass_mode_model=True, subclass_mode_data=True,
                    save_config_callback=SaveConfigToRun, args=args, run=run,
                    parser_kwargs={"default_env": False})


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
    if argv and argv[0] == "import":
        from icprl_lightning.data.importer import main as import_main

        import_main(argv[1:])
        return
    run_cli(argv)


if __name__ == "__main__":
    main()
