"""A person at a terminal labels the pairs: ``TerminalAnnotator``.

Each query is drawn as text on ``output`` — a trajectory pair as an ASCII grid with both DarkRoom paths
and the goal (``describe.grid_text``), a step pair as the agent's cell, the goal and the two proposed
actions — and one key is read from ``input``: ``1`` (first better), ``2`` (second), ``e`` (equal) or
``s`` (skip). Any other key asks again. On a terminal the key is read without Enter (cbreak mode, restored
afterwards); from a pipe or file each line's first character counts. The end of the input is an error.

Streams default to the process's stdin/stdout, and then both must be an open interactive terminal: a
person must see the query and type the key, so a job without one (a batch run, output redirected to a
file, stdin closed) stops at its first query with an error saying so, instead of waiting on a pipe nobody
writes to or drawing for nobody. Streams passed as ``input``/``output`` (tests, programs feeding answers)
need not be terminals, only open. A read or write failing mid-way (the terminal hung up) is an
``AnnotatorError`` too. The check runs when labeling starts, not at construction, so a config naming this
annotator still loads where nobody types (e.g. to train on a dataset labeled earlier).
"""

from __future__ import annotations

import os
import sys
import termios
import tty
from typing import IO, Any, TextIO

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
        input: where keys are read (default ``sys.stdin``, which must then be a terminal).
        output: where queries are drawn (default ``sys.stdout``, which must then be a terminal).
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
        src, dst = self.streams()
        self.asked += 1
        try:
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
        except AnnotatorError:
            raise
        except (OSError, ValueError, termios.error) as e:  # ValueError: "I/O operation on closed file"
            raise AnnotatorError(f"TerminalAnnotator: the terminal failed while asking query {self.asked}: "
                                 f"{type(e).__name__}: {e}") from None

    def streams(self) -> tuple[IO[str], IO[str]]:
        """(input, output), checked: open, and interactive terminals unless passed in (module docstring)."""
        return (_checked(self.input, "input", sys.stdin, "stdin"),
                _checked(self.output, "output", sys.stdout, "stdout"))

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


def _checked(given: IO[str] | None, key: str, default: IO[str] | None, default_name: str) -> IO[str]:
    """``given`` if open; else the process's stream if an open TTY; else an ``AnnotatorError`` saying why."""
    if given is not None:
        if getattr(given, "closed", False):
            raise AnnotatorError(f"TerminalAnnotator: the {key} stream passed in is closed")
        return given
    problem = ("is missing (None)" if default is None else "is closed" if getattr(default, "closed", False)
               else None if _is_tty(default) else "is not a TTY")
    if problem is not None:
        raise AnnotatorError(f"TerminalAnnotator needs an interactive terminal: {default_name} {problem}; use "
                             "HTTPAnnotator or CallableAnnotator to label without one")
    return default


def _is_tty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, OSError, ValueError):  # not a file, or its descriptor is gone
        return False
