"""No writer follows a link or writes into a special file (``io.write_atomic``, ``io.staged_directory``): for each
command that writes, a symbolic link at its output is replaced (the file it points to keeps its bytes) or refused,
and a FIFO there is refused with one error naming it, without blocking. Also: ``icprl report`` reads any CSV."""

from __future__ import annotations

import os
import re
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from factories import save_untrained

from icprl_lightning.commands.report import main as report_main
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.interop import export_dataset
from icprl_lightning.evaluation.heldout_rollouts import HeldOutRollouts
from icprl_lightning.hub import export_model
from icprl_lightning.io import NotReplaceableError, save_figure, write_atomic, write_json_atomic
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

pytestmark = pytest.mark.usefixtures("one_thread")
PRECIOUS = "the user's file, never to be overwritten\n"
METRICS = "epoch,step,train/loss,val/loss\n0,1,0.9,\n0,1,,0.8\n1,3,0.5,\n1,3,,0.6\n"


def _run(tmp: Path) -> Path:
    run = tmp / "run"
    run.mkdir(exist_ok=True)
    (run / "metrics.csv").write_text(METRICS)
    return run


def _report_default(tmp: Path) -> None:
    report_main([str(_run(tmp))])


def _evaluate_outputs(tmp: Path) -> None:
    stats = {"return": 10.0, "return_sem": 1.0}
    payload = {"title": "t", "runs": ["ICPO=/r/config.yaml:/r/last.ckpt"], "seeds": [0], "actions": "greedy",
               "reference_rows_from": "ICPO", "results": {"ICPO": {"low": stats, "high": stats}}}
    HeldOutRollouts.write(payload, tmp / "run" / "curves")


def _figure(tmp: Path) -> None:
    from matplotlib.figure import Figure

    save_figure(Figure(), tmp / "run" / "curves.png")


# writer -> (the file it writes, relative to tmp; what writes it). Records, evaluation JSON, renders, analyses and
# baselines write through write_json_atomic / write_atomic / save_figure, tested here once each.
FILE_WRITERS: dict[str, tuple[str, Callable[[Path], None]]] = {
    "icprl report (default figure)": ("run/curves.png", _report_default),
    "icprl report --figure": ("run/out.png", lambda tmp: report_main([str(_run(tmp)), "--figure",
                                                                      str(tmp / "run" / "out.png")])),
    "icprl evaluate outputs (.md)": ("run/curves.md", _evaluate_outputs),
    "icprl evaluate outputs (.json)": ("run/curves.json", _evaluate_outputs),
    "icprl evaluate outputs (.png)": ("run/curves.png", _evaluate_outputs),
    "records and JSON results": ("run/curves.json", lambda tmp: write_json_atomic(tmp / "run" / "curves.json",
                                                                                   {"a": 1})),
    "renders (write_atomic)": ("run/curves.md", lambda tmp: write_atomic(tmp / "run" / "curves.md", "# page\n")),
    "figures (save_figure)": ("run/curves.png", _figure),
}


def _link(tmp: Path, relative: str) -> tuple[Path, Path]:
    victim = tmp / "victim.txt"
    victim.write_text(PRECIOUS)
    target = tmp / relative
    target.parent.mkdir(parents=True, exist_ok=True)
    target.symlink_to(victim)
    return target, victim


@pytest.fixture
def no_hang():
    def hang(*_):
        raise TimeoutError("the writer blocked on a FIFO")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(30)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("writer", sorted(FILE_WRITERS))
def test_a_symlink_at_a_writers_output_is_replaced_not_followed(tmp_path, writer):
    relative, write = FILE_WRITERS[writer]
    target, victim = _link(tmp_path, relative)
    write(tmp_path)
    assert victim.read_text() == PRECIOUS
    assert not target.is_symlink() and target.is_file() and target.stat().st_size > 0


@pytest.mark.parametrize("writer", sorted(FILE_WRITERS))
def test_a_fifo_at_a_writers_output_is_refused_naming_it(tmp_path, writer, no_hang, capsys):
    relative, write = FILE_WRITERS[writer]
    target = tmp_path / relative
    target.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(target)
    try:
        write(tmp_path)
    except SystemExit as e:  # icprl report: one line, exit 2
        assert e.code == 2
        assert f"{target} is a FIFO (named pipe), not a file; refusing to write" in capsys.readouterr().err
    except NotReplaceableError as e:
        assert str(e).startswith(f"{target} is a FIFO (named pipe), not a file; refusing to write")
    else:
        pytest.fail("the writer returned without refusing the FIFO")
    assert target.is_fifo()


def test_a_fifo_is_refused_by_the_library_writers(tmp_path, no_hang):
    for name in ("a.json", "b.md"):
        os.mkfifo(tmp_path / name)
    with pytest.raises(NotReplaceableError, match=f"{tmp_path / 'a.json'} is a FIFO"):
        write_json_atomic(tmp_path / "a.json", {"a": 1})
    with pytest.raises(NotReplaceableError, match=f"{tmp_path / 'b.md'} is a FIFO"):
        write_atomic(tmp_path / "b.md", "text")
    assert (tmp_path / "a.json").is_fifo() and not list(tmp_path.glob(".*tmp*"))


def test_exports_and_imports_refuse_a_link_or_fifo_at_their_output(tmp_path, no_hang):
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=6,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    ckpt = save_untrained(module, tmp_path / "m.ckpt")
    arrays = {"states": np.zeros((4, 3, 2), np.float32), "actions": np.zeros((4, 3), np.int64),
              "alt_actions": np.ones((4, 3), np.int64), "preferred": np.ones((4, 3), np.uint8)}
    victim_dir = tmp_path / "victim"
    victim_dir.mkdir()
    (victim_dir / "keep.txt").write_text(PRECIOUS)
    dataset = import_preferences(arrays, tmp_path / "ds", n_actions=5).path
    for name, write in (("export", lambda out, ow: export_model(ckpt, out, overwrite=ow)),
                        ("import", lambda out, ow: import_preferences(arrays, out, n_actions=5, overwrite=ow)),
                        ("export-data", lambda out, ow: export_dataset(dataset, "parquet", out))):
        link, fifo = tmp_path / f"{name}_link", tmp_path / f"{name}_fifo"
        link.symlink_to(victim_dir)
        os.mkfifo(fifo)
        for out in (link, fifo):
            for overwrite in (False, True):
                with pytest.raises(FileExistsError, match=str(out)):
                    write(out, overwrite)
        assert link.is_symlink() and fifo.is_fifo()
    assert sorted(p.name for p in victim_dir.iterdir()) == ["keep.txt"]
    assert (victim_dir / "keep.txt").read_text() == PRECIOUS


@pytest.mark.parametrize("row, problem", [("1e400,0.5", "line 2 holds a value that is not a number"),
                                          ("1," + "9" * 200_000, "not a readable CSV file"),
                                          ("1,\0", "not a readable CSV file|not a number")])
def test_icprl_report_reads_any_csv_or_says_which_line(tmp_path, capsys, row, problem):
    (tmp_path / "metrics.csv").write_text(f"step,train/loss\n{row}\n")
    with pytest.raises(SystemExit) as exit_:
        report_main([str(tmp_path), "--no-figure"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "icprl report: error:" in err
    assert re.search(problem, err), err


@pytest.mark.parametrize("limit", [4096, 16384])
def test_icprl_export_onto_a_failing_disk_names_the_path_and_leaves_nothing(tmp_path, limit):
    """A real failing write (RLIMIT_FSIZE: every write past ``limit`` bytes is EFBIG), no mock: one line naming the
    export directory, exit 2, and nothing left beside it (no staged copy, no ``.lock``)."""
    import resource
    import subprocess
    import sys

    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=6,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    ckpt = save_untrained(module, tmp_path / "m.ckpt")
    before = sorted(p.name for p in tmp_path.iterdir())
    done = subprocess.run([sys.executable, "-m", "icprl_lightning", "export", str(ckpt), "--out",
                           str(tmp_path / "model")], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "OMP_NUM_THREADS": "1"},
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.endswith(f"icprl export: error: exporting the model to {tmp_path / 'model'} failed: File too "
                                "large; nothing was written\n"), done.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == before
