"""The figures of ``icprl reproduce`` beyond ``icprl evaluate``'s own: held-out return during training for
every table, and the table-specific ones named by ``Table.figure`` (``FIGURES``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from icprl_lightning.evaluation.report import figure_title
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.io import save_figure
from icprl_lightning.reproduce.tables import Table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

BETA, LAMBDA = "model.init_args.beta", "model.init_args.lam"
EPSILON = "data.init_args.setting.init_args.annotator.init_args.epsilon"


def lambda_beta_figure(table: Table, out_dir: Path) -> None:
    """Return vs λ, one line per β, greedy (solid) and sampled (dashed), one panel per context quality: each run
    is the point of the β and λ its overrides set."""
    from matplotlib.figure import Figure

    grid = {(run.setting(BETA), run.setting(LAMBDA)): run.name for run in table.runs}
    betas = list(dict.fromkeys(beta for beta, _ in grid))
    lambdas = sorted({lam for _, lam in grid}, key=float)
    payloads = {e.suffix: json.loads((out_dir / f"{table.name}{e.suffix}.json").read_text()) for e in table.evaluations}
    qualities = ("low", "medium", "high")
    fig = Figure(figsize=(12, 3.4), layout="tight")
    axes = fig.subplots(1, len(qualities), sharey=True)
    for ax, quality in zip(axes, qualities, strict=True):
        for i, beta in enumerate(betas):
            for suffix, style in (("", "-"), ("_sampled", "--")):
                rows = [payloads[suffix]["results"][grid[beta, lam]][quality] for lam in lambdas]
                ax.errorbar([float(lam) for lam in lambdas], [r["return"] for r in rows],
                            yerr=[r.get("return_sem", 0.0) for r in rows], color=f"C{i}", linestyle=style,
                            marker=".", capsize=2,
                            label=f"β = {beta}, {'greedy' if suffix == '' else 'sampled'}")
        ax.set_title(f"{quality} contexts", fontsize=9)
        ax.set_xlabel("λ")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("held-out return")
    axes[-1].legend(fontsize=6, bbox_to_anchor=(1.02, 1), loc="upper left")
    fig.suptitle(figure_title(f"{table.title} (corners: 3 training seeds, mean ± sem over seeds; others: 1 seed, "
                              "± sem over held-out goals)", fig.get_figwidth()), fontsize=9)
    save_figure(fig, out_dir / f"{table.name}.png", dpi=120)


def teacher_noise_figure(table: Table, out_dir: Path) -> None:
    """The held-out metric vs the teacher's mistake rate, one line per context source (bandits: weak regret,
    DTS dashed) or per context quality (DarkRoom: greedy return, behavior dashed): each run is the point of the
    mistake rate its overrides give the teacher."""
    from matplotlib.figure import Figure

    results = json.loads((out_dir / f"{table.name}.json").read_text())["results"]
    runs = sorted(((float(run.setting(EPSILON)), run.name) for run in table.runs), key=lambda r: r[0])
    sources = list(results[runs[0][1]])
    metric = "weak_regret" if "weak_regret" in results[runs[0][1]][sources[0]] else "return"
    reference = "dts" if metric == "weak_regret" else "behavior"
    fig = Figure(figsize=(5.5, 3.6), layout="tight")
    ax = fig.subplots()
    eps = [e for e, _ in runs]
    for i, source in enumerate(sources):
        rows = [results[name][source] for _, name in runs]
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
    save_figure(fig, out_dir / f"{table.name}_vs_noise.png", dpi=120)


def read_ceiling(path: str | Path) -> dict[str, float]:
    """The held-out return a Bayes-optimal reader of the whole context reaches (``CEILING_READER``), per context
    quality, from the JSON of ``icprl analyze label-ceiling``; ``ValueError`` naming what is missing when the file is
    not one."""
    from icprl_lightning.evaluation.label_ceiling import CEILING, CEILING_READER

    try:
        payload = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not JSON ({e})") from None
    rows = {q: payload[q].get(CEILING_READER) for q in QUALITIES
            if isinstance(payload, dict) and isinstance(payload.get(q), dict)}
    ceiling = {q: row[CEILING] for q, row in rows.items() if isinstance(row, dict) and CEILING in row}
    if not ceiling or not all(isinstance(v, int | float) for v in ceiling.values()):
        raise ValueError(f"{path} holds no numeric {CEILING_READER}.{CEILING} for any quality "
                         f"({', '.join(QUALITIES)}): write it with `icprl analyze label-ceiling`")
    return ceiling


def curve_figure(table: Table, curves: dict[str, dict[str, list]], path: Path) -> Figure | None:
    """Held-out return vs optimizer steps, one panel per quality, one line per run (each training seed thin); a
    second row vs training seconds (``TrainingClock``) when the fits logged them; with the table's ``ceiling``, the
    Bayes-optimal reader's return of each quality as a dashed line. Returns the figure (``None``: no curves)."""
    from matplotlib.figure import Figure

    ceiling = read_ceiling(table.ceiling) if table.ceiling else {}

    axes_keys = ("step", "train_seconds")
    found = {k for per in curves.values() for c in per.values() for p in c for k in p if k not in axes_keys}
    qualities = [q for q in QUALITIES if q in found] + sorted(found - set(QUALITIES))
    if not qualities:
        return
    timed = any("train_seconds" in p for per in curves.values() for c in per.values() for p in c)
    x_axes = [("step", "optimizer steps")] + ([("train_seconds", "training seconds (no validation)")] if timed else [])
    fig = Figure(figsize=(3.6 * len(qualities) + 1.5, 3.2 * len(x_axes)), layout="tight")
    grid = fig.subplots(len(x_axes), len(qualities), sharey=True, squeeze=False)
    for axes, (x_key, x_label) in zip(grid, x_axes, strict=True):
        for ax, quality in zip(axes, qualities, strict=True):
            for i, (name, per_seed) in enumerate(curves.items()):
                color = f"C{i}"
                for j, curve in enumerate(per_seed.values()):
                    points = [(p[x_key], p[quality]) for p in curve if quality in p and x_key in p]
                    if points:
                        ax.plot(*zip(*points, strict=True), color=color, alpha=0.8, marker=".",
                                label=name if j == 0 else None)
            if quality in ceiling:
                ax.axhline(ceiling[quality], color="black", linestyle="--", linewidth=1,
                           label="Bayes-optimal reader of the context")
            ax.set_title(f"{quality} contexts", fontsize=9)
            ax.set_xlabel(x_label)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("held-out return (rollout callback)")
    grid[0][-1].legend(fontsize=7)
    fig.suptitle(figure_title(f"{table.title}: return during training, one line per training seed",
                              fig.get_figwidth()), fontsize=9)
    save_figure(fig, path, dpi=120)
    return fig


FIGURES = {"lambda_beta": lambda_beta_figure, "teacher_noise": teacher_noise_figure}
