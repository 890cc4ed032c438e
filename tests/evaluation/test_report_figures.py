"""The evaluation report's figures say what their error bars are and keep long titles inside the figure."""

from __future__ import annotations

from icprl_lightning.evaluation.report import _error_bars, figure_title, rollout_figure


def _payload(checkpoints_per_run: int) -> dict:
    ckpts = ",".join(f"/r/seed{s}/last.ckpt" for s in range(checkpoints_per_run))
    stats = {"return": 10.0, "return_sem": 1.0}
    return {"title": "a table whose title is far longer than one line of a small figure can hold " * 2,
            "runs": [f"ICPO=/r/config.yaml:{ckpts}"], "seeds": [0], "actions": "greedy",
            "results": {"ICPO": {"low": stats, "high": stats}}}


def test_error_bars_are_over_training_seeds_only_when_a_run_has_several():
    assert "training seeds" in _error_bars(_payload(3))
    assert _error_bars(_payload(1)) == "mean ± sem over held-out tasks"


def test_a_long_title_is_wrapped_to_the_figure_width():
    lines = figure_title("word " * 100, fig_width_inches=5.0).splitlines()
    assert len(lines) > 1 and all(len(line) <= 80 for line in lines)


def test_the_rollout_figure_is_written(tmp_path):
    rollout_figure(_payload(3), tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 1000


def test_bar_colors_never_repeat_within_a_figure():
    from icprl_lightning.evaluation.report import _bar_colors

    for n in (3, 10, 11, 20):
        colors = [str(c) for c in _bar_colors(n)]
        assert len(set(colors)) == n, n
