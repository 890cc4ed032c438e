"""A user script that builds a Reach env at top level, without ``if __name__ == "__main__":``, fails with an
error that says so — not a bare "worker process died".

Why it fails at all: Reach's worker processes start by ``forkserver``, which imports the main script again
before a worker runs (``env.py``, ``_startup_death_message``); ``fork`` would not, but forking a parent
that runs threads (torch, W&B) can deadlock the child.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("metaworld")

from icprl_lightning.families.metaworld_reach.env import _has_main_guard  # noqa: E402

SCRIPT = """\
import numpy as np

from icprl_lightning.families.metaworld_reach.env import ReachVectorEnv

{indent}env = ReachVectorEnv(np.array([[0.0, 0.85, 0.2]]), num_workers=1)
{indent}obs, _ = env.reset(seed=0)
{indent}print("obs", obs.shape)
{indent}env.close()
"""


def _run(tmp_path, guarded: bool) -> subprocess.CompletedProcess:
    body = SCRIPT.format(indent="    " if guarded else "")
    if guarded:
        head, tail = body.split("\n\n    env", 1)
        body = head + '\n\nif __name__ == "__main__":\n    env' + tail
    script = tmp_path / ("guarded.py" if guarded else "unguarded.py")
    script.write_text(body)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)


def test_an_unguarded_script_is_told_to_add_the_main_guard(tmp_path):
    result = _run(tmp_path, guarded=False)
    assert result.returncode != 0
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: a reach-v3 worker process died at start-up"), last
    assert 'if __name__ == "__main__":' in last and str(tmp_path / "unguarded.py") in last, last


@pytest.mark.slow  # another ≈10 s subprocess; the env's own tests cover a working pool
def test_the_same_script_with_the_guard_runs(tmp_path):
    result = _run(tmp_path, guarded=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "obs (1, 39)"


@pytest.mark.parametrize(("source", "guarded"), [
    ('if __name__ == "__main__":\n    main()\n', True),
    ("if '__main__' == __name__:\n    main()\n", True),
    ("main()\n", False),
    ('def f():\n    if __name__ == "__main__":\n        main()\n', False),  # not at top level
    ("if __name__ == 'other':\n    main()\n", False),
])
def test_the_guard_is_recognized_at_top_level_only(tmp_path, source, guarded):
    path = tmp_path / "script.py"
    path.write_text(textwrap.dedent(source))
    assert _has_main_guard(str(path)) is guarded


def test_an_unreadable_script_is_not_called_unguarded(tmp_path):
    assert _has_main_guard(str(tmp_path / "missing.py")) is None
