"""An I-PRL model deployed online on held-out MDP tasks: it asks for preferences as it acts. Prints JSON.

    python scripts/online_mdp.py --config configs/icpo_darkroom.yaml \
        --ckpt runs/reproduce/darkroom_ipref/runs/ICPO-seed0/version_0/checkpoints/last.ckpt [--ckpt ...] \
        [--episodes 5] [--rule action_uniform --rule top_two ...] [--labels own|flipped|random] [--seeds 0 1] \
        [--dqn docs/results/dqn_from_scratch_darkroom.json] [--figure PNG]

The agent (``online.OnlineAgent``) starts every held-out task from an empty context and plays
``--episodes`` episodes in a row, its context carried over from one episode to the next. In each, at
``max_context / episodes`` steps spread evenly over the horizon it proposes a pair at its current state
by the pair rule (``--rule``, ``online.PAIR_RULES``), the dataset's own annotator answers it from the
oracle's A*(s_h, ·) (the config's ``setting.annotator``; the paper's Bradley–Terry oracle by default:
EQUAL/SKIP answers become coins as in data generation), and the answered comparison enters the KV cache
as one token; at every step it acts greedily (or as the checkpoint's default) on the comparisons so far.
A final episode without queries measures the policy of the full online context. The privileged oracle
state is read only to answer the queries (the annotator's side), never by the agent.

Beside it, on the same tasks and episode seeds:

* **offline**: the same checkpoint deployed on the dataset's fixed offline contexts (``Agent`` +
  ``evaluation.rollout``), one row per context quality, with the behavior and optimal returns;
* **DQN from scratch** (``--dqn``, from ``python -m icprl_lightning.baselines.dqn_from_scratch``): its
  greedy evaluation return after 5, 10, 20, 50 and 100 training episodes per goal (its ``eval_curve``);
* ``--labels flipped`` / ``random``: the online label diagnostic (the annotator's answers inverted, or
  replaced by fair coins, before the agent sees them).

Returns are averaged per task, then mean ± sem over tasks for one checkpoint, and mean ± sem over
checkpoints (training seeds) in ``mean``. ``episodes_to_reach[target]``: the first online episode whose
mean return is at least the target (``--targets``; default the offline rows' returns), and the queries
answered by that episode's end. DarkRoom is what we measured; any family whose oracle has ``utility`` runs.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from icprl_lightning.annotators.base import StepQueries
from icprl_lightning.annotators.labels import stored_labels
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.rollout import rollout_seeds
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.metrics import mean_sem, mean_sem_or_none, per_task_mean
from icprl_lightning.online import PAIR_RULES, OnlineAgent

LABELS = ("own", "flipped", "random")
DQN_EPISODES = (5, 10, 20, 50, 100)


def query_steps(horizon: int, queries: int) -> np.ndarray:
    """``queries`` steps of an episode, spread evenly over ``horizon`` (the first at step 0)."""
    if not 0 <= queries <= horizon:
        raise ValueError(f"queries per episode must be in [0, {horizon}], got {queries}")
    return np.unique(np.floor(np.arange(queries) * horizon / max(queries, 1)).astype(int))[:queries]


def online_episodes(agent: OnlineAgent, family, suite, annotator, episodes: int, seed: int, labels: str = "own"
                    ) -> dict[str, np.ndarray]:
    """``episodes`` querying episodes and one final episode without queries: returns ``[episodes + 1, B]``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    counts: dict[str, int] = {}
    per_episode = agent.policy.transformer.max_context // episodes
    asks = set(query_steps(suite.horizon, per_episode).tolist())
    env = suite.make_env()
    returns, lengths = [], []
    try:
        b = env.num_envs
        tasks = np.asarray(env.goals) if hasattr(env, "goals") else None  # what the annotator may read of the task
        agent.reset(b)
        for episode in range(episodes + 1):
            obs, _ = env.reset(seed=seed * 1000 + episode)
            total = np.zeros(b)
            for h in range(suite.horizon):
                obs_t = torch.as_tensor(obs, dtype=torch.float32)
                if episode < episodes and h in asks:
                    first, second = agent.propose(obs_t)
                    both = np.stack([first.cpu().numpy(), second.cpu().numpy()])
                    u = family.oracle.utility(env.oracle_state(), both)
                    queries = StepQueries(np.asarray(obs, dtype=np.float32), both[0], both[1], u[0], u[1], tasks)
                    y = stored_labels(annotator.label_steps(queries, rng), b, type(annotator).__name__, rng, counts)
                    if labels == "flipped":
                        y = 1 - y
                    elif labels == "random":
                        y = (rng.random(b) < 0.5).astype(np.uint8)
                    agent.observe(obs_t, first, second, torch.from_numpy(y.astype(np.int64)))
                obs, reward, terminated, truncated, _ = env.step(agent.act(obs_t).cpu().numpy())
                total += reward
                if np.all(terminated | truncated):
                    break
            returns.append(total)
            lengths.append(agent.length)
    finally:
        if hasattr(env, "close"):
            env.close()
    return {"return": np.stack(returns), "context_length": np.array(lengths), **counts}


def task_stats(values: np.ndarray, task_index: np.ndarray) -> tuple[float, float]:
    """Mean ± sem over tasks of per-task means (episodes [N] aligned with ``task_index``)."""
    return mean_sem(per_task_mean(values, task_index))


def over_seeds(values: list[float]) -> dict[str, float | None]:
    mean, sem = mean_sem_or_none(values)
    return {"return": mean, "return_sem": sem, "per_seed": values}


def dqn_curve(path: Path) -> dict[str, float]:
    """DQN-from-scratch's mean greedy evaluation return after N training episodes per goal (over goals × seeds)."""
    data = json.loads(path.read_text())
    horizon = data["horizon"]
    curves = [run["eval_curve"] for goal in data["per_goal"] for run in goal["runs"]]
    out = {}
    for n in DQN_EPISODES:
        at = [next((ret for step, ret, *_ in curve if step == n * horizon), None) for curve in curves]
        if all(v is not None for v in at):
            out[str(n)] = float(np.mean(at))
    return out


def figure(out: dict, path: Path) -> None:
    """Return per online episode (queries so far on the x axis), offline rows and DQN as horizontal lines."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 3.8), layout="tight")
    ax = fig.subplots()
    for i, (rule, result) in enumerate(out["online"].items()):
        x = result["queries_before_episode"]
        y = [e["return"] for e in result["mean"]]
        err = [e["return_sem"] or 0.0 for e in result["mean"]]
        ax.errorbar(x, y, yerr=err, color=f"C{i}", marker=".", capsize=2, label=f"online, {rule} pairs")
    for j, (quality, row) in enumerate(out["offline"].items()):
        ax.axhline(row["return"], color=f"C{j + 4}", linestyle=":", linewidth=1,
                   label=f"offline {quality} context (100 comparisons)")
    ref = next(iter(out["offline"].values()), {})
    if "optimal_return" in ref:
        ax.axhline(ref["optimal_return"], color="k", linewidth=0.8, label="optimal")
    for n, value in out.get("dqn_from_scratch", {}).items():
        if n in ("10", "100"):  # after 5 episodes DQN is as low as after 10
            ax.axhline(value, color="grey", linestyle="--", linewidth=0.8)
            ax.annotate(f"DQN, {n} episodes", (0, value), fontsize=6, color="grey", va="bottom")
    ax.set_xlabel("answered queries before the episode (the last point: no queries in that episode)")
    ax.set_ylabel("return of the episode")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    ax.set_title(f"online I-PRL on {out['tasks']} held-out tasks, labels: {out['labels']} "
                 f"({len(out['checkpoints'])} training seeds, mean ± sem)", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", action="append", required=True, help="the checkpoints' dataset config(s)")
    parser.add_argument("--ckpt", action="append", required=True, help="an I-PRL checkpoint (repeat: training seeds)")
    parser.add_argument("--episodes", type=int, default=5, help="querying episodes (max_context / episodes each)")
    parser.add_argument("--rule", action="append", choices=sorted(PAIR_RULES), default=None,
                        help="the pair rule (repeat to compare; default action_uniform)")
    parser.add_argument("--labels", choices=LABELS, default="own", help="the online label diagnostic")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="episode seeds")
    parser.add_argument("--quality", default="medium", help="the suite whose tasks and episodes are used online")
    parser.add_argument("--targets", type=float, nargs="*", default=None,
                        help="returns to reach (default: the offline rows')")
    parser.add_argument("--dqn", type=Path, default=None, help="a dqn_from_scratch JSON for its learning curve")
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    started = time.perf_counter()
    dm = datamodule_from_config(*args.config, progress=False)
    dm.prepare_data()
    dm.setup("validate")
    family, annotator = dm.family, dm.setting.annotator
    if not isinstance(family, TaskFamily):
        parser.error(f"{type(family).__name__} is not an MDP family (families/base.TaskFamily): no oracle to "
                     "answer queries at states (dueling bandits: scripts/online_bandit.py)")
    loaded = {ckpt: OnlineAgent.load(ckpt) for ckpt in args.ckpt}  # read once; each seed below reuses the policy
    max_context = {a.policy.transformer.max_context for a in loaded.values()}
    if len(max_context) != 1:
        parser.error(f"the checkpoints' max_context differ ({sorted(max_context)}): one query budget needs one")
    per_episode = max_context.pop() // args.episodes
    suites = {s.quality: s for s in dm.evaluation_suites()}
    if args.quality not in suites:
        parser.error(f"--quality must be one of {sorted(suites)}, got {args.quality!r}")
    suite = suites[args.quality]
    rules = args.rule or ["action_uniform"]

    offline: dict[str, dict] = {}
    for quality, s in suites.items():
        per_ckpt = [task_stats(rollout_seeds(lambda seed, c=c: load_agent(c, seed=seed), s, args.seeds)["return"],
                               np.tile(s.task_index, len(args.seeds)))[0] for c in args.ckpt]
        offline[quality] = {**over_seeds(per_ckpt), **s.reference}
    targets = args.targets if args.targets is not None else [round(r["return"], 1) for r in offline.values()]

    online: dict[str, dict] = {}
    for rule in rules:
        per_ckpt, answers = [], {}
        for ckpt in args.ckpt:
            episodes = []
            for seed in args.seeds:
                probe = loaded[ckpt]
                agent = OnlineAgent(probe.policy, greedy=probe.greedy, seed=seed, pair_rule=PAIR_RULES[rule]())
                result = online_episodes(agent, family, suite, annotator, args.episodes, seed, args.labels)
                episodes.append(result["return"])
                for key in ("skip_count", "equal_count"):
                    answers[key] = answers.get(key, 0) + result.get(key, 0)
            joined = np.concatenate(episodes, axis=1)  # [E + 1, seeds · B]
            per_ckpt.append([task_stats(e, np.tile(suite.task_index, len(args.seeds)))[0] for e in joined])
        means = [over_seeds([c[e] for c in per_ckpt]) for e in range(args.episodes + 1)]
        queries = [e * per_episode for e in range(args.episodes + 1)]
        reach = {}
        for target in targets:
            hit = next((e for e, m in enumerate(means) if m["return"] >= target), None)
            # the return of querying episode e depends on the queries answered up to its end
            reach[str(target)] = None if hit is None else {
                "episode": hit + 1,
                "queries_by_episode_end": queries[hit] + (per_episode if hit < args.episodes else 0)}
        online[rule] = {"mean": means, "queries_before_episode": queries, "queries_per_episode": per_episode,
                        "episodes_to_reach": reach, "annotator_answers": answers}
    tasks = len(np.unique(suite.task_index))
    out = {"checkpoints": args.ckpt, "configs": args.config, "dataset": str(dm.path), "tasks": tasks,
           "episodes_per_task": len(suite.task_index) // tasks * len(args.seeds), "seeds": args.seeds,
           "labels": args.labels,
           "annotator": annotator.config(), "online": online, "offline": offline, "targets": targets}
    if args.dqn is not None:
        out["dqn_from_scratch"] = dqn_curve(args.dqn)
    out["seconds"] = round(time.perf_counter() - started, 1)
    if args.figure:
        figure(out, args.figure)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
