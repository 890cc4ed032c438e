"""What ``icprl reproduce`` reads back from a finished fit's CSV log (``metrics.csv`` beside its checkpoints):
the rollout callback's learning curve and the last epoch's training metrics."""

from __future__ import annotations

from pathlib import Path


def logged_rows(checkpoint: str) -> list[dict[str, str]]:
    """The rows of a fit's CSV log (``metrics.csv`` beside its checkpoints directory); none without a log."""
    import csv

    path = Path(checkpoint).parent.parent / "metrics.csv"
    if not path.exists():
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


def learning_curve(checkpoint: str) -> list[dict[str, float]]:
    """The rollout callback's held-out returns per validation epoch of a fit (its CSV log beside the checkpoint):
    ``[{"step": s, "<quality>": return, ..., "train_seconds": t}]``, empty when the fit logged none.
    ``train_seconds`` (``TrainingClock``: training wall-clock without validation) is there when the fit logged it."""
    points: dict[int, dict[str, float]] = {}
    seconds: dict[int, float] = {}
    for row in logged_rows(checkpoint):
        if row.get("time/train_seconds"):
            seconds[int(row["step"])] = round(float(row["time/train_seconds"]), 1)
        for key, value in row.items():
            parts = key.split("/")
            if value and len(parts) == 4 and parts[0] == "val" and parts[3] == "return":
                points.setdefault(int(row["step"]), {"step": int(row["step"])})[parts[2]] = float(value)
    for step, point in points.items():
        if step in seconds:
            point["train_seconds"] = seconds[step]
    return [points[s] for s in sorted(points)]


def final_epoch_means(checkpoint: str) -> dict[str, float]:
    """Mean of every ``train/`` metric a fit logged in its last epoch (its CSV log beside the checkpoint), e.g.
    DIT's ``clipped_fraction`` and ``weight_std`` at the end of its policy phase; empty without a log."""
    rows = [row for row in logged_rows(checkpoint) if row.get("epoch")]
    last = max((int(row["epoch"]) for row in rows), default=None)
    values: dict[str, list[float]] = {}
    for row in rows:
        if int(row["epoch"]) == last:
            for key, value in row.items():
                if key.startswith("train/") and value:
                    values.setdefault(key[len("train/"):], []).append(float(value))
    return {key: sum(v) / len(v) for key, v in sorted(values.items())}
