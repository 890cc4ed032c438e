"""Progress when stderr is not a terminal: plain lines from ``progress.Progress`` (data generation, rollouts)
and from the ``TrainingProgress`` callback (within an epoch without a bar, and one summary per epoch).

The trackers run on a fake clock here, so the lines they print are exact; the generation test runs the
real recipe with the floor between lines lowered, and reads stderr as a log would.
"""

from __future__ import annotations

import io
import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from factories import darkroom_data
from rich.progress import Progress as RichProgress

from icprl_lightning import progress
from icprl_lightning.callbacks.progress import TrainingProgress
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.evaluation.duels import dts_duels
from icprl_lightning.progress import Progress, format_duration, track


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _run(total: int | None, seconds_per_unit: float, units: int | None = None, **options) -> list[str]:
    """The lines of a loop of ``units`` (default ``total``) units, each taking ``seconds_per_unit``."""
    clock, out = FakeClock(), io.StringIO()
    with Progress(total, "gen", stream=out, clock=clock, **options) as p:
        for _ in range(total if units is None else units):
            clock.now += seconds_per_unit
            p.advance()
    return out.getvalue().splitlines()


def test_a_log_gets_a_line_every_ten_percent_with_count_rate_and_eta():
    lines = _run(100, 1.0)  # 100 s: a line at each 10%, then the last one
    assert len(lines) == 10
    assert lines[0] == "gen: 10% (10/100 steps) 1 steps/s, elapsed 10s, ETA 1m30s"
    assert lines[4].startswith("gen: 50% (50/100 steps)")
    assert lines[-1] == "gen: 100% (100/100 steps) 1 steps/s, elapsed 1m40s"  # done: no ETA


def test_a_slow_loop_gets_a_line_every_thirty_seconds():
    lines = _run(1000, 7.0, units=30)  # 10% would take 700 s: the 30 s rule speaks first
    assert [line.split(" ")[2] for line in lines[:3]] == ["(5/1000", "(10/1000", "(15/1000"]
    assert "7 s/step" in lines[0] and "ETA 1h56m" in lines[0]


def test_a_fast_loop_prints_nothing_and_lines_are_never_closer_than_the_floor():
    assert _run(1000, 0.001) == []  # 1 s in all: below the floor, not worth a line
    lines = _run(100, 0.05)  # 5 s: 10% marks every 0.5 s, but at most one line per 2 s
    assert len(lines) == 3 and lines[-1].startswith("gen: 100%")


def test_unknown_total_prints_count_and_rate():
    clock, out = FakeClock(), io.StringIO()
    with Progress(None, "gen", unit="batch", stream=out, clock=clock) as p:
        for _ in range(40):
            clock.now += 1.0
            p.advance()
    assert out.getvalue().splitlines()[0] == "gen: 30 batches 1 batches/s, elapsed 30s"


def test_terminal_and_disabled_trackers_print_no_plain_line():
    assert _run(100, 1.0, interactive=True) == [] and _run(100, 1.0, enabled=False) == []
    with RichProgress():  # under another live display (e.g. Lightning's rich bar) the bar nests
        assert _run(100, 1.0, interactive=True) == []


@pytest.mark.parametrize(("kwargs", "match"), [({"total": -1}, "total must be >= 0"),
                                               ({"total": 5, "every_percent": 0}, "every_percent must be in")])
def test_bad_arguments_are_one_clear_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Progress(description="gen", **kwargs)


def test_track_counts_a_sized_iterable():
    clock, out = FakeClock(), io.StringIO()
    for _ in track(range(4), "gen", stream=out, clock=clock, min_seconds=0):
        clock.now += 1.0
    assert out.getvalue().splitlines()[-1] == "gen: 100% (4/4 steps) 1 steps/s, elapsed 4s"


def test_format_duration():
    assert [format_duration(s) for s in (0.4, 59, 61, 3599, 7500)] == ["0s", "59s", "1m01s", "59m59s", "2h05m"]


def test_data_generation_prints_plain_lines_into_a_log(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(progress, "MIN_SECONDS", 0.0)  # a tiny dataset's loops are fast: show every 10%
    dm = darkroom_data(root_dir=str(tmp_path), trajectories_per_task=2, val_trajectories_per_task=1,
                       eval_contexts_per_task=1, calibration_episodes=2, n_train_tasks=10, n_test_tasks=5,
                       progress=True)
    dm.prepare_data()
    out = capsys.readouterr().err  # progress goes to stderr; pytest's capture is not a terminal, as a log is not
    for split in ("train contexts", "val contexts", "eval low", "eval high"):
        assert re.search(rf"^{split}: 10% \(10/100 steps\) .* steps/s, elapsed \d+s, ETA \d+s$", out, re.M), out
        assert re.search(rf"^{split}: 100% \(100/100 steps\)", out, re.M), out
    assert "\r" not in out  # no bar redraws in a log


def test_dts_duels_count_their_prefixes_in_a_log(monkeypatch, capsys):
    monkeypatch.setattr(progress, "MIN_SECONDS", 0.0)
    g = torch.Generator().manual_seed(0)
    first = torch.randint(0, 5, (4, 20), generator=g)
    context = StepPreferenceContext(torch.zeros(4, 20, 0), first, (first + 1) % 5,
                                    torch.randint(0, 2, (4, 20), generator=g).float())
    dts_duels(context, 5, np.random.default_rng(0))
    out = capsys.readouterr().err
    assert re.search(r"^DTS duels: 100% \(20/20 prefixes\)", out, re.M), out
    dts_duels(context, 5, np.random.default_rng(0), progress=False)
    assert capsys.readouterr().err == ""


# ---- the training callback, hook by hook on a stand-in trainer ---------------------------------------------

class Bar:
    def __init__(self) -> None:
        self.printed: list[str] = []

    def print(self, line: str) -> None:
        self.printed.append(line)


def _trainer(bar: Bar | None) -> SimpleNamespace:
    return SimpleNamespace(progress_bar_callback=bar, is_global_zero=True, num_training_batches=10, current_epoch=0,
                           max_epochs=3, global_step=0, callback_metrics={}, sanity_checking=False)


def _epoch(callback: TrainingProgress, trainer: SimpleNamespace, clock: FakeClock, validate: bool = True) -> None:
    callback.on_train_epoch_start(trainer, None)
    for i in range(10):
        clock.now += 1.0
        trainer.global_step += 1
        callback.on_train_batch_end(trainer, None, {"loss": torch.tensor(float(i))}, None, i)
    if validate:
        callback.on_validation_start(trainer, None)
        clock.now += 5.0
        trainer.callback_metrics["val/loss"] = torch.tensor(0.25)
        callback.on_validation_end(trainer, None)
    callback.on_train_epoch_end(trainer, None)


def test_without_a_bar_training_prints_progress_lines_and_an_epoch_summary():
    clock, out = FakeClock(), io.StringIO()
    callback, trainer = TrainingProgress(min_seconds=0, stream=out, clock=clock), _trainer(None)
    callback.on_fit_start(trainer, None)
    _epoch(callback, trainer, clock)
    lines = out.getvalue().splitlines()
    assert lines[0] == "epoch 1/3: 10% (1/10 batches) 1 batches/s, elapsed 1s, ETA 9s"
    assert len(lines) == 10  # 9 progress lines (the summary replaces the 100% one) and the summary
    # mean of the step losses 0..9, the validated val/loss, 10 steps over 10 s of training (validation excluded)
    assert lines[-1] == "epoch 1/3: train loss 4.5, val loss 0.25, 1 steps/s, elapsed 15s"
    trainer.current_epoch += 1
    _epoch(callback, trainer, clock, validate=False)  # the previous epoch's val/loss is not this epoch's
    assert out.getvalue().splitlines()[-1] == "epoch 2/3: train loss 4.5, 1 steps/s, elapsed 25s"


def test_with_a_bar_only_the_summary_is_printed_through_the_bar():
    clock, out, bar = FakeClock(), io.StringIO(), Bar()
    callback, trainer = TrainingProgress(min_seconds=0, stream=out, clock=clock), _trainer(bar)
    callback.on_fit_start(trainer, None)
    _epoch(callback, trainer, clock)
    assert out.getvalue() == ""
    assert bar.printed == ["epoch 1/3: train loss 4.5, val loss 0.25, 1 steps/s, elapsed 15s"]


def test_only_rank_zero_prints():
    clock, out = FakeClock(), io.StringIO()
    callback, trainer = TrainingProgress(min_seconds=0, stream=out, clock=clock), _trainer(None)
    trainer.is_global_zero = False
    _epoch(callback, trainer, clock)
    assert out.getvalue() == ""
