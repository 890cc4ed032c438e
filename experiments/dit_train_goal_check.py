"""Question: Does DIT read the task from its reward context on the goals it was trained on (Meta-World Reach),
where on held-out goals another goal's context gives the same return?

Asked: 2026-12-05 (the first commit of this investigation, then scripts/dit_train_goal_check.py).

Answer (docs/RESULTS.md, "Does DIT read its context on the goals it trained on?"):
Barely. On the training goals its own context adds 0.06 normalized return over another goal's (0.56 vs
0.50, every seed) and success stays at 0.12; on the held-out goals the two are level. DIT does not learn to
infer the goal from a reward context at all; it is not that 45 training goals are too few.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

Does DIT read the task from its context on the goals it was trained on? (issue 17, point 3's Reach half)

    python experiments/dit_train_goal_check.py --seeds 0 1 --greedy \
        --run CONFIG:CHECKPOINT[,CHECKPOINT...] --out docs/results/dit_train_goal_check_reach

On held-out goals DIT on Reach returns the same with another goal's context as with its own (docs/RESULTS.md):
it does not use its context there. This tells the two explanations apart. It deploys the checkpoints, through
``load_agent`` as ``icprl evaluate`` does, on the *training* goals with contexts they never trained on (the
validation split's ξ_a: same goals, same behavior policy, new episodes), with their own context and with
another training goal's (``evaluation.diagnostics.other_task``), and on the held-out goals the same way.

* own ≫ other on training goals, own ≈ other on held-out goals: the model reads its context but only
  recognises the goals it saw (too few training goals to learn the general inference);
* own ≈ other on both: it does not condition on the context at all.

Normalized return is (R − R_uniform) / (R_expert − R_uniform) per goal, as the held-out tables; the training
goals' references are simulated here (``family.references``, ``--reference-episodes`` per goal). Prints JSON
and writes it to ``<out>.json``: per split and context, the mean ± sem over training seeds of each seed's
mean over goals.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.evaluation.base import over_training_seeds
from icprl_lightning.evaluation.heldout_rollouts import held_out_means
from icprl_lightning.evaluation.rollout import suite_env
from icprl_lightning.io import write_json_atomic

CONTEXTS = ("own", "other_task")


def training_goal_suite(dm, reference_episodes: int, seed: int) -> EvalSuite:
    """The validation split's ξ_a as DIT's reward contexts, one episode each on its own training goal."""
    family, data = dm.family, dm.load()
    train = np.asarray(data["tasks"][f"train_{family.task_name}"])
    val = data["val"]
    arrays = {k: to_tensor(np.asarray(val[k])) for k in ("states_a", "actions_a", "rewards_a")}
    tasks = np.asarray(val["task_index"])
    refs = family.references(train, {}, reference_episodes, np.random.default_rng(seed))
    if "test_reference_per_task" not in refs:
        raise SystemExit(f"{type(family).__name__}.references gives no per-task uniform and expert returns; this check "
                         "normalizes each training goal by its own (Meta-World Reach does)")
    info = {"test_reference_per_task": refs["test_reference_per_task"]}
    return EvalSuite(env_name=family.metric_env, quality="pretraining",
                     context=dm.setting.eval_context({"behavior_states": arrays["states_a"],
                                                      "behavior_actions": arrays["actions_a"],
                                                      "behavior_rewards": arrays["rewards_a"]}),
                     make_env=lambda: family.make_env(train[tasks]), task_index=tasks, horizon=family.horizon,
                     normalize=family.normalizer(info, "pretraining", tasks))


def evaluate(suite: EvalSuite, checkpoints: list[str], seeds: list[int], greedy: bool | None) -> dict:
    with suite_env(suite) as env:
        return {d: over_training_seeds([held_out_means(suite, d, c, seeds, greedy, env) for c in checkpoints])
                for d in CONTEXTS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="CONFIG:CHECKPOINT[,CHECKPOINT...] (several: training seeds)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="episode seeds")
    parser.add_argument("--greedy", action="store_true", help="Gaussian mean instead of the method's default")
    parser.add_argument("--reference-episodes", type=int, default=4, help="uniform and expert episodes per goal")
    parser.add_argument("--out", required=True, help="output path without extension")
    args = parser.parse_args()
    config, _, checkpoints = args.run.partition(":")
    checkpoints = checkpoints.split(",")
    dm = datamodule_from_config(config)
    dm.prepare_data()
    greedy = True if args.greedy else None
    suites = {"training goals (validation contexts)": training_goal_suite(dm, args.reference_episodes, 0)}
    suites.update({f"held-out goals ({s.quality})": s for s in dm.held_out("rollouts")})
    payload = {"run": args.run, "seeds": args.seeds, "greedy": bool(args.greedy),
               "results": {name: evaluate(suite, checkpoints, args.seeds, greedy) for name, suite in suites.items()}}
    write_json_atomic(f"{args.out}.json", payload)
    print(json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
