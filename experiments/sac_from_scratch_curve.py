"""Question: After how many episodes of online RL does SAC from scratch reach, on the held-out Reach goals, the
return in-context methods get from a context alone?

Asked: 2026-12-02 (the first commit of this investigation, then scripts/sac_from_scratch_curve.py).

Answer (docs/RESULTS.md, "SAC from scratch" (Meta-World Reach, 100 episodes per goal)):
Within 100 episodes per goal, never. Its deterministic evaluation curve rises to 0.50 normalized at 75
episodes and falls to 0.14 at 100 (best checkpoint 0.51 ± 0.03 on fresh episodes), below every in-context
method's medium-context return (0.64–0.75). The figure is docs/results/sac_from_scratch/sac_from_scratch_curve.png.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

SAC from scratch on the held-out Reach goals: normalized evaluation return against training episodes
(issue 13, point 4), beside the zero-shot return of in-context methods, so the reader sees after how many
episodes of online RL a from-scratch agent would reach what ICPRL gets from a context alone.

    python experiments/sac_from_scratch_curve.py docs/results/sac_from_scratch/sac_from_scratch_metaworld_100ep.json \
        --zero-shot docs/results/metaworld_sac_x1/metaworld_sac_x1.json --out docs/results/sac_from_scratch/sac_from_scratch_curve

Each evaluation (``eval_curve`` of ``icprl baseline sac``: the deterministic policy
on fixed-seed episodes every few training episodes) is normalized with its goal's uniform and scripted-expert
returns, (R − R_uniform) / (R_expert − R_uniform), then averaged over goals (± sem). ``--zero-shot`` draws
each method's held-out normalized return (medium contexts, greedy) of a results JSON of ``icprl evaluate``.
Writes ``<out>.png`` and prints the first episode count at which the mean curve reaches each method's line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from icprl_lightning.metrics import mean_sem


def curve(payload: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episodes [E], mean and sem over goals [E] of the normalized evaluation return."""
    horizon = payload["horizon"]
    per_goal = []
    for goal in payload["per_goal"]:
        runs = []
        for run in goal["runs"]:
            refs = run["reference_returns"]
            steps, returns = np.array([c[0] for c in run["eval_curve"]]), np.array([c[1] for c in run["eval_curve"]])
            runs.append((returns - refs["uniform"]) / (refs["expert"] - refs["uniform"]))
        per_goal.append(np.mean(runs, axis=0))
    stats = [mean_sem(np.array(column)) for column in np.stack(per_goal).T]
    return steps / horizon, np.array([m for m, _ in stats]), np.array([s for _, s in stats])


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scratch", type=Path, help="a JSON of `icprl baseline sac`")
    parser.add_argument("--zero-shot", type=Path, default=None, help="a results JSON of icprl evaluate")
    parser.add_argument("--quality", default="medium")
    parser.add_argument("--out", type=Path, default=Path("docs/results/sac_from_scratch/sac_from_scratch_curve"))
    ns = parser.parse_args(args)
    from matplotlib.figure import Figure

    payload = json.loads(ns.scratch.read_text())
    episodes, mean, sem = curve(payload)
    fig = Figure(figsize=(6, 3.6), layout="tight")
    ax = fig.subplots()
    ax.plot(episodes, mean, color="k", label=f"SAC from scratch ({len(payload['per_goal'])} held-out goals)")
    ax.fill_between(episodes, mean - sem, mean + sem, color="k", alpha=0.15)
    if ns.zero_shot is not None:
        results = json.loads(ns.zero_shot.read_text())["results"]
        for i, (name, row) in enumerate(results.items()):
            value = row.get(ns.quality, {}).get("normalized_return")
            if value is None or "from scratch" in name or name in ("expert", "optimal"):
                continue
            reached = episodes[np.argmax(mean >= value)] if np.any(mean >= value) else None
            ax.axhline(value, color=f"C{i}", linestyle="--", linewidth=1, label=f"{name} ({ns.quality} context)")
            print(f"{name}: zero-shot {value:.2f}; SAC from scratch reaches it "
                  + (f"after {reached:.0f} episodes" if reached is not None else f"in none of its {episodes[-1]:.0f}"))
    ax.set_xlabel("training episodes per goal (150 steps each)")
    ax.set_ylabel("normalized return (evaluation)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Meta-World Reach, held-out goals: online SAC vs in-context zero-shot", fontsize=9)
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(ns.out.with_suffix(".png"), dpi=120)
    print(f"final mean {mean[-1]:.2f} ± {sem[-1]:.2f} after {episodes[-1]:.0f} episodes "
          f"-> {ns.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
