"""Question: Are the SAC recipe's preferred and rejected I-PRL actions apart on average, or only state by state?

Asked: 2026-12-02 (the first commit of this investigation, then scripts/ipref_action_balance.py).

Answer (docs/RESULTS.md, "Meta-World Reach I-PRL on the paper's recipe" (ICPO's clock)):
State by state, and the states split in two: 68% of the training steps have the hand within 0.08 of the
goal. Far from it the preferred action points at the goal (mean y-component 0.58 against the rejected 0.16);
near it, where the 80% checkpoint has overshot in +y, the preferred action pulls back (0.15 vs 0.38). On the
scripted recipe near-goal pairs do not differ on average (0.03 vs 0.03). A model that reads the context as
"late in the episode" therefore pulls back from its first step.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

Are an I-PRL dataset's preferred and rejected actions apart on average, or only state by state?

For a stored continuous-action I-PRL dataset (``states``, ``actions``, ``alt_actions``, ``preferred``), prints
per action dimension the mean preferred action, the mean rejected action, their difference and the mean
|preferred − rejected| of a pair. A rejected side biased in one direction (a difference of means comparable
to the per-pair difference) would teach a pull-and-push loss such as ICPO's a state-independent direction.

    python experiments/ipref_action_balance.py data/metaworld_reach_sac-step_preference-<hash> [--split train]

``--near R`` (Meta-World Reach datasets: states[..., 0:3] is the hand, ``tasks/train_goals.npy`` the goals) prints
the same split into the steps whose hand lies within R of the goal and the others, with each group's share: a
behavior that reaches the goal early and hovers past it asks for different actions near and far, which a
model must tell apart by the state (and the context), not by the time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def preferred_and_rejected(split_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """The preferred and the rejected action of every comparison, each [N, H, A]."""
    a, b = np.load(split_dir / "actions.npy"), np.load(split_dir / "alt_actions.npy")
    if a.ndim != 3:
        raise ValueError(f"{split_dir}: continuous actions [N, H, A] expected, got shape {list(a.shape)}")
    won = np.load(split_dir / "preferred.npy")[..., None] == 1
    return np.where(won, a, b), np.where(won, b, a)


def balance(split_dir: Path) -> dict[str, list[float]]:
    preferred, rejected = (x.reshape(-1, x.shape[-1]) for x in preferred_and_rejected(split_dir))
    return {"mean_preferred": preferred.mean(0).tolist(), "mean_rejected": rejected.mean(0).tolist(),
            "difference_of_means": (preferred - rejected).mean(0).tolist(),
            "mean_abs_pair_difference": np.abs(preferred - rejected).mean(0).tolist()}


def balance_by_distance(dataset: Path, split: str, radius: float) -> dict[str, dict[str, object]]:
    """``balance`` of the steps whose hand is within ``radius`` of the goal ("near") and of the others ("far")."""
    d = dataset / split
    preferred, rejected = preferred_and_rejected(d)
    goals = np.load(dataset / "tasks" / f"{'test' if split.startswith('eval') else 'train'}_goals.npy")
    hand = np.load(d / "states.npy")[..., :3]
    near = np.linalg.norm(goals[np.load(d / "task_index.npy")][:, None, :] - hand, axis=-1) <= radius
    out = {}
    for name, rows in (("near", near), ("far", ~near)):
        out[name] = {"share": round(float(rows.mean()), 3),
                     "mean_preferred": [round(float(v), 3) for v in preferred[rows].mean(0)],
                     "mean_rejected": [round(float(v), 3) for v in rejected[rows].mean(0)]}
    return out


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--split", default="train")
    parser.add_argument("--near", type=float, help="Reach: also split the steps by hand-to-goal distance ≤ R")
    ns = parser.parse_args(args)
    out: dict[str, object] = {k: [round(v, 3) for v in values] for k, values in balance(ns.dataset / ns.split).items()}
    if ns.near is not None:
        out["by_distance"] = balance_by_distance(ns.dataset, ns.split, ns.near)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
