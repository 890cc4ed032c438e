"""Question: Where does a Meta-World Reach policy's action point, and does an ICPO trained with aligned pairs read its
context's length as a clock?

Asked: 2026-12-02 (the first commit of this investigation, then scripts/reach_action_probe.py).

Answer (docs/RESULTS.md, "Meta-World Reach I-PRL on the paper's recipe" (ICPO's clock)):
Yes. With its whole context (150 comparisons, as deployed) the aligned-pairs ICPO ends farther from
the goal than it started (final distance 0.31 / 0.38 / 0.46 from 0.28; mean y-action −0.02 / −0.09 / −0.22,
the goals lie in +y); cut to its first 25 comparisons the same weights push towards +y (+0.73 to +0.98) and end
at 0.12–0.14. ICPO with shuffled pairs (``pair_steps: shuffled``, now the default) ends at 0.04–0.07.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

Where does a Reach policy's action point? A trained checkpoint's held-out actions against the goal direction.

For a checkpoint trained on Meta-World Reach, deploys it on the held-out suites of its config (one episode
per context, every context quality) and records, at every step, its action a and the privileged state (tcp,
goal). Prints per quality:

* ``cos_to_goal``: mean cosine between a's xyz part and goal − tcp (1: straight at the goal; a uniform
  action gives 0);
* ``saturated``: share of xyz components with |a| > 0.99 (a tanh mean stuck on the box edge);
* ``mean_action``: the mean action per dimension (a state-independent drift shows here);
* ``final_distance`` vs ``start_distance``: tcp-to-goal distance at the first and the last step;
* with ``--oracle``: ``cos_to_oracle``, the cosine between a's xyz and the family oracle's optimal action at
  the same states (the SAC policy's mean action on the paper's recipe, the scripted expert's otherwise); the
  same statistics for the oracle's own action are the ``oracle_*`` keys.

``--context-steps K`` deploys with each context cut to its first K comparisons: a model that reads the context's
length as a clock (ICPO trained with ``pair_steps: aligned``) acts differently with a short context.

Evaluation-only: the probe reads the goal to score actions, the policy never sees it.

    python experiments/reach_action_probe.py runs/.../checkpoints/last.ckpt --config configs/icpo_metaworld.yaml \\
        [--oracle] [--context-steps 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
import torch

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.deploy import load_agent


def _cos(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-9)


@torch.no_grad()
def probe_suite(agent, suite, seed: int, oracle=None) -> dict[str, object]:
    """Roll out one episode per context of ``suite``, recording actions and the privileged state."""
    env = suite.make_env()
    actions, to_goal, oracle_actions, distances = [], [], [], []
    try:
        obs, _ = env.reset(seed=seed)
        agent.reset(suite.context)
        for _ in range(suite.horizon):
            state = env.oracle_state()
            a = agent.act(torch.as_tensor(obs, dtype=torch.float32)).cpu().numpy()
            actions.append(a)
            to_goal.append(state.goal - state.tcp)
            distances.append(np.linalg.norm(state.goal - state.tcp, axis=-1))
            if oracle is not None:
                oracle_actions.append(oracle.optimal_actions(state))
            obs, *_ = env.step(a)
    finally:
        env.close()
    a, g = np.stack(actions), np.stack(to_goal)  # [T, B, 4], [T, B, 3]
    out: dict[str, object] = {
        "cos_to_goal": float(_cos(a[..., :3], g).mean()),
        "saturated": float((np.abs(a[..., :3]) > 0.99).mean()),
        "mean_action": np.round(a.reshape(-1, a.shape[-1]).mean(0), 3).tolist(),
        "start_distance": float(distances[0].mean()), "final_distance": float(distances[-1].mean())}
    if oracle is not None:
        o = np.stack(oracle_actions)
        out.update({"cos_to_oracle": float(_cos(a[..., :3], o[..., :3]).mean()),
                    "oracle_cos_to_goal": float(_cos(o[..., :3], g).mean()),
                    "oracle_saturated": float((np.abs(o[..., :3]) > 0.99).mean()),
                    "oracle_mean_action": np.round(o.reshape(-1, o.shape[-1]).mean(0), 3).tolist()})
    return out


def main(argv: list[str] | None = None) -> dict[str, dict[str, object]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--config", action="append", required=True, help="the run's config files, in order")
    parser.add_argument("--oracle", action="store_true", help="also score against the family oracle's optimal actions")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sample", action="store_true", help="sampled actions (default: greedy)")
    parser.add_argument("--context-steps", type=int, help="cut every context to its first K comparisons")
    ns = parser.parse_args(argv)
    dm = datamodule_from_config(*ns.config)
    dm.prepare_data()
    oracle = dm.family.oracle if ns.oracle else None
    suites = dm.held_out("rollouts")
    if ns.context_steps is not None:
        suites = [dataclasses.replace(s, context=s.context.map(lambda x: x[:, :ns.context_steps])) for s in suites]
    result = {suite.quality: probe_suite(load_agent(ns.checkpoint, greedy=not ns.sample, seed=ns.seed), suite,
                                         ns.seed, oracle)
              for suite in suites}
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
