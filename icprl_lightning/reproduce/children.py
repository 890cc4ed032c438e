"""The fits ``icprl reproduce`` starts as processes, what a signal does to them, and one reproduction per folder.

* ``Children.run``: one ``icprl fit`` in its own session (a terminal's Ctrl+C reaches it only through here), its
  output into a log that is never a link or a FIFO.
* ``Children.forwarding``: SIGTERM and SIGINT are sent on to every running fit (which saves ``last.ckpt`` at its
  next batch boundary and exits 143) and stop the command with ``Interrupted``; no new fit starts. Each stopped
  fit is recorded as interrupted (``"status": "interrupted"`` and its ``last.ckpt``) and the command exits
  128 + the signal; running it again resumes from that checkpoint instead of training a second copy.
* ``work_lock``: an exclusive, non-blocking ``flock`` on ``<folder>/.reproduce.lock``: a second reproduction
  in the same folder is refused in one line naming the holder's pid.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from icprl_lightning.io import check_writable, write_json_atomic

SIGNALS = (signal.SIGTERM, signal.SIGINT)
GRACE_SECONDS = 600.0  # how long a stopped fit may take to save and exit before it is killed


class Interrupted(Exception):
    """``icprl reproduce`` received ``signum``; its running fits were sent the same signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum


class WorkLocked(ValueError):
    """Another ``icprl reproduce`` holds the folder's lock."""


class Children:
    """The running fits of one ``icprl reproduce``, and the signal that stopped it (None while running)."""

    def __init__(self) -> None:
        self.live: set[subprocess.Popen] = set()
        self.guard = threading.Lock()
        self.stopping: int | None = None

    def run(self, argv: list[str], log: Path, env: dict[str, str]) -> int:
        """Run ``argv`` to its end with its output in ``log``; its exit status. ``Interrupted`` if the command
        is stopping (no new fit starts)."""
        if self.stopping is not None:
            raise Interrupted(self.stopping)
        check_writable(log)
        log.unlink(missing_ok=True)  # a link is replaced, not followed; O_EXCL below
        with open(os.open(log, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "w") as out:
            with self.guard:
                if self.stopping is not None:
                    raise Interrupted(self.stopping)
                child = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
                self.live.add(child)
            try:
                return child.wait()
            finally:
                with self.guard:
                    self.live.discard(child)

    def _stop(self, signum: int, frame: object) -> None:
        with self.guard:
            first = self.stopping is None
            self.stopping = signum
            for child in self.live:
                child.send_signal(signum)
        if first:
            raise Interrupted(signum)

    @contextmanager
    def forwarding(self) -> Iterator[None]:
        """Forward SIGTERM / SIGINT to the running fits (main thread only); on leaving, restore the handlers."""
        previous = {s: signal.signal(s, self._stop) for s in SIGNALS}
        try:
            yield
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    def wait(self, grace: float = GRACE_SECONDS) -> None:
        """Wait for every running fit to exit; after ``grace`` seconds, kill what is left."""
        deadline = time.monotonic() + grace
        while True:
            with self.guard:
                live = list(self.live)
            if not live:
                return
            if time.monotonic() > deadline:
                for child in live:
                    child.kill()
            time.sleep(0.2)


@contextmanager
def work_lock(folder: Path) -> Iterator[None]:
    """Hold ``<folder>/.reproduce.lock`` (``WorkLocked`` at once if another process holds it)."""
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / ".reproduce.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise WorkLocked(f"another icprl reproduce (pid {owner}) is running in {folder}; wait for it to finish, "
                             "or pass another --work") from None
        except OSError as e:
            if e.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
                raise
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass  # the pid is for the message only
        yield
    finally:
        os.close(fd)


def run_fit(command: list[str], inputs: str, log: Path, record: Path, threads: int, which: str,
            children: Children) -> dict:
    """Run one fit (``command``, as ``fit_command`` builds it) to its end through ``children`` and write its
    record: the checkpoint its ``which`` line printed, or, if a signal stopped it, ``"status": "interrupted"`` and
    the ``last.ckpt`` it left (then ``Interrupted``). A failed fit is a ``RuntimeError`` naming its log."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "WANDB_MODE": os.environ.get("WANDB_MODE", "disabled")}
    start = time.time()
    code = children.run([sys.executable, "-m", "icprl_lightning", *command[1:]], log, env)
    printed = log.read_text(errors="replace").splitlines()
    if code != 0 and children.stopping is not None:  # stopped by a signal: recorded so that a rerun resumes it
        run_dirs = [line.removeprefix("run directory: ").strip() for line in printed
                    if line.startswith("run directory: ")]
        last = Path(run_dirs[-1]).absolute() / "checkpoints" / "last.ckpt" if run_dirs else None
        write_json_atomic(record, {"status": "interrupted", "command": shlex.join(command), "inputs_sha256": inputs,
                                   "checkpoint": str(last) if last is not None and last.is_file() else ""})
        raise Interrupted(children.stopping)
    if code != 0:
        raise RuntimeError(f"{shlex.join(command)} failed (exit {code}); its log: {log}")
    # "last checkpoint (epoch 0, step 2): PATH" or "best checkpoint (val/loss = 0.5, epoch 3): PATH"
    line = re.compile(rf"^{which} checkpoint(?: \(.*?\))?: (.+)$")
    last = [m.group(1).strip() for m in map(line.match, printed) if m]
    if not last:
        raise RuntimeError(f"{shlex.join(command)} printed no '{which} checkpoint' line; its log: {log}")
    checkpoint = str(Path(last[-1]).absolute())  # the fit ran in this working directory
    result = {"command": shlex.join(command), "inputs_sha256": inputs, "checkpoint": checkpoint,
              "seconds": round(time.time() - start, 1)}
    write_json_atomic(record, result)
    return result
