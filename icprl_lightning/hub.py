"""A trained model as a directory in the Hugging Face layout, written from a checkpoint and loaded without pickle.

The layout (model.safetensors, config.json, the README.md model card, results.json) and every check
``load_model_dir`` makes before building anything are in docs/pretrained.md. The weights are read by
``safetensors``, never unpickled; a config.json naming a class that is not a registered method
(``registry.py``) is refused before anything is imported. ``export_model`` stages the directory beside
``out_dir`` and loads the staged copy back before renaming it into place (``io.staged_directory``), so every
exported directory has loaded once. ``resolve`` turns a shipped model's short name (``"bandit-icpo"``, under
``icprl_lightning/pretrained/``) into its directory.
"""

from __future__ import annotations

import inspect
import json
import math
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from icprl_lightning import checkpoints
from icprl_lightning.io import StorageError, sha256, staged_directory, storage_error
from icprl_lightning.registry import method_class, method_names, short_names
from icprl_lightning.untrusted import check_argument_types, read_json, read_yaml

WEIGHTS = "model.safetensors"
CONFIG = "config.json"
CARD = "README.md"
RESULTS = "results.json"
SCHEMA_VERSION = 1
WHAT = "icprl model directory"
PRETRAINED = Path(__file__).resolve().parent / "pretrained"
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")  # a short name: no path separator


# ---- shipped models ------------------------------------------------------------------------------------------

def shipped_models() -> list[str]:
    """The short names of the models shipped in ``icprl_lightning/pretrained/``."""
    if not PRETRAINED.is_dir():
        return []
    return sorted(d.name for d in PRETRAINED.iterdir() if (d / CONFIG).is_file())


def resolve(source: str | Path) -> Path:
    """``source`` as a path: an existing file or directory as it is, a shipped model's short name as its directory.

    A string that names nothing on disk and looks like a name (no ``/``, not ``*.ckpt``) must be a shipped model;
    an unknown one is a ``FileNotFoundError`` listing the shipped names. Any other path is returned as it is, for
    the checkpoint reader to report.
    """
    path = Path(source)
    text = str(source)
    if path.exists() or not isinstance(source, str) or not NAME.match(text) or text.endswith(".ckpt"):
        return path
    if text in shipped_models():
        return PRETRAINED / text
    import difflib

    known = ", ".join(shipped_models()) or "none"
    close = difflib.get_close_matches(text, shipped_models(), n=1)
    raise FileNotFoundError(f"{text!r} is neither a checkpoint file, a model directory nor a shipped model"
                            f"{f' (did you mean {close[0]!r}?)' if close else ''}; shipped models: {known}")


# ---- loading -------------------------------------------------------------------------------------------------

def read_config(path: str | Path) -> dict[str, Any]:
    """A model directory's config.json, checked for the fields ``load_model_dir`` needs."""
    directory = Path(path)
    if not directory.is_dir():
        raise FileNotFoundError(f"No model directory at {directory}")
    file = directory / CONFIG
    if not file.exists():
        raise FileNotFoundError(f"{directory} has no {CONFIG}, so it is not a model directory (`icprl export` writes "
                                "one); for a training run pass its checkpoints/last.ckpt")
    config = read_json(file, f"{WHAT} config")
    if not isinstance(config, dict) or config.get("schema_version") != SCHEMA_VERSION:
        found = config.get("schema_version") if isinstance(config, dict) else None
        raise ValueError(f"{file} is not an {WHAT} config of schema version {SCHEMA_VERSION} (schema_version "
                         f"{found!r})")
    for key, kind in (("method", str), ("hyperparameters", dict), ("weights_sha256", str),
                      (checkpoints.CHECKSUM_KEY, str)):
        if not isinstance(config.get(key), kind):
            raise ValueError(f"{file}: field {key!r} must be a {kind.__name__}, got {config.get(key)!r}")
    return config


def load_model_dir(path: str | Path, map_location: str | torch.device = "cpu"):
    """The LightningModule (eval mode) of a model directory, after every check in the module docstring."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    directory = Path(path)
    config = read_config(directory)
    config_file, weights = directory / CONFIG, directory / WEIGHTS
    method = config["method"]
    if method not in method_names():  # checked before anything is imported or read
        raise ValueError(f"{config_file} names class {method!r}, which is not a registered method "
                         f"({short_names()}); refusing to import it")
    if not weights.is_file():
        raise FileNotFoundError(f"{directory} has no {WEIGHTS}")
    if sha256(weights) != config["weights_sha256"]:
        raise ValueError(f"{weights} does not match the SHA-256 recorded in {config_file} (a changed bit or a "
                         "replaced file); export the model again or restore the file")
    try:
        tensors = load_file(weights, device="cpu")
    except (SafetensorError, OSError, ValueError) as e:
        raise ValueError(f"{weights} is not a readable safetensors file ({e})") from None
    ckpt = {checkpoints.CLASS_KEY: method, checkpoints.CHECKSUM_KEY: config[checkpoints.CHECKSUM_KEY],
            "hyper_parameters": config["hyperparameters"], "state_dict": tensors}
    checkpoints.verify(ckpt, config_file)  # checksum over class, hyperparameters and tensors; finite weights
    module = _build(ckpt, config_file)
    _check_tensors(module, tensors, weights)
    module.load_state_dict(tensors, strict=True)
    return module.to(map_location).eval()


def load_model(source: str | Path, map_location: str | torch.device = "cpu"):
    """The LightningModule (eval mode) of a ``.ckpt`` (``checkpoints.load_module``), a model directory
    (``load_model_dir``: a directory holding config.json or model.safetensors) or a shipped model's short name
    (``resolve``). Any other directory goes to the checkpoint reader, whose error says to pass a .ckpt inside it."""
    path = resolve(source)
    model_dir = path.is_dir() and ((path / CONFIG).exists() or (path / WEIGHTS).exists())
    return (load_model_dir if model_dir else checkpoints.load_module)(path, map_location=map_location)


def _build(ckpt: dict[str, Any], config_file: Path):
    """The allow-listed class built from the hyperparameters, as ``checkpoints.build_module`` builds it (only the
    class's own arguments; flat keys gathered into their groups), with its initial weights."""
    cls = method_class(ckpt[checkpoints.CLASS_KEY])
    accepted = inspect.signature(cls.__init__).parameters
    hparams = {k: v for k, v in checkpoints.hyperparameters(ckpt).items() if k in accepted and k != "self"}
    check_argument_types(cls, hparams, str(config_file))
    try:
        return cls(**hparams)
    except (TypeError, ValueError, RuntimeError, KeyError, AssertionError) as e:
        raise ValueError(f"{config_file}: its hyperparameters do not build {cls.__name__} "
                         f"({type(e).__name__}: {_short(e)})") from None


def _check_tensors(module: torch.nn.Module, tensors: dict[str, torch.Tensor], weights: Path) -> None:
    """The tensors' names and shapes are exactly those of ``module`` (built from the hyperparameters)."""
    expected = {k: tuple(v.shape) for k, v in module.state_dict().items()}
    found = {k: tuple(v.shape) for k, v in tensors.items()}
    what = f"{weights} does not fit {type(module).__name__}"
    missing, extra = sorted(set(expected) - set(found)), sorted(set(found) - set(expected))
    if missing:
        raise ValueError(f"{what}: it lacks tensor {missing[0]!r}" + (f" (and {len(missing) - 1} more)"
                                                                       if len(missing) > 1 else ""))
    if extra:
        raise ValueError(f"{what}: it has tensor {extra[0]!r}, which the model does not" +
                         (f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""))
    for name in sorted(expected):
        if expected[name] != found[name]:
            raise ValueError(f"{what}: tensor {name!r} has shape {list(found[name])}, the hyperparameters build "
                             f"{list(expected[name])}")


# ---- exporting -----------------------------------------------------------------------------------------------

def run_config_of(checkpoint: Path) -> Path | None:
    """The ``config.yaml`` that ``icprl fit`` saved in the checkpoint's run directory (the parent of
    ``checkpoints/``), or None."""
    run_dir = checkpoint.parent.parent if checkpoint.parent.name == "checkpoints" else checkpoint.parent
    found = run_dir / "config.yaml"
    return found if found.is_file() else None


def _read_run_config(path: Path) -> dict[str, Any]:
    """What config.json keeps of a run's config.yaml (read with ``yaml.safe_load``: plain values only)."""
    run = read_yaml(path, "run config")
    if not isinstance(run, dict):
        raise ValueError(f"{path} is not a config of `icprl fit` (not a mapping)")
    data = run.get("data") if isinstance(run.get("data"), dict) else {}
    data_args = data.get("init_args") if isinstance(data.get("init_args"), dict) else {}
    trainer = run.get("trainer") if isinstance(run.get("trainer"), dict) else {}
    return {"family": data_args.get("family"), "setting": data_args.get("setting"),
            "seed": run.get("seed_everything"),
            "training_config": {"seed_everything": run.get("seed_everything"), "model": run.get("model"),
                                "data": run.get("data"),
                                "trainer": {k: trainer.get(k) for k in ("max_epochs", "max_steps")}}}


def _read_results(path: Path) -> dict[str, Any]:
    """An ``icprl evaluate`` JSON (its ``results`` table is what the card shows)."""
    evaluation = read_json(path, "results file")
    if not isinstance(evaluation, dict) or not isinstance(evaluation.get("results"), dict):
        raise ValueError(f"{path} is not an `icprl evaluate` JSON (no 'results' table)")
    return evaluation


def _short(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0][:200]


def export_model(checkpoint: str | Path, out_dir: str | Path, *, results: str | Path | None = None,
                 run_config: str | Path | None = None, command: str | None = None, name: str | None = None,
                 overwrite: bool = False) -> Path:
    """Write ``checkpoint`` as a model directory at ``out_dir`` (module docstring); returns ``out_dir``.

    ``results``: an ``icprl evaluate`` JSON to copy as results.json and show in the card. ``run_config``: the
    run's config.yaml (default: the one in the checkpoint's run directory, if any), the source of the family,
    setting and seed. ``command``: the command that trained it. ``name``: the model's name (default: the
    directory's). An existing ``out_dir`` is replaced only with ``overwrite`` and only if it is a model directory.
    """
    from importlib.metadata import version

    from safetensors.torch import save

    checkpoint, out_dir = Path(checkpoint), Path(out_dir)
    ckpt = checkpoints.read_checkpoint(checkpoint)
    module = checkpoints.build_module(ckpt, checkpoint)
    hparams = ckpt["hyper_parameters"]
    try:
        json.dumps(hparams, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{checkpoint}: its hyperparameters are not plain JSON values ({_short(e)}), so they "
                         "cannot go into config.json") from None
    run_config = Path(run_config) if run_config is not None else run_config_of(checkpoint)
    run = _read_run_config(run_config) if run_config is not None else {}
    evaluation = _read_results(Path(results)) if results is not None else None
    tensors = {k: v.detach().cpu().contiguous().clone() for k, v in ckpt["state_dict"].items()}
    config = {"schema_version": SCHEMA_VERSION, "name": name or out_dir.name, "method": ckpt[checkpoints.CLASS_KEY],
              "hyperparameters": hparams, checkpoints.CHECKSUM_KEY: ckpt[checkpoints.CHECKSUM_KEY],
              "weights_sha256": None, "family": run.get("family"), "setting": run.get("setting"),
              "seed": run.get("seed"), "training_command": command, "training_config": run.get("training_config"),
              "epoch": ckpt.get("epoch"), "global_step": ckpt.get("global_step"),
              "parameters": sum(p.numel() for p in module.parameters()),
              "icprl_lightning_version": version("icprl_lightning"), "exported_from": checkpoint.name,
              "results": RESULTS if evaluation is not None else None}
    try:
        _stage(out_dir, overwrite, config, module, evaluation, results,
               lambda tmp: (tmp / WEIGHTS).write_bytes(save(tensors, metadata={"format": "pt"})))
    except (StorageError, FileExistsError):
        raise
    except OSError as e:  # a full disk or a failing write: one line naming the directory; nothing is left behind
        raise storage_error(e, out_dir, "exporting the model to", "nothing was written") from None
    return out_dir


def _stage(out_dir: Path, overwrite: bool, config: dict[str, Any], module: torch.nn.Module,
           evaluation: dict[str, Any] | None, results: Any, write_weights: Callable[[Path], Any]) -> None:
    """Stage a model directory (weights by ``write_weights``, config.json, results.json, card), load the staged
    copy, checks and all, and only then move it into place."""
    with staged_directory(out_dir, marker=CONFIG, schema_version=SCHEMA_VERSION, what=WHAT,
                          overwrite=overwrite) as tmp:
        write_weights(tmp)  # safetensors' save: an OSError, not a SafetensorError
        config["weights_sha256"] = sha256(tmp / WEIGHTS)
        (tmp / CONFIG).write_text(json.dumps(config, indent=2, default=str) + "\n")
        if evaluation is not None:
            shutil.copyfile(results, tmp / RESULTS)
        model_card(config, module, evaluation).save(tmp / CARD)
        load_model_dir(tmp)


def reissue_results(directory: str | Path, results: str | Path) -> Path:
    """Give a model directory another ``icprl evaluate`` JSON of its own weights (e.g. on more held-out tasks) as
    results.json and rewrite its card from it; the weights and config.json's provenance stay. Returns the directory."""
    directory = Path(directory)
    module, config, evaluation = load_model_dir(directory), read_config(directory), _read_results(Path(results))
    config["results"] = RESULTS
    _stage(directory, True, config, module, evaluation, results,
           lambda tmp: shutil.copy2(directory / WEIGHTS, tmp / WEIGHTS))
    return directory


# ---- the model card ------------------------------------------------------------------------------------------

def _short_class(spec: Any) -> str:
    """``{class_path: a.b.C, init_args: {...}}`` -> ``C (k=v, ...)``; None -> "not recorded"."""
    if not isinstance(spec, dict) or not isinstance(spec.get("class_path"), str):
        return "not recorded"
    args = spec.get("init_args") or {}
    inner = ", ".join(f"{k}={v}" for k, v in args.items()) if isinstance(args, dict) else ""
    return f"`{spec['class_path'].rpartition('.')[2]}` ({inner})" if inner else f"`{spec['class_path']}`"


def _metrics(row: dict[str, Any]) -> list[str]:
    """The metrics of a results row that have a standard error beside them, in their order; values after h
    comparisons (``*_h<h>``) stay in results.json."""
    return [k for k, v in row.items() if isinstance(v, (int, float)) and not k.endswith("_sem")
            and isinstance(row.get(f"{k}_sem"), (int, float)) and not re.search(r"_h\d+$", k)]


def _number(x: float) -> str:
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _results_tables(rows: dict[str, dict[str, Any]]) -> list[str]:
    """``{row name: {group: {metric: mean, metric_sem: sem}}}`` as one Markdown table per metric."""
    groups = list(dict.fromkeys(g for by_group in rows.values() for g in by_group if isinstance(by_group[g], dict)))
    metrics = list(dict.fromkeys(m for by_group in rows.values() for g in groups
                                 for m in _metrics(by_group.get(g) or {})))
    lines = []
    for metric in metrics:
        lines += ["", f"{metric} (mean ± sem; 95% interval mean ± 1.96 sem):", "",
                  "| | " + " | ".join(groups) + " |", "|---|" + "---|" * len(groups)]
        for name, by_group in rows.items():
            cells = []
            for group in groups:
                row = by_group.get(group) or {}
                mean, sem = row.get(metric), row.get(f"{metric}_sem")
                cells.append(f"{_number(mean)} ± {_number(sem)}" if isinstance(mean, (int, float)) and
                             isinstance(sem, (int, float)) and math.isfinite(mean) else "–")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _results_section(evaluation: dict[str, Any] | None) -> list[str]:
    if evaluation is None:
        return ["No evaluation results ship with this model: run `icprl evaluate` on it (docs/pretrained.md)."]
    where = ", ".join(f"{k} {evaluation[k]}" for k in ("n_eval_problems", "horizon") if k in evaluation)
    lines = [f"From `icprl evaluate` ({RESULTS}: \"{evaluation.get('title', '')}\"), evaluation seeds "
             f"{evaluation.get('seeds')}{f', {where}' if where else ''}; ± is the standard error over held-out "
             "tasks (over training seeds when a row pools several). Rows other than this model's are the reference "
             "policies on the same held-out tasks; a metric ending in `_auc` is the mean over context sizes "
             "h = 1..H, the others are at the full context."]
    lines += _results_tables(evaluation["results"])
    diagnostics = evaluation.get("diagnostics") or {}
    rows = {f"{run}, {diagnostic}": by_group for run, by_diagnostic in diagnostics.items()
            for diagnostic, by_group in by_diagnostic.items()}
    if rows:
        lines += ["", "Context diagnostics (the same held-out tasks with the context changed: flipped_labels every "
                  "label inverted, random_labels fair coins, other_task another task's context, shuffled_order the "
                  "steps reordered):"]
        lines += _results_tables(rows)
    return lines


def model_card(config: dict[str, Any], module: torch.nn.Module, evaluation: dict[str, Any] | None):
    """The README.md of a model directory: ``huggingface_hub``'s card with a ``ModelCardData`` YAML header."""
    from huggingface_hub import ModelCard, ModelCardData

    method = config["method"].rpartition(".")[2].removesuffix("Module")
    family = (config.get("family") or {}).get("class_path", "").rpartition(".")[2]
    hp = config["hyperparameters"]
    backbone = hp.get("backbone") or {}
    sizes = ", ".join(f"{k} {backbone[k]}" for k in ("n_layer", "n_embd", "n_head") if k in backbone)
    data = ModelCardData(library_name="icprl_lightning", model_name=config["name"],
                         pipeline_tag="reinforcement-learning",
                         tags=[t for t in ("in-context-reinforcement-learning", "preference-based-rl",
                                           method.lower(), family) if t])
    try:
        agent = module.make_agent()
        kind = "discrete" if agent.action_spec.discrete else "continuous"
        use = [f"`load_agent` gives an agent that takes a `{agent.context_kind}` context of at most "
               f"{agent.max_context} steps, observations of size {agent.obs_dim} and {kind} actions of size "
               f"{agent.action_spec.size}.",
               "", "```python", "from icprl_lightning import load_agent", "",
               f'agent = load_agent("{config["name"]}")  # a shipped name, or this directory\'s path',
               "agent.reset(context)  # B held-out tasks' contexts", "action = agent.act(obs)  # obs [B, S]", "```"]
    except TypeError as e:  # a reward model (RewardGen), not a policy
        use = [f"Not a policy: {e}."]
    command = config.get("training_command")
    body = [
        f"# {config['name']}", "",
        f"{method} (`{config['method']}`), a transformer of {sizes} ({config['parameters']:,} parameters), trained "
        f"with icprl_lightning {config['icprl_lightning_version']} from preference feedback only.", "",
        "## Intended use", "",
        "In-context deployment on unseen tasks of the family it was trained on: the agent conditions on a context "
        "and acts, with no parameter updates. It is a research artifact for reproducing and probing in-context "
        "preference-based RL (Dong et al., *Learning in Context, Guided by Choice*), sized to run on a CPU.", "",
        *use, "",
        "## Training data", "",
        f"- family: {_short_class(config.get('family'))}",
        f"- data recipe (setting): {_short_class(config.get('setting'))}",
        f"- seed: {config.get('seed')}; {config.get('global_step')} optimizer steps (last epoch index "
        f"{config.get('epoch')})",
        f"- command: `{command}`" if command else "- command: not recorded (config.json's `training_config` holds the "
        "run's model, data and trainer sections)",
        "- hyperparameters: config.json's `hyperparameters`, as the checkpoint stored them", "",
        "## Results", "", *_results_section(evaluation), "",
        "## Limitations", "",
        "- Trained on one task family and data recipe: tasks, observation or action sizes and context lengths "
        "outside them are refused by `reset` or are out of distribution.",
        "- One training seed; a small model and dataset sized for a CPU, not the paper's sizes.",
        "- A context must come from the same kind of feedback (labels, behaviour policy) as its training data"
        + ("; the context diagnostics above show how it behaves when that fails." if evaluation and
           evaluation.get("diagnostics") else "."), "",
        "## Files", "",
        f"- `{WEIGHTS}`: tensors only; SHA-256 `{config['weights_sha256']}` (config.json `weights_sha256`)",
        f"- `{CONFIG}`: the method, hyperparameters, training provenance and `{checkpoints.CHECKSUM_KEY}` (the "
        "checkpoint's checksum over class, hyperparameters and tensors); `load_agent` verifies both before "
        "building the model, and never unpickles anything", ""]
    return ModelCard(f"---\n{data.to_yaml()}\n---\n\n" + "\n".join(body))
