"""Labels from a web endpoint (an LLM behind an HTTP API): ``HTTPAnnotator``.

For each pair the annotator fills a prompt template with the pair as text (``describe.py``: DarkRoom's
visited cells and goal, as in the paper's appendix "Use LLMs to label trajectory preference"), POSTs
``{"prompt": "<text>"}`` as JSON to ``url`` and reads the answer: the reply body, or its JSON field
``"answer"``, must be ``1``, ``2``, ``skip`` or ``equal`` (case and surrounding space ignored).

Timeouts, connection errors and 5xx replies are retried ``retries`` times, waiting ``backoff · 2^k``
seconds before retry k; a 4xx reply or a malformed answer fails at once (asking again would not change
it), with an ``AnnotatorError`` naming the URL and what came back. The client is the standard library's
``urllib``. Template fields: trajectories ``{goal}``, ``{horizon}``, ``{trajectory_1}``,
``{trajectory_2}``, ``{grid}``; steps ``{goal}``, ``{position}``, ``{action_1}``, ``{action_2}``.
"""

from __future__ import annotations

import json
import string
import time
import urllib.error
import urllib.request
from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.describe import action_text, cell, goal_text, grid_text, path_text
from icprl_lightning.annotators.labels import EQUAL, FIRST, SECOND, SKIP, AnnotatorError
from icprl_lightning.validation import HyperparameterError, check_int, check_nonnegative, check_positive

TRAJECTORY_TEMPLATE = (
    "Two agents moved on a {grid_size}x{grid_size} grid for {horizon} steps. Each earns a reward of 1 for "
    "every step that ends on the goal cell {goal}. Cells are (x, y).\n"
    "Trajectory 1 visited: {trajectory_1}\n"
    "Trajectory 2 visited: {trajectory_2}\n"
    "Which trajectory reaches the goal sooner and stays on it longer (the higher total reward)? "
    'Answer with one word: "1", "2", "equal" or "skip".')
STEP_TEMPLATE = (
    "An agent is at cell {position} of a {grid_size}x{grid_size} grid; the goal is the cell {goal}. Cells are "
    "(x, y); up is y + 1, right is x + 1.\n"
    "Action 1: {action_1}\nAction 2: {action_2}\n"
    'Which action brings the agent closer to the goal? Answer with one word: "1", "2", "equal" or "skip".')
TRAJECTORY_FIELDS = {"goal", "horizon", "trajectory_1", "trajectory_2", "grid", "grid_size"}
STEP_FIELDS = {"goal", "position", "action_1", "action_2", "grid_size"}
ANSWERS = {"1": FIRST, "2": SECOND, "equal": EQUAL, "skip": SKIP}


def _check_template(owner: str, key: str, template: str, fields: set[str]) -> str:
    if not isinstance(template, str):
        raise HyperparameterError(f"{owner}: {key} must be a string, got {type(template).__name__}")
    try:
        used = {name for _, name, _, _ in string.Formatter().parse(template) if name is not None}
    except ValueError as e:
        raise HyperparameterError(f"{owner}: {key} is not a valid format string: {e}") from e
    unknown = sorted(used - fields)
    if unknown:
        raise HyperparameterError(f"{owner}: {key} uses unknown field(s) {unknown}; known: {sorted(fields)}")
    return template


def parse_answer(body: bytes, url: str) -> int:
    """The label code of a reply: plain ``1``/``2``/``skip``/``equal`` or JSON ``{"answer": ...}``."""
    text = body.decode("utf-8", errors="replace").strip()
    try:
        payload = json.loads(text)
    except ValueError:
        payload = text
    if isinstance(payload, dict):
        if "answer" not in payload:
            raise AnnotatorError(f"HTTPAnnotator: the reply of {url} is JSON without an 'answer' field: {text[:200]!r}")
        payload = payload["answer"]
    answer = str(payload).strip().strip("\"'.").lower()
    if answer not in ANSWERS:
        raise AnnotatorError(f"HTTPAnnotator: the reply of {url} must be 1, 2, skip or equal (plain or as JSON "
                             f"{{\"answer\": ...}}), got {text[:200]!r}")
    return ANSWERS[answer]


class HTTPAnnotator(Annotator):
    """One POST per pair to ``url``; see the module docstring.

    Args:
        url: the endpoint (``http://`` or ``https://``).
        template: the prompt of a trajectory pair (a ``str.format`` template; default: DarkRoom's).
        step_template: the prompt of a step pair.
        timeout: seconds to wait for one reply.
        retries: further attempts after a timeout, connection error or 5xx reply.
        backoff: seconds before the first retry, doubled on each next one.
        grid_size: the DarkRoom grid's side, for the prompt.
    """

    def __init__(self, url: str, template: str = TRAJECTORY_TEMPLATE, step_template: str = STEP_TEMPLATE,
                 timeout: float = 30.0, retries: int = 3, backoff: float = 1.0, grid_size: int = 10) -> None:
        owner = type(self).__name__
        if not isinstance(url, str) or not url.startswith(("http://", "https://")):
            raise HyperparameterError(f"{owner}: url must start with http:// or https://, got {url!r}")
        self.url = url
        self.template = _check_template(owner, "template", template, TRAJECTORY_FIELDS)
        self.step_template = _check_template(owner, "step_template", step_template, STEP_FIELDS)
        self.timeout = check_positive(owner, "timeout", timeout)
        self.retries = check_int(owner, "retries", retries, 0)
        self.backoff = check_nonnegative(owner, "backoff", backoff)
        self.grid_size = check_int(owner, "grid_size", grid_size, 1)

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        tasks = queries.tasks
        return np.array([self.ask(self.step_template.format(
            goal=goal_text(None if tasks is None else tasks[i]), position=cell(queries.states[i]),
            action_1=action_text(queries.actions[i]), action_2=action_text(queries.alt_actions[i]),
            grid_size=self.grid_size)) for i in range(len(queries.states))], dtype=np.uint8)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        tasks = queries.tasks
        out = []
        for i in range(len(queries.states_a)):
            task = None if tasks is None else tasks[i]
            out.append(self.ask(self.template.format(
                goal=goal_text(task), horizon=queries.states_a.shape[1], grid_size=self.grid_size,
                trajectory_1=path_text(queries.states_a[i]), trajectory_2=path_text(queries.states_b[i]),
                grid=grid_text(queries.states_a[i], queries.states_b[i], task, self.grid_size))))
        return np.array(out, dtype=np.uint8)

    def ask(self, prompt: str) -> int:
        """POST one prompt and parse its answer, retrying transient failures (module docstring)."""
        data = json.dumps({"prompt": prompt}).encode()
        last: Exception | None = None
        for attempt in range(self.retries + 1):
            if attempt:
                time.sleep(self.backoff * 2 ** (attempt - 1))
            request = urllib.request.Request(self.url, data=data, method="POST",
                                             headers={"Content-Type": "application/json"})
            try:
                with urllib.request.urlopen(request, timeout=self.timeout) as reply:
                    body = reply.read()
            except urllib.error.HTTPError as e:
                if e.code < 500:
                    raise AnnotatorError(f"HTTPAnnotator: {self.url} answered HTTP {e.code} {e.reason}") from e
                last = e
            except (urllib.error.URLError, TimeoutError, ConnectionError) as e:
                last = e
            else:
                return parse_answer(body, self.url)
        raise AnnotatorError(f"HTTPAnnotator: no answer from {self.url} after {self.retries + 1} attempt(s) "
                             f"(timeout {self.timeout} s): {last}")

    def init_args(self) -> dict[str, Any]:
        return {"url": self.url, "template": self.template, "step_template": self.step_template,
                "timeout": self.timeout, "retries": self.retries, "backoff": self.backoff,
                "grid_size": self.grid_size}
