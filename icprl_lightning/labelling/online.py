"""A person answers in the browser as an ``Annotator``: ``BrowserAnnotator`` teaches an agent in context online
(``icprl evaluate online --browser-session DIR``), or labels a DarkRoom dataset while it is generated (a
setting's ``annotator``); docs/labelling.md shows both.

Answers go through the labelling server (``server.py``: the token, the checks) into the session's append-only
log, so every answer is on disk with its response time; each asked comparison goes to ``<session>/asked.jsonl``.
An answer the agent has used can no longer be undone. The page's address (with its token) is printed on stderr
and written to ``<session>/page.url`` (mode 0600), where a program answering for a person finds it. One query
step asks one comparison per held-out task; the page shows them one after another. EQUAL and SKIP enter a
context as a fair coin (``annotators/labels.py``). Only DarkRoom's 2-D cells are drawn; other families' queries
are an error.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.labels import CODES, AnnotatorError
from icprl_lightning.labelling.answer_log import AnswerLog, Refused


@dataclass
class OnlineSession:
    """The comparisons asked so far (what ``server.make_app`` serves), their log and what the page draws."""

    path: Path
    log: AnswerLog
    shown: dict[str, dict[str, Any]] = field(default_factory=dict)
    open_ended = True  # the page waits for the next question instead of saying "all answered"

    def show(self, pair: str) -> dict[str, Any]:
        if pair not in self.shown:  # asked before this run (a continued session), to someone else
            raise Refused(f"pair {pair!r} was asked in an earlier run; answer as the run's annotator", 409)
        return self.shown[pair]


class BrowserAnnotator(Annotator):
    """A person answering the online agent's comparisons in the browser; see the module docstring.

    Args:
        session: the directory of the answer log (created if missing; a log there is continued).
        host, port: where the page is served (default: loopback, any free port); its address is printed.
        annotator: the person's name on the log and in the page's address.
        timeout: seconds to wait for one batch of answers before giving up (``AnnotatorError``).
        grid_size: the DarkRoom grid's side, for the drawing.
    """

    def __init__(self, session: str, host: str = "127.0.0.1", port: int = 0, annotator: str = "person",
                 timeout: float = 3600.0, grid_size: int = 10) -> None:
        self.session_dir, self.host, self.port, self.annotator, self.timeout = session, host, port, annotator, timeout
        self.grid_size = grid_size
        self.url: str | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._episode = {"paths": None, "returns": None}
        self._context: list[list[dict[str, Any]]] = []

    def init_args(self) -> dict[str, Any]:
        return {"session": self.session_dir, "host": self.host, "port": self.port, "annotator": self.annotator,
                "timeout": self.timeout, "grid_size": self.grid_size}

    # ---- the page's server ---------------------------------------------------------------------------------
    def start(self) -> str:
        """Serve the page (once) and return its address, with the token and the annotator's name."""
        if self.url is not None:
            return self.url
        import uvicorn

        from icprl_lightning.labelling.server import LOOPBACK, make_app

        path = Path(self.session_dir)
        path.mkdir(parents=True, exist_ok=True)
        log = AnswerLog.open(path / "answers.jsonl", [])
        log.pair_ids.extend(a["pair"] for a in log.answers.get(self.annotator, []))  # a continued session
        log.frozen[self.annotator] = len(log.pair_ids)
        self.session = OnlineSession(path, log)
        token = secrets.token_urlsafe(24)
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.bind((self.host, self.port))
        sock.listen(128)
        host, port = sock.getsockname()
        app = make_app(self.session, token, LOOPBACK if self.host == "127.0.0.1" else [*LOOPBACK, self.host])
        self._server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
        self._thread = threading.Thread(target=self._server.run, kwargs={"sockets": [sock]}, daemon=True)
        self._thread.start()
        self.url = f"http://{host}:{port}/?token={token}&annotator={self.annotator}"
        fd = os.open(path / "page.url", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)  # as Jupyter's runtime file
        with os.fdopen(fd, "w") as f:
            f.write(self.url + "\n")
        print(f"BrowserAnnotator: answer the agent's comparisons at\n  {self.url}", file=sys.stderr, flush=True)
        return self.url

    def stop(self) -> None:
        if self._server is not None:
            self._server.should_exit = True
            self._thread.join(10)
            self._server, self.url = None, None

    # ---- what the online loop tells it -----------------------------------------------------------------------
    def watch(self, observations: np.ndarray, returns: np.ndarray, step: int) -> None:
        """The agents' cells and returns so far at ``step`` of the episode (step 0 starts a new path)."""
        cells = np.asarray(observations).round().astype(int).tolist()
        if step == 0 or self._episode["paths"] is None:
            self._episode["paths"] = [[c] for c in cells]
        else:
            for path, c in zip(self._episode["paths"], cells, strict=True):
                path.append(c)
        self._episode["returns"] = np.asarray(returns, dtype=float).tolist()

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        n = self._check(queries.states, "step")
        while len(self._context) < n:
            self._context.append([])
        paths, returns = self._episode["paths"] or [[]] * n, self._episode["returns"] or [0.0] * n
        labels = self._ask([{"view": "online_darkroom", "cell": queries.states[i].tolist(),
                             "first": int(queries.actions[i]), "second": int(queries.alt_actions[i]), "task": i,
                             "goal": _goal(queries.tasks, i), "path": paths[i][-200:], "return": returns[i],
                             "context": self._context[i][-30:]} for i in range(n)])
        for i, label in enumerate(labels):
            self._context[i].append({"cell": queries.states[i].tolist(), "first": int(queries.actions[i]),
                                     "second": int(queries.alt_actions[i]), "answer": label})
        return np.array([CODES[label] for label in labels], dtype=np.uint8)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        n = self._check(queries.states_a, "trajectory")
        labels = self._ask([{"view": "darkroom_trajectories", "goal": _goal(queries.tasks, i), "task": i,
                             "first": np.asarray(queries.states_a[i]).round().astype(int).tolist(),
                             "second": np.asarray(queries.states_b[i]).round().astype(int).tolist()}
                            for i in range(n)])
        return np.array([CODES[label] for label in labels], dtype=np.uint8)

    def _check(self, states: np.ndarray, what: str) -> int:
        if states.shape[-1] != 2:
            raise AnnotatorError(f"BrowserAnnotator draws DarkRoom {what} pairs (2-D cells); this family's states have "
                                 f"{states.shape[-1]} numbers")
        return len(states)

    def _ask(self, shown: list[dict[str, Any]]) -> list[str]:
        """Put the comparisons on the page, wait for every answer, return them in order (first / second / ...)."""
        self.start()
        log = self.session.log
        ids = [f"asked-{len(log.pair_ids) + i:05d}" for i in range(len(shown))]
        with open(self.session.path / "asked.jsonl", "a") as f:
            for pair, item in zip(ids, shown, strict=True):
                self.session.shown[pair] = {"pair": pair, "size": self.grid_size, **item}
                f.write(json.dumps(self.session.shown[pair]) + "\n")
        log.pair_ids.extend(ids)
        deadline = time.monotonic() + self.timeout
        while log.current(self.annotator) is not None:
            if time.monotonic() > deadline:
                raise AnnotatorError(f"BrowserAnnotator: no answer to {log.current(self.annotator)} within "
                                     f"{self.timeout:g} s (the page is at {self.url})")
            time.sleep(0.02)
        with log.lock:  # the answers are used from now on: no undo
            log.frozen[self.annotator] = len(log.pair_ids)
            return [a["label"] for a in log.answers[self.annotator][-len(ids):]]


def _goal(tasks: np.ndarray | None, i: int) -> list | None:
    return None if tasks is None else np.asarray(tasks[i]).tolist()
