"""Reporting held-out results: rich tables (callbacks), markdown, JSON and figures (``icprl evaluate``).

Two kinds of result, both the paper's metrics:

* MDP families (DarkRoom, Meta-World Reach): the latent return on held-out tasks (and success rate
  where the environment reports it), mean ± sem over tasks, per context quality, with the behavior
  policy and the optimal/expert policy beside the methods (``results_table``, ``rollout_markdown``,
  ``rollout_figure``);
* dueling bandits: weak regret min(R* − R(a), R* − R(a')) (paper, appendix "Dueling Bandit
  Experiments") and strong regret ((R* − R(a)) + (R* − R(a'))) / 2 vs context size, at h = H, averaged over h
  and at smaller context sizes, mean ± sem over problems, per context source, with DTS, the feature-aware
  baselines, the Bayes reference and the behaviour policy beside the methods (``regret_table``,
  ``regret_markdown``, ``regret_figure``).

Figures use ``matplotlib.figure.Figure`` directly, so importing this module never changes the
matplotlib backend of the caller.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.measure import Measurement
from rich.table import Table

from icprl_lightning.io import save_figure
from icprl_lightning.untrusted import UntrustedFileError, read_json

MDP_METRICS = ("return", "normalized_return", "success")
REGRET_METRICS = (("weak_regret", "weak regret at h = H"), ("weak_regret_auc", "weak regret, mean over h = 1..H"),
                  ("strong_regret", "strong regret at h = H"),
                  ("strong_regret_auc", "strong regret, mean over h = 1..H"))
REFERENCE_STYLES = {"bayes": {"color": "k", "linestyle": "--"}, "behavior": {"color": "0.55", "linestyle": ":"}}
COLUMNS = (("return", "return"), ("normalized", "normalized_return"), ("success", "success"),
           ("behavior return", "behavior_return"), ("behavior normalized", "behavior_normalized_return"),
           ("behavior success", "behavior_success"),
           ("optimal return", "optimal_return"), ("expert return", "expert_return"))


# ---- terminal tables (the callbacks) ---------------------------------------------------------------

def show_table(table: Table) -> None:
    """Print to stderr; a log file (not a terminal) gets the table's full width instead of wrapping at 80."""
    console = Console(stderr=True)
    if not console.is_terminal:
        console.width = max(80, Measurement.get(console, console.options.update_width(1000), table).maximum)
    console.print(table)


def _pm(value: float | None, sem: float | None, fmt: str = ".3g", sem_fmt: str = ".2g") -> str:
    if value is None:
        return ""
    return f"{value:{fmt}}" + ("" if sem is None or not np.isfinite(sem) else f" ± {sem:{sem_fmt}}")


def results_table(results: dict[str, dict[str, float]], title: str) -> Table:
    """One row per ``val/<env>/<quality>`` prefix; the columns any of them reports (± sem where known)."""
    shown = [(head, key) for head, key in COLUMNS if any(key in r for r in results.values())]
    table = Table(title=title)
    table.add_column("")
    for head, _ in shown:
        table.add_column(head, justify="right")
    for prefix, r in results.items():
        table.add_row(prefix.removeprefix("val/"), *(_pm(r.get(key), r.get(f"{key}_sem")) for _, key in shown))
    return table


def regret_table(results: dict[str, dict[str, dict[str, float]]], title: str) -> Table:
    """Bandits: one row per context source, final and mean-over-h weak regret of each method (± sem)."""
    methods = list(dict.fromkeys(m for per_source in results.values() for m in per_source))
    table = Table(title=title)
    table.add_column("context source")
    for method in methods:
        table.add_column(f"{method} final", justify="right", no_wrap=True)
        table.add_column(f"{method} AUC", justify="right", no_wrap=True)
    for source, per_source in results.items():
        cells = []
        for method in methods:
            r = per_source.get(method, {})
            cells += [_pm(r.get(k), r.get(f"{k}_sem"), ".3f", ".3f") for k in ("weak_regret", "weak_regret_auc")]
        table.add_row(source, *cells)
    return table


# ---- MDP outputs (icprl evaluate) ------------------------------------------------------------------

def reference_rows(first: dict[str, dict]) -> dict[str, dict[str, dict[str, float]]]:
    """The behavior and optimal/expert policies' numbers from the dataset manifest, per quality.

    ``first`` maps quality -> a run's row holding the suite's ``reference`` dict.
    """
    behavior, best = {}, {}
    for q, row in first.items():
        ref = row["reference"]
        behavior[q] = {"return": ref["behavior_return"], "return_sem": ref.get("behavior_return_sem", 0.0)}
        if "behavior_success" in ref:
            behavior[q]["success"] = ref["behavior_success"]
        if "behavior_normalized_return" in ref:
            behavior[q]["normalized_return"] = ref["behavior_normalized_return"]
        if "optimal_return" in ref:
            best[q] = {"return": ref["optimal_return"], "return_sem": 0.0, "normalized_return": 1.0}
            behavior[q]["normalized_return"] = ref["behavior_return"] / ref["optimal_return"]
        else:
            best[q] = {"return": ref["expert_return"], "return_sem": 0.0, "normalized_return": 1.0,
                       "success": ref["expert_success"]}
    optimal = "optimal_return" in next(iter(first.values()))["reference"]
    return {"behavior": behavior, "optimal" if optimal else "expert": best}


def read_baseline(path: str | Path) -> dict[str, Any]:
    """A from-scratch baseline's JSON (``baselines/``), checked to hold at least one of ``MDP_METRICS`` as
    ``{"mean": number, "sem": number}``; anything else is one ``ValueError`` naming the file (before any work)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--baseline {path}: no such file")
    try:
        result = read_json(path, "baseline result")
    except UntrustedFileError as e:
        raise ValueError(f"--baseline {e}") from None
    expected = f'a baselines/ result: a JSON object with {" / ".join(MDP_METRICS)} as {{"mean": x, "sem": s}}'
    if not isinstance(result, dict) or not any(m in result for m in MDP_METRICS):
        raise ValueError(f"--baseline {path} is not {expected}")
    for metric in (m for m in MDP_METRICS if m in result):
        value = result[metric]
        numbers = isinstance(value, dict) and all(
            isinstance(value.get(k), int | float) and not isinstance(value.get(k), bool) for k in ("mean", "sem"))
        if not numbers:
            raise ValueError(f"--baseline {path}: {metric!r} is {value!r}, not {{\"mean\": number, \"sem\": number}}")
    return result


def baseline_row(result: dict[str, Any], qualities: list[str]) -> dict[str, dict[str, float]]:
    """A from-scratch baseline's result (``read_baseline``) as the same row for every quality."""
    row = {}
    for metric in MDP_METRICS:
        if metric in result:
            row[metric], row[f"{metric}_sem"] = result[metric]["mean"], result[metric]["sem"]
    return {q: dict(row) for q in qualities}


def cell(res: dict[str, float], metric: str, digits: int) -> str:
    if metric not in res:
        return "–"
    sem = res.get(f"{metric}_sem")
    return f"{res[metric]:.{digits}f}" + (f" ± {sem:.{digits}f}" if sem else "")


def _groups(payload: dict) -> tuple[dict[str, dict], list[str], list[str]]:
    """(results, the deployed runs' names, the columns: qualities or sources, in the first run's order)."""
    results = payload["results"]
    names = [spec.partition("=")[0] for spec in payload["runs"]]
    return results, names, list(results[names[0]])


def _markdown_tables(results: dict, columns: list[str], metrics: list[tuple[str, str, int]], head: str) -> list[str]:
    lines = []
    for metric, title, digits in metrics:
        lines += [f"{title}:", "", f"| {head} | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
        lines += [f"| {name} | " + " | ".join(cell(res.get(c, {}), metric, digits) for c in columns) + " |"
                  for name, res in results.items()]
        lines.append("")
    return lines


def rollout_markdown(payload: dict) -> str:
    """Per metric a table: one row per method and reference, one column per context quality."""
    results, names, qualities = _groups(payload)
    metrics = [(m, m.replace("_", " "), 1 if m == "return" else 2) for m in MDP_METRICS
               if any(m in results[n][q] for n in names for q in qualities)]
    lines = _markdown_tables(results, qualities, metrics, "method")
    lines.append(f"Behavior and {'optimal' if 'optimal' in results else 'expert'} rows: the dataset of "
                 f"{payload['reference_rows_from']}. {_seeds_note(payload)}")
    lines += diagnostics_markdown(payload, [m for m in metrics if m[0] != "success"], "method")
    return "\n".join(lines) + "\n"


DIAGNOSTIC_NAMES = {"own": "own context", "random_labels": "random labels", "flipped_labels": "flipped labels",
                    "other_task": "other task's context", "shuffled_order": "steps in random order"}


def _checkpoints_per_run(payload: dict) -> dict[str, int]:
    """Run name -> its number of checkpoints (training seeds), from the ``--run NAME=CONFIG:CKPT,...`` specs."""
    return {spec.partition("=")[0]: len(spec.partition(":")[2].split(",")) for spec in payload.get("runs", [])}


def _seeds_note(payload: dict) -> str:
    several = {n: k for n, k in _checkpoints_per_run(payload).items() if k > 1}
    seeds = (f"Training seeds: {', '.join(f'{n} {k}' for n, k in several.items())} (mean ± sem over training "
             "seeds of each seed's held-out mean); " if several else "One training seed per run; ")
    return seeds + f"episode seeds {payload['seeds']}, actions: {payload['actions']}."


def diagnostics_markdown(payload: dict, metrics: list[tuple[str, str, int]], head: str) -> list[str]:
    """Per metric one table: for each run its own-context row and, below it, each context diagnostic's."""
    diagnostics = payload.get("diagnostics") or {}
    if not diagnostics:
        return []
    results = payload["results"]
    rows = {}
    for name, per in diagnostics.items():
        rows[f"{name}, {DIAGNOSTIC_NAMES['own']}"] = results[name]
        for diagnostic, res in per.items():
            rows[f"{name}, {DIAGNOSTIC_NAMES[diagnostic]}"] = res
    columns = list(next(iter(rows.values())))
    lines = ["", "Context diagnostics (evaluation.diagnostics: the same episodes with every label inverted, "
             "labels replaced by fair coins, or another held-out task's context):", ""]
    return lines + _markdown_tables(rows, columns, [(m, f"{t}, by context", d) for m, t, d in metrics], head)


def _error_bars(payload: dict) -> str:
    """What a figure's ± is: over training seeds when a run has several, else over held-out tasks."""
    several = any(k > 1 for k in _checkpoints_per_run(payload).values())
    return ("mean ± sem over training seeds (behavior, optimal: over held-out tasks)" if several
            else "mean ± sem over held-out tasks")


def figure_title(text: str, fig_width_inches: float) -> str:
    """``text`` wrapped to the figure's width (about 16 characters per inch at fontsize 9), so no line is cut."""
    return textwrap.fill(text, width=max(40, int(16 * fig_width_inches)))


def _bar_colors(n: int) -> list:
    """``n`` distinct colors: matplotlib's default cycle up to 10 bars, its 20-color map beyond (no repeats)."""
    from matplotlib import colormaps

    return [f"C{i}" for i in range(n)] if n <= 10 else [colormaps["tab20"](i % 20) for i in range(n)]


def rollout_figure(payload: dict, path: str | Path) -> None:
    """Bars per quality (return, and success where reported), one per method, ± sem (see ``_error_bars``)."""
    from matplotlib.figure import Figure

    results, names, qualities = _groups(payload)
    shown = [m for m in ("return", "success") if any(m in results[n][q] for n in names for q in qualities)]
    fig = Figure(figsize=(5.5 * len(shown) + 2.5, 3.6), layout="tight")
    axes = fig.subplots(1, len(shown), squeeze=False)
    width = 0.8 / len(results)
    colors = _bar_colors(len(results))
    for ax, metric in zip(axes[0], shown, strict=True):
        for i, (name, res) in enumerate(results.items()):
            xs = np.arange(len(qualities)) + i * width
            ax.bar(xs, [res[q].get(metric, np.nan) for q in qualities], width, color=colors[i],
                   yerr=[res[q].get(f"{metric}_sem", 0.0) or 0.0 for q in qualities], label=name, capsize=2)
        ax.set_xticks(np.arange(len(qualities)) + width * (len(results) - 1) / 2, qualities)
        ax.set_xlabel("context quality")
        ax.set_ylabel(f"{metric.replace('_', ' ')} on held-out tasks")
    fig.suptitle(figure_title(f"{payload['title']}: {_error_bars(payload)}", fig.get_figwidth()), fontsize=9)
    axes[0][-1].legend(fontsize=7, bbox_to_anchor=(1.02, 1), loc="upper left")
    save_figure(fig, path, dpi=120)


def diagnostics_figure(payload: dict, path: str | Path, metric: str) -> None:
    """One panel per context quality / source: per run, a bar per context (own and each diagnostic)."""
    from matplotlib.figure import Figure

    diagnostics, results = payload["diagnostics"], payload["results"]
    names = list(diagnostics)
    contexts = list(dict.fromkeys(["own", *(d for per in diagnostics.values() for d in per)]))
    columns = list(results[names[0]])
    fig = Figure(figsize=(3.2 * len(columns) + 2.5, 3.4), layout="tight")
    axes = fig.subplots(1, len(columns), sharey=True, squeeze=False)
    width = 0.8 / len(contexts)
    for ax, column in zip(axes[0], columns, strict=True):
        for i, context in enumerate(contexts):
            rows = [results[n] if context == "own" else diagnostics[n].get(context, {}) for n in names]
            ax.bar(np.arange(len(names)) + i * width, [r.get(column, {}).get(metric, np.nan) for r in rows], width,
                   yerr=[r.get(column, {}).get(f"{metric}_sem", 0.0) or 0.0 for r in rows], capsize=2,
                   label=DIAGNOSTIC_NAMES[context])
        ax.set_xticks(np.arange(len(names)) + width * (len(contexts) - 1) / 2, names, fontsize=8,
                      rotation=30 if len(names) > 2 else 0, ha="right" if len(names) > 2 else "center")
        ax.set_title(column, fontsize=9)
    axes[0][0].set_ylabel(metric.replace("_", " "))
    axes[0][-1].legend(fontsize=7, bbox_to_anchor=(1.02, 1), loc="upper left")
    fig.suptitle(figure_title(f"{payload['title']}: context diagnostics, {_error_bars(payload)}", fig.get_figwidth()),
                 fontsize=9)
    save_figure(fig, path, dpi=120)


# ---- bandit outputs (icprl evaluate) ---------------------------------------------------------------

def _context_sizes(results: dict, sources: list[str], horizon: int) -> list[int]:
    """The context sizes h < H at which the rows report regret (keys ``weak_regret_h<h>``), ascending."""
    keys = {k for res in results.values() for source in sources for k in res.get(source, {})}
    sizes = {int(k.removeprefix("weak_regret_h")) for k in keys
             if k.startswith("weak_regret_h") and k.removeprefix("weak_regret_h").isdigit()}
    return sorted(h for h in sizes if h < horizon)


def regret_markdown(payload: dict) -> str:
    """Per statistic a table (one row per method and baseline, one column per context source): weak and strong
    regret at h = H and averaged over h, then each at the smaller context sizes the rows report."""
    results, _, sources = _groups(payload)
    present = {k for res in results.values() for source in sources for k in res.get(source, {})}
    metrics = [(m, t, 3) for m, t in REGRET_METRICS if m in present]
    sizes = _context_sizes(results, sources, payload["horizon"])
    metrics += [(f"{regret}_regret_h{h}", f"{regret} regret at h = {h}", 3) for regret in ("weak", "strong")
                for h in sizes if f"{regret}_regret_h{h}" in present]
    lines = _markdown_tables(results, sources, metrics, "method")
    baselines = [n for n in results if n not in _checkpoints_per_run(payload)]
    strong = " and strong regret ((R* − R(a)) + (R* − R(a'))) / 2" if "strong_regret" in present else ""
    lines.append(f"Weak regret min(R* − R(a), R* − R(a')){strong}, mean ± sem over {payload['n_eval_problems']} "
                 f"held-out problems, H = {payload['horizon']}. Rows {', '.join(baselines)}: the dataset of "
                 f"{payload['reference_rows_from']}. {_seeds_note(payload)}")
    if "bayes" in results:
        lines.append("")
        lines.append("maxinp and bt_thompson use the arm features, with the knobs chosen on training problems "
                     "(families/dueling_bandit/tuning.py). bayes is the Bayes reference, not a learner: for each "
                     "regret the duel the posterior under the family's prior favours after the same h comparisons "
                     "(weak: the pair maximizing E[max(r(a), r(a'))]; strong: the posterior-best arm against itself); "
                     "in expectation over problems no learner goes below it.")
    lines += diagnostics_markdown(payload, [m for m in metrics if m[0].startswith("weak_regret")][:2], "method")
    return "\n".join(lines) + "\n"


def regret_figure(payload: dict, path: str | Path) -> None:
    """One panel per context source, one row per regret (weak; strong when the payload has ``strong_curves``):
    regret vs context size h, mean ± sem band per method; the Bayes reference dashed, behaviour dotted."""
    from matplotlib.figure import Figure

    rows = [("weak", payload["curves"])] + ([("strong", payload["strong_curves"])] if "strong_curves" in payload
                                           else [])
    sources = list(next(iter(payload["curves"].values())))
    fig = Figure(figsize=(4.2 * len(sources) + 1.6, 3.2 * len(rows)), layout="constrained")
    axes = fig.subplots(len(rows), len(sources), sharex=True, sharey="row", squeeze=False)
    for r, (regret, curves) in enumerate(rows):
        for ax, source in zip(axes[r], sources, strict=True):
            for i, (name, per_source) in enumerate(curves.items()):
                mean, sem = np.asarray(per_source[source]["mean"]), np.asarray(per_source[source]["sem"])
                h = np.arange(1, len(mean) + 1)
                style = REFERENCE_STYLES.get(name, {"color": f"C{i}", "linestyle": "-"})
                ax.plot(h, mean, label=name, linewidth=1.2, **style)
                ax.fill_between(h, mean - sem, mean + sem, alpha=0.15, color=style["color"], linewidth=0)
            if r == 0:
                ax.set_title(f"{source} contexts", fontsize=9)
            ax.grid(alpha=0.3)
        axes[r, 0].set_ylabel(f"{regret} regret", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("context size h")
    axes[0, -1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1))
    fig.suptitle(figure_title(f"{payload['title']}: mean ± sem over {payload['n_eval_problems']} problems",
                              fig.get_figwidth()), fontsize=9)
    save_figure(fig, path, dpi=120)


def aligned_tables(markdown: str) -> str:
    """``markdown`` with each pipe table's columns padded to one width, for a terminal (still valid markdown)."""
    lines, out = markdown.splitlines(), []
    i = 0
    while i < len(lines):
        if not lines[i].startswith("|"):
            out.append(lines[i])
            i += 1
            continue
        block = []
        while i < len(lines) and lines[i].startswith("|"):
            block.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
            i += 1
        rule = {r for r, row in enumerate(block) if all(set(c) <= {"-", ":"} and c for c in row)}
        widths = [max(len(row[k]) for r, row in enumerate(block) if r not in rule and k < len(row))
                  for k in range(max(map(len, block)))]
        for r, row in enumerate(block):
            cells = ["-" * w if r in rule else (row[k] if k < len(row) else "").ljust(w) for k, w in enumerate(widths)]
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def write_figures(payload: dict[str, Any], out: str | Path) -> None:
    """The figures of the rollouts and duels kinds: ``<out>.png`` and, with context diagnostics,
    ``<out>_diagnostics.png`` (``icprl reproduce TABLE --redraw`` redraws them from the JSON)."""
    out = Path(out)
    bandit = "curves" in payload
    (regret_figure if bandit else rollout_figure)(payload, out.with_suffix(".png"))
    if payload.get("diagnostics"):
        diagnostics_figure(payload, out.with_name(out.name + "_diagnostics.png"),
                           "weak_regret" if bandit else "return")
