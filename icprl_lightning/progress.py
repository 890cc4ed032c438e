"""Progress of a long loop (data generation, rollouts, training): a bar in a terminal, plain lines elsewhere.

A rich bar redraws one line with carriage returns: in a CI log, a ``tee``'d or ``nohup``'d file or a
notebook it shows nothing until the loop ends. ``Progress`` therefore draws rich's transient bar only
when stdout is a terminal, and otherwise prints one plain line at each 10% of the work or every 30 s,
whichever comes first (never two lines within ``min_seconds``, so fast loops do not flood a log)::

    train contexts: 40% (40/100 steps) 12.3 steps/s, elapsed 3s, ETA 5s

and a last line when the loop took long enough to be worth one (or printed before). ``track`` wraps an
iterable, as ``rich.progress.track`` does.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import IO, TypeVar

T = TypeVar("T")

# Defaults of every tracker, read when one is made (a test may lower them to see lines from a fast loop).
EVERY_PERCENT = 10.0  # a plain line at each this share of the work ...
EVERY_SECONDS = 30.0  # ... or after this long without one, whichever comes first,
MIN_SECONDS = 2.0  # but never two lines closer than this; also the shortest loop worth a last line


def format_duration(seconds: float) -> str:
    """``42s``, ``3m05s``, ``2h04m``: short enough for a progress line."""
    if not math.isfinite(seconds):
        return "?"
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


def format_rate(count: float, seconds: float, unit: str) -> str:
    """``12.3 steps/s``, or ``4.5 s/step`` when slower than one a second (``unit``: singular)."""
    if count <= 0 or seconds <= 0:
        return f"? {plural(unit)}/s"
    rate = count / seconds
    return f"{rate:.3g} {plural(unit)}/s" if rate >= 1 else f"{1 / rate:.3g} s/{unit}"


def plural(unit: str) -> str:
    """``step`` -> ``steps``, ``batch`` -> ``batches``."""
    return unit + ("es" if unit.endswith(("s", "x", "ch", "sh")) else "s")


def is_terminal(stream: IO[str] | None = None) -> bool:
    """Whether ``stream`` (default stdout) is an interactive terminal (a notebook's stdout is not)."""
    stream = sys.stdout if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


class Progress:
    """Counts the work done in a loop and shows it; see the module docstring.

    Args:
        total: units of work in the loop (None: unknown; lines then show count and rate only).
        description: what the loop does, the start of every line.
        unit: the name of one unit of work in lines (``step``, ``batch``, ``episode``).
        enabled: False shows nothing.
        interactive: a rich bar (True) or plain lines (False); None: a bar iff ``stream`` is a terminal.
        every_percent: a plain line each time this share of ``total`` more is done (None: ``EVERY_PERCENT``).
        every_seconds: a plain line at least this often while work advances (None: ``EVERY_SECONDS``).
        min_seconds: no two plain lines closer than this; also the shortest loop worth a last line (None:
            ``MIN_SECONDS``).
        stream: where plain lines go (default stderr, read when the tracker is made: progress is not output,
            so a command's stdout, e.g. ``icprl evaluate``'s tables, stays clean to pipe).
        clock: seconds, monotonic (tests pass a fake one).
    """

    def __init__(self, total: int | None, description: str, unit: str = "step", enabled: bool = True,
                 interactive: bool | None = None, every_percent: float | None = None,
                 every_seconds: float | None = None, min_seconds: float | None = None,
                 stream: IO[str] | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        every_percent = EVERY_PERCENT if every_percent is None else every_percent
        if total is not None and total < 0:
            raise ValueError(f"Progress: total must be >= 0 or None, got {total}")
        if not 0 < every_percent <= 100:
            raise ValueError(f"Progress: every_percent must be in (0, 100], got {every_percent}")
        self.total, self.description, self.unit = total, description, unit
        self.every_percent = every_percent
        self.every_seconds = EVERY_SECONDS if every_seconds is None else every_seconds
        self.min_seconds = MIN_SECONDS if min_seconds is None else min_seconds
        self.stream = sys.stderr if stream is None else stream
        self.clock = clock
        self.enabled = enabled
        self.interactive = is_terminal(self.stream) if interactive is None else interactive
        self.done = 0
        self.lines = 0  # plain lines printed so far
        self._bar = None
        self._task = None
        self._start = self._last_line = clock()
        self._next_mark = self._mark_after(0)
        if enabled and self.interactive:
            self._start_bar()

    def _start_bar(self) -> None:
        from rich.progress import Progress as RichProgress

        self._bar = RichProgress(transient=True)  # nests under another live display (e.g. Lightning's rich bar)
        self._bar.start()
        self._task = self._bar.add_task(self.description, total=self.total)

    def _mark_after(self, done: int) -> float:
        """The count at which the next ``every_percent`` line is due (inf without a total)."""
        if not self.total:
            return math.inf
        step = self.total * self.every_percent / 100
        return (math.floor(done / step) + 1) * step

    def line(self) -> str:
        """The plain line for the work done so far."""
        elapsed = self.clock() - self._start
        rate = format_rate(self.done, elapsed, self.unit)
        if self.total:
            percent = 100 * self.done / self.total
            left = (self.total - self.done) * elapsed / self.done if self.done else math.inf
            eta = "" if self.done >= self.total else f", ETA {format_duration(left)}"
            return (f"{self.description}: {percent:.0f}% ({self.done}/{self.total} {plural(self.unit)}) {rate}, "
                    f"elapsed {format_duration(elapsed)}{eta}")
        return f"{self.description}: {self.done} {plural(self.unit)} {rate}, elapsed {format_duration(elapsed)}"

    def _print(self, now: float) -> None:
        print(self.line(), file=self.stream, flush=True)
        self.lines += 1
        self._last_line = now
        self._next_mark = self._mark_after(self.done)

    def advance(self, n: int = 1) -> None:
        """``n`` more units done; a plain line when one is due."""
        self.done += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(self._task, advance=n)
            return
        now = self.clock()
        since = now - self._last_line
        finished = self.total is not None and self.done >= self.total
        if not finished and since >= self.min_seconds and (self.done >= self._next_mark or since >= self.every_seconds):
            self._print(now)

    def close(self) -> None:
        """End of the loop: remove the bar, or print the last line (if the loop was long or printed before)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
            return
        if not self.enabled:
            return
        now = self.clock()
        if self.lines or now - self._start >= self.min_seconds:
            self._print(now)
            self.enabled = False  # closed: a second close prints nothing

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def track(items: Iterable[T], description: str, total: int | None = None, **options) -> Iterator[T]:
    """Yield ``items`` while a ``Progress`` (``options``: its arguments) counts them; ``total`` defaults to
    ``len(items)`` when it has one."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with Progress(total, description, **options) as progress:
        for item in items:
            yield item
            progress.advance()
