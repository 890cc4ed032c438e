"""``icprl report RUN_DIR``: a run's learning curves and last held-out results, offline, from its CSV metrics.

    icprl report runs/icprl/<run id>            # prints the report, writes <run>/curves.png
    icprl report runs/icprl/<run id> --figure out.png

Reads ``<run>/csv/metrics.csv`` (``callbacks/run_logs.py``; ``<run>/metrics.csv`` when the first logger is a
``CSVLogger``) and prints per metric its first, last and best value and step (best: lowest for losses, regrets
and errors, ``lower_is_better``), then the last held-out tables (``evaluation.report``: rollouts per quality
with the behavior and optimal/expert rows, the bandits' weak regret). Draws the curves with matplotlib's
``Figure`` (Agg; no display): held-out return per quality (behavior dashed) against optimizer steps and
against training seconds, the losses, then the other metrics, one panel per kind.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.table import Table

from icprl_lightning.evaluation.report import regret_table, results_table
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.io import save_figure

FIGURE_NAME = "curves.png"
MAX_PANELS = 12
REFERENCE = re.compile(r"(^|/)(behavior|optimal|expert)_")  # the dataset's constant references, not curves
ROLLOUT_KEYS = ("return", "normalized_return", "success", "behavior_return", "behavior_normalized_return",
                "behavior_success", "optimal_return", "expert_return", "expert_success")
REGRET_KEYS = ("weak_regret", "weak_regret_auc")
FIRST_PANELS = ("loss", "normalized_return", "return", "success", "weak_regret")


@dataclass
class Point:
    step: int
    epoch: int | None
    value: float

    def when(self) -> str:
        return f"step {self.step}" + ("" if self.epoch is None else f" (epoch {self.epoch})")


Curves = dict[str, list[Point]]


def find_metrics(run: Path) -> Path:
    """The run's ``metrics.csv``: ``run`` itself if it is the file, else ``<run>/metrics.csv``, else
    ``<run>/csv/metrics.csv``, else the only one under ``run``; a ``ValueError`` naming ``run`` otherwise."""
    if run.is_file():
        return run
    if not run.is_dir():
        raise ValueError(f"{run}: no such run directory")
    for candidate in (run / "metrics.csv", run / "csv" / "metrics.csv"):
        if candidate.is_file():
            return candidate
    found = sorted(p for p in run.rglob("metrics.csv") if "wandb" not in p.relative_to(run).parts)
    if len(found) == 1:
        return found[0]
    if found:
        raise ValueError(f"{run}: several metrics.csv ({', '.join(str(p.relative_to(run)) for p in found)}); "
                         "name one of them")
    wandb = " (its W&B files can be uploaded with `wandb sync`)" if (run / "wandb").is_dir() else ""
    raise ValueError(f"{run}: no metrics.csv: the run was logged without a CSV logger{wandb}")


def read_metrics(path: Path) -> Curves:
    """Every metric's logged values in order, from a Lightning ``metrics.csv`` (one row per log call, empty
    cells for metrics not logged in it); a cell that is not a number is a ``ValueError`` naming its line."""
    curves: Curves = {}
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            if not reader.fieldnames or "step" not in reader.fieldnames:
                raise ValueError(f"{path}: not a Lightning metrics.csv (no 'step' column in its header)")
            for line, row in enumerate(reader, start=2):
                try:
                    step = int(float(row["step"]))
                    epoch = int(float(row["epoch"])) if row.get("epoch") else None
                    values = {k: float(v) for k, v in row.items() if k not in ("step", "epoch") and k and v}
                except (TypeError, ValueError, OverflowError):  # OverflowError: a step of inf (1e400)
                    raise ValueError(f"{path}: line {line} holds a value that is not a number (or a step or epoch "
                                     "that is not a finite integer)") from None
                for name, value in values.items():
                    curves.setdefault(name, []).append(Point(step, epoch, value))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    except csv.Error as e:  # a cell over csv's field size limit, a NUL byte, ...
        raise ValueError(f"{path}: not a readable CSV file ({e})") from None
    return curves


def lower_is_better(name: str) -> bool:
    leaf = name.rsplit("/", 1)[-1]
    return any(word in leaf for word in ("loss", "regret", "error"))


def learning_curves(curves: Curves) -> Curves:
    """The metrics worth a curve: no ``*_sem`` and no constant reference."""
    return {name: points for name, points in sorted(curves.items())
            if not name.endswith("_sem") and not REFERENCE.search(name)}


def best_point(name: str, points: list[Point]) -> Point | None:
    """The best logged value (None for the clock's ``time/*``, where no value is better)."""
    if is_clock(name):
        return None
    finite = [p for p in points if math.isfinite(p.value)]
    if not finite:
        return None
    pick = min if lower_is_better(name) else max
    return pick(finite, key=lambda p: p.value)


def curves_table(curves: Curves) -> Table:
    table = Table(title="Learning curves (best: lowest for losses/regrets, else highest)")
    for head in ("metric", "points", "first", "last", "best", "best at"):
        table.add_column(head, justify="left" if head in ("metric", "best at") else "right")
    for name, points in learning_curves(curves).items():
        first, last, best = points[0], points[-1], best_point(name, points)
        table.add_row(name, str(len(points)), f"{first.value:.4g}", f"{last.value:.4g} @ {last.when()}",
                      "" if best is None else f"{best.value:.4g}", "" if best is None else best.when())
    return table


def last_values(curves: Curves) -> dict[str, float]:
    return {name: points[-1].value for name, points in curves.items()}


def rollout_results(curves: Curves) -> tuple[dict[str, dict[str, float]], int | None]:
    """``{val/<env>/<quality>[/<diagnostic>]: {metric: last value}}`` and the step of the last rollout."""
    results: dict[str, dict[str, float]] = {}
    step = None
    for name, value in last_values(curves).items():
        prefix, _, key = name.rpartition("/")
        if not prefix.startswith("val/") or prefix.startswith("val/bandit/"):
            continue
        if key.removesuffix("_sem") in ROLLOUT_KEYS:
            results.setdefault(prefix, {})[key] = value
            if key == "return":
                step = max(step or 0, curves[name][-1].step)
    rows = {p: r for p, r in results.items() if "return" in r}
    return dict(sorted(rows.items(), key=lambda item: _quality_order(item[0]))), step


def _quality_order(prefix: str) -> tuple:
    """``val/<env>/<quality>[/<diagnostic>]`` by env, then low, medium, high, then diagnostic."""
    parts = prefix.split("/")
    quality = QUALITIES.index(parts[2]) if len(parts) > 2 and parts[2] in QUALITIES else len(QUALITIES)
    return (parts[1] if len(parts) > 1 else ""), quality, prefix


def regret_results(curves: Curves) -> dict[str, dict[str, dict[str, float]]]:
    """``{source: {method: {metric: last value}}}`` from ``val/bandit/<source>/<method>/<metric>``."""
    results: dict[str, dict[str, dict[str, float]]] = {}
    for name, value in last_values(curves).items():
        parts = name.split("/")
        if len(parts) == 5 and parts[:2] == ["val", "bandit"] and parts[4].removesuffix("_sem") in REGRET_KEYS:
            results.setdefault(parts[2], {}).setdefault(parts[3], {})[parts[4]] = value
    return results


def is_clock(name: str) -> bool:
    """``time/*``: the training clock's bookkeeping, an axis for the curves rather than a curve."""
    return name.startswith("time/")


def quality_curves(curves: Curves, key: str) -> Curves:
    """``val/<env>/<quality>/<key>`` of the own context, by env then low, medium, high: ``{env/quality: points}``."""
    found = {name: points for name, points in curves.items()
             if name.startswith("val/") and not name.startswith("val/bandit/") and name.count("/") == 3
             and name.endswith(f"/{key}")}
    ordered = sorted(found, key=lambda name: _quality_order(name.rpartition("/")[0]))
    return {name.removeprefix("val/").removesuffix(f"/{key}"): found[name] for name in ordered}


def panels(curves: Curves) -> list[tuple[str, str, Curves]]:
    """The figure's panels, ``(title, x axis, curves)``: the held-out return per context quality against
    optimizer steps and against training seconds, the losses, each bandit's weak regret, then every other kind
    of metric (grouped by their last name component) up to ``MAX_PANELS``; never the clock itself."""
    shown: list[tuple[str, str, Curves]] = []
    key = next((k for k in ("return", "normalized_return") if quality_curves(curves, k)), None)
    drawn: set[str] = set()
    if key:
        per_quality = quality_curves(curves, key)
        drawn |= {f"val/{name}/{key}" for name in per_quality}
        shown.append((f"held-out {key.replace('_', ' ')} per context quality", "step", per_quality))
        if "time/train_seconds" in curves:
            shown.append((f"held-out {key.replace('_', ' ')} per context quality", "seconds", per_quality))
    rest = {n: p for n, p in learning_curves(curves).items() if n not in drawn and not is_clock(n)}
    losses = {n: p for n, p in rest.items() if "loss" in n.rsplit("/", 1)[-1]}
    if losses:
        shown.append(("losses", "step", losses))
    groups: dict[str, Curves] = {}
    for name, points in rest.items():
        if name not in losses:
            groups.setdefault(name.rsplit("/", 1)[-1], {})[name] = points
    groups = {g: dict(sorted(m.items(), key=lambda item: _quality_order(item[0].rpartition("/")[0])))
              for g, m in groups.items()}  # low, medium, high
    order = sorted(groups, key=lambda g: (FIRST_PANELS.index(g) if g in FIRST_PANELS else len(FIRST_PANELS), g))
    shown += [(group, "step", groups[group]) for group in order]
    return shown[:MAX_PANELS]


def seconds_at(curves: Curves) -> dict[int, float]:
    """Training seconds (``time/train_seconds``, validation excluded) at each step the clock logged."""
    return {p.step: p.value for p in curves.get("time/train_seconds", [])}


def curves_figure(curves: Curves, path: Path, title: str) -> None:
    """The panels of ``panels`` in a grid, written to ``path`` (PNG); a dashed line is the behavior policy
    of that context quality, the bar an in-context learner should clear."""
    from matplotlib.figure import Figure

    shown = panels(curves)
    if not shown:
        raise ValueError(f"{title}: no metric to draw")
    seconds = seconds_at(curves)
    cols = min(3, len(shown))
    rows = math.ceil(len(shown) / cols)
    fig = Figure(figsize=(5 * cols, 3.4 * rows), layout="constrained")
    fig.suptitle(title, fontsize=9)
    for i, (panel, axis, members) in enumerate(shown):
        ax = fig.add_subplot(rows, cols, i + 1)
        dashed = False
        for name, points in members.items():
            kept = [p for p in points if axis == "step" or p.step in seconds]
            xs = [p.step if axis == "step" else seconds[p.step] for p in kept]
            line, = ax.plot(xs, [p.value for p in kept], marker="o" if len(kept) < 30 else None, markersize=3,
                            label=name)
            leaf = panel.removeprefix("held-out ").partition(" per ")[0].replace(" ", "_")
            behavior = curves.get(f"val/{name}/behavior_{leaf}") if panel.startswith("held-out") else None
            if behavior:
                ax.axhline(behavior[-1].value, color=line.get_color(), linestyle="--", linewidth=0.8)
                dashed = True
        ax.set_title(panel + (" (dashed: behavior policy)" if dashed else ""), fontsize=9)
        ax.set_xlabel("optimizer step" if axis == "step" else "training seconds (validation excluded)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6)
    save_figure(fig, path, dpi=110)


def run_name(run: Path) -> str:
    """``run`` relative to the working directory when it lies inside it, else its last two components."""
    resolved = run.resolve()
    try:
        return str(resolved.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(Path(*resolved.parts[-2:]))


def report(run: Path, figure: Path | None, console: Console) -> Path | None:
    """Print the report of ``run`` on ``console``; write the figure to ``figure`` (None: no figure)."""
    path = find_metrics(run)
    curves = read_metrics(path)
    if not curves:
        raise ValueError(f"{path}: no metric logged yet")
    steps = max(p.step for points in curves.values() for p in points)
    console.print(f"run: {run}\nmetrics: {path} (last step {steps})")
    console.print(curves_table(curves))
    results, step = rollout_results(curves)
    if results:
        console.print(results_table(results, f"In-context rollouts on held-out tasks, last logged (step {step})"))
    regrets = regret_results(curves)
    if regrets:
        console.print(regret_table(regrets, "Weak regret on held-out problems, last logged"))
    if figure is not None:
        curves_figure(curves, figure, f"{run_name(run)}: learning curves")
        console.print(f"figure: {figure}")
    return figure
