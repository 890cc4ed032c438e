"""Every runnable code block of ``README.md`` and ``docs/**/*.md`` runs exactly as printed.

A document's fenced blocks run in order, in one scratch directory per document (the repository's
``configs/`` and ``benchmarks/`` linked into it, so commands written for the repository root
work), with ``OMP_NUM_THREADS=1``, ``WANDB_MODE=disabled`` and the virtualenv's ``bin`` first on ``PATH``:

* ```` ```python ```` blocks run in this process, in one namespace per document (``__name__ == "__main__"``,
  the scratch directory first on ``sys.path``, so ``import chain`` finds a ``chain.py`` written before);
* ```` ```bash ```` (or ``sh``, ``shell``) blocks run under ``bash -e -o pipefail``;
* other blocks (``yaml``, untagged layouts, tables of files) are read, not run, unless a directive names a file.

Directives are HTML comments (invisible once rendered), one per line, on the lines just before a fence:

* ``<!-- not run -->``: the block is illustrative (placeholders, hours of training); keep these few.
* ``<!-- file: PATH -->``: the block is not run but written to ``PATH`` in the scratch directory; several
  blocks naming one path are concatenated in order (a module shown piece by piece).
* ``<!-- expect: TEXT -->``: the block's output (stdout and stderr) must contain ``TEXT``.
* ``<!-- setup: NAME -->``: before the block runs, ``SETUPS[NAME]`` (below) makes what it assumes and
  defines the names it returns, as Python globals and environment variables (e.g. ``CHECKPOINT``).

A document whose blocks train (``icprl fit``, or a setup) is a slow test; the rest are fast.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from factories import REPO, cli_data_args

DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
RUN_LANGUAGES = {"python": "python", "bash": "bash", "sh": "bash", "shell": "bash"}
LINKED = ("configs", "benchmarks")
FENCE = re.compile(r"^```\s*([\w+-]*)\s*$")
DIRECTIVE = re.compile(r"^<!--\s*(not run|file|expect|setup)\s*(?::\s*(.*?))?\s*-->$")
BLOCK_TIMEOUT = 300  # seconds per bash block: the docs' runnable commands take well under a minute


@dataclass
class Block:
    """One fenced block: where it is, its language, its text and the directives before it."""

    document: Path
    line: int  # of the opening fence, 1-based
    language: str
    code: str
    directives: dict[str, list[str]] = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.document.relative_to(REPO)}:{self.line}"

    @property
    def runs(self) -> bool:
        return self.language in RUN_LANGUAGES and not {"not run", "file"} & self.directives.keys()


def blocks(document: Path) -> list[Block]:
    """The fenced blocks of a markdown file with their directives; an unclosed fence is an error."""
    lines = document.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        directives: dict[str, list[str]] = {}
        j = i - 1
        while j >= 0 and (match := DIRECTIVE.match(lines[j].strip())):
            directives.setdefault(match[1], []).insert(0, match[2] or "")
            j -= 1
        end = next((k for k in range(i + 1, len(lines)) if lines[k].strip() == "```"), None)
        if end is None:
            raise ValueError(f"{document}:{i + 1}: a code fence is never closed")
        out.append(Block(document, i + 1, opening[1].lower(), "\n".join(lines[i + 1:end]) + "\n", directives))
        i = end + 1
    return out


# ---- setups: what a block assumes and its own document cannot make in seconds --------------------------------

def _bandit_checkpoint(workdir: Path) -> dict[str, str]:
    """A bandit ICPO checkpoint trained for two steps on a tiny dataset: ``CHECKPOINT``."""
    from icprl_lightning.commands import run_cli

    root = workdir / "_setup_bandit"
    data = cli_data_args("bandit", root_dir=str(root / "data"), n_train_problems=8, n_val_problems=2,
                         n_eval_problems=4, batch_size=4, progress=False)
    run_cli(["fit", "--config", str(REPO / "configs/icpo_bandit.yaml"), "--trainer.logger", "false",
             "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1",
             "--evaluation", "null", "--best_checkpoint", "null", "--trainer.default_root_dir", str(root), *data])
    return {"CHECKPOINT": str(next(root.rglob("*.ckpt")))}


SETUPS: dict[str, Callable[[Path], dict[str, str]]] = {"bandit_checkpoint": _bandit_checkpoint}


# ---- running ---------------------------------------------------------------------------------------------------

def _environment(extra: dict[str, str]) -> dict[str, str]:
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    return {**os.environ, "OMP_NUM_THREADS": "1", "WANDB_MODE": "disabled", "PATH": path, **extra}


def _run_python(block: Block, namespace: dict) -> str:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        exec(compile(block.code, block.where, "exec"), namespace)
    return buffer.getvalue()


def _run_bash(block: Block, workdir: Path, env: dict[str, str]) -> str:
    # its own process group, so a block that outlives BLOCK_TIMEOUT is stopped with every command it started
    with subprocess.Popen(["bash", "-e", "-o", "pipefail", "-c", block.code], cwd=workdir, env=env, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True) as proc:
        try:
            output, _ = proc.communicate(timeout=BLOCK_TIMEOUT)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            output, _ = proc.communicate()
            raise AssertionError(f"{block.where}: still running after {BLOCK_TIMEOUT} s (stopped); a block "
                                 f"that trains for long is illustrative: mark it <!-- not run -->") from None
    if proc.returncode != 0:
        raise AssertionError(f"{block.where}: exit status {proc.returncode}\n{output[-4000:]}")
    return output


def run_document(document: Path, workdir: Path, monkeypatch: pytest.MonkeyPatch) -> list[tuple[Block, str]]:
    """Run a document's blocks in order in ``workdir``; returns each run block with its output."""
    for name in LINKED:
        (workdir / name).symlink_to(REPO / name, target_is_directory=True)
    monkeypatch.chdir(workdir)
    monkeypatch.syspath_prepend(str(workdir))
    modules_before = set(sys.modules)
    namespace: dict = {"__name__": "__main__"}
    given: dict[str, str] = {}
    written: set[str] = set()
    outputs = []
    try:
        for block in blocks(document):
            for path in block.directives.get("file", []):
                target = workdir / path
                target.parent.mkdir(parents=True, exist_ok=True)
                with target.open("a" if path in written else "w") as f:  # later blocks extend the file
                    f.write(block.code if path not in written else "\n\n" + block.code)
                written.add(path)
            if not block.runs:
                continue
            for name in block.directives.get("setup", []):
                given.update(SETUPS[name](workdir))
            namespace.update(given)
            if RUN_LANGUAGES[block.language] == "python":
                try:
                    output = _run_python(block, namespace)
                except Exception as error:
                    raise AssertionError(f"{block.where}: {type(error).__name__}: {error}") from error
            else:
                output = _run_bash(block, workdir, _environment(given))
            for text in block.directives.get("expect", []):
                assert text in output, f"{block.where}: output lacks {text!r}:\n{output[-4000:]}"
            outputs.append((block, output))
    finally:  # modules a document wrote (chain.py) must not leak into another document's run
        for name in set(sys.modules) - modules_before:
            module_file = getattr(sys.modules[name], "__file__", None) or ""
            if module_file.startswith(str(workdir)):
                del sys.modules[name]
    return outputs


def _trains(document: Path) -> bool:
    return any(b.runs and ("icprl fit" in b.code or "setup" in b.directives) for b in blocks(document))


@pytest.mark.parametrize("document", [
    pytest.param(d, id=str(d.relative_to(REPO)), marks=[pytest.mark.slow] if _trains(d) else [])
    for d in DOCUMENTS if any(b.runs or "file" in b.directives for b in blocks(d))])
def test_document_runs_as_printed(document, tmp_path, monkeypatch):
    outputs = run_document(document, tmp_path, monkeypatch)
    assert outputs, f"{document}: no block ran"


# ---- the collector itself ----------------------------------------------------------------------------------------

def test_directives_and_languages_are_read(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("text\n<!-- not run -->\n```bash\nmake run\n```\n\n<!-- file: m.py -->\n```python\nx = 1\n```\n"
                   "<!-- setup: bandit_checkpoint -->\n<!-- expect: 1 -->\n```python\nprint(CHECKPOINT)\n```\n"
                   "```yaml\na: 1\n```\n```\nlayout\n```\n")
    found = blocks(doc)
    assert [(b.language, b.runs) for b in found] == [("bash", False), ("python", False), ("python", True),
                                                     ("yaml", False), ("", False)]
    assert found[1].directives == {"file": ["m.py"]}
    assert found[2].directives == {"setup": ["bandit_checkpoint"], "expect": ["1"]}
    assert found[2].code == "print(CHECKPOINT)\n"


def test_an_unclosed_fence_is_an_error(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("```python\nx = 1\n")
    with pytest.raises(ValueError, match="never closed"):
        blocks(doc)


def test_a_failing_block_names_its_document_and_line(tmp_path, monkeypatch):
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- file: m.py -->\n```python\nVALUE = 2\n```\n```python\nimport m\nprint(m.VALUE)\n```\n"
                   "<!-- expect: 3 -->\n```bash\necho 3\n```\n```bash\nfalse\necho unreachable\n```\n")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    for name in LINKED:
        (tmp_path / name).mkdir()
    with pytest.raises(AssertionError, match=r"doc\.md:13: exit status 1"):
        run_document(doc, work, monkeypatch)
    assert "m" not in sys.modules  # the document's module was unloaded


def test_a_block_that_runs_too_long_is_stopped_with_its_children(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "BLOCK_TIMEOUT", 1)
    block = Block(tmp_path / "doc.md", 1, "bash", "sleep 60 &\necho $! > child.pid\nwait\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    start = time.monotonic()
    with pytest.raises(AssertionError, match="still running after 1 s"):
        _run_bash(block, tmp_path, _environment({}))
    assert time.monotonic() - start < 20  # not after the background command's own 60 s
    child = int((tmp_path / "child.pid").read_text())
    with pytest.raises(ProcessLookupError):  # the background command went with the block
        for _ in range(50):
            os.kill(child, 0)
            time.sleep(0.1)
