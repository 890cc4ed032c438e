"""Label codes of an annotator's answer, their check, and how a context turns them into stored labels.

An annotator answers each pair with one code (uint8):

* ``FIRST = 1``: the first item (``actions`` / ξ_a) is preferred;
* ``SECOND = 0``: the second item (``alt_actions`` / ξ_b) is preferred;
* ``EQUAL = 2``: both are as good (B-Pref's "equal" teacher);
* ``SKIP = 3``: no answer (B-Pref's "skip" teacher: the pair is not informative enough to judge).

1 and 0 are the stored label's own meaning (``preferred = 1``: the first won), so a decided answer is
stored as is. A stored dataset holds only 0/1: its contexts have a fixed length (H steps, one label per
pair), so an undecided comparison cannot be left out. ``resolve_labels`` replaces each EQUAL and each SKIP
by a fair coin drawn from the generator's stream:

* EQUAL: B-Pref trains on y = 1/2 for an equal answer; a fair coin is that label in expectation, and
  is what a Bradley–Terry teacher answers when the two utilities are equal;
* SKIP: B-Pref drops the query; a coin carries no information about the pair either, so a skipped
  step is as uninformative as a dropped one while the context keeps its length.

The coins are drawn only when some answer is undecided, so an annotator that always decides (the
Bradley–Terry oracle) leaves the stream, and hence the dataset's bytes, as they were. The manifest counts
each code (``skip_count``, ``equal_count``), and ``label_agreement`` measures the stored labels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

SECOND, FIRST, EQUAL, SKIP = 0, 1, 2, 3
CODES = {"first": FIRST, "second": SECOND, "equal": EQUAL, "skip": SKIP}


class AnnotatorError(ValueError):
    """An annotator's answer is unusable (wrong shape, dtype or code; a malformed or missing reply)."""


def check_labels(labels: Any, n: int, owner: str) -> np.ndarray:
    """``labels`` as uint8 [n] of codes in {0, 1, 2, 3}; else an ``AnnotatorError`` naming what is wrong."""
    if not isinstance(labels, np.ndarray):
        raise AnnotatorError(f"{owner}: labels must be a numpy array of shape ({n},), got {type(labels).__name__}")
    if labels.shape != (n,):
        raise AnnotatorError(f"{owner}: labels must have shape ({n},) (one per pair), got {labels.shape}")
    if labels.dtype == np.bool_ or not np.issubdtype(labels.dtype, np.integer):
        raise AnnotatorError(f"{owner}: labels must be an integer array (int8/uint8 codes), got dtype {labels.dtype}")
    bad = ~np.isin(labels, list(CODES.values()))
    if bad.any():
        values, where = sorted(set(labels[bad].tolist()))[:5], np.flatnonzero(bad)[:5].tolist()
        raise AnnotatorError(f"{owner}: labels must be 1 (first), 0 (second), {EQUAL} (equal) or {SKIP} (skip); "
                             f"got {values} at pair(s) {where}")
    return labels.astype(np.uint8)


def count_labels(labels: np.ndarray) -> dict[str, int]:
    """How many answers were skipped and how many equal (the manifest's counts)."""
    return {"skip_count": int(np.sum(labels == SKIP)), "equal_count": int(np.sum(labels == EQUAL))}


def resolve_labels(labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stored 0/1 labels: decided answers kept, EQUAL and SKIP replaced by fair coins (module docstring)."""
    undecided = labels > FIRST
    if not undecided.any():
        return labels.astype(np.uint8)
    out = labels.astype(np.uint8)
    out[undecided] = rng.random(int(undecided.sum())) < 0.5
    return out


def stored_labels(answers: Any, n: int, owner: str, rng: np.random.Generator, counts: dict[str, int]) -> np.ndarray:
    """A batch of an annotator's answers as a setting stores them: checked (``check_labels``), their EQUAL and
    SKIP answers added to ``counts`` (``skip_count``, ``equal_count``), resolved to 0/1 (``resolve_labels``)."""
    codes = check_labels(answers, n, owner)
    for key, count in count_labels(codes).items():
        counts[key] = counts.get(key, 0) + count
    return resolve_labels(codes, rng)
