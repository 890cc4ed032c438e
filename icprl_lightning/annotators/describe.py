"""DarkRoom queries as text, for the annotators that ask someone (an LLM over HTTP).

A DarkRoom observation is the agent's cell (x, y); the task is the goal cell, hidden from the agent and
shown to the annotator (as in the paper's appendix "Use LLMs to label trajectory preference", where the
prompt lists the visited cells and the goal). Actions move the agent: 0 up (y + 1), 1 down, 2 left
(x − 1), 3 right, 4 stay (``families/darkroom/env.py``, ``MOVES``). Continuous actions are written as
rounded vectors.
"""

from __future__ import annotations

import numpy as np

ACTION_NAMES = ("up", "down", "left", "right", "stay")


def cell(state: np.ndarray) -> tuple[int, int]:
    """The grid cell of one observation (x, y)."""
    return int(round(float(state[0]))), int(round(float(state[1])))


def goal_text(task: np.ndarray | None) -> str:
    return "unknown" if task is None else str(cell(np.asarray(task)))


def path_text(states: np.ndarray) -> str:
    """The visited cells of one trajectory [H, S], in order: ``(0, 1) (0, 2) ...``."""
    return " ".join(str(cell(s)) for s in states)


def action_text(action: np.ndarray) -> str:
    """A DarkRoom action by name, a continuous action as a rounded vector."""
    a = np.asarray(action)
    if a.ndim == 0 and 0 <= int(a) < len(ACTION_NAMES):
        return ACTION_NAMES[int(a)]
    return np.array2string(a, precision=3, separator=", ")


def grid_text(states_a: np.ndarray, states_b: np.ndarray, task: np.ndarray | None, size: int) -> str:
    """An ASCII picture of two DarkRoom paths on a ``size`` × ``size`` grid (y up).

    ``1`` / ``2``: cells only path 1 / path 2 visited, ``*``: both, ``G``: the goal, ``.``: neither.
    """
    grid = [["." for _ in range(size)] for _ in range(size)]
    for mark, states in (("1", states_a), ("2", states_b)):
        for s in states:
            x, y = cell(s)
            if 0 <= x < size and 0 <= y < size:
                grid[y][x] = "*" if grid[y][x] not in (".", mark) else mark
    if task is not None:
        gx, gy = cell(np.asarray(task))
        if 0 <= gx < size and 0 <= gy < size:
            grid[gy][gx] = "G"
    rows = [f"{y:2d} " + " ".join(grid[y]) for y in range(size - 1, -1, -1)]
    return "\n".join([*rows, "   " + " ".join(str(x % 10) for x in range(size))])
