"""An I-PRL model deployed online on an MDP family's held-out tasks: it asks for preferences as it acts.

The agent (``online.OnlineAgent``) starts every held-out task from an empty context and plays ``episodes``
episodes in a row, its context carried over from one episode to the next. In each, at ``max_context /
episodes`` steps spread evenly over the horizon (``query_steps``) it proposes a pair at its current state by
its pair rule (``online.PAIR_RULES``); the dataset's own annotator answers it from the oracle's A*(s_h, ·)
(the setting's ``annotator``; the paper's Bradley–Terry oracle by default: EQUAL/SKIP answers become coins
as in data generation), and the answered comparison enters the KV cache as one token. At every step it acts
greedily (or as the checkpoint's default) on the comparisons so far. A final episode without queries
measures the policy of the full online context. The privileged oracle state is read only to answer the
queries (the annotator's side), never by the agent.

Beside it, on the same tasks and episode seeds (``evaluate_online_mdp``):

* **offline**: the same checkpoints deployed on the dataset's fixed offline contexts (``load_agent`` +
  ``evaluation.rollout``), one row per context quality, with the behavior and optimal returns;
* **DQN from scratch** (a JSON of ``icprl baseline dqn``): its greedy evaluation return after 5, 10, 20, 50
  and 100 training episodes per goal (its ``eval_curve``);
* ``labels="flipped"`` / ``"random"``: the online label diagnostic (the annotator's answers inverted, or
  replaced by fair coins, before the agent sees them), the online counterpart of the offline
  ``flipped_labels`` / ``random_labels`` contexts.

Returns are averaged per task, then mean ± sem over tasks for one checkpoint, and mean ± sem over
checkpoints (training seeds) in ``mean``. ``episodes_to_reach[target]``: the first online episode whose
mean return is at least the target (default: the offline rows' returns), and the queries answered by that
episode's end. Any family whose oracle has ``utility`` runs.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from icprl_lightning.annotators.base import Annotator, StepQueries
from icprl_lightning.annotators.labels import stored_labels
from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.base import HeldOutEvaluation, Run
from icprl_lightning.evaluation.rollout import rollout_seeds
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.io import save_figure
from icprl_lightning.metrics import mean_sem, mean_sem_or_none, per_task_mean
from icprl_lightning.online import PAIR_RULES, OnlineAgent
from icprl_lightning.untrusted import read_json

LABELS = ("own", "flipped", "random")
DQN_EPISODES = (5, 10, 20, 50, 100)


def query_steps(horizon: int, queries: int) -> np.ndarray:
    """``queries`` steps of an episode, spread evenly over ``horizon`` (the first at step 0)."""
    if not 0 <= queries <= horizon:
        raise ValueError(f"queries per episode must be in [0, {horizon}], got {queries}")
    return np.unique(np.floor(np.arange(queries) * horizon / max(queries, 1)).astype(int))[:queries]


def online_episodes(agent: OnlineAgent, family: TaskFamily, suite: EvalSuite, annotator: Annotator, episodes: int,
                    seed: int, labels: str = "own") -> dict[str, np.ndarray]:
    """``episodes`` querying episodes and one final episode without queries: returns ``[episodes + 1, B]``."""
    if labels not in LABELS:
        raise ValueError(f"labels must be one of {', '.join(LABELS)}, got {labels!r}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    counts: dict[str, int] = {}
    per_episode = agent.policy.transformer.max_context // episodes
    asks = set(query_steps(suite.horizon, per_episode).tolist())
    env = suite.make_env()
    watch = getattr(annotator, "watch", None)  # an annotator that shows a person the episode (BrowserAnnotator)
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
                if watch is not None:
                    watch(obs, total, h)
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


def over_seeds(values: list[float]) -> dict[str, Any]:
    """Mean ± sem of one number over training seeds, and the seeds' values (sem ``None`` for one seed)."""
    mean, sem = mean_sem_or_none(values)
    return {"return": mean, "return_sem": sem, "per_seed": values}


def dqn_curve(path: str | Path) -> dict[str, float]:
    """DQN-from-scratch's mean greedy evaluation return after N training episodes per goal (over goals × seeds)."""
    try:
        data = read_json(path, "`icprl baseline dqn` result")
        horizon = data["horizon"]
        curves = [run["eval_curve"] for goal in data["per_goal"] for run in goal["runs"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"--dqn {path}: not a JSON of `icprl baseline dqn` ({type(e).__name__}: {e})") from None
    out = {}
    for n in DQN_EPISODES:
        at = [next((ret for step, ret, *_ in curve if step == n * horizon), None) for curve in curves]
        if all(v is not None for v in at):
            out[str(n)] = float(np.mean(at))
    return out


def evaluate_online_mdp(dm: Any, checkpoints: Sequence[str], rules: Sequence[str] = ("action_uniform",),
                        labels: str = "own", seeds: Sequence[int] = (0, 1), episodes: int = 5,
                        quality: str = "medium", targets: Sequence[float] | None = None,
                        dqn: str | Path | None = None, annotator: Annotator | None = None) -> dict[str, Any]:
    """Online rows per pair rule beside the offline rows of the same checkpoints, on ``dm``'s held-out tasks.

    ``dm`` is a prepared and set-up DataModule of a ``TaskFamily``; the online tasks and episodes are those of
    its ``quality`` suite; ``annotator`` answers the queries (default: the dataset's). Returns the JSON-ready
    result (module docstring).
    """
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    if labels not in LABELS:
        raise ValueError(f"--labels must be one of {', '.join(LABELS)}, got {labels!r}")
    unknown = sorted(set(rules) - set(PAIR_RULES))
    if unknown:
        raise ValueError(f"--rule {unknown[0]!r} is not a pair rule; choose from {', '.join(sorted(PAIR_RULES))}")
    family, annotator = dm.family, annotator or dm.setting.annotator
    started = time.perf_counter()
    loaded = {c: OnlineAgent.load(c) for c in checkpoints}  # read once; each seed below reuses the policy
    max_context = {a.policy.transformer.max_context for a in loaded.values()}
    if len(max_context) != 1:
        raise ValueError(f"the checkpoints' max_context differ ({sorted(max_context)}): one query budget needs one")
    per_episode = max_context.pop() // episodes
    suites = {s.quality: s for s in dm.held_out("rollouts")}
    if quality not in suites:
        raise ValueError(f"--quality must be one of {', '.join(suites)}, got {quality!r}")
    suite = suites[quality]

    offline: dict[str, dict] = {}
    for name, s in suites.items():
        per_ckpt = [task_stats(rollout_seeds(lambda seed, c=c: load_agent(c, seed=seed), s, seeds)["return"],
                               np.tile(s.task_index, len(seeds)))[0] for c in checkpoints]
        offline[name] = {**over_seeds(per_ckpt), **s.reference}
    targets = list(targets) if targets is not None else [round(r["return"], 1) for r in offline.values()]

    online: dict[str, dict] = {}
    for rule in rules:
        per_ckpt, answers = [], {}
        for checkpoint in checkpoints:
            played = []
            for seed in seeds:
                probe = loaded[checkpoint]
                agent = OnlineAgent(probe.policy, greedy=probe.greedy, seed=seed, pair_rule=PAIR_RULES[rule]())
                result = online_episodes(agent, family, suite, annotator, episodes, seed, labels)
                played.append(result["return"])
                for key in ("skip_count", "equal_count"):
                    answers[key] = answers.get(key, 0) + result.get(key, 0)
            joined = np.concatenate(played, axis=1)  # [E + 1, seeds · B]
            per_ckpt.append([task_stats(e, np.tile(suite.task_index, len(seeds)))[0] for e in joined])
        means = [over_seeds([c[e] for c in per_ckpt]) for e in range(episodes + 1)]
        queries = [e * per_episode for e in range(episodes + 1)]
        reach = {}
        for target in targets:
            hit = next((e for e, m in enumerate(means) if m["return"] >= target), None)
            # the return of querying episode e depends on the queries answered up to its end
            reach[str(target)] = None if hit is None else {
                "episode": hit + 1, "queries_by_episode_end": queries[hit] + (per_episode if hit < episodes else 0)}
        online[rule] = {"mean": means, "queries_before_episode": queries, "queries_per_episode": per_episode,
                        "episodes_to_reach": reach, "annotator_answers": answers}
    tasks = len(np.unique(suite.task_index))
    out = {"checkpoints": list(checkpoints), "dataset": str(dm.path), "tasks": tasks,
           "episodes_per_task": len(suite.task_index) // tasks * len(seeds), "seeds": list(seeds), "labels": labels,
           "annotator": annotator.config(), "online": online, "offline": offline, "targets": targets}
    if dqn is not None:
        out["dqn_from_scratch"] = dqn_curve(dqn)
    out["seconds"] = round(time.perf_counter() - started, 1)
    return out


def online_mdp_figure(out: dict[str, Any], path: str | Path) -> None:
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
                   label=f"offline {quality} context")
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
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=120)


def online_mdp_markdown(out: dict[str, Any]) -> str:
    """The table of an online MDP evaluation: per pair rule, the return of each episode (mean ± sem over training
    seeds) after the queries answered before it, beside the offline contexts' and the optimal return."""
    rules = list(out["online"])
    first = out["online"][rules[0]]
    lines = [f"Online I-PRL on {out['tasks']} held-out tasks, labels {out['labels']}, {len(out['checkpoints'])} "
             "training seeds (mean ± sem over them):", "",
             "| queries answered before the episode | " + " | ".join(f"{r} pairs" for r in rules) + " |",
             "|---|" + "---|" * len(rules)]
    for i, queries in enumerate(first["queries_before_episode"]):
        cells = [f"{out['online'][r]['mean'][i]['return']:.1f} ± {out['online'][r]['mean'][i]['return_sem'] or 0:.1f}"
                 for r in rules]
        lines.append(f"| {queries} | " + " | ".join(cells) + " |")
    lines.append("")
    for quality, row in out["offline"].items():
        optimal = f"; optimal {row['optimal_return']:.1f}" if "optimal_return" in row else ""
        lines.append(f"Offline {quality} context: {row['return']:.1f} ± {row['return_sem']:.1f} (behavior "
                     f"{row['behavior_return']:.1f}{optimal}).")
    return "\n".join(lines) + "\n"


class OnlineMDP(HeldOutEvaluation):
    """An MDP family's held-out tasks played online (the module docstring), one run's checkpoints (its training
    seeds); the options are ``icprl evaluate online``'s: ``rules``, ``labels``, ``episodes``, ``quality``,
    ``targets`` and ``dqn``."""

    name: ClassVar[str] = "online"

    def __init__(self, rules: Sequence[str] = ("action_uniform",), labels: str = "own", episodes: int = 5,
                 quality: str = "medium", targets: Sequence[float] | None = None, dqn: str | None = None) -> None:
        self.options = {"rules": list(rules), "labels": labels, "episodes": episodes, "quality": quality,
                        "targets": targets, "dqn": dqn}

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        return super().recognizes(payload) or {"online", "offline", "checkpoints"} <= set(payload)

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        if len(runs) != 1:
            raise ValueError(f"the online evaluation plays one run (its checkpoints: training seeds), got {len(runs)}")
        (run,) = runs
        run.data.setup("validate")
        return {"configs": [run.config], **evaluate_online_mdp(run.data, run.checkpoints, seeds=seeds, **self.options)}

    markdown = staticmethod(online_mdp_markdown)
    figure = staticmethod(online_mdp_figure)
