"""The catalogue of ``icprl reproduce``: a table is runs (a method's configs and overrides, per training seed)
and the evaluations made of them; ``TABLES`` holds every table of ``docs/RESULTS.md`` that one command remakes."""

from __future__ import annotations

import re
from dataclasses import dataclass

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
MERGED = "configs/overlays/merged_layout.yaml"
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
DIT_G099 = ("--model.init_args.eta", "1.0", "--model.init_args.gamma", "0.99")
# Â as V̂'s one-step TD error instead of Q̂ − V̂ (methods/dit.py; scripts/dit_weight_quality.py says why), at the pick
DIT_TD = (*DIT_PICK, "--model.init_args.advantage", "td")
# Â as the return-to-go over V̂ (AWR's Monte Carlo advantage: V̂ only a baseline, its errors cannot reorder actions)
DIT_RTG = (*DIT_PICK, "--model.init_args.advantage", "return_to_go")
# RewardGen's per-step rewards bounded to DarkRoom's [0, 1] (methods/reward_gen.py): scripts/reward_gen_bayes.py
# shows one pair identifies the goal, so the unbounded r̂'s weak correlation is the objective's, not the data's
BOUNDED = ("--model.init_args.reward_range", "[0, 1]")
FOLDS = 2
REWARD_GEN = "configs/reward_gen_darkroom.yaml"


def holdout(fold: int) -> tuple[str, ...]:
    """Overrides: RewardGen fitted on every training goal but those of ``fold`` of ``FOLDS`` (cross-fitting)."""
    return ("--data.init_args.folds", str(FOLDS), "--data.init_args.holdout_fold", str(fold))


def _tprl_runs() -> tuple[Run, ...]:
    """ICRG's stages beside their oracles: RewardGen on all training goals and on each fold's complement, ICRG on
    in-sample and on cross-fitted labels, DIT on true rewards, DP²T on the same pairs."""
    folds = tuple(f"RewardGen fold{i}" for i in range(FOLDS))
    icrg = ("configs/icrg_darkroom.yaml",)
    stage1 = ("--model.init_args.reward_gen_checkpoint", ("RewardGen",))
    return (Run("RewardGen", (REWARD_GEN,), TPRL_SCALE, evaluated=False, checkpoint="best"),
            *(Run(name, (REWARD_GEN,), (*TPRL_SCALE, *holdout(i)), evaluated=False, checkpoint="best")
              for i, name in enumerate(folds)),
            Run("ICRG in-sample labels", icrg, (*TPRL_SCALE, *DIT_PICK), needs=(stage1,)),
            Run("ICRG cross-fitted labels", icrg, (*TPRL_SCALE, *DIT_PICK),
                needs=(stage1, ("--model.init_args.cross_fit_checkpoints", folds))),
            Run("DIT true rewards", ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, *DIT_PICK)),
            # γ = 0.99: the sweep's best DIT on true rewards greedily; ICRG and its oracle at that γ too
            Run("ICRG in-sample labels g0.99", icrg, (*TPRL_SCALE, *DIT_G099), needs=(stage1,)),
            Run("DIT true rewards g0.99", ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, *DIT_G099)),
            # TD advantages: DIT's oracle and both ICRG label sources
            Run("ICRG in-sample labels TD", icrg, (*TPRL_SCALE, *DIT_TD), needs=(stage1,)),
            Run("ICRG cross-fitted labels TD", icrg, (*TPRL_SCALE, *DIT_TD),
                needs=(stage1, ("--model.init_args.cross_fit_checkpoints", folds))),
            Run("DIT true rewards TD", ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, *DIT_TD)),
            # sharper weights: RewardGen's TD advantages rank actions weakly (scripts/dit_weight_quality.py)
            Run("ICRG in-sample labels TD eta0.3", icrg, (*TPRL_SCALE, *DIT_TD, "--model.init_args.eta", "0.3"),
                needs=(stage1,)),
            # RewardGen with per-step rewards in [0, 1], and ICRG TD on its in-sample and cross-fitted labels
            Run("RewardGen bounded", (REWARD_GEN,), (*TPRL_SCALE, *BOUNDED), evaluated=False, checkpoint="best"),
            Run("ICRG bounded in-sample labels TD", icrg, (*TPRL_SCALE, *DIT_TD),
                needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen bounded",)),)),
            *(Run(f"RewardGen bounded fold{i}", (REWARD_GEN,), (*TPRL_SCALE, *BOUNDED, *holdout(i)),
                  evaluated=False, checkpoint="best") for i in range(FOLDS)),
            Run("ICRG bounded cross-fitted labels TD", icrg, (*TPRL_SCALE, *DIT_TD),
                needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen bounded",)),
                       ("--model.init_args.cross_fit_checkpoints",
                        tuple(f"RewardGen bounded fold{i}" for i in range(FOLDS))))),
            # 3× the optimizer steps: is RewardGen's gap to the Bayes reward (scripts/reward_gen_bayes.py) its budget?
            Run("RewardGen bounded 12 epochs", (REWARD_GEN,), (*TPRL_SCALE, *BOUNDED, "--trainer.max_epochs", "12"),
                evaluated=False, checkpoint="best", seeds=(0,)),
            Run("ICRG bounded 12 epochs in-sample labels TD", icrg, (*TPRL_SCALE, *DIT_TD),
                needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen bounded 12 epochs",)),), seeds=(0,)),
            Run("DP2T", ("configs/dp2t_darkroom_tprl.yaml",), TPRL_SCALE))


# Meta-World Reach T-PRL on the paper's recipe (issue 17, points 3–4): both trajectories of a pair from the SAC
# oracle's 50%-return checkpoint (configs/overlays/sac_oracle.yaml), not the 86%-uniform scripted mixture; 4× the
# configs' 10 pairs per goal, every epoch 4× the steps. ICRG's stages beside their oracle (DIT on true rewards), DP²T.
SAC_ORACLE = "configs/overlays/sac_oracle.yaml"
REACH_TPRL_PAIRS = ("--data.init_args.setting.init_args.trajectories_per_task", "40")
LONG_VALUE_PHASE = ("--model.init_args.value_epochs", "12", "--trainer.max_epochs", "16")
NORMALIZED = ("--model.init_args.normalize_inputs", "true")
# the advantage stage's oracle (issue 17, point 5): A* of the SAC oracle served with the data, no value phase; the
# config's 4 policy epochs
ORACLE_ADVANTAGE = (*REACH_TPRL_PAIRS, *NORMALIZED, "--data.init_args.setting.init_args.oracle_advantages", "true",
                    "--model.init_args.advantage", "oracle", "--model.init_args.value_epochs", "0",
                    "--trainer.max_epochs", "4")
WIDER = ("--model.init_args.n_layer", "4", "--model.init_args.n_embd", "128")


def _reach_tprl_runs() -> tuple[Run, ...]:
    stage1 = ("--model.init_args.reward_gen_checkpoint", ("RewardGen",))
    return (Run("RewardGen", ("configs/reward_gen_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS, evaluated=False,
                checkpoint="best"),
            Run("ICRG", ("configs/icrg_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS, needs=(stage1,)),
            Run("DIT true rewards", ("configs/dit_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS),
            Run("DP2T", ("configs/dp2t_metaworld_tprl.yaml", SAC_ORACLE), REACH_TPRL_PAIRS))


def _reach_advantage_runs() -> tuple[Run, ...]:
    """DIT on true rewards and ICRG with the return-to-go over V̂ as advantage (issue 17, point 3 on Reach);
    metaworld_tprl_sac has the same runs with the paper's Q̂ − V̂."""
    rtg = (*REACH_TPRL_PAIRS, "--model.init_args.advantage", "return_to_go")
    return (Run("DIT true rewards return-to-go", ("configs/dit_metaworld.yaml", SAC_ORACLE), rtg),
            Run("RewardGen", ("configs/reward_gen_metaworld.yaml", SAC_ORACLE), REACH_TPRL_PAIRS, evaluated=False,
                checkpoint="best"),
            Run("ICRG return-to-go", ("configs/icrg_metaworld.yaml", SAC_ORACLE), rtg,
                needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen",)),)))


def _reach_normalized_runs() -> tuple[Run, ...]:
    """ICRG (return-to-go advantage) and its RewardGen, and DP²T, with standardized inputs (normalize_inputs,
    models/normalization.py) for every network (issue 17). DIT on true rewards with standardized inputs, its oracle,
    is metaworld_dit_goal_signal's "DIT return-to-go normalized inputs"."""
    normalized = (*REACH_TPRL_PAIRS, *NORMALIZED)
    return (Run("RewardGen", ("configs/reward_gen_metaworld.yaml", SAC_ORACLE), normalized, evaluated=False,
                checkpoint="best"),
            Run("ICRG", ("configs/icrg_metaworld.yaml", SAC_ORACLE),
                (*normalized, "--model.init_args.advantage", "return_to_go"),
                needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen",)),)),
            Run("DP2T", ("configs/dp2t_metaworld_tprl.yaml", SAC_ORACLE), normalized))


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
                     (*data, "--model.init_args.pair_steps", "aligned"), seeds=(0,)),
                 # issue 12: the merged layout (models/policy.py), the same steps, and its objective (the context's
                 # own next comparison) in the appended layout
                 Run("ICPO merged", ("configs/icpo_metaworld.yaml", *ipref, MERGED), data),
                 # ≈ the appended layout's wall-clock: its fits took 1.7-2.1x the merged ones' (5 December)
                 Run("ICPO merged 90 epochs", ("configs/icpo_metaworld.yaml", *ipref, MERGED),
                     (*data, "--trainer.max_epochs", "90")),
                 Run("ICPO next comparison", ("configs/icpo_metaworld.yaml", *ipref),
                     (*data, "--model.init_args.pair_source", "next", "--data.init_args.pairs", "false")))
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


TABLES = {t.name: t for t in (
    Table("darkroom_ipref", "DarkRoom I-PRL, the paper's recipe (states follow the preferred action)",
          (*(Run(n, (c,)) for n, c in DARKROOM_METHODS),
           Run("ICPO beta1 lam0.5", ("configs/icpo_darkroom.yaml",), ICPO_BETA1_LAM05)),
          baselines=("DQN from scratch=docs/results/dqn_from_scratch_darkroom.json",),
          budget="≈ 2 min per fit on 1 core of 2 busy ones"),
    Table("darkroom_ipref_uniform", "DarkRoom I-PRL, label-informative recipe (states drawn uniformly)",
          (*(Run(n, (c, UNIFORM_STATES), LABEL_INFORMATIVE) for n, c in DARKROOM_METHODS),
           Run("ICPO beta1 lam0.5", ("configs/icpo_darkroom.yaml", UNIFORM_STATES),
               (*LABEL_INFORMATIVE, *ICPO_BETA1_LAM05)),
           # issue 12: the merged layout (models/policy.py) at the same 2,000 steps and at 5,000 steps, ≈ the
           # appended layout's wall-clock (benchmarks/learning_speed.py: 2.2–2.6× its steps/s); and its objective
           # (the context's own next comparison) in the appended layout
           Run("ICPO merged", ("configs/icpo_darkroom.yaml", UNIFORM_STATES, MERGED), LABEL_INFORMATIVE),
           Run("ICPO merged 5 epochs", ("configs/icpo_darkroom.yaml", UNIFORM_STATES, MERGED),
               (*LABEL_INFORMATIVE, "--trainer.max_epochs", "5")),
           Run("ICPO next comparison", ("configs/icpo_darkroom.yaml", UNIFORM_STATES),
               (*LABEL_INFORMATIVE, "--model.init_args.pair_source", "next", "--data.init_args.pairs", "false"))),
          baselines=("DQN from scratch=docs/results/dqn_from_scratch_darkroom.json",),
          budget="≈ 8–11 min per fit on 1 core of 2 busy ones (2,000 steps of 32 contexts)"),
    Table("darkroom_lambda_beta", "ICPO on DarkRoom I-PRL: β × λ", _lambda_beta_runs(), contexts=("own",),
          eval_seeds=(0,),
          budget="≈ 2.5 min per fit on 1 core of 2 busy ones; 24 fits with --seeds 0", figure="lambda_beta"),
    Table("darkroom_dit_sweep", "DIT on true rewards, DarkRoom T-PRL trajectories (600 pairs per goal): η and γ",
          _dit_sweep_runs(), contexts=("own",), eval_seeds=(0, 1),
          budget="≈ 11 min per fit on 1 idle core; 5 fits with --seeds 0"),
    Table("darkroom_dit_steps", "DIT on true rewards with TD advantages, DarkRoom T-PRL (600 pairs per goal): 3× "
          "darkroom_tprl's policy steps (2 value + 6 policy epochs; rollouts every 2 epochs are the learning curve)",
          (Run("DIT true rewards TD 6 policy epochs", ("configs/dit_darkroom.yaml",),
               (*TPRL_SCALE, *DIT_TD, "--trainer.max_epochs", "8")),),
          contexts=("own", "other_task"),
          budget="≈ 12 min per fit on 1 idle core (2,400 steps; the data from darkroom_tprl)"),
    Table("darkroom_return_to_go", "DarkRoom T-PRL (600 pairs per goal): DIT and ICRG (bounded RewardGen, "
          "in-sample labels) with the return-to-go over V̂ as advantage (darkroom_tprl has the TD and Q̂ − V̂ rows)",
          (Run("DIT true rewards return-to-go", ("configs/dit_darkroom.yaml",), (*TPRL_SCALE, *DIT_RTG)),
           Run("RewardGen bounded", (REWARD_GEN,), (*TPRL_SCALE, *BOUNDED), evaluated=False, checkpoint="best"),
           Run("ICRG bounded in-sample labels return-to-go", ("configs/icrg_darkroom.yaml",), (*TPRL_SCALE, *DIT_RTG),
               needs=(("--model.init_args.reward_gen_checkpoint", ("RewardGen bounded",)),))),
          budget="≈ 5–8 min per fit on 1 core; ICRG after its RewardGen"),
    Table("darkroom_tprl", "DarkRoom T-PRL (600 pairs per goal): ICRG's stages against their oracles, DP²T",
          _tprl_runs(),
          budget="≈ 3–8 min per fit with 3–4 jobs on the 2 cores (3 December); 8 runs × seeds, each ICRG after "
                 "its RewardGens"),
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
    Table("metaworld_dit_epochs", "DIT on true rewards, Meta-World Reach T-PRL (metaworld_tprl_sac's data): 16 "
          "policy epochs instead of the config's 4 (its rollouts every 4 epochs are the learning curve)",
          (Run("DIT true rewards 20 epochs", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*REACH_TPRL_PAIRS, "--trainer.max_epochs", "20")),),
          evaluations=(Evaluation("", ("--greedy",)),),
          baselines=("SAC from scratch (20 episodes)=docs/results/sac_from_scratch_metaworld.json",),
          budget="≈ 25–30 min per fit on 1 core of 2 busy ones (the data from metaworld_tprl_sac)"),
    Table("metaworld_dit_advantages", "Meta-World Reach T-PRL (metaworld_tprl_sac's data): DIT on true rewards and "
          "ICRG with the return-to-go over V̂ (AWR's advantage) instead of the paper's Q̂ − V̂",
          _reach_advantage_runs(), evaluations=(Evaluation("", ("--greedy",)),),
          baselines=("SAC from scratch (20 episodes)=docs/results/sac_from_scratch_metaworld.json",),
          budget="≈ 15–30 min per fit on 1 core (the data from metaworld_tprl_sac)"),
    Table("metaworld_dit_eta", "Meta-World Reach T-PRL (metaworld_tprl_sac's data): DIT on true rewards with the "
          "return-to-go advantage at sharper weights exp(Â/η), η = 0.3 and 0.1 (the configs' η = 1 is in "
          "metaworld_dit_advantages): does a policy that imitates only the better actions learn to read its context?",
          tuple(Run(f"DIT return-to-go eta{eta}", ("configs/dit_metaworld.yaml", SAC_ORACLE),
                    (*REACH_TPRL_PAIRS, "--model.init_args.advantage", "return_to_go", "--model.init_args.eta", eta))
                for eta in ("0.3", "0.1")),
          evaluations=(Evaluation("", ("--greedy",)),), contexts=("other_task",),
          budget="≈ 10–20 min per fit on 1 core (the data from metaworld_tprl_sac)"),
    Table("metaworld_dit_goal_signal", "Meta-World Reach T-PRL (metaworld_tprl_sac's data): DIT on true rewards with "
          "the return-to-go advantage, 12 value epochs instead of 4, with the policy's own auxiliary return-to-go "
          "head (value_auxiliary 1), or with standardized inputs (at the config's 4 + 4 epochs, at η = 0.1, or with 12 "
          "policy epochs): does a longer value phase, a goal-dependent target for the policy's features, or O(1) "
          "inputs make DIT read its context?",
          tuple(Run(name, ("configs/dit_metaworld.yaml", SAC_ORACLE),
                    (*REACH_TPRL_PAIRS, "--model.init_args.advantage", "return_to_go", *extra))
                for name, extra in (("DIT return-to-go 12 value epochs", LONG_VALUE_PHASE),
                                    ("DIT return-to-go 12 value epochs value aux",
                                     (*LONG_VALUE_PHASE, "--model.init_args.value_auxiliary", "1.0")),
                                    ("DIT return-to-go normalized inputs", NORMALIZED),
                                    ("DIT return-to-go normalized inputs eta0.1",
                                     (*NORMALIZED, "--model.init_args.eta", "0.1")),
                                    ("DIT return-to-go normalized inputs 12 policy epochs",
                                     (*NORMALIZED, "--trainer.max_epochs", "16")))),
          evaluations=(Evaluation("", ("--greedy",)),), contexts=("other_task",),
          budget="≈ 15–45 min per fit on 1 core (the data from metaworld_tprl_sac)"),
    Table("metaworld_tprl_normalized", "Meta-World Reach T-PRL (metaworld_tprl_sac's data): ICRG (return-to-go "
          "advantage) and its RewardGen, and DP²T, with standardized inputs",
          _reach_normalized_runs(), evaluations=(Evaluation("", ("--greedy",)),),
          baselines=("SAC from scratch (20 episodes)=docs/results/sac_from_scratch_metaworld.json",),
          budget="≈ 10–25 min per fit on 1 core (the data from metaworld_tprl_sac); ICRG after its RewardGen"),
    # Can a weighted clone of the 50% checkpoint beat the behavior when its weights are right? DIT on true rewards
    # whose advantage stage is its oracle, the SAC oracle's A*(s_h, a_h) of each behavior action, standardized inputs
    # (η = 1, also 4 layers × 128; seed 0 also at η = 0.1, for 16 epochs, and on a 4× larger dataset of the same
    # recipe), beside the plain behavior clone (η = 10⁶).
    Table("metaworld_dit_oracle_advantage", "Meta-World Reach T-PRL (40 SAC 50% pairs per goal, standardized "
          "inputs): DIT weighted by the oracle's A*, and the plain behavior clone",
          (Run("DIT oracle advantage", ("configs/dit_metaworld.yaml", SAC_ORACLE), ORACLE_ADVANTAGE),
           Run("DIT oracle advantage eta0.1", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, "--model.init_args.eta", "0.1"), seeds=(0,)),
           Run("DIT oracle advantage 16 epochs", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, "--trainer.max_epochs", "16"), seeds=(0,)),
           Run("DIT oracle advantage 4x128", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, *WIDER)),
           Run("behavior cloning 4x128", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, *WIDER, "--model.init_args.eta", "1e6"), seeds=(0,)),
           Run("DIT oracle advantage 160 pairs", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, "--data.init_args.setting.init_args.trajectories_per_task", "160"), seeds=(0,)),
           # every weight exp(Â/η) ≈ 1: the plain behavior clone the advantages improve on
           Run("behavior cloning", ("configs/dit_metaworld.yaml", SAC_ORACLE),
               (*ORACLE_ADVANTAGE, "--model.init_args.eta", "1e6"))),
          evaluations=(Evaluation("", ("--greedy",)),), contexts=("other_task",),
          budget="≈ 3–6 min per 4-epoch fit on 1 core beside another fit; the first also generates the data with A* "
                 "(seed 0: 527 s in all)"),
    Table("metaworld_dpt_context_source", "Meta-World Reach, the paper's recipe: can DPT read the goal from its "
          "context's rewards? DPT trained on reward contexts of SAC's 50% checkpoint (DIT's data policy) or of the "
          "20/40/80% ones in turn, instead of the converged policy's",
          (Run("DPT 50% contexts", ("configs/dpt_metaworld.yaml",),
               ("--data.init_args.setting.init_args.pretraining_target", "0.5")),
           Run("DPT mixed contexts", ("configs/dpt_metaworld.yaml", "configs/overlays/dpt_mixed_contexts.yaml"))),
          evaluations=(Evaluation("", ("--greedy",)),), contexts=("other_task",),
          budget="≈ 10–20 min per fit on 1 core"),
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
