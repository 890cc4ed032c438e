"""Label codes of an annotator's answer, their check, and how a context turns them into stored labels.

Codes: ``FIRST = 1`` and ``SECOND = 0`` (the stored label's own meaning), ``EQUAL = 2`` and ``SKIP = 3``
(B-Pref's "equal" and "skip" teachers). A stored context has a fixed length, so an undecided comparison
cannot be left out: ``resolve_labels`` makes each EQUAL and SKIP a fair coin — B-Pref's y = 1/2 in
expectation, and as uninformative as a dropped query. The coins are drawn only when some answer is
undecided, so an annotator that always decides leaves the stream, and the dataset's bytes, as they were.
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
