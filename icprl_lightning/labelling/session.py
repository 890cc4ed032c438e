"""A labelling session's directory: what is asked (``session.json``, ``queue.npz``) and what was answered.

    <session>/session.json   {"format", "version", "view", "pairs", "seed"}
    <session>/queue.npz      the pairs' arrays (``pairs.py``), drawn once from the seed
    <session>/answers.jsonl  the append-only answer log (``answer_log.py``)

The first ``icprl label`` in an empty directory draws the queue and writes both files atomically (temp file,
fsync, rename); a later one reopens them, so a restarted server shows the same pairs. Reopening with another
view, size or seed is an error naming the field (a queue is never redrawn under its answers). One server holds
the session's lock (``flock``, released by the kernel even on SIGKILL), so two servers never append to one log.
"""

from __future__ import annotations

import fcntl
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.io import write_atomic, write_json_atomic
from icprl_lightning.labelling.answer_log import AnswerLog
from icprl_lightning.labelling.pairs import VIEWS, PairSource

FORMAT, VERSION = "icprl_label_session", 1


@dataclass
class Session:
    path: Path
    config: dict[str, Any]
    arrays: dict[str, np.ndarray]
    log: AnswerLog

    @property
    def source(self) -> PairSource:
        return VIEWS[self.config["view"]]()

    @property
    def pair_ids(self) -> list[str]:
        return self.log.pair_ids

    def show(self, pair: str) -> dict[str, Any]:
        """What the page draws for ``pair`` (no utility: the latent ordering stays on the server)."""
        i = self.pair_ids.index(pair)
        return {"pair": pair, "view": self.config["view"], **self.source.show(self.arrays, i)}


def pair_ids(view: str, n: int) -> list[str]:
    return [f"{view}-{i:05d}" for i in range(n)]


def open_session(path: str | Path, view: str | None = None, pairs: int | None = None, seed: int | None = None
                 ) -> Session:
    """Open the session at ``path``, drawing its queue first if it has none (then ``view`` and ``pairs`` are needed)."""
    path = Path(path)
    meta = path / "session.json"
    if meta.exists():
        config = json.loads(meta.read_text())
        if config.get("format") != FORMAT or config.get("version") != VERSION:
            raise ValueError(f"{meta} is not a labelling session of version {VERSION}")
        for key, value in (("view", view), ("pairs", pairs), ("seed", seed)):
            if value is not None and value != config[key]:
                raise ValueError(f"{path} holds a session with {key} {config[key]!r}, not {value!r}; "
                                 f"label it as it is (leave --{key} out) or choose a new --session directory")
    else:
        if view not in VIEWS:
            raise ValueError(f"--view must be one of {sorted(VIEWS)} for a new session, got {view!r}")
        if not isinstance(pairs, int) or not 1 <= pairs <= 10_000:
            raise ValueError(f"--pairs must be an integer in [1, 10000], got {pairs!r}")
        config = {"format": FORMAT, "version": VERSION, "view": view, "pairs": pairs,
                  "seed": 0 if seed is None else seed}
        path.mkdir(parents=True, exist_ok=True)
        arrays = VIEWS[view]().build(pairs, config["seed"])
        write_atomic(path / "queue.npz", lambda f: np.savez(f, **arrays))
        write_json_atomic(meta, config)  # last: a session.json means a whole queue
    with np.load(path / "queue.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return Session(path, config, arrays, AnswerLog.open(path / "answers.jsonl", pair_ids(config["view"],
                                                                                         config["pairs"])))


def hold_lock(path: str | Path) -> int:
    """Take the session's server lock (a file descriptor the caller keeps open); an error if a server holds it."""
    fd = os.open(Path(path) / ".server.lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise ValueError(f"another icprl label server is serving {path}; stop it first") from None
    return fd
