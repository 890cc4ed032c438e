"""A person at a terminal labels the pairs: ``TerminalAnnotator``.

Each query is drawn as text on ``output`` — a trajectory pair as an ASCII grid with both DarkRoom paths
and the goal (``describe.grid_text``), a step pair as the agent's cell, the goal and the two proposed
actions — and one key is read from ``input``: ``1`` (first better), ``2`` (second), ``e`` (equal) or
``s`` (skip). Any other key asks again. On a terminal the key is read without Enter (cbreak mode, restored
afterwards); from a pipe or file each line's first character counts. The end of the input is an error.
Streams default to the process's stdin/stdout.
"""

from __future__ import annotations

import os
import sys
import termios
import tty
from typing import Any, TextIO

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.describe import action_text, cell, goal_text, grid_text
from icprl_lightning.annotators.labels import EQUAL, FIRST, SECOND, SKIP, AnnotatorError
from icprl_lightning.validation import check_int

KEYS = {"1": FIRST, "2": SECOND, "e": EQUAL, "s": SKIP}
PROMPT = "Better: [1] / [2], [e]qual, [s]kip > "


class TerminalAnnotator(Annotator):
    """Labels typed by a person; see the module docstring.

    Args:
        grid_size: the DarkRoom grid's side, for the drawing.
        input: where keys are read (default ``sys.stdin``).
        output: where queries are drawn (default ``sys.stdout``).
    """

    def __init__(self, grid_size: int = 10, input: TextIO | None = None, output: TextIO | None = None) -> None:
        self.grid_size = check_int(type(self).__name__, "grid_size", grid_size, 1)
        self.input = input
        self.output = output
        self.asked = 0

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        out = []
        for i in range(len(queries.states)):
            task = None if queries.tasks is None else queries.tasks[i]
            out.append(self.ask(f"Agent at {cell(queries.states[i])}, goal {goal_text(task)}\n"
                                f"  1: {action_text(queries.actions[i])}\n"
                                f"  2: {action_text(queries.alt_actions[i])}"))
        return np.array(out, dtype=np.uint8)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        out = []
        for i in range(len(queries.states_a)):
            task = None if queries.tasks is None else queries.tasks[i]
            picture = grid_text(queries.states_a[i], queries.states_b[i], task, self.grid_size)
            out.append(self.ask(f"Two paths of {queries.states_a.shape[1]} steps (1, 2; * both; G goal "
                                f"{goal_text(task)})\n{picture}"))
        return np.array(out, dtype=np.uint8)

    def ask(self, text: str) -> int:
        """Draw one query and read keys until one of 1 / 2 / e / s."""
        src, dst = self.input or sys.stdin, self.output or sys.stdout
        self.asked += 1
        dst.write(f"\n[query {self.asked}]\n{text}\n")
        while True:
            dst.write(PROMPT)
            dst.flush()
            key = self._read_key(src)
            if key == "":
                raise AnnotatorError("TerminalAnnotator: the input ended before an answer (1, 2, e or s)")
            dst.write(key + "\n")
            if key.lower() in KEYS:
                return KEYS[key.lower()]

    @staticmethod
    def _read_key(src: TextIO) -> str:
        if not src.isatty():
            line = src.readline()
            return line.strip()[:1] or ("?" if line else "")
        fd = src.fileno()
        saved = termios.tcgetattr(fd)
        try:
            tty.setcbreak(fd, termios.TCSANOW)  # TCSANOW: keep keys typed ahead
            return os.read(fd, 1).decode(errors="replace")
        finally:
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    def init_args(self) -> dict[str, Any]:
        return {"grid_size": self.grid_size}
