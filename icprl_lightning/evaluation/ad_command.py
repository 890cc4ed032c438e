"""``icprl evaluate ad``: the in-context learning curve of Algorithm Distillation checkpoints on held-out goals,
beside the source learner they distilled and the optimal return (Laskin et al. 2022, section 5 and figure 4).

    icprl evaluate ad --run AD=configs/ad_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt[,CKPT...] \
        [--run ...] --episodes 20 --seeds 0 1 --out results/ad_darkroom [--title T] \
        [--against "ICPO online=docs/results/online_darkroom_paper/online_darkroom_paper.json"]

Each ``--run`` is NAME=CONFIG:CHECKPOINT[,CHECKPOINT...] (several checkpoints: training seeds): the config's data
are learning histories (``LearningHistoryDataModule``), every checkpoint an ``ADModule`` that fits them. Each is
loaded by ``load_agent`` (sampled actions) and played on every held-out goal from an empty history for
``--episodes`` consecutive episodes, its history kept across them (``evaluation.ad_rollout``; re-encoded once per
episode when full, ``agent.slide = H``), once per ``--seeds`` value. Beside it, on the same goals and seeds: the
first run's source learner (``QLearningHistories``) from scratch, and the optimal return of the very episodes AD
played (DarkRoom's closed-form V*). ``--against NAME=JSON`` adds the per-episode curve of an ``icprl evaluate
online`` result on the same held-out goals (its first pair rule; its last episode asks no queries).

Per episode: each training seed's mean over goals and episode seeds, then mean ± sem over training seeds (one
checkpoint: ± over goals). ``results`` holds the first and last episodes with ``per_task`` (training seed × goal;
the source learner's: one run per episode seed) for ``icprl reproduce --render``'s bootstrap. Every input is
checked before any episode, each problem one line naming the option. Writes ``<out>.json``, ``<out>.md`` (episodes
1, 5, 10, ..., N) and ``<out>.png``; ``evaluate_ad`` is the same as a function.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from icprl_lightning.evaluation.base import HeldOutEvaluation, Run
from icprl_lightning.io import save_figure
from icprl_lightning.untrusted import UntrustedFileError, read_json

KIND = "ad_learning_curve"  # the JSON's ``kind``: how ``reproduce.render`` tells it from an ``icprl evaluate`` one
SOURCE = "Q-learning (source)"
OPTIMAL = "optimal"
RESERVED = {SOURCE, OPTIMAL}


class ADInputError(ValueError):
    """A user input ``icprl evaluate ad`` cannot take; the message names the option."""


def is_ad_payload(payload: Any) -> bool:
    return isinstance(payload, dict) and payload.get("kind") == KIND


# ---- checks (every one before any episode) ------------------------------------------------------------------------

def parse_run(spec: str) -> tuple[str, str, list[str]]:
    """``NAME=CONFIG:CKPT[,CKPT...]`` -> (name, config, checkpoints); a ``ValueError`` naming ``--run`` else."""
    name, _, rest = spec.partition("=")
    config, _, checkpoints = rest.partition(":")
    paths = [c for c in checkpoints.split(",") if c]
    if not (name and config and paths):
        raise ADInputError(f"--run {spec!r} is not NAME=CONFIG:CHECKPOINT[,CHECKPOINT...]")
    return name, config, paths


def check_run(name: str, config: str, checkpoints: Sequence[str]):
    """``config``'s ``LearningHistoryDataModule`` (nothing generated), after checking every checkpoint is an AD one
    that fits it and can keep one whole episode in its window."""
    from icprl_lightning.data.learning_histories import LearningHistoryDataModule
    from icprl_lightning.evaluation.pairing import fit_errors, run_datamodule
    from icprl_lightning.hub import load_model
    from icprl_lightning.methods.ad import ADModule

    if not Path(config).is_file():
        raise ADInputError(f"--run {name}: config {config} does not exist")
    try:
        dm = run_datamodule(name, config, [])
    except ValueError as e:  # its message names --run
        raise ADInputError(str(e)) from None
    if not isinstance(dm, LearningHistoryDataModule):
        raise ADInputError(f"--run {name}: config {config} holds {type(dm).__name__} data, not learning histories "
                         "(LearningHistoryDataModule, e.g. configs/ad_darkroom.yaml): AD is deployed on their "
                         "family's held-out goals beside their source learner")
    for checkpoint in checkpoints:
        try:
            module = load_model(checkpoint)
        except (ValueError, FileNotFoundError) as e:
            raise ADInputError(f"--run {name}: {e}") from None
        if not isinstance(module, ADModule):
            raise ADInputError(f"--run {name}: {checkpoint} is a {type(module).__name__} checkpoint, not an AD one "
                             "(ADModule): icprl evaluate ad deploys Algorithm Distillation; evaluate other methods "
                             "with icprl evaluate")
        errors = fit_errors(module, dm)
        window = module.hparams["max_context"] - 1
        if window < dm.family.horizon:
            errors.append(f"keeps {window} steps of history, less than one episode ({dm.family.horizon})")
        if errors:
            raise ADInputError(f"--run {name}: {checkpoint} does not fit the learning histories of {config}: "
                             f"ADModule {'; '.join(errors)}")
    return dm


def read_against(name: str, path: str, family) -> dict[str, Any]:
    """The per-episode return curve of an ``icprl evaluate online`` JSON on ``family``'s held-out goals (its first
    pair rule), checked: an MDP online result whose configs name the same family and goals."""
    from icprl_lightning.data.config import datamodule_from_config

    where = f"--against {name}={path}"
    try:
        result = read_json(path, "online result")
    except FileNotFoundError:
        raise ADInputError(f"{where}: no such file") from None
    except UntrustedFileError as e:
        raise ADInputError(f"{where}: {e}") from None
    online = result.get("online") if isinstance(result, dict) else None
    if not isinstance(online, dict) or not online or "episodes_per_task" not in result:
        raise ADInputError(f"{where}: not the JSON of `icprl evaluate online` on an MDP family (no per-episode "
                         "'online' curves)")
    try:
        dm = datamodule_from_config(*result["configs"])
    except Exception as e:  # noqa: BLE001 - any failure to rebuild its data is one line naming the option
        raise ADInputError(f"{where}: its configs {result.get('configs')} do not give its data ({e})".splitlines()[0]
                         ) from None
    theirs = getattr(dm, "family", None)
    if type(theirs) is not type(family) or not np.array_equal(theirs.test_goals, family.test_goals):
        raise ADInputError(f"{where}: its held-out tasks are not the ones AD is deployed on ({type(family).__name__} "
                         f"test goals); compare results on the same goals")
    rule, curve = next(iter(online.items()))
    return {"json": path, "rule": rule, "labels": result.get("labels", "own"),
            "queries_per_episode": curve.get("queries_per_episode"),
            "mean": [float(e["return"]) for e in curve["mean"]],
            "sem": [float(e.get("return_sem") or 0.0) for e in curve["mean"]]}


def check_inputs(runs: Mapping[str, tuple[str, Sequence[str]]], episodes: int, seeds: Sequence[int],
                 against: Mapping[str, str]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Every user input checked: (the runs' DataModules by name, the ``against`` curves by name)."""
    if not runs:
        raise ADInputError("--run: give at least one NAME=CONFIG:CHECKPOINT")
    if type(episodes) is not int or episodes < 1:
        raise ADInputError(f"--episodes must be an integer ≥ 1, got {episodes!r}")
    if not seeds or not all(type(s) is int and s >= 0 for s in seeds) or len(set(seeds)) < len(seeds):
        raise ADInputError(f"--seeds must be distinct integers ≥ 0, got {list(seeds)}")
    for name in [*runs, *against]:
        if name in RESERVED:
            raise ADInputError(f"name {name!r} is taken (reference rows: {', '.join(sorted(RESERVED))})")
    if set(runs) & set(against):
        raise ADInputError(f"--against names {sorted(set(runs) & set(against))} are --run names: names must be unique")
    datamodules = {name: check_run(name, config, list(checkpoints)) for name, (config, checkpoints) in runs.items()}
    first = next(iter(datamodules.values()))
    for name, dm in datamodules.items():
        if dm.family != first.family:
            raise ADInputError(f"--run {name}: its family {dm.family} differs from the first run's {first.family}: "
                             "every run is deployed on the same held-out goals")
    curves = {name: read_against(name, path, first.family) for name, path in against.items()}
    return datamodules, curves


# ---- the evaluation ----------------------------------------------------------------------------------------------

def _mean_sem(rows: np.ndarray) -> tuple[list[float], list[float]]:
    """Mean and sem over axis 0 of [n, N] (n = 1: zero sem)."""
    mean = rows.mean(0)
    sem = rows.std(0, ddof=1) / np.sqrt(len(rows)) if len(rows) > 1 else np.zeros_like(mean)
    return mean.tolist(), sem.tolist()


def _cell(per_run_task: np.ndarray) -> dict[str, Any]:
    """One results cell from [runs, goals]: mean ± sem over runs of each run's mean over goals (one run: over
    goals), the runs' values, and ``per_task`` for the bootstrap."""
    means = per_run_task.mean(1)
    if len(means) > 1:
        sem = float(means.std(ddof=1) / np.sqrt(len(means)))
    else:
        sem = float(per_run_task[0].std(ddof=1) / np.sqrt(per_run_task.shape[1])) if per_run_task.shape[1] > 1 else 0.0
    return {"return": float(means.mean()), "return_sem": sem, "per_seed": {"return": means.tolist()},
            "per_task": {"return": per_run_task.tolist()}}


def evaluate_ad(runs: Mapping[str, tuple[str, Sequence[str]]], episodes: int = 20, seeds: Sequence[int] = (0, 1),
                out: str | Path | None = None, title: str = "AD on held-out goals",
                against: Mapping[str, str] | None = None) -> dict[str, Any]:
    """``icprl evaluate ad`` as a function: ``runs`` name -> (config, checkpoints); the JSON it writes as a dict.

    ``out`` writes ``<out>.json``, ``<out>.md`` and ``<out>.png``. Every input is checked first (``ADInputError``,
    a ``ValueError`` naming its option).
    """
    from icprl_lightning.deploy import load_agent
    from icprl_lightning.evaluation.ad_rollout import ad_learning_curve, optimal_curve, source_learning_curve

    against = dict(against or {})
    seeds = list(seeds)
    datamodules, against_curves = check_inputs(runs, episodes, seeds, against)
    reference = next(iter(datamodules))
    family, learner = datamodules[reference].family, datamodules[reference].learner
    goals = family.test_goals
    total = sum(len(c) for _, c in runs.values()) * len(seeds)
    done = 0
    results: dict[str, dict[str, Any]] = {}
    curves: dict[str, dict[str, Any]] = {}
    first, last = "episode 1", f"episode {episodes}"
    for name, (_, checkpoints) in runs.items():
        per_checkpoint = []  # [checkpoints][goals, episodes]: mean over episode seeds
        for k, checkpoint in enumerate(checkpoints):
            per_seed = []
            for seed in seeds:
                agent = load_agent(checkpoint, seed=seed)
                agent.slide = family.horizon  # one re-encoding per episode once the window is full
                per_seed.append(ad_learning_curve(agent, family, goals, episodes, seed))
                done += 1
                returns = per_seed[-1].mean(0)
                print(f"[{done}/{total}] {name} checkpoint {k + 1}/{len(checkpoints)}, episode seed {seed}: mean "
                      f"return {returns[0]:.1f} (episode 1) -> {returns[-1]:.1f} (episode {episodes})",
                      file=sys.stderr, flush=True)
            per_checkpoint.append(np.mean(per_seed, axis=0))
        tasks = np.asarray(per_checkpoint)  # [checkpoints, goals, episodes]
        seed_curves = tasks.mean(1)  # [checkpoints, episodes]
        mean, sem = _mean_sem(seed_curves if len(checkpoints) > 1 else tasks[0])
        curves[name] = {"mean": mean, "sem": sem, "per_seed": seed_curves.tolist()}
        results[name] = {first: _cell(tasks[:, :, 0]), last: _cell(tasks[:, :, -1])}
    print(f"source learner ({type(learner).__name__}) from scratch, {episodes} episodes per goal", file=sys.stderr,
          flush=True)
    source_learner = dataclasses.replace(learner, episodes=episodes)  # its first episodes: the same ε, the same draws
    source = np.asarray([source_learning_curve(source_learner, family, goals, seed) for seed in seeds])  # [S, G, N]
    mean, sem = _mean_sem(source.mean(1))  # over the episode seeds' runs
    curves[SOURCE] = {"mean": mean, "sem": sem, "per_seed": source.mean(1).tolist()}
    results[SOURCE] = {first: _cell(source[:, :, 0]), last: _cell(source[:, :, -1])}
    curves.update(against_curves)
    optimal = np.mean([optimal_curve(family, goals, episodes, seed) for seed in seeds], axis=0)  # [goals, episodes]
    curves[OPTIMAL] = {"mean": optimal.mean(0).tolist(), "per_goal": optimal.mean(1).tolist()}
    results[OPTIMAL] = {first: {"return": float(optimal[:, 0].mean())}, last: {"return": float(optimal[:, -1].mean())}}
    payload = {"kind": KIND, "title": title, "runs": [f"{n}={c}:{','.join(p)}" for n, (c, p) in runs.items()],
               "reference_rows_from": reference, "against": [f"{n}={p}" for n, p in against.items()],
               "family": family.config(), "learner": source_learner.config(), "goals": goals.tolist(),
               "episodes": episodes, "seeds": seeds, "slide": family.horizon,
               "actions": "sampled (AD's default, through load_agent)",
               "results": results, "learning_curves": curves}
    if out is not None:
        ADEpisodes.write(payload, out)
    return payload


# ---- outputs -----------------------------------------------------------------------------------------------------

def shown_episodes(episodes: int) -> list[int]:
    """1, 5, 10, ..., and the last."""
    return sorted({1, *range(5, episodes + 1, 5), episodes})


def ad_markdown(payload: dict[str, Any]) -> str:
    """The table of ``<out>.md``: the return at episodes 1, 5, 10, ..., N of every curve."""
    curves = payload["learning_curves"]
    names = [*curves]
    lines = [f"Return per episode on the {len(payload['goals'])} held-out goals, {payload['episodes']} consecutive "
             "episodes from an empty history kept across them:", "",
             "| episode | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for episode in shown_episodes(payload["episodes"]):
        cells = []
        for name in names:
            curve = curves[name]
            if episode > len(curve["mean"]):
                cells.append("–")
                continue
            value = f"{curve['mean'][episode - 1]:.1f}"
            sem = curve.get("sem", [0.0] * len(curve["mean"]))[episode - 1]
            cells.append(value + (f" ± {sem:.1f}" if sem else ""))
        lines.append(f"| {episode} | " + " | ".join(cells) + " |")
    checkpoints = {spec.partition("=")[0]: len(spec.partition(":")[2].split(",")) for spec in payload["runs"]}
    seeds = ", ".join(f"{n} {k} training seed{'s' if k > 1 else ''}" for n, k in checkpoints.items())
    lines += ["", f"{seeds} (mean ± sem over training seeds of each seed's mean over goals and episode seeds; one "
              f"seed: ± over goals); episode seeds {payload['seeds']}; actions {payload['actions']}; the history "
              f"re-encoded every {payload['slide']} steps once full. {SOURCE}: {payload['learner']['learner']} from "
              "scratch on the same goals, one run per episode seed (± over them). Optimal: V* of the starts AD "
              f"played. Source learner and optimal from {payload['reference_rows_from']}'s config."]
    for spec in payload.get("against", []):
        name, _, path = spec.partition("=")
        curve = curves[name]
        lines.append(f"{name}: `{path}`, pair rule {curve['rule']}, labels {curve['labels']}, "
                     f"{curve['queries_per_episode']} queries per episode but the last.")
    return "\n".join(lines) + "\n"


def ad_figure(payload: dict[str, Any], path: str | Path) -> None:
    """Return against episode: AD runs and the source learner with ± bands, ``against`` curves, the optimum."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for name, curve in payload["learning_curves"].items():
        x = np.arange(1, len(curve["mean"]) + 1)
        mean = np.asarray(curve["mean"])
        if name == OPTIMAL:
            ax.plot(x, mean, color="k", linestyle="--", linewidth=0.9, label=name)
            continue
        style = {"color": "tab:gray"} if name == SOURCE else {"marker": "o", "markersize": 3} if "rule" in curve else {}
        ax.plot(x, mean, label=name, **style)
        sem = np.asarray(curve.get("sem", np.zeros_like(mean)))
        ax.fill_between(x, mean - sem, mean + sem, alpha=0.2, color=ax.lines[-1].get_color())
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("episode on the held-out goal")
    ax.set_ylabel("return")
    ax.set_title(payload["title"], fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


class ADEpisodes(HeldOutEvaluation):
    """Algorithm Distillation's in-context learning curve (the module docstring): every run's AD checkpoints for
    ``episodes`` consecutive episodes on the family's held-out goals, beside the source learner and the optimum;
    ``against``: name -> the JSON of an online evaluation drawn beside it. The runs' configs are read here (their
    learning histories), so the runs' ``data`` are not used."""

    name: ClassVar[str] = "ad"

    def __init__(self, episodes: int = 20, against: dict[str, str] | None = None,
                 title: str = "AD on held-out goals") -> None:
        self.episodes, self.against, self.title = episodes, dict(against or {}), title

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        return super().recognizes(payload) or is_ad_payload(payload)

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        return evaluate_ad({r.name: (r.config, list(r.checkpoints)) for r in runs}, self.episodes, seeds,
                           title=self.title, against=self.against)

    markdown = staticmethod(ad_markdown)
    figure = staticmethod(ad_figure)
