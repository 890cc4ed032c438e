"""Question: Does more pretraining data per goal change the Meta-World Reach I-PRL ordering of DPT, DP²T and ICPO?

Asked: 2026-12-02 (the first commit of this investigation, then scripts/reach_scale_curves.py).

Answer (docs/RESULTS.md, "Twice the data" and "Four times the data" (Meta-World Reach I-PRL)):
No. From 20 to 40 to 80 contexts per goal no row moves by more than 0.05 normalized return: ICPO stays
ahead at low and medium quality (0.76 → 0.77 → 0.73 and 0.75 → 0.78 → 0.73, against DP²T's 0.64 → 0.62 → 0.62
and DPT's 0.58 → 0.60 → 0.63 at low), and the three are level near 0.93 at high. The curves are
docs/results/metaworld_scale.{png,md}.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

Data-scale curves of Meta-World Reach I-PRL (issue 13): normalized held-out return of DPT, DP²T and ICPO
against contexts per training goal, one panel per recipe and context quality, from the tables
``icprl reproduce metaworld_<recipe>_x<k>`` wrote (``docs/results/metaworld_<recipe>_x<k>.json``, greedy).

    python experiments/reach_scale_curves.py                      # every table present
    python experiments/reach_scale_curves.py --out docs/results/metaworld_scale/metaworld_scale
    python experiments/reach_scale_curves.py --rows sac:1=docs/results/metaworld_sac_x1/metaworld_sac_x1_icpo.json:ICPO

``--rows RECIPE:K=FILE:METHOD[,METHOD]`` takes those methods' rows and diagnostics from another evaluation's
JSON (``icprl evaluate --out``) instead of the table's, for a method refitted after its table was made; the
Markdown names every replaced row and its file.

Writes ``<out>.png`` and ``<out>.md`` (the numbers plotted: mean ± sem over training seeds, and the
diagnostics of ICPO and DP²T: flipped and random labels, another goal's context). A scale whose table is
missing is left out and named in the Markdown.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from icprl_lightning.families.base import QUALITIES

# the metaworld_<recipe>_x<k> experiment files (configs/experiment/): recipes, scales and contexts per goal at x1
RECIPE_TITLES = {"scripted": "scripted-expert recipe", "sac": "the paper's recipe (SAC oracle)"}
REACH_RECIPES = tuple(RECIPE_TITLES)
REACH_SCALES = (1, 2, 4, 8)
REACH_CONTEXTS_PER_GOAL = 20

METHODS = ("DPT", "DP2T", "ICPO")
DIAGNOSED = ("DP2T", "ICPO")


def load(results_dir: Path) -> dict[str, dict[int, dict]]:
    out: dict[str, dict[int, dict]] = {}
    for recipe in REACH_RECIPES:
        for k in REACH_SCALES:
            path = results_dir / f"metaworld_{recipe}_x{k}.json"
            if path.exists():
                out.setdefault(recipe, {})[k] = json.loads(path.read_text())
    return out


def replace_rows(tables: dict[str, dict[int, dict]], spec: str) -> str:
    """Apply one ``--rows RECIPE:K=FILE:METHOD[,METHOD]``; returns the note the Markdown prints."""
    try:
        where, source = spec.split("=", 1)
        recipe, k = where.split(":")
        path, methods = source.rsplit(":", 1)
        k = int(k)
    except ValueError:
        raise SystemExit(f"--rows wants RECIPE:K=FILE:METHOD[,METHOD], got {spec!r}") from None
    if k not in tables.get(recipe, {}):
        raise SystemExit(f"--rows {spec!r}: there is no metaworld_{recipe}_x{k}.json to replace rows in")
    payload, other = tables[recipe][k], json.loads(Path(path).read_text())
    for method in methods.split(","):
        if method not in other["results"]:
            raise SystemExit(f"--rows {spec!r}: {path} has no {method!r} row (it has {sorted(other['results'])})")
        payload["results"][method] = other["results"][method]
        if method in other.get("diagnostics", {}):
            payload.setdefault("diagnostics", {})[method] = other["diagnostics"][method]
    return f"{RECIPE_TITLES[recipe]}, {REACH_CONTEXTS_PER_GOAL * k} contexts per goal: {methods} from {path}"


def _cell(row: dict, key: str = "normalized_return") -> str:
    sem = row.get(f"{key}_sem")
    return f"{row[key]:.2f}" + ("" if sem is None else f" ± {sem:.2f}")


def markdown(tables: dict[str, dict[int, dict]], notes: tuple[str, ...] = ()) -> str:
    lines = ["Normalized held-out return (greedy; 0 = uniform actions, 1 = the scripted expert), mean ± sem over "
             "training seeds, by contexts per training goal.", ""]
    if notes:
        lines += ["Rows replaced by a later evaluation (`--rows`):", "", *(f"- {n}" for n in notes), ""]
    for recipe, by_scale in tables.items():
        lines += [f"### {RECIPE_TITLES[recipe]}", "",
                  "| method | contexts / goal | seeds | " + " | ".join(QUALITIES) + " |",
                  "|---|---|---|" + "---|" * len(QUALITIES)]
        for method in (*METHODS, "behavior"):
            for k, payload in sorted(by_scale.items()):
                res = payload["results"].get(method)
                if res is None:
                    continue
                seeds = res[QUALITIES[0]].get("training_seeds", "–")
                lines.append(f"| {method} | {REACH_CONTEXTS_PER_GOAL * k} | {seeds} | "
                             + " | ".join(_cell(res[q]) for q in QUALITIES) + " |")
        diag = [(k, p) for k, p in sorted(by_scale.items()) if p.get("diagnostics")]
        if diag:
            lines += ["", "Diagnostics (normalized return, medium quality): own context / flipped labels / random "
                      "labels / another goal's context", ""]
            for k, payload in diag:
                for method in DIAGNOSED:
                    d = payload["diagnostics"].get(method)
                    if d is not None:
                        cells = [_fmt(payload["results"][method]["medium"])] + [
                            _fmt(d.get(c, {}).get("medium")) for c in ("flipped_labels", "random_labels", "other_task")]
                        lines.append(f"- {method}, {REACH_CONTEXTS_PER_GOAL * k} contexts / goal: " + " / ".join(cells))
        missing = [REACH_CONTEXTS_PER_GOAL * k for k in REACH_SCALES if k not in by_scale]
        if missing:
            lines += ["", f"Not run: {', '.join(map(str, missing))} contexts per goal."]
        lines.append("")
    return "\n".join(lines)


def _fmt(row: dict | None) -> str:
    if not row:
        return "–"
    return f"{row['normalized_return']:.2f}" if "normalized_return" in row else f"{row.get('return', float('nan')):.1f}"


def figure(tables: dict[str, dict[int, dict]], out: Path) -> None:
    from matplotlib.figure import Figure

    recipes = list(tables)
    fig = Figure(figsize=(4 * len(QUALITIES), 3.2 * max(len(recipes), 1)), layout="tight")
    axes = fig.subplots(max(len(recipes), 1), len(QUALITIES), squeeze=False)
    for r, recipe in enumerate(recipes):
        by_scale = tables[recipe]
        ks = sorted(by_scale)
        x = [REACH_CONTEXTS_PER_GOAL * k for k in ks]
        for c, quality in enumerate(QUALITIES):
            ax = axes[r][c]
            for i, method in enumerate((*METHODS, "behavior")):
                rows = [by_scale[k]["results"].get(method, {}).get(quality) for k in ks]
                if not all(rows):
                    continue
                ax.errorbar(x, [row["normalized_return"] for row in rows],
                            yerr=[row.get("normalized_return_sem", 0.0) for row in rows], marker="o", capsize=2,
                            color=f"C{i}", linestyle="--" if method == "behavior" else "-", label=method)
            ax.set_xscale("log", base=2)
            ax.set_xticks(x, [str(v) for v in x])
            ax.set_title(f"{RECIPE_TITLES[recipe]}, {quality} contexts", fontsize=8)
            ax.set_xlabel("contexts per training goal")
            ax.grid(alpha=0.3)
        axes[r][0].set_ylabel("normalized return (greedy)")
    axes[0][-1].legend(fontsize=7)
    fig.savefig(out.with_suffix(".png"), dpi=120)


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("docs/results"))
    parser.add_argument("--out", type=Path, default=Path("docs/results/metaworld_scale/metaworld_scale"))
    parser.add_argument("--rows", action="append", default=[], metavar="RECIPE:K=FILE:METHOD[,METHOD]",
                        help="take these methods' rows from another evaluation's JSON (repeatable)")
    ns = parser.parse_args(args)
    tables = load(ns.results)
    if not tables:
        raise SystemExit(f"no metaworld_<recipe>_x<k>.json in {ns.results}: "
                         "run `icprl reproduce metaworld_sac_x1` first")
    notes = tuple(replace_rows(tables, spec) for spec in ns.rows)
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.with_suffix(".md").write_text(markdown(tables, notes))
    figure(tables, ns.out)
    print(ns.out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
