"""``icprl label --export OUT``: a session's answers as our datasets and as other tools' rows (the files are listed
in docs/labelling.md: answers.jsonl, agreement.json, dataset/, trl_rows.parquet, imitation_pairs.npz).

One row per (annotator, pair) answer. A skipped pair is in no dataset. A tie is the label 0.5 end to end
(``ties="soft"``): the dataset's manifest then says ``soft_labels`` and only ICPO and RewardGen train on it
(``validation.pairing_errors``); ``ties="drop"`` leaves ties out. TRL rows hold the decided answers only (a row
names its winner by its column). Bandit duels have no state, so their answers go to answers.jsonl and the
imitation rows only. The goal and the latent utilities stay in the session: no exported context carries them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.importer import KINDS, import_preferences
from icprl_lightning.io import write_json_atomic
from icprl_lightning.labelling.agreement import agreement
from icprl_lightning.labelling.session import Session

SOFT = {"first": 1.0, "second": 0.0, "equal": 0.5}
TIES = ("soft", "drop")


def counted_answers(session: Session) -> list[dict[str, Any]]:
    """The answers that count, annotator by annotator, each with its pair's ``row`` and ``task_index``."""
    index = {pair: i for i, pair in enumerate(session.pair_ids)}
    out = []
    for who in sorted(session.log.answers):
        for a in session.log.answers[who]:
            row = index[a["pair"]]
            out.append({"annotator": who, "pair": a["pair"], "label": a["label"], "response_ms": a["response_ms"],
                        "time": a["time"], "row": row, "task_index": int(session.arrays["task_index"][row])})
    return out


def _rows(session: Session, rows: np.ndarray) -> dict[str, np.ndarray]:
    return {k: session.arrays[k][rows] for k in KINDS[session.source.kind] if k != "preferred"}


def export(session: Session, out: str | Path, overwrite: bool = False, ties: str = "soft", val_fraction: float = 0.2,
           seed: int = 0) -> dict[str, Any]:
    """Write ``out`` (module docstring); returns what was written, with the counts."""
    if ties not in TIES:
        raise ValueError(f"ties must be one of {list(TIES)}, got {ties!r}")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"{out} is not empty; pass --overwrite to replace its files")
    out.mkdir(parents=True, exist_ok=True)
    answers = counted_answers(session)
    with open(out / "answers.jsonl", "w") as f:
        f.writelines(json.dumps(a, sort_keys=True) + "\n" for a in answers)
    report = agreement(session.log.answers, session.pair_ids, session.arrays["utility_first"],
                       session.arrays["utility_second"])
    write_json_atomic(out / "agreement.json", report)
    source = session.source
    for line, a in enumerate(answers):
        a["line"] = line  # the dataset's ``source_row``
    soft = [a for a in answers if a["label"] in SOFT]
    hard = [a for a in soft if a["label"] != "equal"]
    written = {"answers": len(answers), "decided": len(hard), "ties": len(soft) - len(hard),
               "skips": sum(a["label"] == "skip" for a in answers)}
    labelled = soft if ties == "soft" else hard
    if source.stateless:  # a duel has no state, and a recorded dataset (like a TRL prompt) needs one
        labelled = hard = []
        written["dataset"] = "not written: bandit duels have no state (answers.jsonl and the imitation rows hold them)"
    if labelled:
        rows = np.array([a["row"] for a in labelled])
        arrays = _rows(session, rows)
        label = np.array([SOFT[a["label"]] for a in labelled], dtype=np.float32)
        arrays["preferred"] = label.reshape((len(rows), 1) if source.kind == "step_preference" else (len(rows),))
        arrays["task_index"] = session.arrays["task_index"][rows]
        size = {"n_actions": source.action_size} if source.discrete else {"action_dim": source.action_size}
        import_preferences(arrays, out / "dataset", kind=source.kind, val_fraction=val_fraction, seed=seed,
                           overwrite=True, source_rows=np.array([a["line"] for a in labelled]), **size,
                           soft_labels=bool(written["ties"]) and ties == "soft",
                           origin={"format": "icprl label", "session": str(session.path), "ties": ties,
                                   "ties_left_out": 0 if ties == "soft" else written["ties"],
                                   "skips_left_out": written["skips"]})
    if hard:
        rows = np.array([a["row"] for a in hard])
        arrays = {**_rows(session, rows), "task_index": session.arrays["task_index"][rows]}
        _write_trl(arrays, np.array([a["label"] == "first" for a in hard]), source.kind, out / "trl_rows.parquet")
    if soft:
        rows = np.array([a["row"] for a in soft])
        arrays = _rows(session, rows)
        a_, b_ = (("states", "actions"), ("states", "alt_actions")) if source.kind == "step_preference" else \
            (("states_a", "actions_a"), ("states_b", "actions_b"))
        np.savez(out / "imitation_pairs.npz", states_1=arrays[a_[0]], actions_1=arrays[a_[1]], states_2=arrays[b_[0]],
                 actions_2=arrays[b_[1]], label=np.array([SOFT[a["label"]] for a in soft]),
                 task_index=session.arrays["task_index"][rows])
    return written


def _pick(mask: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise ``x`` where ``mask`` [N] else ``y``."""
    return np.where(mask.reshape(-1, *[1] * (x.ndim - 1)), x, y)


def _write_trl(arrays: dict[str, np.ndarray], first: np.ndarray, kind: str, path: Path) -> None:
    """TRL rows: ``chosen`` over ``rejected`` (``data/interop/preference_rows.py``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if kind == "step_preference":
        a, b = arrays["actions"][:, 0], arrays["alt_actions"][:, 0]
        columns = {"prompt": arrays["states"][:, 0].tolist(), "chosen": _pick(first, a, b).tolist(),
                   "rejected": _pick(first, b, a).tolist()}
    else:
        sides = {"chosen": (first, "_a", "_b"), "rejected": (first, "_b", "_a")}
        columns = {side: [dict(zip(("states", "actions"), step, strict=True)) for step in zip(
            *[_pick(mask, arrays[f + x], arrays[f + y]).tolist() for f in ("states", "actions")], strict=True)]
            for side, (mask, x, y) in sides.items()}
    columns["task_index"] = arrays["task_index"].tolist()
    pq.write_table(pa.table(columns), path)
