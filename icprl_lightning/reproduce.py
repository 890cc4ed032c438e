"""``icprl reproduce TABLE``: regenerate a results table of ``docs/RESULTS.md`` and its figure from scratch.

    icprl reproduce --list
    icprl reproduce darkroom_ipref                     # 3 training seeds per method, then evaluation
    icprl reproduce darkroom_ipref --seeds 0 --jobs 1  # a quicker, one-seed version
    icprl reproduce darkroom_ipref --dry-run           # print the commands only

A table is a list of runs (a method's configs and overrides) and the evaluations made of them. Every run
is trained once per training seed (``--seed_everything``) with ``icprl fit`` in its own process, at most
``--jobs`` at a time (``OMP_NUM_THREADS`` = cores / jobs each), its log in ``<work>/<table>/<run>-seed<s>.log``;
then ``icprl evaluate`` deploys each run's last checkpoints (all its training seeds) on the held-out
contexts with the context diagnostics, greedy and sampled, and writes ``docs/results/<table>[_sampled]``
(``.json``, ``.md``, ``.png``, ``_diagnostics.png``). Training seeds share the dataset (the family's seed
fixes it); they differ in initialization, shuffling and the pairs drawn.

Each fit logs to CSV; the rollout callback's held-out returns per epoch become ``learning_curves`` in
the summary and ``docs/results/<table>_curve.png``. A finished fit records its checkpoint in
``<run>-seed<s>.json`` with a digest of its inputs (the fit command and the text of its config files);
running the command again skips a fit whose inputs are unchanged, so an interrupted reproduction resumes
where it stopped, and retrains one whose command or configs changed since (``--refit`` trains all
again). The command prints, and writes to ``docs/results/<table>_reproduce.json``, each stage's
wall-clock seconds, the checkpoints and the exact commands.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from icprl_lightning.families.base import QUALITIES
from icprl_lightning.io import write_json_atomic

ALL_CONTEXTS = ("own", "random_labels", "flipped_labels", "other_task")


def slug(name: str) -> str:
    """A run name as a file name (no spaces, commas or '=', which ``--run`` and paths would misread)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")


@dataclass(frozen=True)
class Run:
    """One method of a table: its configs (stacked, as repeated ``--config``) and command-line overrides.

    A later stage of a pipeline (ICRG after RewardGen) names its earlier stages in ``needs``: each
    ``(flag, runs)`` passes the checkpoints of the same training seed of ``runs`` as ``flag``'s value (one path,
    or a list when ``runs`` has several). Such a run is trained after the runs it needs, and again whenever
    one of them is.
    """

    name: str  # a table row; no '=' or ',' (``icprl evaluate --run NAME=CONFIG:CKPT,CKPT``)
    configs: tuple[str, ...]
    overrides: tuple[str, ...] = ()
    seeds: tuple[int, ...] | None = None  # this run's training seeds, whatever the command's ``--seeds``
    needs: tuple[tuple[str, tuple[str, ...]], ...] = ()
    evaluated: bool = True  # False: an earlier stage that is no policy (RewardGen): trained, not deployed
    checkpoint: str = "last"  # the checkpoint the record keeps: "last", or "best" (the fit's monitored best)


@dataclass(frozen=True)
class Evaluation:
    """One ``icprl evaluate`` of a table's runs: output suffix and its flags (``--greedy``, ``--sample``)."""

    suffix: str
    flags: tuple[str, ...]


@dataclass(frozen=True)
class Table:
    name: str
    title: str
    runs: tuple[Run, ...]
    evaluations: tuple[Evaluation, ...] = (Evaluation("", ("--greedy",)), Evaluation("_sampled", ("--sample",)))
    contexts: tuple[str, ...] = ALL_CONTEXTS
    eval_seeds: tuple[int, ...] = (0, 1)
    baselines: tuple[str, ...] = ()
    budget: str = ""  # what one run costs here, for --list
    figure: str = ""  # a table-specific figure made from the evaluations (``FIGURES``)


DARKROOM_METHODS = (("DPT", "configs/dpt_darkroom.yaml"), ("DP2T", "configs/dp2t_darkroom.yaml"),
                    ("ICPO", "configs/icpo_darkroom.yaml"))
# ICPO as every DarkRoom table was trained before the β × λ sweep picked β = 0.1, λ = 1 (the configs' default since)
ICPO_BETA1_LAM05 = ("--model.init_args.beta", "1.0", "--model.init_args.lam", "0.5")
UNIFORM_STATES = "configs/overlays/uniform_states.yaml"
# 400 contexts per goal (4× the paper-recipe configs' data), 2 epochs = 2,000 steps, held-out rollouts every 250
LABEL_INFORMATIVE = ("--data.init_args.setting.init_args.trajectories_per_task", "400",
                     "--trainer.val_check_interval", "250")


# DarkRoom T-PRL at 10× the configs' 60 trajectory pairs per goal (issue 17), at the configs' optimizer steps:
# every epoch is 300 batches drawn from the larger dataset
TPRL_SCALE = ("--data.init_args.setting.init_args.trajectories_per_task", "600", "--trainer.limit_train_batches", "300")


def _dit_sweep_runs() -> tuple[Run, ...]:
    """DIT on true rewards: η at γ = 0.95, a longer horizon γ = 0.99 at η = 1, and the uncentred advantages of
    before issue 17 (5 fits: what one seed of the sweep costs on 2 cores in about an hour)."""
    def dit(name: str, eta: str, gamma: str, center: str = "true") -> Run:
        return Run(name, ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, "--model.init_args.eta", eta,
                                                          "--model.init_args.gamma", gamma,
                                                          "--model.init_args.center_advantages", center))
    return (dit("uncentred eta1 g0.95", "1.0", "0.95", "false"),
            *(dit(f"eta{e} g0.95", e, "0.95") for e in ("1.0", "0.3", "0.1")),
            dit("eta1.0 g0.99", "1.0", "0.99"))


# DIT's η and γ picked by darkroom_dit_sweep (DIT on true rewards), for DIT and ICRG alike
DIT_PICK = ("--model.init_args.eta", "1.0", "--model.init_args.gamma", "0.95")
FOLDS = 2
REWARD_GEN = "configs/reward_gen_darkroom.yaml"


def _tprl_runs() -> tuple[Run, ...]:
    """ICRG's stages beside their oracles: RewardGen on all training goals and on each fold's complement, ICRG on
    in-sample and on cross-fitted labels, DIT on true rewards, DP²T on the same pairs."""
    folds = tuple(f"RewardGen fold{i}" for i in range(FOLDS))
    icrg = ("configs/icrg_darkroom.yaml",)
    stage1 = ("--model.init_args.reward_gen_checkpoint", ("RewardGen",))
    return (Run("RewardGen", (REWARD_GEN,), TPRL_SCALE, evaluated=False, checkpoint="best"),
            *(Run(name, (REWARD_GEN,), (*TPRL_SCALE, "--data.init_args.folds", str(FOLDS),
                                        "--data.init_args.holdout_fold", str(i)), evaluated=False, checkpoint="best")
              for i, name in enumerate(folds)),
            Run("ICRG in-sample labels", icrg, (*TPRL_SCALE, *DIT_PICK), needs=(stage1,)),
            Run("ICRG cross-fitted labels", icrg, (*TPRL_SCALE, *DIT_PICK),
                needs=(stage1, ("--model.init_args.cross_fit_checkpoints", folds))),
            Run("DIT true rewards", ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, *DIT_PICK)),
            # γ = 0.99: the sweep's best DIT on true rewards, which finished after this table's other fits
            Run("ICRG in-sample labels g0.99", icrg, (*TPRL_SCALE, "--model.init_args.eta", "1.0",
                                                      "--model.init_args.gamma", "0.99"), needs=(stage1,)),
            Run("DP2T", ("configs/dp2t_darkroom_tprl.yaml",), TPRL_SCALE))


# Meta-World Reach T-PRL on the paper's recipe (issue 17, points 3–4): both trajectories of a pair from the SAC
# oracle's 50%-return checkpoint (configs/overlays/sac_oracle.yaml), not the 86%-uniform scripted mixture; 4× the
# configs' 10 pairs per goal, every epoch 4× the steps. ICRG's stages beside their oracle (DIT on true rewards), DP²T.
SAC_ORACLE = "configs/overlays/sac_oracle.yaml"
REACH_TPRL_PAIRS = ("--data.init_args.setting.init_args.trajectories_per_task", "40")


def _reach_tprl_runs() -> tuple[Run, ...]:
    stage1 = ("--model.init_args.reward_gen_checkpoint", ("RewardGen",))
    return (Run("RewardGen", ("configs/reward_gen_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS, evaluated=False,
                checkpoint="best"),
            Run("ICRG", ("configs/icrg_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS, needs=(stage1,)),
            Run("DIT true rewards", ("configs/dit_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS),
            Run("DP2T", ("configs/dp2t_metaworld_tprl.yaml", SAC_ORACLE), REACH_TPRL_PAIRS))


# Meta-World Reach I-PRL (issue 13): the paper's recipe (the configs as they are: the committed SAC oracle) and
# the scripted-expert one (its overlays), at multiples of the configs' 20 contexts per training goal, the
# configs' 50 epochs each. Per recipe: (DPT's overlays, the I-PRL configs' overlays).
REACH_RECIPES = {"scripted": (("configs/overlays/scripted_expert_dpt.yaml",),
                              ("configs/overlays/scripted_expert_ipref.yaml",)),
                 "sac": ((), ())}
RECIPE_TITLES = {"scripted": "scripted-expert recipe", "sac": "the paper's recipe (SAC oracle)"}
REACH_SCALES = (1, 2, 4, 8)
REACH_CONTEXTS_PER_GOAL = 20


def _reach_runs(recipe: str, scale: int) -> tuple[Run, ...]:
    """DPT, DP²T and ICPO on one Reach recipe at ``scale`` × 20 contexts per goal (DPT's training contexts from
    the converged policy on the SAC recipe, as the paper's)."""
    dpt, ipref = REACH_RECIPES[recipe]
    data = ("--data.init_args.setting.init_args.trajectories_per_task", str(REACH_CONTEXTS_PER_GOAL * scale))
    runs = (Run("DPT", ("configs/dpt_metaworld.yaml", *dpt), data),
            Run("DP2T", ("configs/dp2t_metaworld.yaml", *ipref), data),
            Run("ICPO", ("configs/icpo_metaworld.yaml", *ipref), data))
    if scale == 1:  # ICPO as it was trained before 2 December (ICPOModule.pair_steps): the context's length a clock
        runs += (Run("ICPO aligned pairs", ("configs/icpo_metaworld.yaml", *ipref),
                     (*data, "--model.init_args.pair_steps", "aligned"), seeds=(0,)),)
    return runs


def _reach_tables() -> tuple[Table, ...]:
    return tuple(
        Table(f"metaworld_{recipe}_x{k}", f"Meta-World Reach I-PRL, {RECIPE_TITLES[recipe]}, "
              f"{REACH_CONTEXTS_PER_GOAL * k} contexts per goal: DPT, DP²T, ICPO", _reach_runs(recipe, k),
              baselines=("SAC from scratch (20 episodes)=docs/results/sac_from_scratch_metaworld.json",),
              # greedy only: a Gaussian-mean head acts by its mean when sampling too, so "_sampled" repeated it
              evaluations=(Evaluation("", ("--greedy",)),),
              budget=f"≈ {5 + 4 * k} min per fit on 1 idle core (data generation included)")
        for recipe in REACH_RECIPES for k in REACH_SCALES)


BETAS, LAMBDAS = ("1", "0.3", "0.1", "0.03"), ("0.25", "0.5", "0.75", "1")
MISTAKE_RATES = ("0", "0.1", "0.2", "0.3")


def teacher(epsilon: str) -> tuple[str, ...]:
    """Overrides: B-Pref's scripted teacher labels the pretraining data, rationality 1 (the family's Bradley–Terry
    temperature), mistake rate ``epsilon``."""
    key = "--data.init_args.setting.init_args.annotator"
    return (key, "icprl_lightning.annotators.ScriptedTeacher", f"{key}.init_args.beta", "1.0",
            f"{key}.init_args.epsilon", epsilon)


def _lambda_beta_runs() -> tuple[Run, ...]:
    """ICPO on the paper's DarkRoom recipe for every β × λ: the four corners with training seeds 0, 1, 2, the
    others with the command's ``--seeds`` (``--seeds 0``: 24 fits)."""
    runs = []
    for beta in BETAS:
        for lam in LAMBDAS:
            corner = beta in (BETAS[0], BETAS[-1]) and lam in (LAMBDAS[0], LAMBDAS[-1])
            runs.append(Run(f"b{beta}_l{lam}", ("configs/icpo_darkroom.yaml",),
                            ("--model.init_args.beta", beta, "--model.init_args.lam", lam),
                            seeds=(0, 1, 2) if corner else None))
    return tuple(runs)


def lambda_beta_figure(table: Table, out_dir: Path) -> None:
    """Return vs λ, one line per β, greedy (solid) and sampled (dashed), one panel per context quality."""
    from matplotlib.figure import Figure

    payloads = {e.suffix: json.loads((out_dir / f"{table.name}{e.suffix}.json").read_text()) for e in table.evaluations}
    qualities = ("low", "medium", "high")
    fig = Figure(figsize=(12, 3.4), layout="tight")
    axes = fig.subplots(1, len(qualities), sharey=True)
    for ax, quality in zip(axes, qualities, strict=True):
        for i, beta in enumerate(BETAS):
            for suffix, style in (("", "-"), ("_sampled", "--")):
                rows = [payloads[suffix]["results"][f"b{beta}_l{lam}"][quality] for lam in LAMBDAS]
                ax.errorbar([float(lam) for lam in LAMBDAS], [r["return"] for r in rows],
                            yerr=[r.get("return_sem", 0.0) for r in rows], color=f"C{i}", linestyle=style,
                            marker=".", capsize=2,
                            label=f"β = {beta}, {'greedy' if suffix == '' else 'sampled'}")
        ax.set_title(f"{quality} contexts", fontsize=9)
        ax.set_xlabel("λ")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("held-out return")
    axes[-1].legend(fontsize=6, bbox_to_anchor=(1.02, 1), loc="upper left")
    fig.suptitle(f"{table.title} (corners: 3 training seeds, mean ± sem over seeds; others: 1 seed, "
                 "± sem over held-out goals)", fontsize=9)
    fig.savefig(out_dir / f"{table.name}.png", dpi=120)


def teacher_noise_figure(table: Table, out_dir: Path) -> None:
    """The held-out metric vs the teacher's mistake rate, one line per context source (bandits: weak regret,
    DTS dashed) or per context quality (DarkRoom: greedy return, behavior dashed)."""
    from matplotlib.figure import Figure

    results = json.loads((out_dir / f"{table.name}.json").read_text())["results"]
    sources = list(results[f"ICPO eps{MISTAKE_RATES[0]}"])
    metric = "weak_regret" if "weak_regret" in results[f"ICPO eps{MISTAKE_RATES[0]}"][sources[0]] else "return"
    reference = "dts" if metric == "weak_regret" else "behavior"
    fig = Figure(figsize=(5.5, 3.6), layout="tight")
    ax = fig.subplots()
    eps = [float(e) for e in MISTAKE_RATES]
    for i, source in enumerate(sources):
        rows = [results[f"ICPO eps{e}"][source] for e in MISTAKE_RATES]
        ax.errorbar(eps, [r[metric] for r in rows], yerr=[r.get(f"{metric}_sem", 0.0) for r in rows],
                    color=f"C{i}", marker=".", capsize=2, label=f"ICPO, {source} contexts")
        if reference in results and source in results[reference]:
            ax.axhline(results[reference][source][metric], color=f"C{i}", linestyle="--", linewidth=0.8,
                       label=f"{reference}, {source} contexts")
    ax.set_xlabel("teacher's mistake rate ε (pretraining labels)")
    ax.set_ylabel("weak regret after the whole context" if metric == "weak_regret" else "held-out return (greedy)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    ax.set_title("ICPO pretrained on a scripted teacher's labels (3 training seeds, mean ± sem)", fontsize=8)
    fig.savefig(out_dir / f"{table.name}_vs_noise.png", dpi=120)


FIGURES = {"lambda_beta": lambda_beta_figure, "teacher_noise": teacher_noise_figure}


TABLES = {t.name: t for t in (
    Table("darkroom_ipref", "DarkRoom I-PRL, the paper's recipe (states follow the preferred action)",
          (*(Run(n, (c,)) for n, c in DARKROOM_METHODS),
           Run("ICPO beta1 lam0.5", ("configs/icpo_darkroom.yaml",), ICPO_BETA1_LAM05)),
          baselines=("DQN from scratch=docs/results/dqn_from_scratch_darkroom.json",),
          budget="≈ 2 min per fit on 1 core of 2 busy ones"),
    Table("darkroom_ipref_uniform", "DarkRoom I-PRL, label-informative recipe (states drawn uniformly)",
          (*(Run(n, (c, UNIFORM_STATES), LABEL_INFORMATIVE) for n, c in DARKROOM_METHODS),
           Run("ICPO beta1 lam0.5", ("configs/icpo_darkroom.yaml", UNIFORM_STATES),
               (*LABEL_INFORMATIVE, *ICPO_BETA1_LAM05))),
          baselines=("DQN from scratch=docs/results/dqn_from_scratch_darkroom.json",),
          budget="≈ 8–11 min per fit on 1 core of 2 busy ones (2,000 steps of 32 contexts)"),
    Table("darkroom_lambda_beta", "ICPO on DarkRoom I-PRL: β × λ", _lambda_beta_runs(), contexts=("own",),
          eval_seeds=(0,),
          budget="≈ 2.5 min per fit on 1 core of 2 busy ones; 24 fits with --seeds 0", figure="lambda_beta"),
    Table("darkroom_dit_sweep", "DIT on true rewards, DarkRoom T-PRL trajectories (600 pairs per goal): η and γ",
          _dit_sweep_runs(), contexts=("own",), eval_seeds=(0, 1),
          budget="≈ 11 min per fit on 1 idle core; 5 fits with --seeds 0"),
    Table("darkroom_tprl", "DarkRoom T-PRL (600 pairs per goal): ICRG's stages against their oracles, DP²T",
          _tprl_runs(),
          budget="≈ 20–40 min per fit on 1 core of 2 busy ones; 7 runs × seeds, each ICRG after its RewardGens"),
    Table("reward_gen_forms", "RewardGen in the paper's form (its own pair, read causally) beside the other-pair "
          "form: DarkRoom (the other-pair RewardGen is darkroom_tprl's) and Meta-World Reach T-PRL",
          (Run("DarkRoom causal", (REWARD_GEN,), (*TPRL_SCALE, "--model.init_args.pair_source", "context_causal"),
               evaluated=False, checkpoint="best"),
           Run("Reach other pair", ("configs/reward_gen_metaworld.yaml",), evaluated=False, checkpoint="best"),
           Run("Reach causal", ("configs/reward_gen_metaworld.yaml",),
               ("--model.init_args.pair_source", "context_causal"), evaluated=False, checkpoint="best")),
          budget="≈ 5–20 min per fit on 1 core; measured by scripts/reward_gen_quality.py, not deployed"),
    *_reach_tables(),
    Table("metaworld_tprl_sac", "Meta-World Reach T-PRL, the paper's recipe (pairs from SAC's 50%-return "
          "checkpoint, 40 per goal): ICRG, DIT on true rewards, DP²T", _reach_tprl_runs(),
          evaluations=(Evaluation("", ("--greedy",)),),  # Gaussian means: sampling would repeat the greedy pass
          baselines=("SAC from scratch (20 episodes)=docs/results/sac_from_scratch_metaworld.json",),
          budget="≈ 10–25 min per fit on 1 core (data generation included); ICRG after its RewardGen"),
    Table("bandit", "Linear dueling bandits: ICPO vs DTS", (Run("ICPO", ("configs/icpo_bandit.yaml",)),),
          evaluations=(Evaluation("", ()),), contexts=ALL_CONTEXTS,
          eval_seeds=(0,), budget="≈ 2–4 min per fit on 1 core"),
    Table("bandit_teacher_noise",
          "Linear dueling bandits: ICPO pretrained on a scripted teacher's labels (mistake rate ε)",
          tuple(Run(f"ICPO eps{e}", ("configs/icpo_bandit.yaml",), teacher(e)) for e in MISTAKE_RATES),
          evaluations=(Evaluation("", ()),), contexts=ALL_CONTEXTS, eval_seeds=(0,),
          budget="≈ 2 min per fit on 1 core; 12 fits", figure="teacher_noise"),
    Table("darkroom_teacher_noise",
          "DarkRoom I-PRL, label-informative recipe: ICPO pretrained on a scripted teacher's labels (mistake rate ε)",
          tuple(Run(f"ICPO eps{e}", ("configs/icpo_darkroom.yaml", UNIFORM_STATES), (*LABEL_INFORMATIVE, *teacher(e)))
                for e in MISTAKE_RATES),
          budget="≈ 8–11 min per fit on 1 core of 2 busy ones; 12 fits", figure="teacher_noise"),
    Table("bandit_paper_data", "Linear dueling bandits, the paper's 100k pretraining contexts: ICPO vs DTS",
          (Run("ICPO", ("configs/icpo_bandit.yaml",),
               ("--data.init_args.setting.init_args.n_train_problems", "50000", "--trainer.max_epochs", "1")),),
          evaluations=(Evaluation("", ()),), contexts=ALL_CONTEXTS, eval_seeds=(0,),
          budget="one epoch of 100k contexts (3,125 steps): ≈ 7 min per fit on 1 core"),
)}


def fit_command(run: Run, seed: int, root: Path, needed: dict[str, str] | None = None) -> list[str]:
    """``icprl fit`` of one run and training seed, logging to CSV in ``<root>/<run>-seed<s>/version_0``;
    ``needed`` maps each run of ``run.needs`` to its checkpoint for this seed."""
    configs = [arg for config in run.configs for arg in ("--config", config)]
    stages = []
    for flag, names in run.needs:
        paths = [(needed or {})[name] for name in names]
        stages += [flag, paths[0] if len(names) == 1 else "[" + ",".join(paths) + "]"]
    return ["icprl", "fit", *configs, *run.overrides, *stages, "--seed_everything", str(seed),
            "--trainer.logger", "lightning.pytorch.loggers.CSVLogger", "--trainer.logger.init_args.save_dir",
            str(root), "--trainer.logger.init_args.name", f"{slug(run.name)}-seed{seed}",
            "--trainer.default_root_dir", str(root)]


def fit_inputs(run: Run, command: list[str], needed_inputs: tuple[str, ...] = ()) -> str:
    """Digest of what a fit's result depends on that this command controls: its arguments, the text of its
    config files and the digests of the earlier stages it needs (the code is the repository's: a table is
    remade from one commit)."""
    digest = hashlib.sha256(shlex.join(command).encode())
    for config in run.configs:
        digest.update(b"\0" + Path(config).read_bytes())
    for inputs in needed_inputs:
        digest.update(b"\0" + inputs.encode())
    return digest.hexdigest()


def stages(runs: tuple[Run, ...]) -> list[list[Run]]:
    """The runs in the order they can be trained: each stage only needs runs of earlier stages."""
    names = {run.name for run in runs}
    order, placed = [], set()
    while len(placed) < len(runs):
        ready = [r for r in runs if r.name not in placed and all(n in placed for _, ns in r.needs for n in ns)]
        if not ready:
            missing = {n for r in runs for _, ns in r.needs for n in ns} - names
            raise ValueError(f"runs need {sorted(missing)}, which the table lacks" if missing else
                             "the runs' needs form a cycle")
        order.append(ready)
        placed.update(r.name for r in ready)
    return order


def logged_rows(checkpoint: str) -> list[dict[str, str]]:
    """The rows of a fit's CSV log (``metrics.csv`` beside its checkpoints directory); none without a log."""
    import csv

    path = Path(checkpoint).parent.parent / "metrics.csv"
    if not path.exists():
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


def learning_curve(checkpoint: str) -> list[dict[str, float]]:
    """The rollout callback's held-out returns per validation epoch of a fit (its CSV log beside the checkpoint):
    ``[{"step": s, "<quality>": return, ...}]``, empty when the fit logged none."""
    points: dict[int, dict[str, float]] = {}
    for row in logged_rows(checkpoint):
        for key, value in row.items():
            parts = key.split("/")
            if value and len(parts) == 4 and parts[0] == "val" and parts[3] == "return":
                points.setdefault(int(row["step"]), {"step": int(row["step"])})[parts[2]] = float(value)
    return [points[s] for s in sorted(points)]


def final_epoch_means(checkpoint: str) -> dict[str, float]:
    """Mean of every ``train/`` metric a fit logged in its last epoch (its CSV log beside the checkpoint), e.g.
    DIT's ``clipped_fraction`` and ``weight_std`` at the end of its policy phase; empty without a log."""
    rows = [row for row in logged_rows(checkpoint) if row.get("epoch")]
    last = max((int(row["epoch"]) for row in rows), default=None)
    values: dict[str, list[float]] = {}
    for row in rows:
        if int(row["epoch"]) == last:
            for key, value in row.items():
                if key.startswith("train/") and value:
                    values.setdefault(key[len("train/"):], []).append(float(value))
    return {key: sum(v) / len(v) for key, v in sorted(values.items())}


def curve_figure(table: Table, curves: dict[str, dict[str, list]], path: Path) -> None:
    """Held-out return vs optimizer steps, one panel per quality, one line per run (each training seed thin)."""
    from matplotlib.figure import Figure

    found = {k for per in curves.values() for c in per.values() for p in c for k in p if k != "step"}
    qualities = [q for q in QUALITIES if q in found] + sorted(found - set(QUALITIES))
    if not qualities:
        return
    fig = Figure(figsize=(3.6 * len(qualities) + 1.5, 3.2), layout="tight")
    axes = fig.subplots(1, len(qualities), sharey=True, squeeze=False)[0]
    for ax, quality in zip(axes, qualities, strict=True):
        for i, (name, per_seed) in enumerate(curves.items()):
            color = f"C{i}"
            for j, curve in enumerate(per_seed.values()):
                points = [(p["step"], p[quality]) for p in curve if quality in p]
                if points:
                    ax.plot(*zip(*points, strict=True), color=color, alpha=0.8, marker=".",
                            label=name if j == 0 else None)
        ax.set_title(f"{quality} contexts", fontsize=9)
        ax.set_xlabel("optimizer steps")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("held-out return (rollout callback)")
    axes[-1].legend(fontsize=7)
    fig.suptitle(f"{table.title}: return during training, one line per training seed", fontsize=9)
    fig.savefig(path, dpi=120)


def evaluate_command(table: Table, evaluation: Evaluation, checkpoints: dict[str, list[str]], out_dir: Path
                     ) -> list[str]:
    command = ["icprl", "evaluate", "--title", table.title, "--seeds", *map(str, table.eval_seeds),
               *evaluation.flags, "--out", str(out_dir / f"{table.name}{evaluation.suffix}")]
    if table.contexts != ("own",):
        command += ["--contexts", *table.contexts]
    for run in (r for r in table.runs if r.evaluated):
        # the first seed's saved config.yaml names the run's exact dataset (configs, overlays and overrides)
        config = Path(checkpoints[run.name][0]).parent.parent / "config.yaml"
        command += ["--run", f"{run.name}={config}:{','.join(checkpoints[run.name])}"]
    for baseline in table.baselines:
        command += ["--baseline", baseline]
    return command


def _run_fit(command: list[str], inputs: str, log: Path, record: Path, threads: int, which: str = "last") -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "WANDB_MODE": os.environ.get("WANDB_MODE", "disabled")}
    start = time.time()
    with open(log, "w") as out:
        code = subprocess.run([sys.executable, "-m", "icprl_lightning.cli", *command[1:]], stdout=out,
                              stderr=subprocess.STDOUT, env=env).returncode
    if code != 0:
        raise RuntimeError(f"{shlex.join(command)} failed (exit {code}); its log: {log}")
    last = [line.split(":", 1)[1].strip() for line in log.read_text().splitlines()
            if line.startswith(f"{which} checkpoint:")]
    if not last:
        raise RuntimeError(f"{shlex.join(command)} printed no '{which} checkpoint:' line; its log: {log}")
    result = {"command": shlex.join(command), "inputs_sha256": inputs, "checkpoint": last[-1],
              "seconds": round(time.time() - start, 1)}
    write_json_atomic(record, result)
    return result


def needed_runs(table: Table, only: list[str]) -> Table:
    """``table`` cut to the runs named in ``only`` and the earlier stages they need."""
    by_name = {run.name: run for run in table.runs}
    unknown = sorted(set(only) - set(by_name))
    if unknown:
        raise ValueError(f"--only {unknown}: no such run in {table.name}; its runs: {list(by_name)}")
    keep, todo = set(), list(only)
    while todo:
        name = todo.pop()
        if name not in keep:
            keep.add(name)
            todo += [n for _, names in by_name[name].needs for n in names]
    return replace(table, runs=tuple(run for run in table.runs if run.name in keep))


def reproduce(table: Table, seeds: list[int], jobs: int, work: Path, out_dir: Path, refit: bool = False,
              dry_run: bool = False, threads: int | None = None, only: list[str] | None = None) -> dict:
    """Train every run of ``table`` per seed (resuming recorded fits), then evaluate and write the outputs; with
    ``only``, train just those runs and what they need, and stop there (the records serve the full command)."""
    if only:
        table = needed_runs(table, only)
    root = work / table.name
    root.mkdir(parents=True, exist_ok=True)
    threads = threads or max(1, (os.cpu_count() or 1) // jobs)
    done: dict[tuple[str, int], dict] = {}
    run_seeds = {run.name: list(run.seeds or seeds) for run in table.runs}
    for run in table.runs:
        for _, names in run.needs:
            for name in names:
                if not set(run_seeds[run.name]) <= set(run_seeds[name]):
                    raise ValueError(f"{run.name} needs {name} at training seeds {run_seeds[run.name]}, "
                                     f"which has only {run_seeds[name]}")
    start = time.time()
    order = [run for stage in stages(table.runs) for run in stage]  # every fit after the fits it needs

    def fit(run: Run, seed: int, needed: list[dict | None]) -> dict | None:
        """The fit's record: reused while its inputs are unchanged, else trained (None: dry run, not known)."""
        if None in needed:  # dry run: an earlier stage still to train, so its checkpoint is unknown
            print(f"# {run.name} seed {seed}: after the runs it needs", flush=True)
            return None
        paths = dict(zip((n for _, names in run.needs for n in names), (n["checkpoint"] for n in needed), strict=True))
        record = root / f"{slug(run.name)}-seed{seed}.json"
        command = fit_command(run, seed, root / "runs", paths)
        inputs = fit_inputs(run, command, tuple(n["inputs_sha256"] for n in needed))
        recorded = json.loads(record.read_text()) if record.exists() and not refit else None
        if recorded is not None and recorded.get("inputs_sha256") == inputs:
            return recorded
        if recorded is not None:
            print(f"{run.name} seed {seed}: its command, configs or earlier stages changed since {record} was "
                  "written; training it again", flush=True)
        if dry_run:
            print(shlex.join(command), flush=True)
            return None
        print(f"  training {run.name} seed {seed}", flush=True)
        result = _run_fit(command, inputs, root / f"{slug(run.name)}-seed{seed}.log", record, threads, run.checkpoint)
        print(f"  {run.name} seed {seed}: {result['seconds']} s -> {result['checkpoint']}", flush=True)
        return result

    # A worker waits for the fits its run needs: they were submitted before it, so they are running or done
    # (never queued behind it), and a later stage starts as soon as its own seed's earlier stages are done.
    futures: dict[tuple[str, int], Future] = {}
    with ThreadPoolExecutor(max_workers=1 if dry_run else jobs) as pool:
        for run in order:
            for seed in run_seeds[run.name]:
                deps = [futures[(name, seed)] for _, names in run.needs for name in names]

                def task(run: Run = run, seed: int = seed, deps: list[Future] = deps) -> dict | None:
                    return fit(run, seed, [d.result() for d in deps])

                futures[(run.name, seed)] = pool.submit(task)
        for key, future in futures.items():
            result = future.result()
            if result is not None:
                done[key] = result
    if dry_run:
        return {}
    fit_seconds = round(time.time() - start, 1)
    if only:
        print(f"{table.name}: trained {sorted(only)} and what they need in {fit_seconds} s; run the command without "
              "--only to evaluate the whole table", flush=True)
        return {"fits": {f"{n}-seed{s}": r for (n, s), r in sorted(done.items())}, "fit_wall_seconds": fit_seconds}
    checkpoints = {run.name: [done[(run.name, s)]["checkpoint"] for s in run_seeds[run.name]] for run in table.runs}
    evaluations = []
    from icprl_lightning.evaluation.command import main as evaluate_main

    for evaluation in table.evaluations if any(run.evaluated for run in table.runs) else ():
        command = evaluate_command(table, evaluation, checkpoints, out_dir)
        began = time.time()
        evaluate_main(command[2:])
        evaluations.append({"command": shlex.join(command), "seconds": round(time.time() - began, 1)})
    if table.figure:
        FIGURES[table.figure](table, out_dir)
    curves = {run.name: {str(s): learning_curve(done[(run.name, s)]["checkpoint"]) for s in run_seeds[run.name]}
              for run in table.runs if run.evaluated}
    curve_figure(table, curves, out_dir / f"{table.name}_curve.png")
    final_metrics = {f"{run.name}-seed{s}": final_epoch_means(done[(run.name, s)]["checkpoint"])
                     for run in table.runs for s in run_seeds[run.name]}
    summary = {"table": table.name, "training_seeds": seeds, "jobs": jobs, "threads_per_fit": threads,
               "fit_wall_seconds": fit_seconds, "final_epoch_train_metrics": final_metrics,
               "fits": {f"{n}-seed{s}": r for (n, s), r in sorted(done.items())}, "evaluations": evaluations,
               "learning_curves": curves, "total_wall_seconds": round(time.time() - start, 1)}
    write_json_atomic(out_dir / f"{table.name}_reproduce.json", summary)
    print(f"{table.name}: fits {fit_seconds} s wall, all {summary['total_wall_seconds']} s "
          f"-> {out_dir / table.name}.md", flush=True)
    return summary


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="icprl reproduce", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("table", nargs="?", choices=sorted(TABLES))
    parser.add_argument("--list", action="store_true", help="list the tables and what one fit costs")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    parser.add_argument("--jobs", type=int, default=2, help="fits at a time (each gets cores / jobs threads)")
    parser.add_argument("--threads", type=int, help="torch threads per fit (default: cores / jobs)")
    parser.add_argument("--work", default="runs/reproduce", help="fit logs, run directories and records")
    parser.add_argument("--out", default="docs/results", help="where the tables and figures go")
    parser.add_argument("--refit", action="store_true", help="train again even where a fit is recorded")
    parser.add_argument("--dry-run", action="store_true", help="print the fit commands, run nothing")
    parser.add_argument("--only", nargs="+", metavar="RUN", help="train only these runs (and the earlier stages "
                        "they need), evaluate nothing")
    args = parser.parse_args(argv)
    if args.list or args.table is None:
        for table in TABLES.values():
            print(f"{table.name}: {table.title}; {len(table.runs)} runs × seeds; {table.budget}")
        return {}
    if args.jobs < 1:
        parser.error(f"--jobs must be ≥ 1, got {args.jobs}")
    return reproduce(TABLES[args.table], args.seeds, args.jobs, Path(args.work), Path(args.out), args.refit,
                     args.dry_run, args.threads, args.only)
