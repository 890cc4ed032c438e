"""How far the people agree: with each other and with the latent ordering, per annotator (the fields are in
docs/labelling.md). Only answers that count (not undone) are used; an equal or skipped answer is in no
agreement (it names no winner), and a rate over no pair is ``null``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

DECIDED = ("first", "second")


def _rate(hits: int, n: int) -> float | None:
    return None if n == 0 else hits / n


def agreement(answers: dict[str, list[dict[str, Any]]], pair_ids: list[str], utility_first: np.ndarray,
              utility_second: np.ndarray) -> dict[str, dict[str, Any]]:
    """``{annotator: report}`` (module docstring) from the answers that count per annotator."""
    index = {pair: i for i, pair in enumerate(pair_ids)}
    decided = {who: {a["pair"]: a["label"] for a in mine if a["label"] in DECIDED} for who, mine in answers.items()}
    report = {}
    for who, mine in sorted(answers.items()):
        counts = {label: sum(a["label"] == label for a in mine) for label in ("first", "second", "equal", "skip")}
        hits = n = 0
        for pair, label in decided[who].items():
            i = index[pair]
            if utility_first[i] != utility_second[i]:
                n += 1
                hits += (label == "first") == bool(utility_first[i] > utility_second[i])
        others = {}
        for other in sorted(answers):
            if other != who:
                both = decided[who].keys() & decided[other].keys()
                same = sum(decided[who][p] == decided[other][p] for p in both)
                others[other] = {"agreement": _rate(same, len(both)), "pairs": len(both)}
        report[who] = {"answered": len(mine), **counts,
                       "median_response_ms": float(np.median([a["response_ms"] for a in mine])) if mine else None,
                       "latent_agreement": _rate(hits, n), "latent_pairs": n, "inter_annotator": others}
    return report
