"""The append-only answer log of a labelling session (``answers.jsonl``): nothing answered is lost.

One JSON line per event, written with one ``write`` and ``fsync``'d before the server acknowledges it:

* ``{"event": "answer", "annotator", "pair", "label", "nonce", "response_ms", "time"}``: a person's answer
  (``label`` one of first / second / equal / skip) to a pair, how long they looked at it, when (UTC, ISO 8601);
* ``{"event": "undo", "annotator", "pair", "nonce", "time"}``: the person took back their last answer (to
  ``pair``); the line stays, the answer no longer counts.

The state (who answered what) is a replay of the lines, so a server killed at any instant restarts exactly
where it stopped: every acknowledged line is on disk, and a last line cut short by the kill (never
acknowledged) is cut off when the log is opened. A line that is not JSON elsewhere is a corrupt log, an
error naming the line. Each request carries a fresh ``nonce``; a nonce seen before (a replayed request) is
refused, as is an answer to a pair other than the one the annotator is being shown. One lock orders the
appends of concurrent requests (several browser sessions on one queue); each annotator answers every pair
once, in queue order, so their answers can be compared (``agreement.py``).
"""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

LABELS = ("first", "second", "equal", "skip")


class Refused(ValueError):
    """A request the log refuses, with the HTTP status that says why (409: out of turn or replayed)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


@dataclass
class AnswerLog:
    """The log at ``path`` and its replayed state; ``pair_ids`` is the queue, in order."""

    path: Path
    pair_ids: list[str]
    answers: dict[str, list[dict[str, Any]]] = field(default_factory=dict)  # annotator -> answers that count
    nonces: set[str] = field(default_factory=set)
    frozen: dict[str, int] = field(default_factory=dict)  # annotator -> answers already used (not undoable)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @classmethod
    def open(cls, path: str | Path, pair_ids: list[str]) -> AnswerLog:
        log = cls(Path(path), list(pair_ids))
        if log.path.exists():
            data = log.path.read_bytes()
            whole = data[:data.rfind(b"\n") + 1]
            if len(whole) != len(data):  # a line cut short by a kill: never acknowledged, drop it
                with open(log.path, "r+b") as f:
                    f.truncate(len(whole))
                    os.fsync(f.fileno())
            for number, line in enumerate(whole.decode().splitlines(), 1):
                try:
                    record = json.loads(line)
                except json.JSONDecodeError as e:
                    raise ValueError(f"{log.path}: line {number} is not JSON ({e}); the answer log is "
                                     "corrupt") from None
                log._apply(record)
        return log

    def current(self, annotator: str) -> str | None:
        """The pair ``annotator`` is to answer next (None when they have answered them all)."""
        done = len(self.answers.get(annotator, []))
        return self.pair_ids[done] if done < len(self.pair_ids) else None

    def progress(self, annotator: str) -> tuple[int, int]:
        return len(self.answers.get(annotator, [])), len(self.pair_ids)

    def answer(self, annotator: str, pair: str, label: str, nonce: str, response_ms: int) -> dict[str, Any]:
        with self.lock:
            self._check_nonce(nonce)
            if label not in LABELS:
                raise Refused(f"label must be one of {list(LABELS)}, got {label!r}")
            expected = self.current(annotator)
            if pair != expected:
                raise Refused(f"pair {pair!r} is not the one annotator {annotator!r} is shown ({expected!r})", 409)
            return self._append({"event": "answer", "annotator": annotator, "pair": pair, "label": label,
                                 "nonce": nonce, "response_ms": response_ms})

    def undo(self, annotator: str, nonce: str) -> dict[str, Any]:
        with self.lock:
            self._check_nonce(nonce)
            if len(self.answers.get(annotator, [])) <= self.frozen.get(annotator, 0):
                raise Refused(f"annotator {annotator!r} has no answer to undo (answers an agent has used stay)", 409)
            return self._append({"event": "undo", "annotator": annotator,
                                 "pair": self.answers[annotator][-1]["pair"], "nonce": nonce})

    def _check_nonce(self, nonce: str) -> None:
        if nonce in self.nonces:
            raise Refused(f"request {nonce!r} was already received (a replay)", 409)

    def _append(self, record: dict[str, Any]) -> dict[str, Any]:
        record["time"] = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        line = (json.dumps(record, sort_keys=True) + "\n").encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, line)
            os.fsync(fd)
        finally:
            os.close(fd)
        self._apply(record)
        return record

    def _apply(self, record: dict[str, Any]) -> None:
        self.nonces.add(record["nonce"])
        mine = self.answers.setdefault(record["annotator"], [])
        if record["event"] == "answer":
            mine.append(record)
        elif record["event"] == "undo" and mine:
            mine.pop()
