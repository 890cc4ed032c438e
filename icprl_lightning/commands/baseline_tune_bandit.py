"""``icprl baseline tune-bandit``: tune the feature-aware dueling-bandit baselines on training problems
(``families/dueling_bandit/tuning.py``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import numpy as np

import icprl_lightning.families.dueling_bandit.tuning as source
from icprl_lightning.families.dueling_bandit.bayes import BayesReference, laplace_check
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.linear_baselines import prefix_duels
from icprl_lightning.families.dueling_bandit.tuning import GRIDS, dts_score, offline_score, training_problems, tune


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="icprl baseline tune-bandit", description=source.__doc__.split("\n\n")[0])
    parser.add_argument("--problems", type=int, default=300, help="training problems (the first of the split)")
    parser.add_argument("--horizon", type=int, default=50, help="comparisons per uniform-pair context")
    parser.add_argument("--seed", type=int, default=0, help="contexts and learners' random streams")
    parser.add_argument("--family-seed", type=int, default=0, help="LinearDuelingBanditFamily seed (features)")
    parser.add_argument("--learners", nargs="+", choices=list(GRIDS), default=list(GRIDS), help="grids to search")
    args = parser.parse_args(argv)
    family = LinearDuelingBanditFamily(seed=args.family_seed)
    theta = training_problems(family, args.problems)
    context_seed, learner_seed, check_seed = np.random.SeedSequence(args.seed).spawn(3)
    context = family.with_horizon(args.horizon).uniform_pairs_context(theta, np.random.default_rng(context_seed))
    seed = int(learner_seed.generate_state(1)[0])
    report: dict[str, Any] = {"problems": args.problems, "horizon": args.horizon, "seed": args.seed}
    for name in args.learners:
        learner, grid = GRIDS[name]
        best, rows = tune(learner, grid, family, theta, context, seed)
        report[name] = {"best": best, "grid": rows}
        print(f"{name}: best {best}", flush=True)
        for row in rows:
            print("  " + ", ".join(f"{k}={v:.4g}" for k, v in row.items()), flush=True)
    report["dts"] = dts_score(family, theta, context, seed)
    for rule in ("weak", "random_second"):
        bayes = BayesReference.for_family(family, len(theta), rng=np.random.default_rng(seed), rule=rule)
        report[f"bayes_{rule}"] = offline_score(prefix_duels(bayes, context["arms_first"], context["arms_second"],
                                                             context["preferred"]), family.expected_rewards(theta))
    check_rng = np.random.default_rng(check_seed)
    report["laplace_check"] = [laplace_check(family, theta[:20], {k: v[:20, :h] for k, v in context.items()},
                                             check_rng) for h in (5, args.horizon)]
    for key in ("dts", "bayes_weak", "bayes_random_second"):
        print(f"{key}: " + ", ".join(f"{k}={v:.4g}" for k, v in report[key].items()))
    for row in report["laplace_check"]:
        print("laplace_check: " + ", ".join(f"{k}={v:.4g}" for k, v in row.items()))
    print(json.dumps(report, indent=None, default=float))
    return report
