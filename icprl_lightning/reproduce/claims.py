"""The claims table: each of the paper's claims, one verdict per condition, read from its results JSON.

``docs/claims.yaml`` lists the claims; each is "row ``a`` beats row ``b``" of one ``icprl evaluate`` JSON, in
each of its ``columns``; a row is a results row (``ICPO``) or one of its diagnostics (``ICPO@flipped_labels``).
With per-task values (training seeds × held-out tasks) a cell is the verdict of the 95% stratified bootstrap
interval of the difference of means (``statistics.difference``): ``holds +0.485 [+0.407, +0.555]``. With only
each seed's mean, no interval (3 values cannot make one): each seed's paired difference and how many fall on the
claimed side: ``3 of 3 seeds +0.146 +0.193 +0.232``. ``render`` writes the short table into README.md and
docs/RESULTS.md, the full numbers into docs/RESULTS.md only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from icprl_lightning.reproduce.statistics import Scores, difference, main_metric, scores_of, verdict

CLAIMS = Path("docs/claims.yaml")
# how a column of a results JSON is named in the claims table's header
COLUMN_NAMES = {"dirichlet": "Dirichlet", "dts": "DTS"}
# what a set of columns varies, named by its first column
CONDITIONS = {"low": "the quality of the context", "uniform": "the source of the bandit's context"}
METRIC_NAMES = {"normalized_return": "normalized return", "weak_regret": "weak regret", "return": "return"}


@dataclass(frozen=True)
class Claim:
    """A claim "A beats B" read from one JSON of a table: rows ``a`` and ``b`` in each of ``columns``;
    ``labels`` names the row whose own context is set against its flipped labels (*labels read?*)."""

    claim: str
    setting: str
    table: str
    file: str
    columns: list[str]
    a: str
    b: str
    labels: str | None = None


def read_claims(path: Path = CLAIMS) -> list[Claim]:
    items = yaml.safe_load(path.read_text()) or []
    return [Claim(**item) for item in items]


def signed(value: float) -> str:
    return f"{value:+.3f}"


def _scores(payload: dict[str, Any], where: str, row: str, column: str, metric: str) -> Scores:
    name, _, diagnostic = row.partition("@")
    source = payload["results"][name] if not diagnostic else payload["diagnostics"][name][diagnostic]
    scores = scores_of(source[column], metric)
    if scores is None:
        raise KeyError(f"{where}: {row}/{column} has no {metric}")
    return scores


def seed_differences(a: Scores, b: Scores, where: str) -> np.ndarray:
    """Each training seed's ``a − b`` (paired by seed; ``b`` may be one reference value)."""
    left, right = a.values.mean(axis=1), b.values.mean(axis=1)
    if right.size not in (1, left.size):
        raise ValueError(f"{where}: {left.size} seeds against {right.size} cannot be paired by seed")
    return left - right


@dataclass(frozen=True)
class Comparison:
    """One claim in one column: both rows' scores and the cell it renders to."""

    column: str
    a: Scores
    b: Scores
    higher_is_better: bool
    where: str

    @property
    def per_task(self) -> bool:
        return self.a.tasks_recorded or self.b.tasks_recorded

    def n(self) -> str:
        return f"{self.a.runs} seeds × {self.a.tasks} tasks" if self.per_task else f"{self.a.runs} seeds"

    def on_claimed_side(self) -> int:
        deltas = seed_differences(self.a, self.b, self.where)
        return int((deltas > 0).sum() if self.higher_is_better else (deltas < 0).sum())

    def difference(self) -> str:
        """The difference with its interval, or each seed's difference: the numbers a verdict reads."""
        if self.per_task:
            diff = difference(self.a, self.b)
            return f"{signed(diff.point)} [{signed(diff.low)}, {signed(diff.high)}]"
        return " ".join(signed(d) for d in seed_differences(self.a, self.b, self.where))

    def verdict(self) -> str:
        if self.per_task:
            return verdict(difference(self.a, self.b), self.higher_is_better)
        return f"{self.on_claimed_side()} of {self.a.runs} seeds"

    def cell(self) -> str:
        return f"**{self.verdict()}** {self.difference()}"


def comparisons(root: Path, claim: Claim, a: str, b: str) -> tuple[str, list[Comparison]]:
    """The metric key and, per column of ``claim``, rows ``a`` against ``b`` of its JSON."""

    path = root / claim.table / f"{claim.file}.json"
    payload = json.loads(path.read_text())
    metric = main_metric(payload)
    return metric.key, [Comparison(column, _scores(payload, str(path), a, column, metric.key),
                                   _scores(payload, str(path), b, column, metric.key), metric.higher_is_better,
                                   str(path)) for column in claim.columns]


def labels_cell(root: Path, claim: Claim) -> str:
    """*Labels read?*: own context against flipped labels, per column (yes / no / inverted, or k of 3 seeds)."""
    if not claim.labels:
        return "–"
    _, cells = comparisons(root, claim, claim.labels, f"{claim.labels}@flipped_labels")
    if not cells[0].per_task:
        return " / ".join(str(c.on_claimed_side()) for c in cells) + f" of {cells[0].a.runs} seeds"
    return " / ".join({"holds": "yes", "tie": "no", "reversed": "inverted"}[c.verdict()] for c in cells)


def groups(claims: list[Claim]) -> list[tuple[list[str], list[Claim]]]:
    """The claims gathered by their conditions: each group's columns hold every column of its claims."""
    out: list[tuple[list[str], list[Claim]]] = []
    for claim in claims:
        group = next((g for g in out if set(claim.columns) <= set(g[0]) or set(g[0]) <= set(claim.columns)), None)
        if group is None:
            out.append((list(claim.columns), [claim]))
        else:
            if len(claim.columns) > len(group[0]):
                group[0][:] = claim.columns
            group[1].append(claim)
    return out


def short_table(root: Path, columns: list[str], claims: list[Claim]) -> list[str]:
    names = [COLUMN_NAMES.get(c, c) for c in columns]
    lines = ["| the paper's claim | setting | " + " | ".join(names) + " | labels read? | command |",
             "|---|---|" + "---|" * len(columns) + "---|---|"]
    for claim in claims:
        _, cells = comparisons(root, claim, claim.a, claim.b)
        by_column = {c.column: c.cell() for c in cells}
        lines.append(f"| {claim.claim} | {claim.setting} | " + " | ".join(by_column.get(c, "–") for c in columns)
                     + f" | {labels_cell(root, claim)} | `icprl reproduce {claim.table}` |")
    return lines


def claims_table(root: Path, path: Path = CLAIMS) -> str:
    """The short claims table, one per set of conditions (context quality; the bandit's context source)."""
    lines: list[str] = []
    for columns, claims in groups(read_claims(path)):
        metrics = {comparisons(root, c, c.a, c.b)[0] for c in claims}
        what = " or ".join(sorted(METRIC_NAMES.get(m, m) for m in metrics))
        kind = CONDITIONS.get(columns[0], "the condition")
        lines += [f"Columns: {kind} ({' / '.join(COLUMN_NAMES.get(c, c) for c in columns)}). Cells: the verdict, "
                  f"then Δ of the mean {what} (A − B) with its 95% interval, or each seed's Δ.", "",
                  *short_table(root, columns, claims), ""]
    return "\n".join(lines)


def full_table(root: Path, path: Path = CLAIMS) -> str:
    """Every number a claim's cells read: both rows' means per column, the difference, and n."""
    lines = ["| the paper's claim | A | B | metric | condition | A mean | B mean | Δ, 95% CI or per seed | n |",
             "|---|---|---|---|---|---|---|---|---|"]
    for claim in read_claims(path):
        metric, cells = comparisons(root, claim, claim.a, claim.b)
        for c in cells:
            lines.append(f"| {claim.claim} | {claim.a} | {claim.b} | {METRIC_NAMES.get(metric, metric)} | "
                         f"{c.column} | {c.a.values.mean():.3f} | {c.b.values.mean():.3f} | {c.difference()} | "
                         f"{c.n()} |")
    return "\n".join(lines) + "\n"
