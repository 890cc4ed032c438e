"""Does a checkpoint fit the data it is about to be evaluated on? ``icprl evaluate``'s check, run before any
dataset is generated or any episode played.

A run of ``icprl evaluate`` pairs a config (whose data section names the held-out tasks) with checkpoints.
``icprl fit`` links the model's sizes from that data (``state_dim``, ``action_dim``, ``discrete``,
``max_context`` = the context length) and checks the context kind (``validation.pairing_errors``); a
checkpoint evaluated with another config skips both, and would fail late (a shape error deep in a
rollout) or, worse, run on data it was never trained for. ``run_datamodule`` builds the config's
DataModule (nothing generated), reads every checkpoint as untrusted (``hub.load_model``: a ``.ckpt``, a model
directory or a shipped model's short name) and compares the two, so a bandit checkpoint with an MDP config (or
the reverse), a RewardGen reward model, or a model of another size is one ``ValueError`` naming the run, the
checkpoint and the config. The data side is read through the data contract (``data_contract.PreferenceData``):
its sizes and the evaluations it ``offers``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import yaml
from jsonargparse import ArgumentError

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.data_contract import PreferenceData, missing_members
from icprl_lightning.hub import load_model
from icprl_lightning.validation import consumed_kinds


def is_bandit_data(datamodule: PreferenceData) -> bool:
    """Dueling-bandit data (weak regret, ``duels``) rather than an MDP family's (rollouts); known from the
    evaluations the DataModule declares, before its data exists."""
    return "duels" in datamodule.offers


def _sizes(kind: str, state_dim: int, discrete: bool, actions: int, length: int) -> str:
    return (f"{kind} contexts, state_dim {state_dim}, {actions} {'discrete actions' if discrete else 'action dims'}, "
            f"context length {length}")


def fit_errors(module: Any, datamodule: PreferenceData) -> list[str]:
    """Every way ``module`` (a loaded checkpoint) cannot deploy on ``datamodule``'s held-out tasks, each a phrase
    after the module's class name (empty: it fits)."""
    if getattr(module, "policy", None) is None:  # RewardGen: a reward model, deployed only inside ICRG
        return ["holds a reward model, not a policy (evaluate the ICRG checkpoint trained on it)"]
    kinds, spec = consumed_kinds(module) or (), module.action_spec
    state_dim, max_context = module.hparams["state_dim"], module.hparams["max_context"]
    data_spec = datamodule.action_spec
    errors = []
    if datamodule.context_kind not in kinds:
        errors.append(f"takes {' or '.join(kinds)} contexts, the data {datamodule.context_kind}")
    if state_dim != datamodule.state_dim:
        errors.append(f"has state_dim {state_dim}, the data {datamodule.state_dim}")
    if (spec.discrete, spec.size) != (data_spec.discrete, data_spec.size):
        kind = {True: "discrete actions", False: "action dims"}
        errors.append(f"has {spec.size} {kind[spec.discrete]}, the data {data_spec.size} {kind[data_spec.discrete]}")
    if max_context < datamodule.context_length:
        errors.append(f"has max_context {max_context}, shorter than the data's contexts ({datamodule.context_length})")
    return errors


# jsonargparse's lines about the Union (data: DataModule | None) it tried, around the one that names the problem.
_UNION_NOISE = ("Does not validate against any of the Union subtypes", "Subtypes:", "Errors:",
                "- Expected a <class 'NoneType'>", "Given value type:", "Given value:")


def _config_error(error: BaseException) -> str:
    """jsonargparse and yaml spread one problem over several lines: join them into one, short, keeping the line
    that names the wrong key or value."""
    lines = [line.strip().removeprefix("- ") for line in str(error).splitlines()]
    return " ".join(line for line in lines if line and not line.startswith(_UNION_NOISE))[:400]


def run_datamodule(name: str, config: str, checkpoints: list[str], data: Sequence[str] = ()) -> PreferenceData:
    """``config``'s DataModule, with the data sections of the files ``data`` stacked on it (no data generated
    yet), after checking every checkpoint of run ``name`` fits it; else one ``ValueError`` naming the run, the
    file and what does not fit."""
    try:
        datamodule = datamodule_from_config(config, *data)
    except (OSError, ValueError, yaml.YAMLError, ArgumentError) as e:
        files = " + ".join([config, *data])
        raise ValueError(f"--run {name}: config {files} does not give a DataModule ({_config_error(e)})") from None
    if not isinstance(datamodule, PreferenceData):
        raise ValueError(f"--run {name}: config {config} gives {type(datamodule).__name__}, which does not implement "
                         f"the data contract (icprl_lightning.data_contract.PreferenceData): it lacks "
                         f"{missing_members(datamodule)}")
    data = (f"{'dueling-bandit' if is_bandit_data(datamodule) else 'MDP'} data ({datamodule.metric_env}: "
            + _sizes(datamodule.context_kind, datamodule.state_dim, datamodule.action_spec.discrete,
                     datamodule.action_spec.size, datamodule.context_length) + ")")
    for checkpoint in checkpoints:
        try:
            module = load_model(checkpoint)
        except (ValueError, FileNotFoundError) as e:
            raise ValueError(f"--run {name}: {e}") from None
        errors = fit_errors(module, datamodule)
        if errors:
            raise ValueError(f"--run {name}: {checkpoint} does not fit the {data} of {config}: "
                             f"{type(module).__name__} {'; '.join(errors)}")
    return datamodule
